//! Gains of the P/PI cascade from the identified model, with their margins, and the check of
//! the load inertia by simulation matching (seed 000, method 1).

use feedloop_control::loop_model::{margins, Gains};
use feedloop_model::model::{PlantParams, TwoMassParams};
use serde::Serialize;

use super::device::Device;
use super::excitation::Identified;
use super::facts::Facts;
use super::friction::Survey;
use super::inertia_check::{check_inertia, InertiaCheck};
use super::Notes;

/// Smallest phase margin the tuned loop keeps, deg.
pub const PHASE_MARGIN_DEG: f64 = 45.0;
/// Smallest gain margin, dB.
pub const GAIN_MARGIN_DB: f64 = 6.0;

/// Margins of a gain set on the identified model.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Margins {
    /// Phase margin (the smaller of the velocity and the position loop), deg.
    pub phase_deg: f64,
    /// Gain margin, dB.
    pub gain_db: f64,
    /// Whether both reach the asked margins.
    pub met: bool,
}

/// The tuned loop.
#[derive(Debug, Clone, Serialize)]
pub struct Tuned {
    /// The drive's starting gains.
    pub start: Gains,
    /// Their margins on the identified model.
    pub start_margins: Option<Margins>,
    /// The gains chosen.
    pub gains: Gains,
    /// Their margins.
    pub margins: Margins,
    /// Asked margins: phase deg, gain dB.
    pub asked: (f64, f64),
    /// The load inertia the feedforward uses (the two-mass fit's), kg m^2.
    pub jl_kgm2: f64,
    /// The check by simulation matching.
    pub inertia_check: Option<InertiaCheck>,
}

/// The identified plant (the viscous part of the friction as DM).
pub fn plant(f: &Facts, s: &Survey, id: &Identified, jl: f64) -> PlantParams {
    let fr = &s.friction;
    PlantParams::BallScrew {
        two_mass: TwoMassParams {
            jm_kgm2: f.jm_kgm2,
            dm_nms_per_rad: 0.5
                * (fr.positive.viscous_nms_per_rad + fr.negative.viscous_nms_per_rad).max(0.0),
            kl_nm_per_rad: id.kl_nm_per_rad,
            cl_nms_per_rad: 0.0,
            jl_kgm2: jl,
            dl_nms_per_rad: 0.0,
        },
        lead_m: f.lead_m,
        gear_ratio: f.gear_ratio,
    }
}

/// The margins of `g` on `p` (one period of transport delay besides the hold).
pub fn margins_of(p: &PlantParams, g: Gains, period_s: f64, asked: (f64, f64)) -> Option<Margins> {
    margins(p, g, period_s, period_s).map(|(pm, gm)| Margins {
        phase_deg: pm,
        gain_db: gm,
        met: pm >= asked.0 && gm >= asked.1,
    })
}

/// The stiffest cascade that keeps the asked margins: over a grid of Kv (0.5 .. 2 times the
/// starting gain), Tv (2, 4, 8 times the velocity loop's time constant J / Kv) and Kp (up to a
/// quarter of the velocity loop's bandwidth Kv / J, and at most twice the starting gain: the
/// position loop closes through the backlash, which the margins do not see, and the
/// feedforwards do the tracking), the largest Kp, and of the gain sets that reach it the one
/// with the smallest Kv: the velocity measurement's noise enters the torque through Kv, and a
/// larger Kv (tried: 12 N m s/rad instead of 3 on an axis with 0.02 rad/s of noise) drives
/// the torque to its limit on the verification circle.
pub fn choose_gains(p: &PlantParams, f: &Facts, asked: (f64, f64)) -> Option<(Gains, Margins)> {
    let j = p.total_inertia();
    let mut best: Option<(Gains, Margins)> = None;
    for i in 0..13 {
        let kv = f.start.kv_nms_per_rad * 0.5 * 4f64.powf(i as f64 / 12.0);
        for m in [2.0, 4.0, 8.0] {
            let tv = m * j / kv;
            for q in 0..12 {
                let kp = (0.25 * kv / j).min(2.0 * f.start.kp_per_s) * (q as f64 + 1.0) / 12.0;
                let g = Gains {
                    kp_per_s: kp,
                    kv_nms_per_rad: kv,
                    tv_s: tv,
                };
                let Some(mg) = margins_of(p, g, f.period_s, asked) else {
                    continue;
                };
                if !mg.met {
                    continue;
                }
                // Kv rises through the search: a later set wins only by a larger Kp
                let better = best.as_ref().is_none_or(|(b, _)| kp > b.kp_per_s * 1.0001);
                if better {
                    best = Some((g, mg));
                }
            }
        }
    }
    best
}

/// Tunes the cascade and checks the load inertia.
pub fn tune(
    dev: &mut dyn Device,
    f: &Facts,
    axis: &str,
    s: &Survey,
    id: &Identified,
    asked: (f64, f64),
    notes: &mut Notes,
) -> Result<Tuned, String> {
    let check = check_inertia(dev, f, axis, s, id, notes);
    let (check, jl) = match check {
        Ok(c) => {
            let jl = id.jl_kgm2;
            (Some(c), jl)
        }
        Err(e) => {
            notes.warn(format!(
                "the load inertia could not be checked by simulation matching: {e}"
            ));
            (None, id.jl_kgm2)
        }
    };
    let p = plant(f, s, id, jl);
    let (gains, margins) = choose_gains(&p, f, asked).ok_or_else(|| {
        format!(
            "no gain set of the search keeps {} deg and {} dB on the identified model",
            asked.0, asked.1
        )
    })?;
    Ok(Tuned {
        start: f.start,
        start_margins: margins_of(&p, f.start, f.period_s, asked),
        gains,
        margins,
        asked,
        jl_kgm2: jl,
        inertia_check: check,
    })
}
