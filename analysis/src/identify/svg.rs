//! The plots of the identification tools, drawn with [`crate::plot`]: the Bode plot of
//! `identify stiffness --svg` and the heat map of `tune --svg`.

use feedloop_model::units::sig;

use super::frf::Frf;
use super::tune::{GridAxis, TuneResult};
use crate::plot::{stacked, Axis, HeatMap, Mark, Plot, Series, PALETTE};

/// The unit of a tunable parameter, from its name.
pub fn param_unit(name: &str) -> &'static str {
    match name {
        "kp_per_s" => "1/s",
        "kv_nms_per_rad" => "N m s/rad",
        "tv_s" => "s",
        _ => "",
    }
}

/// The Bode plot of the torque-to-motor-velocity response `frf` between `f_lo` and `f_hi`:
/// magnitude, phase and coherence over log frequency, with a reference line at each of `marks`
/// (label, Hz).
pub fn bode_svg(frf: &Frf, f_lo: f64, f_hi: f64, marks: &[(&str, f64)]) -> String {
    let inside: Vec<usize> = (0..frf.f_hz.len())
        .filter(|&i| frf.f_hz[i] >= f_lo && frf.f_hz[i] <= f_hi && frf.f_hz[i] > 0.0)
        .collect();
    let f: Vec<f64> = inside.iter().map(|&i| frf.f_hz[i]).collect();
    let mag: Vec<f64> = inside
        .iter()
        .map(|&i| 20.0 * frf.h[i].norm().max(1e-300).log10())
        .collect();
    let phase: Vec<f64> = inside
        .iter()
        .map(|&i| frf.h[i].arg().to_degrees())
        .collect();
    let coh: Vec<f64> = inside.iter().map(|&i| frf.coherence[i]).collect();
    let lo = f_lo.max(f.first().copied().unwrap_or(f_lo));
    let freq = || Axis::log("frequency", "Hz").range(lo, f_hi);
    let colours = ["#d62728", "#2ca02c", "#9467bd", "#ff7f0e"];
    let with_marks = |mut p: Plot, legend: bool| {
        for (k, (label, hz)) in marks.iter().enumerate() {
            let text = if legend {
                format!("{label} {} Hz", sig(*hz))
            } else {
                String::new()
            };
            p = p.vline(Mark::new(&text, *hz, colours[k % colours.len()]));
        }
        p
    };
    let magnitude = with_marks(
        Plot::new(
            "magnitude",
            freq(),
            Axis::linear("magnitude", "dB re 1 (rad/s)/(N m)"),
        )
        .size(860.0, 280.0)
        .series(Series::line("measured response", PALETTE[0], &f, &mag)),
        true,
    );
    let phase_ticks = (-2..=2)
        .map(|k| (90.0 * k as f64, format!("{}", 90 * k)))
        .collect();
    let phase = with_marks(
        Plot::new(
            "phase",
            freq(),
            Axis::linear("phase", "deg")
                .range(-190.0, 190.0)
                .ticks(phase_ticks),
        )
        .size(860.0, 230.0)
        .series(Series::line("measured response", PALETTE[0], &f, &phase)),
        false,
    );
    let coherence = with_marks(
        Plot::new(
            "coherence",
            freq(),
            Axis::linear("coherence", "0 to 1").range(0.0, 1.05),
        )
        .size(860.0, 180.0)
        .series(Series::line("coherence", PALETTE[2], &f, &coh)),
        false,
    );
    stacked(
        &format!(
            "identify stiffness: torque to motor velocity ({} segments averaged)",
            frf.segments
        ),
        &[magnitude, phase, coherence],
    )
}

/// The heat map of `tune --svg` for `axis`: E over the first two grid parameters (the best over
/// the others), rejected sets grey, the best set marked.
pub fn tune_heatmap_svg(grid: &[GridAxis], r: &TuneResult, axis: &str) -> String {
    let xs = &grid[0];
    let ys = grid.get(1);
    let ny = ys.map_or(1, |y| y.values.len());
    let inner: usize = grid.iter().skip(1).map(|g| g.values.len()).product();
    let per_y = inner / ny.max(1);
    let mut m = vec![vec![f64::NAN; xs.values.len()]; ny];
    for (k, e) in r.all.iter().enumerate() {
        let ix = k / inner.max(1);
        let iy = (k % inner.max(1)) / per_y.max(1);
        if let Some(v) = e.e {
            let c = &mut m[iy][ix];
            if c.is_nan() || v < *c {
                *c = v;
            }
        }
    }
    // the best set's cell: its first two parameters
    let value_of = |name: &str| match name {
        "kp_per_s" => r.best.kp_per_s,
        "kv_nms_per_rad" => r.best.kv_nms_per_rad,
        _ => r.best.tv_s,
    };
    let nearest = |g: &GridAxis| {
        let v = value_of(&g.name);
        (0..g.values.len())
            .min_by(|&a, &b| (g.values[a] - v).abs().total_cmp(&(g.values[b] - v).abs()))
            .unwrap_or(0)
    };
    let best_text = grid
        .iter()
        .map(|g| format!("{} {}", g.name, sig(value_of(&g.name))))
        .collect::<Vec<_>>()
        .join(", ");
    let marker = r.e_best.is_finite().then(|| {
        (
            nearest(xs),
            ys.map_or(0, nearest),
            format!("best: {best_text} (E {})", sig(r.e_best)),
        )
    });
    let (y_axis, y_values) = match ys {
        Some(y) => (Axis::linear(&y.name, param_unit(&y.name)), y.values.clone()),
        None => (
            Axis::linear("(one grid parameter)", "").ticks(vec![]),
            vec![0.0],
        ),
    };
    let over = match ys {
        Some(y) => format!("{} and {}", xs.name, y.name),
        None => xs.name.clone(),
    };
    let others = if grid.len() > 2 {
        " (the best over the others)"
    } else {
        ""
    };
    HeatMap {
        title: format!(
            "tune, axis {axis}: E over {over}{others}; defaults E {}",
            sig(r.e_default)
        ),
        x: Axis::linear(&xs.name, param_unit(&xs.name)),
        y: y_axis,
        xs: xs.values.clone(),
        ys: y_values,
        values: m,
        value_label: "E, weighted RMS error".into(),
        log_colour: true,
        missing: "rejected (torque saturated or margins too small)".into(),
        marker,
    }
    .svg()
}
