//! Exact zero-order-hold discretisation of the linear part of an axis, and the hot-path kernel.
//!
//! For a continuous model `x' = A x + B u` with `u` held over `dt`, the exact discrete model is
//! `x(t + dt) = Ad x(t) + Bd u` with `[[Ad, Bd], [0, I]] = exp([[A, B], [0, 0]] dt)`
//! (matrix exponential by nalgebra, computed once when the axis is built). The bank holds one
//! `(Ad, Bd)` per mode (which bodies stick, whether the backlash gap is open) and per
//! sub-step level (`dt = period / 2^(base + level)`), so that events inside a period can be
//! located by bisection without any run-time matrix function.

use nalgebra::DMatrix;

/// Largest state dimension (2-mass 4 + third mass 2 + current lag 1).
pub(crate) const MAX_N: usize = 8;
/// Inputs: held torque command (into the lag or the motor), motor-side torque, load-side torque.
pub(crate) const NU: usize = 3;

/// A state vector (only the first `n` entries are used).
pub(crate) type State = [f64; MAX_N];

/// Discrete matrices for every (mode, level), column-major `[Ad | Bd]` blocks of `n x (n + 3)`.
#[derive(Debug, Clone)]
pub(crate) struct Bank {
    levels: usize,
    block: usize,
    data: Vec<f64>,
    /// Offset of level 0 of each mode's blocks in `data` (`usize::MAX`: mode not built).
    offset_of_mode: [usize; 8],
    /// The kernel for this state dimension, chosen once.
    kernel: Kernel,
}

type Kernel = fn(&[f64], &State, &[f64; NU]) -> State;

/// Computes `exp([[A, B], [0, 0]] dt)` and returns `(Ad, Bd)`.
pub(crate) fn discretise(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    dt: f64,
) -> (DMatrix<f64>, DMatrix<f64>) {
    let n = a.nrows();
    let m = b.ncols();
    let mut aug = DMatrix::<f64>::zeros(n + m, n + m);
    aug.view_mut((0, 0), (n, n)).copy_from(&(a * dt));
    aug.view_mut((0, n), (n, m)).copy_from(&(b * dt));
    let e = aug.exp();
    (
        e.view((0, 0), (n, n)).into_owned(),
        e.view((0, n), (n, m)).into_owned(),
    )
}

impl Bank {
    /// Builds the bank. `modes` lists the modes to build; `model(mode)` gives the continuous
    /// `(A, B)` of a mode and the state rows that are frozen in it (stuck bodies), which are
    /// made exact identity rows with zero input.
    pub fn new(
        n: usize,
        period_s: f64,
        base_level: u32,
        levels: usize,
        modes: &[usize],
        model: impl Fn(usize) -> (DMatrix<f64>, DMatrix<f64>, Vec<usize>),
    ) -> Self {
        let block = n * (n + NU);
        let mut data = vec![0.0; block * levels * modes.len()];
        let mut slot_of_mode = [usize::MAX; 8];
        for (slot, &mode) in modes.iter().enumerate() {
            slot_of_mode[mode] = slot;
            let (a, b, frozen) = model(mode);
            for level in 0..levels {
                let dt = period_s / f64::from(1u32 << (base_level as usize + level));
                let (mut ad, mut bd) = discretise(&a, &b, dt);
                for &r in &frozen {
                    for c in 0..n {
                        ad[(r, c)] = if r == c { 1.0 } else { 0.0 };
                    }
                    for c in 0..NU {
                        bd[(r, c)] = 0.0;
                    }
                }
                let off = (slot * levels + level) * block;
                let blk = &mut data[off..off + block];
                for c in 0..n {
                    for r in 0..n {
                        blk[c * n + r] = ad[(r, c)];
                    }
                }
                for c in 0..NU {
                    for r in 0..n {
                        blk[(n + c) * n + r] = bd[(r, c)];
                    }
                }
            }
        }
        let mut offset_of_mode = [usize::MAX; 8];
        for (o, &slot) in offset_of_mode.iter_mut().zip(&slot_of_mode) {
            if slot != usize::MAX {
                *o = slot * levels * block;
            }
        }
        let kernel: Kernel = match n {
            2 => kernel::<2>,
            3 => kernel::<3>,
            4 => kernel::<4>,
            5 => kernel::<5>,
            6 => kernel::<6>,
            7 => kernel::<7>,
            _ => kernel::<8>,
        };
        Self {
            levels,
            block,
            data,
            offset_of_mode,
            kernel,
        }
    }

    /// One exact sub-step in `mode` at `level`: returns `Ad x + Bd u` (`x` unchanged for a
    /// mode that was not built).
    #[inline]
    pub fn step(&self, mode: usize, level: usize, x: &State, u: &[f64; NU]) -> State {
        let base = self.offset_of_mode[mode & 7];
        if base == usize::MAX {
            return *x;
        }
        let off = base + level.min(self.levels.saturating_sub(1)) * self.block;
        match self.data.get(off..off + self.block) {
            Some(m) => (self.kernel)(m, x, u),
            None => *x,
        }
    }
}

#[inline(always)]
fn kernel<const N: usize>(m: &[f64], x: &State, u: &[f64; NU]) -> State {
    if m.len() < N * (N + NU) {
        return *x;
    }
    // Three independent accumulators (even state columns, odd state columns, inputs) keep the
    // floating-point dependency chain short; the summation order is fixed, so results are
    // bit-reproducible.
    let mut ya = [0.0f64; N];
    let mut yb = [0.0f64; N];
    let mut yu = [0.0f64; N];
    for (j, col) in m[..N * N].chunks_exact(N).enumerate() {
        let z = x[j];
        let acc = if j % 2 == 0 { &mut ya } else { &mut yb };
        for i in 0..N {
            acc[i] += col[i] * z;
        }
    }
    for (j, col) in m[N * N..N * (N + NU)].chunks_exact(N).enumerate() {
        let z = u[j];
        for i in 0..N {
            yu[i] += col[i] * z;
        }
    }
    let mut out = [0.0; MAX_N];
    for i in 0..N {
        out[i] = (ya[i] + yb[i]) + yu[i];
    }
    out
}

/// Dot product of two state-length rows with four independent partial sums.
#[inline(always)]
pub(crate) fn dot8(a: &State, b: &State) -> f64 {
    let mut acc = [0.0f64; 4];
    for i in 0..MAX_N {
        acc[i % 4] += a[i] * b[i];
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn discretised_double_integrator_matches_closed_form() {
        let a = DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]);
        let b = DMatrix::from_row_slice(2, 1, &[0.0, 2.0]);
        let (ad, bd) = discretise(&a, &b, 0.1);
        assert!((ad[(0, 1)] - 0.1).abs() < 1e-15);
        assert!((bd[(0, 0)] - 0.01).abs() < 1e-15);
        assert!((bd[(1, 0)] - 0.2).abs() < 1e-15);
    }
}
