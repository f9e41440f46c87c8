//! Learning the `quadrant_compensator` table from recorded runs (seed 004, steps (1)-(8)).
//!
//! 1. Reversals are found in the commanded velocity with the compensator's own
//!    [`ReversalDetector`]; around each one the following error e = th - thL (load units) is
//!    resampled on tau = -L, ..., 0, T, 2T, ... about the interpolated reversal instant (the
//!    approach, `lead_s` = L before it, and `window_s` after it), its value at tau = -L
//!    subtracted (the error in steady motion, before the friction's Stribeck rise), and the
//!    curves of all reversals of one direction averaged. The spike is the largest |e(tau) -
//!    e(-L)| of any single reversal. (Measured from e(0) instead, the approach error at the
//!    reversal, -66 nm on the shipped circle, reappears as +62 nm at the end of every window,
//!    where no pulse after the reversal can reach it.)
//! 2. In a region of that curve the maximum |e| is the "max point"; the start point is the last
//!    sample before it, and the end point the first after it, where |e| falls to `threshold` of
//!    the maximum (or changes sign); otherwise the region's bounds.
//! 3. Two acceleration-planned models (see [`feedloop_plugins::quadrant`]) span start->max and
//!    max->end; their rise/fall splits are chosen by bisection on the sign of the least-squares
//!    residual's slope, with the amplitude at the measured maximum, and kept so that every
//!    acceleration phase lasts at least `min_phase_s`; the common amplitude is then the
//!    least-squares fit of both models to the curve.
//! 4. Pass 1 fits the spike after the reversal (against e(0), its start point tried at the
//!    threshold and at the reversal, kept per axis as it ran better) and the approach, the lobe
//!    of what is left through the reversal, played from the predicted reversal instant. The
//!    pulses are written to the table, the job is run again with them, and later passes fit one
//!    pulse to each lobe of the residual (one sign between zero crossings, so each pulse leaves
//!    and returns to zero where its lobe does), until the spike is below `accept` or the pass
//!    count is reached.
//!
//! [`learn_quadrant`] runs that loop. It does not know how to run a job: the caller passes a
//! closure (the CLI's `feedloop learn quadrant` passes the in-process simulation), so the
//! learning loop stays independent of how a job is run.
//!
//! [`ReversalDetector`]: feedloop_plugins::quadrant::ReversalDetector

mod curves;
mod options;
mod run;

pub use curves::{
    fit_pass, fit_pulse, fit_pulse_at, lobes, reversal_curves, spike_points, ReversalCurves,
    SpikeStart,
};
pub use options::{
    AxisSpike, LearnError, LearnOptions, LearnReport, PassReport, RunJob, RunRecords,
    MAX_BACKTRACKS,
};
pub use run::learn_quadrant;
