//! What `identify stiffness` is asked (options) and what it answers (the pair and its checks).

use serde::Serialize;

use super::super::frf::Frf;
use super::super::reversals::ReversalEffects;

/// Which frequency response to read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrfKind {
    /// Torque -> motor velocity (the plant alone; the one the formulas hold for).
    TorqueToVelocity,
    /// Command -> table position of the closed loop: refused (no anti-resonance, its peak is a
    /// closed-loop pole; the formulas then give a negative inertia).
    CommandToTable,
}

/// How the torque -> velocity response is estimated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Estimator {
    /// `S_ry / S_ru` with the command `r` as instrument when the trace has a moving command,
    /// else H1.
    Auto,
    /// H1 = `S_uy / S_uu` (biased by torque noise and feedback in a closed loop).
    H1,
    /// The command as instrument (required: a moving `A.cmd`).
    Instrument,
}

/// Options of [`identify_stiffness`](crate::identify::stiffness::identify_stiffness).
#[derive(Debug, Clone)]
pub struct StiffnessOptions {
    /// Motor inertia JM from the data sheet, kg m^2 (> 0).
    pub jm_kgm2: f64,
    /// Band searched, Hz.
    pub f_min_hz: f64,
    /// Band end, Hz (default: 0.4 times the sample rate).
    pub f_max_hz: Option<f64>,
    /// Frequency resolution, Hz (Welch segment = 1 / resolution).
    pub resolution_hz: f64,
    /// Minimum prominence of an extremum, dB.
    pub prominence_db: f64,
    /// Estimator.
    pub estimator: Estimator,
    /// Which FRF (only torque -> velocity is accepted).
    pub frf: FrfKind,
    /// Time cut after each reversal (and before the next) from the one-direction windows, s.
    pub settle_s: f64,
}

impl StiffnessOptions {
    /// Defaults for a motor inertia: band 5 Hz .. 0.4 fs, 0.3 Hz resolution, 6 dB, auto,
    /// 0.2 s settling after a reversal.
    pub fn new(jm_kgm2: f64) -> Self {
        Self {
            jm_kgm2,
            f_min_hz: 5.0,
            f_max_hz: None,
            resolution_hz: 0.3,
            prominence_db: 6.0,
            estimator: Estimator::Auto,
            frf: FrfKind::TorqueToVelocity,
            settle_s: 0.2,
        }
    }
}

/// One anti-resonance / resonance pair with what it implies.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ModePair {
    /// Anti-resonance, Hz.
    pub antiresonance_hz: f64,
    /// Resonance, Hz.
    pub resonance_hz: f64,
}

/// Result of [`identify_stiffness`](crate::identify::stiffness::identify_stiffness).
#[derive(Debug, Clone, Serialize)]
pub struct StiffnessResult {
    /// Equivalent stiffness seen from the motor, N m/rad.
    pub kl_nm_per_rad: f64,
    /// Load inertia seen from the motor, kg m^2.
    pub jl_kgm2: f64,
    /// First anti-resonance, Hz.
    pub antiresonance_hz: f64,
    /// First resonance, Hz.
    pub resonance_hz: f64,
    /// Smallest torque -> velocity coherence between 0.8 wa and 1.2 wr (the notch excluded).
    pub coherence_min: f64,
    /// The next pair above the first, when there is one (e.g. a third mass).
    pub second: Option<ModePair>,
    /// `instrument` or `h1`.
    pub estimator: &'static str,
    /// Averaged Welch segments.
    pub segments: usize,
    /// Whether every check of `checks` passed.
    pub credible: bool,
    /// How far the result can be trusted: the figures it is judged on and what fails.
    pub checks: StiffnessChecks,
    /// Friction and backlash read at the traverse's reversals (null without reversals between
    /// one-direction windows).
    pub reversal_effects: Option<ReversalEffects>,
    /// The FRF (not serialised).
    #[serde(skip)]
    pub frf: Option<Frf>,
}

/// Least averaged Welch segments for a coherence that means something (with one segment it is
/// 1 whatever the data).
pub const MIN_SEGMENTS: usize = 4;
/// Largest relative standard error of the averaged response around each pick,
/// `sqrt((1 - g) / (2 N g))` for the median coherence `g` over `N` segments: 0.25 is about
/// 2 dB, a third of the prominence an extremum needs ([`StiffnessOptions::prominence_db`]'s
/// default), so that the picks stand out of the scatter.
pub const MAX_BIN_ERROR: f64 = 0.25;
/// Least distance between the two picks, and of each pick from the band's edges, in bins.
pub const MIN_PICK_BINS: f64 = 3.0;
/// Largest relative difference between the KL of the two directions of a traverse (each then
/// lies within 1 % of their mean).
pub const MAX_DIRECTION_SPREAD: f64 = 0.02;
/// Largest 95 % confidence half-width of KL and JL from the two-mass fit, % (the accuracy a
/// commissioning result is asked for).
pub const MAX_CI_PCT: f64 = 1.0;
/// Largest factor between the given JM and the one the response shows above the resonance.
pub const JM_FACTOR: f64 = 2.0;

/// What [`identify_stiffness`](crate::identify::stiffness::identify_stiffness) judges its own result on (reported beside the picks).
#[derive(Debug, Clone, Serialize, Default)]
pub struct StiffnessChecks {
    /// Averaged Welch segments (at least [`MIN_SEGMENTS`]).
    pub segments: usize,
    /// Median coherence of the estimate within +-20 % of the anti-resonance (its notch, +-5 %,
    /// left out): torque -> velocity for H1; with the command as instrument, what the
    /// instrument's coherences with torque and velocity leave (see `Frf::quality`).
    pub coherence_antiresonance: f64,
    /// The same within +-20 % of the resonance.
    pub coherence_resonance: f64,
    /// How far the anti-resonance stands below the response around it (+-20 %), dB.
    pub prominence_antiresonance_db: f64,
    /// How far the resonance stands above the response around it, dB.
    pub prominence_resonance_db: f64,
    /// Distance of the resonance from the anti-resonance, frequency bins.
    pub separation_bins: f64,
    /// The motor inertia the response shows above the resonance (1 / |H w| between 1.5 and 3
    /// times the resonance), kg m^2; null when the band does not reach there.
    pub jm_from_response_kgm2: Option<f64>,
    /// The total inertia the response shows below the anti-resonance (1 / |H w| between the band's
    /// start and half the anti-resonance), kg m^2; the pair and JM say JM (wr / wa)^2; null when
    /// the band does not reach there.
    pub total_from_response_kgm2: Option<f64>,
    /// Velocity reversals in the analysed data (the nut crossing its backlash, friction
    /// changing sign: each mixes another plant into the response).
    pub reversals: usize,
    /// Reversals cut out of the record with their settling (0 when the whole record is read).
    pub reversals_cut: usize,
    /// One-direction windows (positive velocity) whose segments were averaged.
    pub windows_positive: usize,
    /// One-direction windows (negative velocity) whose segments were averaged.
    pub windows_negative: usize,
    /// Averaged segments from windows of positive velocity.
    pub segments_positive: usize,
    /// Averaged segments from windows of negative velocity.
    pub segments_negative: usize,
    /// Averaged segments per analysed window (not serialised).
    #[serde(skip)]
    pub per_window: Vec<usize>,
    /// KL from the windows of positive velocity alone (when they hold enough segments).
    pub kl_positive_nm_per_rad: Option<f64>,
    /// KL from the windows of negative velocity alone.
    pub kl_negative_nm_per_rad: Option<f64>,
    /// 95 % confidence half-width of KL from the two-mass fit to the response around the
    /// picks, % of KL (null when the fit failed and the picks alone give the result).
    pub kl_ci_pct: Option<f64>,
    /// 95 % confidence half-width of JL, %.
    pub jl_ci_pct: Option<f64>,
    /// Frequency bins the two-mass model was fitted to.
    pub fit_bins: usize,
    /// What is not credible, with the figures; empty when the result passes.
    pub problems: Vec<String>,
    /// What to change for a credible result.
    pub advice: Vec<String>,
}

impl StiffnessChecks {
    /// Whether every check passed.
    pub fn credible(&self) -> bool {
        self.problems.is_empty()
    }
}
