//! Linear least squares over contiguous blocks of samples, and blocked cross-validation.
//!
//! The normal equations of each block are accumulated once; a fold's fit uses the sums of all
//! other blocks and is scored on its own block, so a k-fold cross-validation costs one pass over
//! the data. Solving uses column scaling and a pseudo-inverse, so collinear regressors (e.g. motor
//! and load inertia when only one position is measured) share the estimate instead of failing.

use nalgebra::{DMatrix, DVector};

/// Half-width of a refitted value's confidence interval, in standard errors (jackknife over
/// the blocks; with 5 blocks, 3 standard errors is about the 96 % interval of Student's t with
/// 4 degrees of freedom).
pub const CI_SIGMAS: f64 = 3.0;

/// Smallest cross-validated error reduction that counts, % of the model's error.
pub const MIN_REDUCTION_PCT: f64 = 3.0;
/// Whether a fit that takes its channel's error from `before` to `after` (%) cuts it
/// materially: by at least [`MIN_REDUCTION_PCT`] % of it (a step that moves the error in its
/// second decimal is no finding, whatever its cross-validated score).
pub fn material_cut(before: f64, after: f64) -> bool {
    after < before * (1.0 - MIN_REDUCTION_PCT / 100.0)
}

/// Normal equations of one block: `X^T X`, `X^T y`, `y^T y`, sample count.
#[derive(Debug, Clone)]
pub struct Normal {
    /// `X^T X`.
    pub xtx: DMatrix<f64>,
    /// `X^T y`.
    pub xty: DVector<f64>,
    /// `y^T y`.
    pub yty: f64,
    /// Samples.
    pub n: usize,
}

impl Normal {
    fn zeros(p: usize) -> Self {
        Self {
            xtx: DMatrix::zeros(p, p),
            xty: DVector::zeros(p),
            yty: 0.0,
            n: 0,
        }
    }

    fn add(&mut self, o: &Normal) {
        self.xtx += &o.xtx;
        self.xty += &o.xty;
        self.yty += o.yty;
        self.n += o.n;
    }

    /// The normal equations of the columns `idx` alone (in that order).
    pub fn select(&self, idx: &[usize]) -> Normal {
        let p = idx.len();
        Normal {
            xtx: DMatrix::from_fn(p, p, |i, j| self.xtx[(idx[i], idx[j])]),
            xty: DVector::from_fn(p, |i, _| self.xty[idx[i]]),
            yty: self.yty,
            n: self.n,
        }
    }

    /// Sum of squared residuals of `theta` on the samples of this block.
    pub fn sse(&self, theta: &DVector<f64>) -> f64 {
        if theta.is_empty() {
            return self.yty;
        }
        (self.yty - 2.0 * theta.dot(&self.xty) + (theta.transpose() * &self.xtx * theta)[(0, 0)])
            .max(0.0)
    }

    /// Least-squares solution (scaled pseudo-inverse): columns are scaled to unit norm and
    /// directions with a singular value below `1e-6 p` are left at zero (minimum-norm solution), so
    /// a combination the data cannot see does not move.
    pub fn solve(&self) -> DVector<f64> {
        let p = self.xty.len();
        if p == 0 {
            return DVector::zeros(0);
        }
        let scale: Vec<f64> = (0..p)
            .map(|i| {
                let d = self.xtx[(i, i)];
                if d > 0.0 {
                    1.0 / d.sqrt()
                } else {
                    0.0
                }
            })
            .collect();
        let mut a = self.xtx.clone();
        let mut b = self.xty.clone();
        for i in 0..p {
            b[i] *= scale[i];
            for j in 0..p {
                a[(i, j)] *= scale[i] * scale[j];
            }
        }
        let svd = a.svd(true, true);
        let z = svd
            .solve(&b, 1e-6 * p as f64)
            .unwrap_or_else(|_| DVector::zeros(p));
        DVector::from_iterator(p, (0..p).map(|i| z[i] * scale[i]))
    }
}

/// Splits `range` into `k` contiguous blocks of (nearly) equal length.
pub fn blocks(range: (usize, usize), k: usize) -> Vec<(usize, usize)> {
    let (a, b) = range;
    let n = b.saturating_sub(a);
    let k = k.clamp(1, n.max(1));
    (0..k)
        .map(|i| (a + n * i / k, a + n * (i + 1) / k))
        .collect()
}

/// [`blocks`] of `range` holding equal numbers of the rows where `mask` is not 0 (every row
/// when `mask` is `None`): a block of the record that is mostly standstill would otherwise
/// carry a fold of its own with a handful of informative rows, and its vote on a candidate
/// would be the noise of those few. Each boundary sits at an informative row.
pub fn blocks_of_rows(
    range: (usize, usize),
    k: usize,
    mask: Option<&[f64]>,
) -> Vec<(usize, usize)> {
    let Some(mask) = mask else {
        return blocks(range, k);
    };
    let (a, b) = range;
    let rows: Vec<usize> = (a..b.min(mask.len())).filter(|i| mask[*i] != 0.0).collect();
    let n = rows.len();
    if n < k.max(1) {
        return blocks(range, k);
    }
    let k = k.max(1);
    let mut out = Vec::with_capacity(k);
    let mut start = a;
    for i in 1..=k {
        let end = if i == k { b } else { rows[n * i / k] };
        out.push((start, end));
        start = end;
    }
    out
}

/// Dot product, four partial sums (so the compiler can vectorise it).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut s = [0.0f64; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        s[0] += x[0] * y[0];
        s[1] += x[1] * y[1];
        s[2] += x[2] * y[2];
        s[3] += x[3] * y[3];
    }
    let mut t = (s[0] + s[1]) + (s[2] + s[3]);
    for (x, y) in ra.iter().zip(rb) {
        t += x * y;
    }
    t
}

/// Dot product of `a` and `b` over the rows where the 0/1 mask `w` is 1, four partial sums.
fn dot_masked(a: &[f64], b: &[f64], w: &[f64]) -> f64 {
    let n = a.len().min(b.len()).min(w.len());
    let (a, b, w) = (&a[..n], &b[..n], &w[..n]);
    let mut s = [0.0f64; 4];
    let (ca, cb, cw) = (a.chunks_exact(4), b.chunks_exact(4), w.chunks_exact(4));
    let (ra, rb, rw) = (ca.remainder(), cb.remainder(), cw.remainder());
    for ((x, y), m) in ca.zip(cb).zip(cw) {
        s[0] += x[0] * y[0] * m[0];
        s[1] += x[1] * y[1] * m[1];
        s[2] += x[2] * y[2] * m[2];
        s[3] += x[3] * y[3] * m[3];
    }
    let mut t = (s[0] + s[1]) + (s[2] + s[3]);
    for ((x, y), m) in ra.iter().zip(rb).zip(rw) {
        t += x * y * m;
    }
    t
}

/// Normal equations of regressors `cols` and target `y` over each block.
pub fn normals(cols: &[&[f64]], y: &[f64], blocks: &[(usize, usize)]) -> Vec<Normal> {
    normals_masked(cols, y, blocks, None)
}

/// [`normals`] over the rows where the 0/1 `mask` (when given) is 1: the other rows are left out
/// of every block.
pub fn normals_masked(
    cols: &[&[f64]],
    y: &[f64],
    blocks: &[(usize, usize)],
    mask: Option<&[f64]>,
) -> Vec<Normal> {
    let p = cols.len();
    blocks
        .iter()
        .map(|&(a, b)| {
            let mut ne = Normal::zeros(p);
            let yb = &y[a..b];
            let d = |u: &[f64], v: &[f64]| match mask {
                Some(m) => dot_masked(u, v, &m[a..b]),
                None => dot(u, v),
            };
            for i in 0..p {
                let ci = &cols[i][a..b];
                ne.xty[i] = d(ci, yb);
                for (j, cj) in cols.iter().enumerate().skip(i) {
                    let v = d(ci, &cj[a..b]);
                    ne.xtx[(i, j)] = v;
                    ne.xtx[(j, i)] = v;
                }
            }
            ne.yty = d(yb, yb);
            ne.n = match mask {
                Some(m) => m[a..b].iter().filter(|w| **w != 0.0).count(),
                None => b - a,
            };
            ne
        })
        .collect()
}

/// Result of a blocked cross-validation.
#[derive(Debug, Clone)]
pub struct Cv {
    /// RMS of the out-of-fold residual over all blocks.
    pub rms: f64,
    /// Out-of-fold mean squared residual per block.
    pub fold_mse: Vec<f64>,
    /// Fit on all blocks.
    pub theta: DVector<f64>,
    /// In-sample RMS of that fit.
    pub rms_in: f64,
    /// Standard error of each coefficient of `theta`, from the spread of the leave-one-block-out
    /// fits (jackknife over the blocks, so correlated noise inside a block is accounted for).
    pub theta_se: DVector<f64>,
    /// The leave-one-block-out fits themselves (empty with fewer than two blocks).
    pub loo_theta: Vec<DVector<f64>>,
}

/// Blocked k-fold cross-validation from per-block normal equations.
pub fn cross_validate(ne: &[Normal]) -> Cv {
    let p = ne.first().map(|n| n.xty.len()).unwrap_or(0);
    let mut total = Normal::zeros(p);
    for n in ne {
        total.add(n);
    }
    let theta = total.solve();
    let rms_in = (total.sse(&theta) / total.n.max(1) as f64).sqrt();
    let mut sse = 0.0;
    let mut fold_mse = Vec::with_capacity(ne.len());
    let mut loo: Vec<DVector<f64>> = Vec::with_capacity(ne.len());
    for (i, fold) in ne.iter().enumerate() {
        let th = if ne.len() == 1 {
            theta.clone()
        } else {
            let mut train = Normal::zeros(p);
            for (j, n) in ne.iter().enumerate() {
                if j != i {
                    train.add(n);
                }
            }
            train.solve()
        };
        let s = fold.sse(&th);
        sse += s;
        fold_mse.push(s / fold.n.max(1) as f64);
        loo.push(th);
    }
    let k = loo.len() as f64;
    let theta_se = DVector::from_fn(p, |j, _| {
        if loo.len() < 2 {
            return 0.0;
        }
        let m = loo.iter().map(|t| t[j]).sum::<f64>() / k;
        ((k - 1.0) / k * loo.iter().map(|t| (t[j] - m).powi(2)).sum::<f64>()).sqrt()
    });
    Cv {
        rms: (sse / total.n.max(1) as f64).sqrt(),
        fold_mse,
        theta,
        rms_in,
        theta_se,
        loo_theta: if loo.len() < 2 { Vec::new() } else { loo },
    }
}

/// Rows at most used to size a contribution (more are thinned evenly).
const SIZE_ROWS: usize = 20_000;

/// The rows of `rows` (0/1 `mask` applied when given) a contribution is sized on: at most
/// [`SIZE_ROWS`], evenly spread.
pub fn sizing_rows(rows: (usize, usize), mask: Option<&[f64]>) -> Vec<usize> {
    let kept: Vec<usize> = (rows.0..rows.1)
        .filter(|i| mask.is_none_or(|m| m.get(*i).is_some_and(|w| *w != 0.0)))
        .collect();
    let step = kept.len().div_ceil(SIZE_ROWS).max(1);
    kept.into_iter().step_by(step).collect()
}

/// The size of the contribution of columns `cols`, whose coefficients in fit `cv` start at
/// `first`: its RMS over `rows` (its mean removed when `centred`: a constant carried by
/// another column), and the standard error of that contribution from the spread of the
/// leave-one-block-out fits (jackknife over the blocks, RMS over the rows). A contribution
/// inside a few standard errors of none is one the data cannot pin down.
pub fn contribution_size(
    cols: &[&[f64]],
    cv: &Cv,
    first: usize,
    rows: &[usize],
    centred: bool,
) -> (f64, f64) {
    if rows.is_empty() || cv.theta.len() < first + cols.len() {
        return (0.0, 0.0);
    }
    let shape = |t: &DVector<f64>| -> Vec<f64> {
        let f: Vec<f64> = rows
            .iter()
            .map(|&i| {
                cols.iter()
                    .enumerate()
                    .map(|(j, c)| t[first + j] * c[i])
                    .sum()
            })
            .collect();
        if !centred {
            return f;
        }
        let m = f.iter().sum::<f64>() / f.len() as f64;
        f.into_iter().map(|x| x - m).collect()
    };
    let n = rows.len() as f64;
    let fit = shape(&cv.theta);
    let size = (fit.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
    let k = cv.loo_theta.len();
    if k < 2 {
        return (size, 0.0);
    }
    let loo: Vec<Vec<f64>> = cv.loo_theta.iter().map(shape).collect();
    let kf = k as f64;
    let spread: f64 = (0..rows.len())
        .map(|i| {
            let m = loo.iter().map(|f| f[i]).sum::<f64>() / kf;
            loo.iter().map(|f| (f[i] - m).powi(2)).sum::<f64>()
        })
        .sum();
    (size, ((kf - 1.0) / kf * spread / n).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_contribution_is_sized_against_the_spread_of_its_block_wise_fits() {
        // y = 2 x + a small deterministic noise; z has no part in y
        let n = 2000;
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.01).sin()).collect();
        let z: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).cos()).collect();
        let mut state = 12345u64;
        let y: Vec<f64> = x
            .iter()
            .map(|v| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                2.0 * v + 0.05 * ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5)
            })
            .collect();
        let cv = cross_validate(&normals(&[&x, &z], &y, &blocks((0, n), 5)));
        assert_eq!(cv.loo_theta.len(), 5);
        let rows = sizing_rows((0, n), None);
        let (size, se) = contribution_size(&[&x], &cv, 0, &rows, false);
        let rms_x = (x.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
        assert!((size / (2.0 * rms_x) - 1.0).abs() < 1e-3, "{size}");
        assert!(size > 100.0 * se, "{size} +- {se}");
        let (size_z, se_z) = contribution_size(&[&z], &cv, 1, &rows, false);
        assert!(size_z < CI_SIGMAS * se_z, "{size_z} +- {se_z}");
        // centred: a constant column's contribution is no variation at all
        let one = vec![1.0; n];
        let cv1 = cross_validate(&normals(&[&one], &y, &blocks((0, n), 5)));
        assert!(contribution_size(&[&one], &cv1, 0, &rows, true).0 < 1e-12);
        // masked rows are left out, and no rows give no size
        let mask: Vec<f64> = (0..n).map(|i| if i < 10 { 1.0 } else { 0.0 }).collect();
        assert_eq!(sizing_rows((0, n), Some(&mask)).len(), 10);
        assert_eq!(contribution_size(&[&x], &cv, 0, &[], false), (0.0, 0.0));
    }

    #[test]
    fn blocks_of_rows_hold_equal_numbers_of_informative_rows() {
        // standstill (0) over the first 60 % and the last 20 % of 1000 rows: equal-length
        // blocks would give two folds no informative row at all
        let mask: Vec<f64> = (0..1000)
            .map(|i| if (600..800).contains(&i) { 1.0 } else { 0.0 })
            .collect();
        let bl = blocks_of_rows((0, 1000), 5, Some(&mask));
        assert_eq!(bl.len(), 5);
        assert_eq!((bl[0].0, bl[4].1), (0, 1000));
        for w in bl.windows(2) {
            assert_eq!(w[0].1, w[1].0, "{bl:?}");
        }
        for (a, b) in &bl {
            let rows = mask[*a..*b].iter().filter(|m| **m != 0.0).count();
            assert_eq!(rows, 40, "{bl:?}");
        }
        assert_eq!(blocks_of_rows((0, 1000), 5, None), blocks((0, 1000), 5));
        // fewer informative rows than blocks: the plain split
        let sparse: Vec<f64> = (0..1000).map(|i| if i == 3 { 1.0 } else { 0.0 }).collect();
        assert_eq!(
            blocks_of_rows((0, 1000), 5, Some(&sparse)),
            blocks((0, 1000), 5)
        );
    }

    #[test]
    fn least_squares_recovers_a_line_and_cross_validation_scores_noise_level() {
        let n = 1000;
        let x: Vec<f64> = (0..n).map(|k| (k as f64 * 0.37).sin()).collect();
        let one = vec![1.0; n];
        // deterministic "noise" of RMS ~0.1
        let e: Vec<f64> = (0..n)
            .map(|k| 0.1 * ((k * 7919 % 1000) as f64 / 500.0 - 1.0) * 1.732)
            .collect();
        let y: Vec<f64> = (0..n).map(|k| 2.0 * x[k] + 0.5 + e[k]).collect();
        let ne = normals(&[&x, &one], &y, &blocks((0, n), 5));
        let cv = cross_validate(&ne);
        assert!((cv.theta[0] - 2.0).abs() < 0.02, "{}", cv.theta[0]);
        assert!((cv.theta[1] - 0.5).abs() < 0.02, "{}", cv.theta[1]);
        assert!(cv.rms > 0.09 && cv.rms < 0.12, "{}", cv.rms);
    }

    #[test]
    fn collinear_columns_share_the_estimate_instead_of_failing() {
        let x: Vec<f64> = (0..100).map(|k| k as f64).collect();
        let y: Vec<f64> = x.iter().map(|v| 3.0 * v).collect();
        let ne = normals(&[&x, &x], &y, &blocks((0, 100), 1));
        let th = ne[0].solve();
        assert!((th[0] + th[1] - 3.0).abs() < 1e-9);
        assert!((th[0] - 1.5).abs() < 1e-9);
    }
}
