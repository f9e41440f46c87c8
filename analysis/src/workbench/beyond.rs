//! A candidate refitted beyond the effects of another: the forward selection after the first
//! significant candidate and the pairs of candidates that hide each other judge it by the same
//! rules.

use super::data::AxisData;
use super::effects::{channel, Channel, Effect, WbModel};
use super::lsq::Cv;
use super::refit::{best_effect, cv_cols_masked, flat, Refit};
use super::scoring::*;
use super::verdict::vetoed;
use super::words::evidence;

/// What the torque channel's candidates are scored with: the base columns, the residual, the
/// cross-validation blocks and the rows used (the moving rows, `refit::moving_mask`).
pub(super) struct TorqueFit<'a> {
    /// Smallest reduction that counts, % of the model's error (see [`TorqueChannel`]).
    pub min_pct: f64,
    pub base_cols: &'a [&'a [f64]],
    /// Current values of the inertias among the base parameters (`refit::inertias_now`).
    pub now: &'a [f64],
    pub res: &'a [f64],
    pub bl: &'a [(usize, usize)],
    pub mask: Option<&'a [f64]>,
}

/// How a candidate fares beyond the effects of a first one (see [`beyond_top`]).
pub(super) struct Earned {
    /// Whether its cross-validated cut alone counts (the smallest cut that counts, in
    /// [`MIN_FOLD_WINS`] blocks), whatever its confidence interval.
    pub cuts: bool,
    /// Its cut of the cross-validated error left beside the first one's effects, % of it.
    pub share: f64,
    /// Its size and that size's standard error (see [`leading_size`]).
    pub size: Option<(f64, f64)>,
    /// Its extra cut of the cross-validated error, % of the model's error.
    pub extra: f64,
    /// Its refit beyond them, when it is a single effect refitted alone.
    pub rescored: Option<Refit>,
}

impl Earned {
    /// Whether its size lies inside its own confidence interval (a size that is no number
    /// does).
    fn inside_ci(&self) -> bool {
        self.size
            .is_some_and(|(c, se)| c.is_nan() || c <= CI_SIGMAS * se)
    }

    /// Whether it earns its significance beyond the first one's effects: its cut counts and its
    /// size lies outside its own confidence interval.
    pub fn earns(&self) -> bool {
        self.cuts && !self.inside_ci()
    }

    /// Why, its cut counting, it is still not named: its size inside its own confidence
    /// interval, or its nonlinear parameter at an edge of its search. `None` when it is named.
    pub fn held_back(&self) -> Option<String> {
        if self.inside_ci() {
            return Some("its size stays inside its own confidence interval".into());
        }
        self.rescored
            .as_ref()
            .and_then(|f| f.doubtful.as_ref())
            .map(|why| format!("{why}: doubtful"))
    }
}

/// Each of `cands` refitted together with the base parameters and the effects of `top`: it
/// earns its significance when it lowers the cross-validated error further by the channel's
/// smallest cut that counts, in [`MIN_FOLD_WINS`] blocks, with its size outside its own
/// confidence interval.
pub(super) fn beyond_top(
    top: &Top,
    cands: &[&Candidate],
    model: &WbModel,
    d: &AxisData,
    tf: &TorqueFit<'_>,
    e0: f64,
) -> Vec<Earned> {
    let needed = model.torque_needed(d);
    let mut with_top = model.clone();
    let top_cols = add_effects(&mut with_top, d, &top.add);
    let mut cols: Vec<&[f64]> = tf.base_cols.to_vec();
    cols.extend(top_cols.iter().map(|c| c.as_slice()));
    let mut now_ext = tf.now.to_vec();
    now_ext.resize(cols.len(), 0.0);
    let beyond = Beyond {
        with_top: &with_top,
        d,
        tf,
        needed: &needed,
        cols: &cols,
        now: &now_ext,
    };
    let t_ref = beyond.target_of(&with_top);
    let cv_ref = cv_cols_masked(&cols, &[], &t_ref, tf.bl, tf.mask);
    let nb = cols.len();
    cands
        .iter()
        .map(|c| {
            let (cv, rescored) = beyond.rescore(c, top, &t_ref);
            let extra = 100.0 * (cv_ref.rms - cv.rms) / e0;
            let wins = fold_wins(&cv, &cv_ref.fold_mse);
            let size = rescored.as_ref().and_then(|r| {
                (channel(r.effect.id) == Channel::Torque)
                    .then(|| leading_size(&r.effect, &r.cv, nb, d))
                    .flatten()
            });
            Earned {
                cuts: extra >= tf.min_pct && wins >= MIN_FOLD_WINS,
                share: 100.0 * (cv_ref.rms - cv.rms) / cv_ref.rms.max(1e-300),
                size,
                extra,
                rescored,
            }
        })
        .collect()
}

/// Adds the torque-path effects among `add` to `m` (they change the target); the columns of
/// its torque-channel effects.
fn add_effects(m: &mut WbModel, d: &AxisData, add: &[Effect]) -> Vec<Vec<f64>> {
    let mut cols: Vec<Vec<f64>> = Vec::new();
    for e in add {
        match channel(e.id) {
            Channel::TorquePath => m.effects.push(e.clone()),
            Channel::Torque => cols.extend(e.columns(d)),
            Channel::Deflection => {}
        }
    }
    cols
}

/// The first significant candidate of the forward selection, or the leader of a pair.
pub(super) struct Top {
    pub add: Vec<Effect>,
    pub class: String,
    pub name: String,
}

impl Top {
    /// The effects, class and name of candidate `c`.
    pub fn of(c: &Candidate) -> Self {
        Self {
            add: c.add.clone(),
            class: c.class.clone(),
            name: c.effect.clone(),
        }
    }

    /// Marks candidate `c` by whether it `earns` its significance beyond the first one (by
    /// `extra` % of the model's error, refitted as `rescored` when refitted alone); the
    /// candidate's effect when the first one already includes it.
    pub fn judge(
        &self,
        c: &mut Candidate,
        earns: bool,
        extra: f64,
        rescored: Option<Refit>,
        d: &AxisData,
    ) -> Option<String> {
        let top_name = &self.name;
        // a refit that more than doubles the error reads -100 %, as every candidate's cut
        let extra = extra.clamp(-100.0, 100.0);
        if vetoed(&c.evidence) {
            // out of its physical range or contradicted by the motion: it stays as it was
            c.significant = false;
            return None;
        }
        if earns {
            if let Some(Refit { effect: e, .. }) = rescored {
                c.params = flat(&e.to_table(d.kind, d.r));
                c.evidence = evidence(&e, d);
                c.add = vec![e];
            }
            if !c.significant {
                c.significant = true;
                c.error_reduction_pct = extra;
            }
            c.evidence = format!(
                "{}; beyond {top_name} it lowers the cross-validated error by {extra:.1} %",
                c.evidence
            );
            return None;
        }
        c.significant = false;
        c.error_reduction_pct = extra;
        let mut included = None;
        if c.add.iter().all(|e| self.add.iter().any(|t| t.id == e.id)) {
            c.class = self.class.clone();
            if !c.same_as.contains(top_name) {
                c.same_as.push(top_name.clone());
            }
            included = Some(c.effect.clone());
        }
        c.evidence = format!(
            "{}; beyond {top_name} it lowers the cross-validated error by only {extra:.1} % (not significant)",
            c.evidence
        );
        included
    }
}

/// What a candidate is refitted with beyond the first one: the model with the first one's
/// torque-path effects, the base columns followed by the first one's columns, and the current
/// values of the inertias among them.
struct Beyond<'a> {
    with_top: &'a WbModel,
    d: &'a AxisData,
    tf: &'a TorqueFit<'a>,
    /// The torque the model needs for the measured motion.
    needed: &'a [f64],
    cols: &'a [&'a [f64]],
    now: &'a [f64],
}

impl Beyond<'_> {
    /// The torque residual of `m`: its applied torque less the torque needed, its dry friction
    /// holding the torque at rest, as the channel's (the channel's residual without a recorded
    /// torque).
    fn target_of(&self, m: &WbModel) -> Vec<f64> {
        match m.applied(self.d) {
            Some(t) => m.balance_residual(self.d, &t, self.needed),
            None => self.tf.res.to_vec(),
        }
    }

    /// The cross-validation of candidate `c` beyond the first one (`top`, whose residual is
    /// `t_ref`), and its refit when it is a single effect refitted alone.
    fn rescore(&self, c: &Candidate, top: &Top, t_ref: &[f64]) -> (Cv, Option<Refit>) {
        let (d, tf) = (self.d, self.tf);
        // a single effect is refitted beyond the first one (its nonlinear parameter chosen
        // again: the first one's misfit no longer hides it)
        let single = (c.add.len() == 1).then(|| c.add[0].id).filter(|id| {
            channel(*id) != Channel::Deflection
                && (id.repeatable() || !top.add.iter().any(|t| t.id == *id))
        });
        let rescored = single.and_then(|id| {
            best_effect(
                id,
                self.with_top,
                d,
                self.cols,
                self.now,
                t_ref,
                tf.bl,
                tf.mask,
            )
            .ok()
        });
        let cv = match &rescored {
            Some(r) => r.cv.clone(),
            None => {
                let mut with = self.with_top.clone();
                let extra_cols = add_effects(&mut with, d, &c.add);
                let t = if with.effects.len() > self.with_top.effects.len() {
                    self.target_of(&with)
                } else {
                    t_ref.to_vec()
                };
                let refs: Vec<&[f64]> = extra_cols.iter().map(|x| x.as_slice()).collect();
                cv_cols_masked(self.cols, &refs, &t, tf.bl, tf.mask)
            }
        };
        (cv, rescored)
    }
}
