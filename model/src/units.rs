//! Figures for people: significant digits, and an SI prefix that fits the magnitude.
//!
//! Files and JSON keep SI values with full precision; what a person reads (summary lines,
//! tool results, plot ticks) goes through these helpers, so a following error of 3e-9 m prints
//! as `3 nm` rather than `0.000 um`, and a period of 0.020000000000000004 s as `20 ms`.
//!
//! - [`sig`]: a bare number to [`DIGITS`] significant digits (`0.02`, `1.235e-7`).
//! - [`si`]: a quantity with its unit prefixed to fit (`3 nm`, `1.235 um`, `250 us`).
//! - [`prefix_for`]: the prefix and scale [`si`] would choose, for a whole plot axis.

/// Significant digits of printed figures.
pub const DIGITS: usize = 4;

/// Prefixes [`si`] may use, from the smallest: exponent of ten and symbol (ASCII `u` for micro,
/// as elsewhere in feedloop's text). Larger values than 1 keep the bare unit (`1500 N`, `3600 s`).
const PREFIXES: [(i32, &str); 5] = [(-12, "p"), (-9, "n"), (-6, "u"), (-3, "m"), (0, "")];

/// `v` rounded to `digits` significant digits, as (mantissa digits as an integer, exponent
/// of ten of the first digit); `None` for zero or non-finite values.
fn round_sig(v: f64, digits: usize) -> Option<(f64, i32)> {
    if v == 0.0 || !v.is_finite() {
        return None;
    }
    // `{:e}` rounds correctly in decimal (no log10 edge cases at powers of ten).
    let s = format!("{:.*e}", digits - 1, v.abs());
    let (m, e) = s.split_once('e')?;
    Some((m.parse().ok()?, e.parse().ok()?))
}

/// Fixed-point text of `v` (already rounded) with `decimals` digits, trailing zeros and a
/// trailing point trimmed.
fn trimmed(v: f64, decimals: usize) -> String {
    let s = format!("{v:.decimals$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    };
    if s == "-0" {
        "0".into()
    } else {
        s
    }
}

/// `v` to [`DIGITS`] significant digits, trailing zeros trimmed: fixed-point from 1e-4 up to
/// 1e4, exponent form (`1.5e-7`, `1.235e5`) outside.
///
/// ```
/// use feedloop_model::units::sig;
/// assert_eq!(sig(0.020000000000000004), "0.02");
/// assert_eq!(sig(0.00030000000000000003), "0.0003");
/// assert_eq!(sig(1234.56), "1235");
/// assert_eq!(sig(-1.5e-7), "-1.5e-7");
/// ```
pub fn sig(v: f64) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    let Some((m, e)) = round_sig(v, DIGITS) else {
        return "0".into();
    };
    let sign = if v < 0.0 { "-" } else { "" };
    if (-4..4).contains(&e) {
        let decimals = (DIGITS as i32 - 1 - e).max(0) as usize;
        format!("{sign}{}", trimmed(m * 10f64.powi(e), decimals))
    } else {
        format!("{sign}{}e{e}", trimmed(m, DIGITS - 1))
    }
}

/// `v` with all its digits (the shortest text that reads back as `v`), fixed-point from 1e-4 up
/// to 1e6 and exponent form outside, so a range bound reads `1e-12` or `1e9`, never a row of
/// zeros.
///
/// ```
/// use feedloop_model::units::exact;
/// assert_eq!(exact(1e-12), "1e-12");
/// assert_eq!(exact(1e9), "1e9");
/// assert_eq!(exact(0.25), "0.25");
/// assert_eq!(exact(1000000000.5), "1.0000000005e9");
/// ```
pub fn exact(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e6).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// The prefix for values up to `max_abs` in `unit`: (factor to multiply SI values by, prefixed
/// unit). The largest prefix not above the magnitude, so numbers read between 1 and 1000; zero
/// or non-finite magnitudes keep the bare unit.
///
/// ```
/// use feedloop_model::units::prefix_for;
/// assert_eq!(prefix_for(4e-6, "m"), (1e6, "um".to_string()));
/// assert_eq!(prefix_for(0.25, "s"), (1e3, "ms".to_string()));
/// assert_eq!(prefix_for(12.0, "N m"), (1.0, "N m".to_string()));
/// ```
pub fn prefix_for(max_abs: f64, unit: &str) -> (f64, String) {
    let e = match round_sig(max_abs, DIGITS) {
        Some((_, e)) => e,
        None => 0,
    };
    let (p, sym) = PREFIXES
        .iter()
        .rev()
        .find(|(p, _)| *p <= e)
        .copied()
        .unwrap_or(PREFIXES[0]);
    (10f64.powi(-p), format!("{sym}{unit}"))
}

/// `v` (SI, in `unit`) to [`DIGITS`] significant digits with the prefix that fits, trailing zeros
/// trimmed.
///
/// ```
/// use feedloop_model::units::si;
/// assert_eq!(si(3e-9, "m"), "3 nm");
/// assert_eq!(si(1.23456e-6, "m"), "1.235 um");
/// assert_eq!(si(0.020000000000000004, "s"), "20 ms");
/// assert_eq!(si(-4.2e-3, "rad"), "-4.2 mrad");
/// ```
pub fn si(v: f64, unit: &str) -> String {
    if !v.is_finite() {
        return format!("{v} {unit}");
    }
    let Some((m, e)) = round_sig(v, DIGITS) else {
        return format!("0 {unit}");
    };
    // choose the prefix from the rounded value, so 999.96e-6 m reads 1 mm, not 1000 um
    let rounded = m * 10f64.powi(e);
    let (scale, unit) = prefix_for(rounded, unit);
    let x = rounded * scale;
    let lead = if x >= 1.0 {
        x.log10().floor() as i32
    } else {
        e
    };
    let decimals = (DIGITS as i32 - 1 - lead).max(0) as usize;
    let sign = if v < 0.0 { "-" } else { "" };
    if !(1.0..1e6).contains(&x) {
        return format!("{sign}{} {unit}", sig(x));
    }
    format!("{sign}{} {unit}", trimmed(x, decimals))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lengths_take_the_prefix_that_fits() {
        assert_eq!(si(3e-9, "m"), "3 nm");
        assert_eq!(si(3.1e-10, "m"), "310 pm");
        assert_eq!(si(2e-6, "m"), "2 um");
        assert_eq!(si(1.23456e-6, "m"), "1.235 um");
        assert_eq!(si(9.99996e-4, "m"), "1 mm");
        assert_eq!(si(0.5, "m"), "500 mm");
        assert_eq!(si(2.5, "m"), "2.5 m");
        assert_eq!(si(0.0, "m"), "0 m");
        assert_eq!(si(-0.0, "m"), "0 m");
        assert_eq!(si(-3e-3, "rad"), "-3 mrad");
    }

    #[test]
    fn times_take_the_prefix_that_fits() {
        assert_eq!(si(2.5e-4, "s"), "250 us");
        assert_eq!(si(1e-4, "s"), "100 us");
        assert_eq!(si(0.020000000000000004, "s"), "20 ms");
        assert_eq!(si(4.2e-8, "s"), "42 ns");
        assert_eq!(si(12.345678, "s"), "12.35 s");
        assert_eq!(si(3600.0, "s"), "3600 s");
        assert_eq!(si(1.5e7, "s"), "1.5e7 s");
    }

    #[test]
    fn bare_numbers_have_four_significant_digits() {
        assert_eq!(sig(0.020000000000000004), "0.02");
        assert_eq!(sig(0.00030000000000000003), "0.0003");
        assert_eq!(sig(80.0), "80");
        assert_eq!(sig(0.35), "0.35");
        assert_eq!(sig(2.71239), "2.712");
        assert_eq!(sig(99999.0), "1e5");
        assert_eq!(sig(123456.0), "1.235e5");
        assert_eq!(sig(1.5e-7), "1.5e-7");
        assert_eq!(sig(-2.0), "-2");
        assert_eq!(sig(0.0), "0");
    }

    #[test]
    fn prefixes_for_an_axis_follow_its_largest_value() {
        assert_eq!(prefix_for(4e-6, "m"), (1e6, "um".into()));
        assert_eq!(prefix_for(1e-3, "m"), (1e3, "mm".into()));
        assert_eq!(prefix_for(999e-6, "m"), (1e6, "um".into()));
        assert_eq!(prefix_for(0.0, "s"), (1.0, "s".into()));
        assert_eq!(prefix_for(1e-15, "m"), (1e12, "pm".into()));
    }
}
