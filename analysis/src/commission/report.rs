//! The output files: `commission.json`, `job.toml` (the tuned chain and the feedforwards on the
//! machine), `report.html` (the plots a servo engineer reads at a glance). `model.toml` is
//! written by the procedure itself (the verification's learner reads it).

use std::fmt::Write;
use std::path::Path;

use rustfft::num_complex::Complex64;
use serde_json::json;

use super::model_out::{chain, Compensation};
use super::verify::circle;
use super::Commissioning;
use crate::plot::{Axis, Mark, Plot, Series};

/// `commission.json`.
pub fn json(c: &Commissioning) -> serde_json::Value {
    let t = &c.tuned;
    json!({
        "kl_nm_per_rad": c.identified.kl_nm_per_rad,
        "jl_kgm2": t.jl_kgm2,
        "backlash_m": c.identified.backlash_m,
        "friction": {
            "positive": c.survey.friction.positive,
            "negative": c.survey.friction.negative,
            "coulomb_nm": c.survey.friction.coulomb_nm(),
            "noise_rad_per_s": c.survey.noise_rad_per_s,
            "lost_motion_m": c.survey.lost_motion_m,
            "total_inertia_kgm2": c.survey.total_inertia_kgm2,
        },
        "gains": { "start": t.start, "tuned": t.gains },
        "margins": {
            "phase_deg": t.margins.phase_deg,
            "gain_db": t.margins.gain_db,
            "asked_phase_deg": t.asked.0,
            "asked_gain_db": t.asked.1,
            "met": t.margins.met,
            "start": t.start_margins,
        },
        "experiments": c.experiments,
        "verification": c.verification,
        "identification": c.identified,
        "inertia_check": t.inertia_check,
        "machine_s": c.machine_s,
        "warnings": c.warnings,
        "facts": c.facts,
    })
}

/// `job.toml`: the verification circle on two axes like the commissioned one, each with the
/// tuned cascade, the inverse-model feedforward and the learned quadrant compensation over the
/// measured friction; `machine` is the model file the axes run on.
pub fn job_text(c: &Commissioning, axis: &str, machine: &Path) -> String {
    let twin = format!("{axis}2");
    let comp = Compensation {
        inverse: true,
        friction: true,
        quadrant: Some("quadrant.toml".into()),
    };
    let (f, s, id, t) = (&c.facts, &c.survey, &c.identified, &c.tuned);
    let mut ch = chain(axis, t.gains, &comp, f, s, id, t.jl_kgm2);
    ch.extend(chain(&twin, t.gains, &comp, f, s, id, t.jl_kgm2));
    let mut job = toml::Table::new();
    job.insert("name".into(), "commissioned".into());
    job.insert("period_s".into(), toml::Value::Float(f.period_s));
    let mut axes = toml::Table::new();
    for a in [axis, twin.as_str()] {
        let mut m = toml::Table::new();
        m.insert("model".into(), machine.display().to_string().into());
        axes.insert(a.into(), toml::Value::Table(m));
    }
    job.insert("axes".into(), toml::Value::Table(axes));
    job.insert("chain".into(), toml::Value::Array(ch));
    let mut traj = circle(c.verification.radius_m, c.verification.feed_m_per_s);
    traj.insert(
        "axes".into(),
        toml::Value::Array(vec![axis.into(), twin.as_str().into()]),
    );
    job.insert("trajectory".into(), toml::Value::Table(traj));
    format!(
        "# The commissioned loop: written by feedloop commission. Two axes like the commissioned one\n\
         # on the verification circle; the gains, the inverse-model feedforward (identified JL, KL),\n\
         # the measured friction curve, the backlash crossing and the learned pulses (quadrant.toml).\n{}",
        toml::to_string(&job).unwrap_or_default()
    )
}

/// `report.html`: response with the fit, friction per direction, margins, circle before/after.
pub fn html(c: &Commissioning) -> String {
    let mut h = String::from(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>Commissioning report</title>\
         <style>body{font-family:sans-serif;max-width:960px;margin:auto}td,th{padding:2px 8px;text-align:right}</style>\
         </head><body><h1>Commissioning report</h1>",
    );
    let t = &c.tuned;
    let _ = write!(
        h,
        "<table><tr><th>KL</th><td>{:.1} N m/rad</td></tr><tr><th>JL</th><td>{:.4e} kg m<sup>2</sup></td></tr>\
         <tr><th>backlash</th><td>{}</td></tr><tr><th>Coulomb (+ / -)</th><td>{:.4} / {:.4} N m</td></tr>\
         <tr><th>gains</th><td>Kp {:.1} 1/s, Kv {:.3} N m s/rad, Tv {:.2} ms</td></tr>\
         <tr><th>margins</th><td>{:.1} deg, {:.1} dB (asked {} deg, {} dB): {}</td></tr>\
         <tr><th>contour error</th><td>{:.3} um before, {:.3} um after: {:.1}x</td></tr>\
         <tr><th>machine time</th><td>{:.0} s</td></tr></table>",
        c.identified.kl_nm_per_rad,
        t.jl_kgm2,
        c.identified
            .backlash_m
            .map_or("none seen".into(), |b| format!("{:.2} um", b * 1e6)),
        c.survey.friction.positive.coulomb_nm,
        c.survey.friction.negative.coulomb_nm,
        t.gains.kp_per_s,
        t.gains.kv_nms_per_rad,
        t.gains.tv_s * 1e3,
        t.margins.phase_deg,
        t.margins.gain_db,
        t.asked.0,
        t.asked.1,
        if t.margins.met { "met" } else { "NOT MET" },
        c.verification.before.contour_max_m * 1e6,
        c.verification.after.contour_max_m * 1e6,
        c.verification.contour_ratio,
        c.machine_s
    );
    for p in [
        response_plot(c),
        friction_plot(c),
        margins_plot(c),
        circle_plot(c),
    ]
    .into_iter()
    .flatten()
    {
        h.push_str(&p);
    }
    h.push_str("</body></html>\n");
    h
}

/// The measured torque -> motor velocity response with the two-mass model at the result.
fn response_plot(c: &Commissioning) -> Option<String> {
    let frf = c.identified.frf.as_ref()?;
    let (jm, jl, kl) = (c.facts.jm_kgm2, c.tuned.jl_kgm2, c.identified.kl_nm_per_rad);
    let f_hi = 3.0 * c.identified.resonance_hz;
    let keep: Vec<usize> = (0..frf.f_hz.len())
        .filter(|&k| frf.f_hz[k] >= 5.0 && frf.f_hz[k] <= f_hi)
        .collect();
    let f: Vec<f64> = keep.iter().map(|&k| frf.f_hz[k]).collect();
    let m: Vec<f64> = keep.iter().map(|&k| frf.h[k].norm()).collect();
    let fit: Vec<f64> = f
        .iter()
        .map(|&fz| {
            let s = Complex64::new(0.0, 2.0 * std::f64::consts::PI * fz);
            ((jl * s * s + kl) / (s * (jm * jl * s * s + kl * (jm + jl)))).norm()
        })
        .collect();
    Some(
        Plot::new(
            "Torque to motor velocity: measured and the two-mass fit",
            Axis::log("frequency", "Hz"),
            Axis::log("|H|", "rad/(s N m)"),
        )
        .series(Series::line("measured", "#1f77b4", &f, &m))
        .series(Series::dashed("two-mass fit", "#d62728", &f, &fit))
        .vline(Mark::new(
            "anti-resonance",
            c.identified.antiresonance_hz,
            "#2ca02c",
        ))
        .vline(Mark::new("resonance", c.identified.resonance_hz, "#9467bd"))
        .svg(),
    )
}

/// Measured friction per direction with the fitted curves.
fn friction_plot(c: &Commissioning) -> Option<String> {
    let fr = &c.survey.friction;
    let mut p = Plot::new(
        "Friction per direction (motor side)",
        Axis::log("motor speed", "rad/s"),
        Axis::linear("friction torque", "N m"),
    );
    for (name, pts, side, col) in [
        ("positive", &fr.points_positive, &fr.positive, "#1f77b4"),
        ("negative", &fr.points_negative, &fr.negative, "#d62728"),
    ] {
        let w: Vec<f64> = pts.iter().map(|x| x.0).collect();
        let curve: Vec<f64> = w.iter().map(|&x| side.at(x)).collect();
        p = p
            .series(Series::points(&format!("{name} measured"), col, pts))
            .series(Series::dashed(&format!("{name} fit"), col, &w, &curve));
    }
    p.has_data().then(|| p.svg())
}

/// Phase and gain margins of the start and the tuned gains against the asked ones.
fn margins_plot(c: &Commissioning) -> Option<String> {
    let t = &c.tuned;
    let s = t.start_margins?;
    let pts_start = [(s.gain_db, s.phase_deg)];
    let pts_tuned = [(t.margins.gain_db, t.margins.phase_deg)];
    Some(
        Plot::new(
            "Loop margins on the identified model",
            Axis::linear("gain margin", "dB"),
            Axis::linear("phase margin", "deg"),
        )
        .series(Series::points("starting gains", "#7f7f7f", &pts_start))
        .series(Series::points("tuned gains", "#1f77b4", &pts_tuned))
        .vline(Mark::new("asked gain margin", t.asked.1, "#d62728"))
        .hline(Mark::new("asked phase margin", t.asked.0, "#d62728"))
        .svg(),
    )
}

/// The circle's radial error over the angle, before and after.
fn circle_plot(c: &Commissioning) -> Option<String> {
    let v = &c.verification;
    let mut p = Plot::new(
        "Verification circle: radial error",
        Axis::linear("angle", "rad"),
        Axis::linear("radial error", "m").si(),
    );
    for (name, run, col) in [
        (
            "before (starting gains, no feedforward)",
            &v.before,
            "#7f7f7f",
        ),
        ("after commissioning", &v.after, "#1f77b4"),
    ] {
        let x: Vec<f64> = run.curve.iter().map(|q| q.0).collect();
        let y: Vec<f64> = run.curve.iter().map(|q| q.1).collect();
        p = p.series(Series::dots(name, col, &x, &y));
    }
    p.has_data().then(|| p.svg())
}
