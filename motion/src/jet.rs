//! Truncated Taylor series ("jets") of order 5: exact derivatives of compositions up to the 5th.
//!
//! A jet `u = [u0, u1, ..., u5]` stands for `u(t0 + e) = sum_k u_k e^k + O(e^6)`, so the `k`-th
//! time derivative at `t0` is `k! u_k`. The operations below are the standard recurrences
//! (each coefficient from the lower ones, no allocation):
//!
//! - product `w_k = sum_{j<=k} u_j v_{k-j}`; quotient `w_k = (u_k - sum_{j>=1} v_j w_{k-j}) / v_0`
//! - square root `w_0 = sqrt(u_0)`, `w_k = (u_k - sum_{j=1}^{k-1} w_j w_{k-j}) / (2 w_0)`
//! - sine/cosine `s_k = (1/k) sum_{j=1}^k j u_j c_{k-j}`, `c_k = -(1/k) sum_{j=1}^k j u_j s_{k-j}`
//! - `atan2(y, x)`: `w' = (x y' - y x') / (x^2 + y^2)`, integrated term by term
//!
//! This is Faa di Bruno's formula evaluated numerically: e.g. the circle
//! `x = R cos(phi(t))` gets its 5th derivative from the jet of `phi` without a symbolic formula.

use feedloop_control::controller::REF_DERIVS;

use super::RefState;

/// Taylor coefficients 0..5 of a function of time around one instant.
pub type Jet = [f64; REF_DERIVS];

const N: usize = REF_DERIVS;
const FACT: [f64; N] = [1.0, 1.0, 2.0, 6.0, 24.0, 120.0];

/// The jet of a function whose value and derivatives 1..5 are `d`.
pub fn from_derivs(d: &RefState) -> Jet {
    let mut j = [0.0; N];
    for k in 0..N {
        j[k] = d[k] / FACT[k];
    }
    j
}

/// Value and derivatives 1..5 of a jet.
pub fn to_derivs(j: &Jet) -> RefState {
    let mut d = [0.0; N];
    for k in 0..N {
        d[k] = j[k] * FACT[k];
    }
    d
}

/// A constant.
pub fn constant<const L: usize>(c: f64) -> [f64; L] {
    let mut j = [0.0; L];
    if let Some(j0) = j.first_mut() {
        *j0 = c;
    }
    j
}

/// The independent variable at `x0` (value `x0`, first derivative 1).
pub fn variable<const L: usize>(x0: f64) -> [f64; L] {
    let mut j = constant(x0);
    if let Some(j1) = j.get_mut(1) {
        *j1 = 1.0;
    }
    j
}

/// `u + v`.
pub fn add<const L: usize>(u: &[f64; L], v: &[f64; L]) -> [f64; L] {
    std::array::from_fn(|k| u[k] + v[k])
}

/// `u - v`.
pub fn sub<const L: usize>(u: &[f64; L], v: &[f64; L]) -> [f64; L] {
    std::array::from_fn(|k| u[k] - v[k])
}

/// `c u`.
pub fn scale<const L: usize>(u: &[f64; L], c: f64) -> [f64; L] {
    std::array::from_fn(|k| c * u[k])
}

/// `u + c`.
pub fn add_const<const L: usize>(u: &[f64; L], c: f64) -> [f64; L] {
    let mut w = *u;
    if let Some(w0) = w.first_mut() {
        *w0 += c;
    }
    w
}

/// `u v`.
pub fn mul<const L: usize>(u: &[f64; L], v: &[f64; L]) -> [f64; L] {
    let mut w = [0.0; L];
    for k in 0..L {
        for j in 0..=k {
            w[k] += u[j] * v[k - j];
        }
    }
    w
}

/// `u / v` (`v_0 != 0`).
pub fn div<const L: usize>(u: &[f64; L], v: &[f64; L]) -> [f64; L] {
    let mut w = [0.0; L];
    for k in 0..L {
        let mut acc = u[k];
        for j in 1..=k {
            acc -= v[j] * w[k - j];
        }
        w[k] = acc / v[0];
    }
    w
}

/// `sqrt(u)` (`u_0 > 0`).
pub fn sqrt<const L: usize>(u: &[f64; L]) -> [f64; L] {
    let mut w = [0.0; L];
    if L == 0 {
        return w;
    }
    w[0] = u[0].sqrt();
    for k in 1..L {
        let mut acc = u[k];
        for j in 1..k {
            acc -= w[j] * w[k - j];
        }
        w[k] = acc / (2.0 * w[0]);
    }
    w
}

/// `(sin u, cos u)`.
pub fn sin_cos<const L: usize>(u: &[f64; L]) -> ([f64; L], [f64; L]) {
    let mut s = [0.0; L];
    let mut c = [0.0; L];
    if L == 0 {
        return (s, c);
    }
    (s[0], c[0]) = super::trig::sin_cos(u[0]);
    for k in 1..L {
        let (mut sa, mut ca) = (0.0, 0.0);
        for j in 1..=k {
            let ju = j as f64 * u[j];
            sa += ju * c[k - j];
            ca -= ju * s[k - j];
        }
        s[k] = sa / k as f64;
        c[k] = ca / k as f64;
    }
    (s, c)
}

/// The jet of `w` given the value `w0` and the jet of its derivative `dw` (order one lower
/// is enough: `w_k = dw_{k-1} / k`).
fn integrate<const L: usize>(w0: f64, dw: &[f64; L]) -> [f64; L] {
    let mut w = constant(w0);
    for k in 1..L {
        w[k] = dw[k - 1] / k as f64;
    }
    w
}

/// Derivative jet `u'` (the top coefficient is lost, which `integrate` never reads).
fn derivative<const L: usize>(u: &[f64; L]) -> [f64; L] {
    let mut d = [0.0; L];
    for k in 0..L.saturating_sub(1) {
        d[k] = (k + 1) as f64 * u[k + 1];
    }
    d
}

/// `atan2(y, x)` (not both zero), continuous in time around `t0`.
pub fn atan2<const L: usize>(y: &[f64; L], x: &[f64; L]) -> [f64; L] {
    if L == 0 {
        return [0.0; L];
    }
    let num = sub(&mul(x, &derivative(y)), &mul(y, &derivative(x)));
    let den = add(&mul(x, x), &mul(y, y));
    integrate(y[0].atan2(x[0]), &div(&num, &den))
}

/// `atan(u)`.
pub fn atan<const L: usize>(u: &[f64; L]) -> [f64; L] {
    if L == 0 {
        return [0.0; L];
    }
    let den = add_const(&mul(u, u), 1.0);
    integrate(u[0].atan(), &div(&derivative(u), &den))
}

/// `f(x0 + d)` for a function with Taylor coefficients `c_k = f^(k)(x0) / k!` at `x0`, where
/// `d` is a jet with zero value (the deviation from `x0`): Horner's rule on jets.
pub fn compose_taylor<const L: usize>(c: &[f64], d: &[f64; L]) -> [f64; L] {
    let mut acc = [0.0; L];
    for ck in c.iter().take(L).rev() {
        acc = add_const(&mul(&acc, d), *ck);
    }
    acc
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Jet of `t` around `t0`.
    fn var(t0: f64) -> Jet {
        let mut j = [0.0; N];
        j[0] = t0;
        j[1] = 1.0;
        j
    }

    fn close(a: &Jet, b: &Jet, tol: f64) {
        for k in 0..N {
            assert!(
                (a[k] - b[k]).abs() <= tol * (1.0 + b[k].abs()),
                "k={k}: {a:?} vs {b:?}"
            );
        }
    }

    #[test]
    fn sine_of_time_has_the_known_taylor_series() {
        let t0: f64 = 0.7;
        let (s, c) = sin_cos(&var(t0));
        let (st, ct) = t0.sin_cos();
        let expect_s = [st, ct, -st / 2.0, -ct / 6.0, st / 24.0, ct / 120.0];
        let expect_c = [ct, -st, -ct / 2.0, st / 6.0, ct / 24.0, -st / 120.0];
        close(&s, &expect_s, 1e-14);
        close(&c, &expect_c, 1e-14);
    }

    #[test]
    fn short_jets_agree_with_the_leading_terms_of_long_ones() {
        let x0 = 0.37;
        let long: Jet = variable(x0);
        let short: [f64; 2] = variable(x0);
        let f6 = atan2(
            &sqrt(&add_const(&mul(&long, &long), 2.0)),
            &sin_cos(&long).1,
        );
        let f2 = atan2(
            &sqrt(&add_const(&mul(&short, &short), 2.0)),
            &sin_cos(&short).1,
        );
        assert_eq!(f2[0], f6[0]);
        assert!((f2[1] - f6[1]).abs() < 1e-15 * (1.0 + f6[1].abs()));
        // a one-term jet is the plain value
        let v: [f64; 1] = div(&constant(3.0), &constant(4.0));
        assert_eq!(v, [0.75]);
    }

    #[test]
    fn quotient_square_root_and_arctangent_invert_their_operations() {
        let u = [1.3, -0.4, 0.25, 0.1, -0.05, 0.02];
        let v = [0.8, 0.3, -0.2, 0.15, 0.07, -0.01];
        close(&mul(&div(&u, &v), &v), &u, 1e-13);
        let r = sqrt(&u);
        close(&mul(&r, &r), &u, 1e-13);
        // tan(atan(u)) = u via sin/cos.
        let a = atan(&u);
        let (s, c) = sin_cos(&a);
        close(&div(&s, &c), &u, 1e-12);
        // atan2(k y, k x) = atan2(y, x), and atan2(u, 1) = atan(u).
        close(&atan2(&u, &constant(1.0)), &a, 1e-13);
        close(
            &atan2(&scale(&u, 2.0), &scale(&v, 2.0)),
            &atan2(&u, &v),
            1e-13,
        );
    }
}
