//! Kind `trace`: the command read from a trace file, with derivatives from a zero-phase
//! smoothing differentiator.
//!
//! A quantised command cannot be differentiated by differencing: a 1 nm step differenced five
//! times at 10 kHz is `1e-9 * 2^4 / (1e-4)^5 ~ 1.6e12 m/s^5`. Because the whole command is known
//! in advance, each sample is instead fitted, by least squares, with a polynomial of degree `p`
//! over the `2M + 1` samples around it (Savitzky-Golay; `M = round(smoothing_s / (2 h))`) and the
//! fit's derivatives are taken at the sample:
//!
//! `y^(d)(t_i) ~ (1 / (M h)^d) sum_{k=-M}^{M} w_d[k] y_{i+k}`, with `w_d = Q R^-T b_d`, where
//! `Q R` is the QR factorisation of the Vandermonde matrix `V[k][j] = (k / M)^j` and
//! `b_d[j] = d/dx^d x^j` at `x = 0`. The window is centred (no phase lag); within `M` samples of
//! either end it is shifted inside the data and the fit is evaluated off-centre. Polynomials up
//! to degree `p` pass through exactly; the noise gain of derivative `d` falls as
//! `M^-(d + 1/2)`.
//!
//! Between samples (a job period other than the trace's), the command is the degree-5 Taylor
//! expansion around the nearest sample: `y^(k)(t_i + e) = sum_{d=k}^{5} y^(d)(t_i) e^(d-k) / (d-k)!`.
//! Trajectory time 0 is the trace's first row.

use std::path::{Path, PathBuf};

use feedloop_control::controller::REF_DERIVS;
use feedloop_model::params::{ConfigError, Fields, Range};
use feedloop_trace::{Trace, TraceError};

use super::poly::FACT;
use super::{Ctx, RefState, Trajectory};

/// Default window of the smoothing differentiator, s.
pub const DEFAULT_SMOOTHING_S: f64 = 0.02;
/// Default degree of the local fits.
pub const DEFAULT_FIT_DEGREE: usize = 7;

/// A least-squares polynomial fit over `2M + 1` equally spaced points `x_k = k / M`.
struct LocalFit {
    /// Orthonormal columns of the Vandermonde matrix (each of length `2M + 1`).
    q: Vec<Vec<f64>>,
    /// Columns of the upper-triangular factor: `r_cols[j][i] = R[i][j]` for `i <= j`.
    r_cols: Vec<Vec<f64>>,
    m: usize,
}

impl LocalFit {
    fn new(m: usize, degree: usize) -> Self {
        let len = 2 * m + 1;
        let xs: Vec<f64> = (0..len)
            .map(|k| (k as f64 - m as f64) / m.max(1) as f64)
            .collect();
        let mut q: Vec<Vec<f64>> = Vec::with_capacity(degree + 1);
        let mut r_cols = Vec::with_capacity(degree + 1);
        for j in 0..=degree {
            let mut v: Vec<f64> = xs.iter().map(|x| x.powi(j as i32)).collect();
            let mut col = vec![0.0; j + 1];
            // Modified Gram-Schmidt, twice for orthogonality to rounding.
            for _ in 0..2 {
                for (qi, ri) in q.iter().zip(col.iter_mut()) {
                    let c: f64 = qi.iter().zip(&v).map(|(a, b)| a * b).sum();
                    *ri += c;
                    v.iter_mut().zip(qi).for_each(|(vv, qq)| *vv -= c * qq);
                }
            }
            let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            col[j] = norm;
            v.iter_mut().for_each(|x| *x /= norm);
            q.push(v);
            r_cols.push(col);
        }
        Self { q, r_cols, m }
    }

    /// Weights giving the `d`-th derivative (w.r.t. `x`) of the fit at `x0`.
    fn weights(&self, x0: f64, d: usize) -> Vec<f64> {
        // b[j] = d^d/dx^d x^j at x0; solve R^T z = b by forward substitution.
        let mut z: Vec<f64> = Vec::with_capacity(self.q.len());
        for (j, col) in self.r_cols.iter().enumerate() {
            let b = if j < d {
                0.0
            } else {
                let falling: f64 = (0..d).map(|k| (j - k) as f64).product();
                falling * x0.powi((j - d) as i32)
            };
            let acc = b - col.iter().zip(&z).map(|(r, zi)| r * zi).sum::<f64>();
            z.push(acc / col[j]);
        }
        let mut w = vec![0.0; 2 * self.m + 1];
        for (zj, qj) in z.iter().zip(&self.q) {
            w.iter_mut().zip(qj).for_each(|(wk, qk)| *wk += zj * qk);
        }
        w
    }
}

/// Smoothed value and derivatives 1..5 of a uniformly sampled signal `y` (step `period_s`) by
/// local polynomial fits of `degree` over `2 half_width + 1` samples (see the module docs).
/// The window and degree are reduced to what the data allow (`half_width <= (n - 1) / 2`,
/// `degree <= 2 half_width`); derivatives above the degree are zero.
pub fn differentiate(y: &[f64], period_s: f64, half_width: usize, degree: usize) -> Vec<RefState> {
    let n = y.len();
    if n < 2 {
        return y
            .iter()
            .map(|v| {
                let mut s = [0.0; REF_DERIVS];
                s[0] = *v;
                s
            })
            .collect();
    }
    let m = half_width.clamp(1, (n - 1) / 2);
    let degree = degree.clamp(1, 2 * m);
    let len = 2 * m + 1;
    let fit = LocalFit::new(m, degree);
    let nd = REF_DERIVS.min(degree + 1);
    let scale: Vec<f64> = (0..nd)
        .map(|d| 1.0 / (m as f64 * period_s).powi(d as i32))
        .collect();
    let mut out = vec![[0.0; REF_DERIVS]; n];
    let apply = |w: &[Vec<f64>], start: usize, o: &mut RefState| {
        let seg = &y[start..start + len];
        for ((od, wd), sd) in o.iter_mut().zip(w).zip(&scale) {
            let s: f64 = wd.iter().zip(seg).map(|(a, b)| a * b).sum();
            *od = s * sd;
        }
    };
    // Interior: centred window.
    let centre: Vec<Vec<f64>> = (0..nd).map(|d| fit.weights(0.0, d)).collect();
    for (i, o) in out.iter_mut().enumerate().take(n - m).skip(m) {
        apply(&centre, i - m, o);
    }
    // Ends: window shifted inside the data, fit evaluated off-centre.
    for i in 0..m {
        let x0 = (i as f64 - m as f64) / m as f64;
        let w: Vec<Vec<f64>> = (0..nd).map(|d| fit.weights(x0, d)).collect();
        apply(&w, 0, &mut out[i]);
        let j = n - 1 - i;
        let w: Vec<Vec<f64>> = (0..nd).map(|d| fit.weights(-x0, d)).collect();
        apply(&w, n - len, &mut out[j]);
    }
    out
}

/// A command taken from a trace (kind `trace`).
pub struct TraceCommand {
    axes: Vec<String>,
    source: PathBuf,
    period_s: f64,
    /// Per axis, per trace sample: smoothed value and derivatives.
    states: Vec<Vec<RefState>>,
    /// For axes without a column: held position.
    duration_s: f64,
}

impl TraceCommand {
    /// Builds the command of `axes` from the columns `columns` (same order) of `trace`, with a
    /// smoothing window of `smoothing_s` (s) and local fits of `degree`.
    pub fn new(
        trace: &Trace,
        axes: &[String],
        columns: &[String],
        smoothing_s: f64,
        degree: usize,
    ) -> Result<Self, TraceError> {
        let h = trace.period_s();
        let m = ((smoothing_s / (2.0 * h)).round() as usize).max(1);
        let mut states = Vec::with_capacity(axes.len());
        for c in columns {
            let y = trace.require(c)?;
            states.push(differentiate(y, h, m, degree));
        }
        Ok(Self {
            axes: axes.to_vec(),
            source: trace.path.clone(),
            period_s: h,
            duration_s: trace.span_s(),
            states,
        })
    }

    /// The trace file it came from.
    pub fn source(&self) -> &Path {
        &self.source
    }

    /// The trace's sampling period, s.
    pub fn trace_period_s(&self) -> f64 {
        self.period_s
    }
}

impl Trajectory for TraceCommand {
    axes_and_duration!(self => self.duration_s);

    fn eval(&self, t_s: f64, out: &mut [RefState]) {
        for (o, st) in out.iter_mut().zip(&self.states) {
            let n = st.len();
            *o = [0.0; REF_DERIVS];
            if n == 0 {
                continue;
            }
            if t_s.is_nan() || t_s >= self.duration_s {
                o[0] = st[n - 1][0];
                continue;
            }
            if t_s <= 0.0 {
                o[0] = st[0][0];
                continue;
            }
            let i = ((t_s / self.period_s).round() as usize).min(n - 1);
            let e = t_s - i as f64 * self.period_s;
            let s = &st[i];
            for (k, ok) in o.iter_mut().enumerate() {
                // Horner on sum_{d>=k} s[d] e^(d-k) / (d-k)!.
                let mut acc = 0.0;
                for d in (k..REF_DERIVS).rev() {
                    acc = acc * e + s[d] / FACT[d - k];
                }
                *ok = acc;
            }
        }
    }

    fn kind(&self) -> &str {
        "trace"
    }
}

/// Why the command file `rel` (read from the job's folder `dir`) is not there, and what to do:
/// a path written from the current folder instead of the job's (`examples/jobs/cmd.csv` in a job
/// in `examples/jobs/`) is named as such with the line to write; otherwise the step that makes
/// the file, writing it where the job reads it.
fn missing_file(dir: &Path, rel: &str, made_by: Option<&str>) -> String {
    let path = dir.join(rel);
    let in_dir = Path::new(rel).strip_prefix(dir).ok().filter(|_| {
        !dir.as_os_str().is_empty() && dir != Path::new(".") && Path::new(rel).is_relative()
    });
    let (target, fix) = match in_dir {
        Some(inner) => (
            Path::new(rel).to_path_buf(),
            format!(
                "; the path is read from the job's folder ({}/), so the folder is named twice: \
                 write file = \"{}\"",
                dir.display(),
                inner.display()
            ),
        ),
        None if Path::new(rel).is_relative() && Path::new(rel).exists() => {
            let abs = std::fs::canonicalize(rel).unwrap_or_else(|_| rel.into());
            return format!(
                "{}: no such file (the path is read from the job's folder, {}/); `{rel}` is there \
                 from the current folder: write its path from the job's folder, or file = \"{}\"",
                path.display(),
                dir.display(),
                abs.display()
            );
        }
        None => (
            path.clone(),
            format!(
                " (the path is read from the job's folder, {}/)",
                dir.display()
            ),
        ),
    };
    if in_dir.is_some() && target.exists() {
        return format!("{}: no such file{fix}", path.display());
    }
    // a command file made by another step (an excitation): say which step
    let how = match made_by {
        Some(cmd) => format!("make it first: `{cmd} --out {}`", target.display()),
        None => format!(
            "if it is an excitation, make it first with `feedloop excite --kind random-segments|prbs|multisine --out {}` (docs/identification.md)",
            target.display()
        ),
    };
    format!("{}: no such file{fix}; {how}", path.display())
}

/// `kind = "trace"`.
pub(crate) fn build(mut f: Fields, ctx: &Ctx) -> Result<Box<dyn Trajectory>, ConfigError> {
    let rel = f.str("file")?;
    let dir = f.file().parent().unwrap_or(Path::new("."));
    let path = dir.join(rel);
    let mut columns: Vec<String> = ctx.axes.iter().map(|a| format!("{a}.cmd")).collect();
    if let Some(t) = f.opt_table("columns")? {
        for (axis, v) in t {
            let key = format!("columns.{axis}");
            let i = ctx.axis_index(&f, &key, axis)?;
            columns[i] = v
                .as_str()
                .ok_or_else(|| {
                    f.error(&key, format!("must be a column name, got {}", v.type_str()))
                })?
                .to_string();
        }
    }
    let made_by = f.opt_str("made_by")?;
    let smoothing_s = f.f64_or("smoothing_s", Range::Positive, DEFAULT_SMOOTHING_S)?;
    let degree = f
        .opt_i64("fit_degree", 2, 11)?
        .unwrap_or(DEFAULT_FIT_DEGREE as i64) as usize;
    let file = f.file();
    let (k_file, k_columns, k_smoothing) =
        (f.path("file"), f.path("columns"), f.path("smoothing_s"));
    f.finish()?;
    let err = |key: &str, reason: String| ConfigError::new(file, key, reason);
    if !path.exists() {
        return Err(err(&k_file, missing_file(dir, rel, made_by)));
    }
    let trace = Trace::read(&path).map_err(|e| err(&k_file, format!("{e}")))?;
    for c in &columns {
        trace
            .require(c)
            .map_err(|e| err(&k_columns, format!("{e}")))?;
    }
    let h = trace.period_s();
    let m = (smoothing_s / (2.0 * h)).round() as usize;
    if 2 * m + 1 < degree + 3 {
        return Err(err(
            &k_smoothing,
            format!(
                "{smoothing_s} s spans {} samples of this {h} s trace; fits of degree {degree} need at least {} (longer smoothing_s or lower fit_degree)",
                2 * m + 1,
                degree + 3
            ),
        ));
    }
    if trace.len() < 2 * m + 1 {
        return Err(err(
            &k_smoothing,
            format!(
                "the window of {} samples is longer than the trace ({} rows)",
                2 * m + 1,
                trace.len()
            ),
        ));
    }
    // A job period far finer than the trace's would stretch each sample's Taylor expansion
    // over many cycles; up to 100x is allowed.
    if ctx.period_s * 100.0 < h {
        return Err(err(
            &k_file,
            format!(
                "trace period {h} s is more than 100 times the control period {} s",
                ctx.period_s
            ),
        ));
    }
    let cmd = TraceCommand::new(&trace, ctx.axes, &columns, smoothing_s, degree)
        .map_err(|e| err(&k_columns, format!("{e}")))?;
    Ok(Box::new(cmd))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::poly::smoothstep;
    use crate::test_util::*;
    use feedloop_trace::TraceWriter;

    #[test]
    fn polynomials_up_to_the_fit_degree_are_differentiated_exactly() {
        let h = 1e-3;
        let n = 200;
        // y = 0.3 + 2 t - t^2 + 5 t^3 + 7 t^5 (degree 5 <= 7), at every sample incl. the ends.
        let f = |t: f64| -> RefState {
            [
                0.3 + 2.0 * t - t * t + 5.0 * t.powi(3) + 7.0 * t.powi(5),
                2.0 - 2.0 * t + 15.0 * t * t + 35.0 * t.powi(4),
                -2.0 + 30.0 * t + 140.0 * t.powi(3),
                30.0 + 420.0 * t * t,
                840.0 * t,
                840.0,
            ]
        };
        let y: Vec<f64> = (0..n).map(|k| f(k as f64 * h)[0]).collect();
        let d = differentiate(&y, h, 10, 7);
        for (k, s) in d.iter().enumerate() {
            let e = f(k as f64 * h);
            for j in 0..REF_DERIVS {
                // Rounding of y (~1e-16) is amplified by 1 / (M h)^j (1e8 for snap).
                let floor = 1e-11 / (10.0 * h).powi(j as i32);
                assert!(
                    (s[j] - e[j]).abs() < 1e-6 * (1.0 + e[j].abs()) + floor,
                    "sample {k} derivative {j}: {} vs {}",
                    s[j],
                    e[j]
                );
            }
        }
    }

    /// Analytic 50 mm / 0.3 s C5 move starting at 0.05 s.
    fn c5_move(t: f64) -> RefState {
        let (d, tt) = (0.05, 0.3);
        let s = smoothstep((t - 0.05) / tt);
        std::array::from_fn(|k| d * s[k] / tt.powi(k as i32))
    }

    #[test]
    fn the_smoothing_differentiator_recovers_a_quantised_move_where_differencing_blows_up() {
        let h = 1e-4;
        let n = 4001; // 0.4 s at 10 kHz
        let q = 1e-9;
        let y: Vec<f64> = (0..n)
            .map(|k| (c5_move(k as f64 * h)[0] / q).round() * q)
            .collect();
        // Default window: 0.02 s = 2 * 100 samples, degree 7.
        let d = differentiate(&y, h, 100, 7);
        let mut peak = [0.0f64; REF_DERIVS];
        let mut err = [0.0f64; REF_DERIVS];
        for (k, s) in d.iter().enumerate() {
            let e = c5_move(k as f64 * h);
            for j in 0..REF_DERIVS {
                peak[j] = peak[j].max(e[j].abs());
                err[j] = err[j].max((s[j] - e[j]).abs());
            }
        }
        let rel: Vec<f64> = (0..REF_DERIVS).map(|j| err[j] / peak[j]).collect();
        // Naive: difference the quantised samples j times (backward differences, compared at
        // the centre of their stencil).
        let mut naive_rel = [0.0f64; REF_DERIVS];
        let mut cur = y.clone();
        for j in 1..REF_DERIVS {
            cur = cur.windows(2).map(|w| (w[1] - w[0]) / h).collect();
            let mut worst = 0.0f64;
            for (k, v) in cur.iter().enumerate() {
                let t = (k as f64 + j as f64 / 2.0) * h;
                worst = worst.max((v - c5_move(t)[j]).abs());
            }
            naive_rel[j] = worst / peak[j];
        }
        eprintln!("peaks {peak:?}\nsmoothing differentiator error / peak {rel:?}\nnaive differencing error / peak {naive_rel:?}");
        // Measured: error / peak = 4e-8 (position), 1.3e-7, 5.2e-6, 1.6e-4, 2.3e-3, 6.7e-2;
        // naive differencing: 2e-5, 2.9e-2, 16, 1.0e4, 5.6e6.
        assert!(err[0] < 1e-9, "position within 1 nm: {}", err[0]);
        assert!(rel[1] < 1e-5, "velocity {}", rel[1]);
        assert!(
            rel[2] < 1e-4,
            "acceleration error < 0.01 % of peak: {}",
            rel[2]
        );
        assert!(rel[3] < 1e-3, "jerk error < 0.1 % of peak: {}", rel[3]);
        assert!(rel[4] < 1e-2, "snap error < 1 % of peak: {}", rel[4]);
        assert!(rel[5] < 0.15, "crackle error < 15 % of peak: {}", rel[5]);
        assert!(naive_rel[3] > 1.0, "naive jerk is noise: {}", naive_rel[3]);
        assert!(naive_rel[4] > 1e3, "naive snap blows up: {}", naive_rel[4]);
        assert!(
            naive_rel[5] > 1e6,
            "naive crackle blows up: {}",
            naive_rel[5]
        );
        assert!(naive_rel[5] > 1e4 * rel[5]);
    }

    fn write_trace(dir: &Path, name: &str, h: f64, n: usize) -> PathBuf {
        let path = dir.join(name);
        let cols: Vec<String> = ["t", "x.cmd", "x.load", "y.cmd", "y.load"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        let mut w = TraceWriter::create(&path, &[], &cols).unwrap();
        for k in 0..n {
            let t = k as f64 * h;
            let p = c5_move(t)[0];
            w.write_row(&[t + 2.0, p, p, -0.5 * p, 0.0]).unwrap();
        }
        w.finish().unwrap();
        path
    }

    fn tmpdir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("feedloop-traj-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_trace_command_at_another_period_is_resampled_smoothly() {
        let dir = tmpdir("resample");
        write_trace(&dir, "cmd.csv", 1e-3, 451); // 1 kHz trace, 0.45 s
        let t: toml::Table = "kind = \"trace\"\nfile = \"cmd.csv\"\nsmoothing_s = 0.02"
            .parse()
            .unwrap();
        let axes = vec!["x".to_string(), "y".to_string()];
        let tr = crate::build(&t, &dir.join("job.toml"), &axes, 1e-4).unwrap();
        assert!((tr.duration_s() - 0.45).abs() < 1e-9);
        // Between the 1 kHz samples the 10 kHz command follows the analytic move.
        for k in 0..4500 {
            let t = k as f64 * 1e-4;
            let s = at(tr.as_ref(), t);
            let e = c5_move(t);
            assert!(
                (s[0][0] - e[0]).abs() < 2e-9,
                "{t}: {} vs {}",
                s[0][0],
                e[0]
            );
            assert!((s[0][1] - e[1]).abs() < 1e-5 * 0.46, "{t}");
            assert!((s[0][2] - e[2]).abs() < 1e-3 * 6.0, "{t}");
            assert!((s[1][0] + 0.5 * e[0]).abs() < 2e-9);
        }
        check_final_hold(tr.as_ref());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn trace_derivatives_match_central_differences_of_the_interpolant() {
        let dir = tmpdir("fd");
        write_trace(&dir, "cmd.csv", 1e-4, 4001);
        let t: toml::Table = "kind = \"trace\"\nfile = \"cmd.csv\"\ncolumns = { y = \"x.load\" }"
            .parse()
            .unwrap();
        let axes = vec!["x".to_string(), "y".to_string()];
        let tr = crate::build(&t, &dir.join("job.toml"), &axes, 1e-4).unwrap();
        // Central differences within one sample's Taylor expansion (h << sample period).
        let h = 1e-7;
        for k in 1..399 {
            let t = k as f64 * 1e-3 + 1e-5;
            let lo = at(tr.as_ref(), t - h);
            let mid = at(tr.as_ref(), t);
            let hi = at(tr.as_ref(), t + h);
            for d in 1..5 {
                let fd = (hi[0][d - 1] - lo[0][d - 1]) / (2.0 * h);
                assert!(
                    (fd - mid[0][d]).abs()
                        <= 1e-6 * (1.0 + mid[0][d].abs()) + 1e-6 * 10f64.powi(d as i32 * 2),
                    "t={t} d={d}: {fd} vs {}",
                    mid[0][d]
                );
            }
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn a_missing_trace_column_is_named_with_the_file() {
        let dir = tmpdir("missing");
        write_trace(&dir, "cmd.csv", 1e-4, 400);
        let t: toml::Table = "kind = \"trace\"\nfile = \"cmd.csv\"".parse().unwrap();
        let axes = vec!["x".to_string(), "z".to_string()];
        let e = crate::build(&t, &dir.join("job.toml"), &axes, 1e-4)
            .err()
            .unwrap();
        assert_eq!(e.key, "trajectory.columns");
        assert!(e.reason.contains("missing column `z.cmd`"), "{e}");
        assert!(e.reason.contains("cmd.csv"), "{e}");
        let t: toml::Table = "kind = \"trace\"\nfile = \"nope.csv\"".parse().unwrap();
        let e = crate::build(&t, &dir.join("job.toml"), &axes, 1e-4)
            .err()
            .unwrap();
        assert_eq!(e.key, "trajectory.file");
        let t: toml::Table = "kind = \"trace\"\nfile = \"cmd.csv\"\nsmoothing_s = 0.0002"
            .parse()
            .unwrap();
        let e = crate::build(&t, &dir.join("job.toml"), &axes[..1], 1e-4)
            .err()
            .unwrap();
        assert_eq!(e.key, "trajectory.smoothing_s");
        std::fs::remove_dir_all(&dir).ok();
    }
}
