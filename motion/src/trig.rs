//! Sine and cosine together, for the trajectories' per-cycle evaluation.
//!
//! The argument is reduced to r in [-pi/4, pi/4] around the nearest multiple q of pi/2, with pi/2
//! split into three parts so that q * part is exact for |q| < 2^20 (about 1.6 million rad), and
//! sin r, cos r are their Taylor series up to r^17 and r^18: the first omitted terms are below
//! 1e-19, far under half an ulp. Outside that range (or for non-finite input) the standard
//! library's `sin_cos` is used. The result is within about one ulp of the correctly rounded
//! value and is a pure function of the input, so every process computes the same bits.

use std::f64::consts::FRAC_2_PI;

/// pi/2 = PIO2_A + PIO2_B + PIO2_C (+ 8.5e-32): the leading 33 bits, the next 33, and the next
/// 53 (given as bit patterns, so they are exactly these numbers).
const PIO2_A: f64 = f64::from_bits(0x3FF9_21FB_5440_0000);
const PIO2_B: f64 = f64::from_bits(0x3DD0_B461_1A60_0000);
const PIO2_C: f64 = f64::from_bits(0x3BA3_198A_2E00_0000);

/// Largest |q| for which q * PIO2_A and q * PIO2_B are exact.
const Q_MAX: f64 = 1_048_576.0;

/// (sin x, cos x).
#[inline]
pub fn sin_cos(x: f64) -> (f64, f64) {
    let t = x * FRAC_2_PI;
    // Also catches a non-finite x: the comparison is then not `Less`.
    if t.abs().partial_cmp(&Q_MAX) != Some(std::cmp::Ordering::Less) {
        return x.sin_cos();
    }
    // Nearest integer (ties to even) by the 1.5 * 2^52 shift: exact for |t| < 2^51, and no call
    // to `round` (not an instruction on baseline x86-64).
    const SHIFT: f64 = 6_755_399_441_055_744.0;
    let q = (t + SHIFT) - SHIFT;
    let r = ((x - q * PIO2_A) - q * PIO2_B) - q * PIO2_C;
    let (s, c) = kernel(r);
    match (q as i64) & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// sin r and cos r for |r| <= pi/4 (a little beyond is fine).
#[inline(always)]
fn kernel(r: f64) -> (f64, f64) {
    // Coefficients of the Taylor series: (-1)^k / (2k+1)! and (-1)^k / (2k)!.
    const S: [f64; 8] = [
        -1.0 / 6.0,
        1.0 / 120.0,
        -1.0 / 5040.0,
        1.0 / 362_880.0,
        -1.0 / 39_916_800.0,
        1.0 / 6_227_020_800.0,
        -1.0 / 1_307_674_368_000.0,
        1.0 / 355_687_428_096_000.0,
    ];
    const C: [f64; 8] = [
        1.0 / 24.0,
        -1.0 / 720.0,
        1.0 / 40_320.0,
        -1.0 / 3_628_800.0,
        1.0 / 479_001_600.0,
        -1.0 / 87_178_291_200.0,
        1.0 / 20_922_789_888_000.0,
        -1.0 / 6_402_373_705_728_000.0,
    ];
    // Estrin's scheme: the same polynomials in fewer dependent steps than Horner's.
    let z = r * r;
    let z2 = z * z;
    let z4 = z2 * z2;
    let est = |c: &[f64; 8]| {
        let a = (c[0] + c[1] * z) + z2 * (c[2] + c[3] * z);
        let b = (c[4] + c[5] * z) + z2 * (c[6] + c[7] * z);
        a + z4 * b
    };
    let ps = est(&S);
    let pc = est(&C);
    let s = r + r * z * ps;
    // cos r = 1 - z/2 + z^2 (1/24 - ...): the small tail is added to the exactly rounded head.
    let c = 1.0 - 0.5 * z + z * z * pc;
    (s, c)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distance in units of the last place of `want`.
    fn ulps(got: f64, want: f64) -> f64 {
        let ulp = f64::EPSILON * want.abs().max(f64::MIN_POSITIVE);
        (got - want).abs() / ulp
    }

    #[test]
    fn matches_the_standard_library_within_two_ulps_over_many_turns() {
        let mut worst = 0.0f64;
        let mut x = -700.0;
        while x < 700.0 {
            let (s, c) = sin_cos(x);
            let (s0, c0) = x.sin_cos();
            // Compare against the larger of |value| and 1e-3 so that near-zero crossings are
            // judged on an absolute scale (the reduction error dominates there).
            let es = (s - s0).abs() / (f64::EPSILON * s0.abs().max(1e-3));
            let ec = (c - c0).abs() / (f64::EPSILON * c0.abs().max(1e-3));
            worst = worst.max(es).max(ec);
            x += 0.000_731;
        }
        assert!(worst <= 2.0, "worst error {worst} ulp");
    }

    #[test]
    fn exact_quadrant_points_and_identity() {
        assert_eq!(sin_cos(0.0), (0.0, 1.0));
        let (s, c) = sin_cos(std::f64::consts::FRAC_PI_2);
        assert!(ulps(s, 1.0) <= 1.0 && c.abs() < 1e-16, "{s} {c}");
        for &x in &[0.3, 1.7, -2.9, 12.5, 201.06, -1.0e5] {
            let (s, c) = sin_cos(x);
            assert!((s * s + c * c - 1.0).abs() < 4.0 * f64::EPSILON, "{x}");
        }
    }

    #[test]
    fn huge_and_non_finite_inputs_fall_back_to_the_standard_library() {
        for x in [1.0e7, -3.0e9, 1.0e300] {
            assert_eq!(sin_cos(x), x.sin_cos());
        }
        let (s, c) = sin_cos(f64::NAN);
        assert!(s.is_nan() && c.is_nan());
        let (s, c) = sin_cos(f64::INFINITY);
        assert!(s.is_nan() && c.is_nan());
    }
}
