//! `fit`: add effects, refit, write the new model, and measure the errors before and after.
//!
//! By default the plant's base parameters are refitted together with the added effects
//! (ordinary least squares on the inverse-dynamics equation, one nonlinear parameter per effect
//! chosen by cross-validated grid search), and so are the coefficients of the effects already in
//! the model (their nonlinear parameters kept): what is added competes with the whole model
//! refitted, as in `diagnose`. `free` narrows the refitted parameters (base keys, effect ids).
//! The controller is taken as given.

use std::collections::BTreeMap;

use serde_json::{json, Value};

use feedloop_model::units::sig;
use feedloop_plant::effects::read_effects;

use super::adder::{Adder, Held};
use super::base::{BaseClass, BaseParam};
use super::compare::{classify, equation_error, SegKind};
use super::controller::ControllerChannel;
use super::data::AxisData;
use super::effects::{channel, Channel, Effect, EffectId, WbModel};
use super::gap_sizing::size_gaps_on_window;
use super::lsq::{blocks, normals};
use super::refit::{flat, spanned_base, Released};
use super::signal::nrmse_pct;
use super::window::window_sim;
use super::WorkbenchError;

/// Error figures of one model on one trace.
#[derive(Debug, Clone, Copy, Default)]
pub struct Errors {
    /// Equation-error NRMSE, % (None without torque).
    pub equation_nrmse_pct: Option<f64>,
    /// Relative equation error `||e|| / ||y||`, %.
    pub relative_error_pct: Option<f64>,
    /// Equation-error NRMSE over the samples where the axis moves (standstills left out: there
    /// dry friction takes whatever the loop applies), %.
    pub equation_moving_nrmse_pct: Option<f64>,
    /// Windowed-simulation NRMSE of the headline channel, %.
    pub window_sim_nrmse_pct: Option<f64>,
    /// NRMSE of the recorded torque against the controller law, % (None without torque or
    /// without a controller in the model).
    pub controller_nrmse_pct: Option<f64>,
}

impl Errors {
    /// Errors of `model` on `d`.
    pub fn of(model: &WbModel, d: &AxisData, window_s: f64) -> Self {
        let eq = d.torque.as_ref().map(|y| equation_error(model, d, y));
        let ws = window_sim(model, d, window_s);
        let moving = eq.as_ref().and_then(|e| {
            let kinds = classify(d);
            let (a, b) = d.range;
            let rows: Vec<usize> = (a..b)
                .filter(|k| kinds.get(*k).is_some_and(|s| *s != SegKind::Standstill))
                .collect();
            (!rows.is_empty()).then(|| {
                let m: Vec<f64> = rows.iter().map(|k| e.measured[*k]).collect();
                let r: Vec<f64> = rows.iter().map(|k| e.residual[*k]).collect();
                nrmse_pct(&m, &r)
            })
        });
        Self {
            equation_nrmse_pct: eq.as_ref().map(|e| e.nrmse_pct),
            relative_error_pct: eq.as_ref().map(|e| e.relative_error_pct),
            equation_moving_nrmse_pct: moving,
            window_sim_nrmse_pct: ws.headline_nrmse_pct(),
            controller_nrmse_pct: ControllerChannel::new(model, d).map(|c| c.nrmse_pct),
        }
    }

    /// As JSON.
    pub fn to_json(&self) -> Value {
        json!({
            "equation_nrmse_pct": self.equation_nrmse_pct,
            "relative_error_pct": self.relative_error_pct,
            "equation_moving_nrmse_pct": self.equation_moving_nrmse_pct,
            "window_sim_nrmse_pct": self.window_sim_nrmse_pct,
            "controller_nrmse_pct": self.controller_nrmse_pct,
        })
    }
}

/// Result of [`fit`].
#[derive(Debug, Clone)]
pub struct FitResult {
    /// The new model.
    pub model: WbModel,
    /// Effect ids added.
    pub added: Vec<String>,
    /// Every fitted parameter (base and effects) under the model file's keys.
    pub params: BTreeMap<String, f64>,
    /// Errors of the input model.
    pub before: Errors,
    /// Errors of the new model.
    pub after: Errors,
    /// What the fit held, clamped or could not determine (each a sentence).
    pub warnings: Vec<String>,
    /// The model's effects that an added effect contains and so replaced (ids).
    pub replaced: Vec<String>,
}

impl FitResult {
    /// The JSON printed by `fit --json`.
    pub fn to_json(&self) -> Value {
        json!({
            "added": self.added,
            "params": self.params,
            "error_before": self.before.to_json(),
            "error_after": self.after.to_json(),
            "warnings": self.warnings,
        })
    }
}

/// The entries of flag values given as comma-separated lists (`--add a,b --add c`), trimmed,
/// empty ones dropped.
fn comma_list(list: &[String]) -> impl Iterator<Item = &str> {
    list.iter()
        .flat_map(|s| s.split(','))
        .map(str::trim)
        .filter(|s| !s.is_empty())
}

/// Checks effect ids given with `--add`.
pub fn parse_effects(list: &[String]) -> Result<Vec<EffectId>, WorkbenchError> {
    let mut out = Vec::new();
    for s in comma_list(list) {
        let Some(id) = EffectId::parse(s) else {
            return Err(WorkbenchError::BadArgument {
                arg: format!("--add {s}"),
                reason: format!(
                    "unknown effect{} (effects of the library: {})",
                    EffectId::did_you_mean(s),
                    EffectId::list(|_| true)
                ),
            });
        };
        if !out.contains(&id) {
            out.push(id);
        }
    }
    Ok(out)
}

/// The model an addition of `add` starts from: an added effect that contains one the model
/// has (directional or Stribeck friction and a Coulomb friction) replaces it instead of being
/// fitted as a correction of it; an added effect whose columns hold a base parameter's (the
/// damping beside a friction with viscous slopes) carries that parameter whole: it is set to
/// zero and refitted as the effect's coefficient, which then keeps its physical sign. Each
/// change is said in `warnings`; the effects replaced are returned beside the model.
fn prepared(
    model: &WbModel,
    d: &AxisData,
    add: &[EffectId],
    free_keys: &[BaseParam],
    warnings: &mut Vec<String>,
) -> (WbModel, Vec<String>) {
    let mut work = model.clone();
    let mut replaced = Vec::new();
    for &id in add {
        if let Some((reduced, old)) = work
            .without_superseded(id)
            .filter(|(_, s)| !add.contains(s))
        {
            work = reduced;
            warnings.push(format!("{id} replaces the model's {old} (it contains it)"));
            replaced.push(old.to_string());
        }
    }
    let cols: Vec<&[f64]> = free_keys.iter().map(|k| k.column(d)).collect();
    for &id in add {
        for i in spanned_base(id, d, &cols) {
            let p = free_keys[i];
            if let Some((_, v)) = work.base.iter_mut().find(|(k, v)| *k == p && *v != 0.0) {
                warnings.push(format!("{p} = {} moved into {id} (set to 0)", sig(*v)));
                *v = 0.0;
            }
        }
    }
    update_plant(&mut work);
    (work, replaced)
}

/// Adds effects by id (nonlinear parameters chosen by cross-validated grid search) and refits:
/// the model the addition starts from ([`prepared`]), each effect's best variant on the channel
/// where it shows ([`Adder::effect`]), then the joint refit ([`fit_with`]) with what those refits
/// held still held ([`Adder::narrowed`]).
pub fn fit(
    model: &WbModel,
    d: &AxisData,
    add: &[EffectId],
    free: Option<&[String]>,
    window_s: f64,
) -> Result<FitResult, WorkbenchError> {
    let mut warnings: Vec<String> = Vec::new();
    let original = model;
    let (free_keys, free_effects) = free_keys(model, d, free)?;
    let (work, replaced) = prepared(model, d, add, &free_keys, &mut warnings);
    let moved = work.base != model.base || work.effects.len() != model.effects.len();
    let model = &work;
    // each effect is searched beside those added before it (their coefficients refitted with
    // the base parameters): a friction and a gravity torque that each hide the other are found
    // together, the nonlinear parameter of the second (an unbalance's period) chosen with the
    // first in place
    let mut effects: Vec<Effect> = Vec::new();
    let mut search = model.clone();
    let mut held = Held::default();
    for &id in add {
        let only: Option<Vec<EffectId>> = free_effects.as_ref().map(|f| {
            let mut v = f.clone();
            v.extend(effects.iter().map(|e| e.id));
            v
        });
        let rel = Released::of(&search, d, only.as_deref());
        let mut adder = Adder::new(&search, d, &free_keys, &rel);
        let e = adder.effect(id, &mut warnings)?;
        held.base.extend(adder.held_all);
        held.effects.extend(adder.held_effects);
        if channel(e.id) != Channel::Deflection {
            search.effects.push(e.clone());
        }
        effects.push(e);
    }
    // the base parameters the effects' own refits held (what the data cannot tell apart from
    // them) stay held in the joint refit: the same refit that diagnose ranks by
    let narrowed = held.narrowed(model, &free_keys, free_effects.as_deref());
    let free = narrowed.as_deref().or(free);
    let mut r = fit_with(model, d, effects, free, window_s)?;
    // the replaced friction's side served its replacement's search; the model written carries
    // every friction with its own side
    r.model.replaced_side = None;
    if moved {
        r.before = Errors::of(original, d, window_s);
    }
    warnings.append(&mut r.warnings);
    r.warnings = warnings;
    r.replaced = replaced;
    Ok(r)
}

/// Most base parameters and model effects' coefficients whose subsets the constrained refit of
/// [`fit_with`] tries holding (2^N refits of a small regression).
const MAX_HELD_SEARCH: usize = 12;

/// The parameters a refit changes: the base parameters, and the effects already in the model
/// whose coefficients are refitted beside them (`None`: all of them). By default all; `free`
/// narrows both (a base parameter's key, or the id of an effect of the model).
fn free_keys(
    model: &WbModel,
    d: &AxisData,
    free: Option<&[String]>,
) -> Result<(Vec<BaseParam>, Option<Vec<EffectId>>), WorkbenchError> {
    let keys = BaseParam::of_kind(model.kind());
    match free {
        None => Ok((
            keys.iter()
                .copied()
                .filter(|k| d.has_motor() || !k.on_load())
                .collect(),
            None,
        )),
        Some(list) => {
            let mut out = Vec::new();
            let mut ids = Vec::new();
            for s in comma_list(list) {
                if let Some(p) = BaseParam::parse(model.kind(), s) {
                    out.push(p);
                    continue;
                }
                if let Some(id) =
                    EffectId::parse(s).filter(|id| model.effects.iter().any(|e| e.id == *id))
                {
                    ids.push(id);
                    continue;
                }
                let mut accepted: Vec<&str> = keys.iter().map(|k| k.key()).collect();
                accepted.extend(model.effects.iter().map(|e| e.id.id()));
                return Err(WorkbenchError::BadArgument {
                    arg: format!("--free {s}"),
                    reason: format!(
                        "neither a base parameter of a {} model nor an effect of this model (free parameters: {})",
                        model.kind().id(),
                        accepted.join(", ")
                    ),
                });
            }
            Ok((out, Some(ids)))
        }
    }
}

/// Adds the given effects (nonlinear parameters fixed as given, coefficients refitted) and
/// refits the free base parameters jointly with them: torque-path effects first (they change
/// the target), the joint refit on the torque ([`joint_refit`]), the parameters fitted
/// ([`fitted_params`]), and a check that the plant accepts the model ([`plant_accepts`]).
pub fn fit_with(
    model: &WbModel,
    d: &AxisData,
    effects: Vec<Effect>,
    free: Option<&[String]>,
    window_s: f64,
) -> Result<FitResult, WorkbenchError> {
    let before = Errors::of(model, d, window_s);
    let (free_keys, free_effects) = free_keys(model, d, free)?;
    let rel = Released::of(model, d, free_effects.as_deref());
    let mut warnings: Vec<String> = Vec::new();
    let mut new = model.clone();
    // torque-path effects first: they change the target
    for e in effects
        .iter()
        .filter(|e| channel(e.id) == Channel::TorquePath)
    {
        new.effects.push(e.clone());
    }
    let mut params = BTreeMap::new();
    if d.torque.is_some() {
        let refit = JointRefit {
            model,
            d,
            effects: &effects,
            free_keys: &free_keys,
            rel: &rel,
        };
        refit.run(&mut new, &mut params, &mut warnings);
    } else {
        for e in effects.iter().filter(|e| channel(e.id) == Channel::Torque) {
            new.effects.push(e.clone());
        }
    }
    for e in effects
        .iter()
        .filter(|e| channel(e.id) == Channel::Deflection)
    {
        new.effects.push(e.clone());
    }
    if effects.iter().any(|e| e.id == EffectId::Backlash) {
        // the simulation runs on the parsed plant: bring the refitted base values there first
        update_plant(&mut new);
        size_gaps_on_window(&mut new, d, window_s);
    }
    let added: Vec<String> = effects.iter().map(|e| e.id.id().to_string()).collect();
    fitted_params(&new, &effects, &rel, &free_keys, &mut params);
    // the parsed model file must reflect the new base values for the simulation
    update_plant(&mut new);
    plant_accepts(&new, &effects, &added)?;
    let after = Errors::of(&new, d, window_s);
    Ok(FitResult {
        model: new,
        added,
        params,
        before,
        after,
        warnings,
        replaced: Vec::new(),
    })
}

/// The joint refit of [`fit_with`] on the torque: the free base parameters, the model's own
/// effects' coefficients ([`Released`]) and the added torque-channel effects' coefficients in
/// one regression, whose columns are in that order.
struct JointRefit<'a> {
    model: &'a WbModel,
    d: &'a AxisData,
    effects: &'a [Effect],
    free_keys: &'a [BaseParam],
    rel: &'a Released,
}

impl JointRefit<'_> {
    /// Refits into `new` (which holds the torque-path effects already; the torque-channel
    /// effects are added fitted), the base parameters into `params`, what was held into
    /// `warnings`.
    fn run(
        &self,
        new: &mut WbModel,
        params: &mut BTreeMap<String, f64>,
        warnings: &mut Vec<String>,
    ) {
        let (model, d, free_keys, rel) = (self.model, self.d, self.free_keys, self.rel);
        let y_app = new.applied(d).unwrap_or_default();
        // target: the residual of the current model; base parameters are refitted as changes
        // from their current values (a direction the data cannot see stays where it was)
        let f = new.torque_needed(d);
        let target: Vec<f64> = y_app.iter().zip(&f).map(|(a, b)| a - b).collect();
        let mut ecols: Vec<Vec<f64>> = Vec::new();
        let mut slots = Vec::new();
        for (i, e) in self
            .effects
            .iter()
            .enumerate()
            .filter(|(_, e)| channel(e.id) == Channel::Torque)
        {
            for (j, col) in e.columns(d).into_iter().take(e.free_count()).enumerate() {
                slots.push((i, j));
                ecols.push(col);
            }
        }
        // a constrained least squares over the base parameters: every subset of them is held at
        // its values in turn, and the fit that keeps the free ones in range (no inertia below a
        // tenth of its value, no negative damping) with the fewest held, then the smallest
        // residual, wins. Two nearly collinear columns (the motor's and the load's damping on an
        // axis whose encoders travel together) swing to opposite extremes; holding whichever is
        // found first could hold the wrong one.
        let mut refs: Vec<&[f64]> = free_keys.iter().map(|k| k.column(d)).collect();
        refs.extend(rel.cols.iter().map(|c| c.as_slice()));
        refs.extend(ecols.iter().map(|c| c.as_slice()));
        let all = normals(&refs, &target, &blocks(d.range, 1))
            .into_iter()
            .next()
            .expect("one block");
        let (nk, nr) = (free_keys.len(), rel.cols.len());
        let split = unseen_split(free_keys, d);
        let (keep, delta) = constrained(&all, model, free_keys, rel, split);
        // said when holding it mattered: a free split would have moved the motor's inertia by
        // more than a percent
        let mattered = split.filter(|i| {
            let (_, free) = constrained(&all, model, free_keys, rel, None);
            free[*i].abs() > 0.01 * model.base_value(free_keys[*i]).abs()
        });
        for (i, key) in free_keys.iter().enumerate() {
            let v = model.base_value(*key) + delta[i];
            if let Some(b) = new.base.iter_mut().find(|(kk, _)| kk == key) {
                b.1 = v;
            }
        }
        rel.apply(new, &delta[nk..nk + nr]);
        for key in free_keys {
            params.insert(key.key().to_string(), new.base_value(*key));
        }
        if let Some(w) = self.held_warning(&keep, split) {
            warnings.push(w);
        }
        if mattered.is_some() {
            warnings.push(format!(
                "{} held at its value: on this record the motor's and the load's accelerations are one column (the transmission barely deflects), so the data determine only the total inertia; its change went to {}",
                BaseParam::JmKgm2.key(),
                BaseParam::JlKgm2.key()
            ));
        }
        let mut fitted = self.effects.to_vec();
        for (s, (i, j)) in slots.iter().enumerate() {
            fitted[*i].coef[*j] = delta[nk + nr + s];
        }
        for e in fitted
            .into_iter()
            .filter(|e| channel(e.id) == Channel::Torque)
        {
            new.effects.push(e);
        }
    }

    /// The sentence naming the base parameters and model effects the refit held (those of
    /// whose columns `keep` lists none), when it held any.
    fn held_warning(&self, keep: &[usize], split: Option<usize>) -> Option<String> {
        let (free_keys, nk) = (self.free_keys, self.free_keys.len());
        let mut held: Vec<String> = (0..nk)
            .filter(|i| !keep.contains(i) && Some(*i) != split)
            .map(|i| free_keys[i].key().to_string())
            .collect();
        for (k, (e, _)) in self.rel.slots.iter().enumerate() {
            let name = self.model.effects[*e].id.id().to_string();
            if !keep.contains(&(nk + k)) && !held.contains(&name) {
                held.push(name);
            }
        }
        (!held.is_empty()).then(|| format!(
            "{} held at {} value: the joint refit took {} out of {} range (an inertia below a tenth of its value, a negative damping, or a friction level of the other sign), which these data cannot determine together with the added effects",
            held.join(", "),
            if held.len() == 1 { "its" } else { "their" },
            if held.len() == 1 { "it" } else { "them" },
            if held.len() == 1 { "its" } else { "their" },
        ))
    }
}

/// Into `params`: the parameters of the added `effects` and of the model's effects refitted
/// (`rel`) under the model file's keys (`effects.ID.KEY` where a key is taken), and the free
/// base parameters' new values.
fn fitted_params(
    new: &WbModel,
    effects: &[Effect],
    rel: &Released,
    free_keys: &[BaseParam],
    params: &mut BTreeMap<String, f64>,
) {
    let kind = new.kind();
    let r = new.file.plant.motor_per_load();
    for (_, e) in new.effects.iter().enumerate().filter(|(i, e)| {
        effects.iter().any(|a| a.id == e.id) || rel.slots.iter().any(|(r, _)| r == i)
    }) {
        for (k, v) in flat(&e.to_table(kind, r)) {
            let key = if params.contains_key(&k) {
                format!("effects.{}.{k}", e.id)
            } else {
                k
            };
            params.insert(key, v);
        }
    }
    for (k, v) in &new.base {
        if free_keys.contains(k) {
            params.insert(k.key().to_string(), *v);
        }
    }
}

/// What is written must be a model the plant accepts: a fitted parameter outside its physical
/// range (a negative friction level, say) refuses the effect it belongs to (of `effects`, whose
/// ids are `added`).
fn plant_accepts(
    new: &WbModel,
    effects: &[Effect],
    added: &[String],
) -> Result<(), WorkbenchError> {
    let Err(e) = read_effects(&new.sim_file()) else {
        return Ok(());
    };
    let effect = effects
        .iter()
        .map(|e| e.id)
        .find(|id| e.key.contains(id.id()))
        .map(|id| id.to_string())
        .unwrap_or_else(|| added.join(", "));
    Err(WorkbenchError::EffectRefused {
        effect,
        reason: format!(
            "the model it would write is one the plant refuses (`{}`: {}){}",
            e.key,
            e.reason,
            if e.reason.starts_with("must be") {
                ": a fitted value outside its physical range means these data do not show the effect"
            } else {
                ""
            }
        ),
        advice: "nothing was written; run `feedloop diagnose`, refit with other base parameters free (--free), or leave it out".into(),
    })
}

/// The constrained least squares of [`fit_with`] on the normal equations `all`, whose columns
/// are the free base parameters, then the model's own effects' coefficients ([`Released`]),
/// then the added effects': every subset of the first two groups is held at its values in turn
/// (the released ones only while their subsets are few enough to try), a fit counts when every
/// free one stays in range, and the one with the fewest held, then the smallest residual, wins.
/// Returns the columns kept and the change of every column (0 for a held one).
fn constrained(
    all: &super::lsq::Normal,
    model: &WbModel,
    free_keys: &[BaseParam],
    rel: &Released,
    held: Option<usize>,
) -> (Vec<usize>, Vec<f64>) {
    let p = all.xty.len();
    let (nk, nr) = (free_keys.len(), rel.cols.len());
    let nh = if nk + nr <= MAX_HELD_SEARCH {
        nk + nr
    } else {
        nk
    };
    let in_range = |i: usize, delta: f64| {
        if i >= nk {
            return rel.in_range(model, i - nk, delta);
        }
        let key = free_keys[i];
        let now = model.base_value(key);
        let v = now + delta;
        match key.class() {
            BaseClass::Damping => v >= 0.0,
            BaseClass::Inertia => v > 0.1 * now.max(0.0),
        }
    };
    let mut best: Option<(u32, f64, Vec<usize>, nalgebra::DVector<f64>)> = None;
    let forced: u32 = held.filter(|i| *i < nh).map_or(0, |i| 1 << i);
    for mask in (0u32..(1 << nh)).filter(|m| m & forced == forced) {
        let keep: Vec<usize> = (0..nh)
            .filter(|i| mask & (1 << i) == 0)
            .chain(nh..p)
            .collect();
        let sub = all.select(&keep);
        let th = sub.solve();
        if !keep
            .iter()
            .enumerate()
            .all(|(k, i)| *i >= nk + nr || in_range(*i, th[k]))
        {
            continue;
        }
        let sse = sub.sse(&th);
        if best
            .as_ref()
            .is_none_or(|b| (mask.count_ones(), sse) < (b.0, b.1))
        {
            best = Some((mask.count_ones(), sse, keep, th));
        }
    }
    let (_, _, keep, th) = best.expect("holding every base parameter is always in range");
    let mut delta = vec![0.0; p];
    for (k, i) in keep.iter().enumerate() {
        delta[*i] = th[k];
    }
    (keep, delta)
}

/// The index of `jm_kgm2` among `free_keys` when it is free beside `jl_kgm2` and the two
/// columns, the motor's and the load's acceleration, are one (a fit of the first on the second
/// leaves less than 1 % of its energy): the split of a change between them is then set by the
/// noise of the two derivatives, not by the motion (the noisier acceleration's inertia is
/// diluted and the other takes its share), and a model with the wrong split reads its
/// transmission's deflection wrong. The motor's inertia is the data sheet's; the load's is the
/// one that changes with the workpiece, so the change goes to it.
fn unseen_split(free_keys: &[BaseParam], d: &AxisData) -> Option<usize> {
    let jm = free_keys.iter().position(|k| *k == BaseParam::JmKgm2)?;
    let jl = free_keys.iter().position(|k| *k == BaseParam::JlKgm2)?;
    let (am, al) = (free_keys[jm].column(d), free_keys[jl].column(d));
    super::refit::spanned(am, &[al], d.range, None).then_some(jm)
}

fn update_plant(m: &mut WbModel) {
    let mut plant = m.file.plant;
    m.base_into(&mut plant);
    m.file.plant = plant;
}
