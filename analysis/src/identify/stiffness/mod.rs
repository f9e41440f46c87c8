//! Stiffness identification (seed 001): FRF torque -> motor velocity, first anti-resonance and
//! resonance by peak picking with parabolic interpolation, then (motor side)
//! `KL = JL wa^2` and `JL = JM (wr^2 / wa^2 - 1)`.
//!
//! Peaks are picked on the torque -> motor *acceleration* magnitude `|H| w`, which is flat
//! (`1 / (JM + JL)` below, `1 / JM` above) apart from the notch and the peak, so the 1/s slope
//! does not shift them. Extrema count only when they stand out by `prominence_db` from the
//! response within +-20 % of their frequency.

mod checks;
mod direction;
mod options;
mod picks;
mod two_mass;

pub use direction::{count_reversals, identify_stiffness, one_direction_windows};
pub use options::{
    Estimator, FrfKind, ModePair, StiffnessChecks, StiffnessOptions, StiffnessResult, JM_FACTOR,
    MAX_BIN_ERROR, MAX_CI_PCT, MAX_DIRECTION_SPREAD, MIN_PICK_BINS, MIN_SEGMENTS,
};
pub use picks::{identify_stiffness_from, identify_stiffness_windows};

#[cfg(test)]
mod tests {
    use super::super::frf::welch_frf_windows;
    use super::*;

    #[test]
    fn one_direction_windows_cut_the_reversals_and_their_settling() {
        // +1 for 1000 samples, a reversal through zero, -1 for 1000, noise below the band.
        let mut v: Vec<f64> = (0..1000)
            .map(|k| 1.0 + 0.01 * ((k % 7) as f64 - 3.0))
            .collect();
        v.extend((0..20).map(|k| 1.0 - k as f64 / 10.0));
        v.extend((0..1000).map(|k| -1.0 + 0.01 * ((k % 5) as f64 - 2.0)));
        let w = one_direction_windows(&v, 100);
        assert_eq!(w.len(), 2, "{w:?}");
        assert_eq!((w[0].0, w[0].2), (100, 1));
        assert_eq!(w[1].2, -1);
        // Every kept sample keeps its window's sign, at least `settle` from the reversal.
        for (a, b, s) in &w {
            assert!(v[*a..*b].iter().all(|x| x.signum() == f64::from(*s)));
        }
        let zero = v.iter().position(|x| *x <= 0.0).unwrap();
        assert!(w[0].1 + 100 <= zero && zero + 100 <= w[1].0, "{w:?} {zero}");
        assert_eq!(count_reversals(&v), 1);
    }

    #[test]
    fn welch_segments_stay_inside_their_windows() {
        let n = 3000;
        let u: Vec<f64> = (0..n).map(|k| ((k * 7919) % 101) as f64 - 50.0).collect();
        let y: Vec<f64> = u.iter().map(|x| 2.0 * x).collect();
        // 1000 samples hold 9 segments of 200 (hop 100); 300 hold 2; 150 none.
        let (frf, per) = welch_frf_windows(
            &u,
            &y,
            None,
            1e-3,
            200,
            &[(0, 1000), (1200, 1500), (1500, 1650)],
        )
        .unwrap();
        assert_eq!(per, vec![9, 2, 0]);
        assert_eq!(frf.segments, 11);
        assert!(
            frf.h[10].re > 1.99 && frf.h[10].re < 2.01,
            "{:?}",
            frf.h[10]
        );
        assert!(welch_frf_windows(&u, &y, None, 1e-3, 200, &[(0, 150)]).is_err());
    }
}
