//! `feedloop commission`: the whole commissioning of one axis in one command (see
//! docs/commissioning.md). The model file stands for the machine: it is played as the plant,
//! and the procedure sees only the records of its experiments and the data-sheet facts.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{anyhow, Context};
use feedloop_analysis::commission::device::SimDevice;
use feedloop_analysis::commission::facts::Facts;
use feedloop_analysis::commission::{commission, report, Commissioning};
use feedloop_model::model::ModelFile;

/// `feedloop commission`.
#[derive(clap::Args, Debug)]
pub struct CommissionArgs {
    /// Model file of the machine's axis (played as the plant; the procedure reads only its
    /// data-sheet facts: lead, gear ratio, torque limit, encoder, starting gains).
    #[arg(long)]
    machine: PathBuf,
    /// Motor inertia from the data sheet, kg m^2.
    #[arg(long)]
    jm_kgm2: f64,
    /// Output folder (commission.json, model.toml, job.toml, quadrant.toml, report.html).
    #[arg(long)]
    out: PathBuf,
    /// Name of the axis in the written job.
    #[arg(long, default_value = "x")]
    axis: String,
    /// Travel either side of the start position the experiments may use, m.
    #[arg(long, default_value_t = 0.1)]
    travel_m: f64,
    /// Smallest phase margin of the tuned loop, deg.
    #[arg(long, default_value_t = 45.0)]
    phase_margin_deg: f64,
    /// Smallest gain margin of the tuned loop, dB.
    #[arg(long, default_value_t = 6.0)]
    gain_margin_db: f64,
    /// Print commission.json only.
    #[arg(long)]
    json: bool,
    /// Do not draw the progress bar.
    #[arg(long)]
    quiet: bool,
}

/// Runs the procedure; exit 0 when every target is met, 1 when the outputs were written but a
/// target was not met (said as NOT MET).
pub fn run(a: CommissionArgs) -> anyhow::Result<ExitCode> {
    let model = ModelFile::load(&a.machine).map_err(|e| anyhow!("{e}"))?;
    let facts = Facts::from_model(&model, a.jm_kgm2, a.travel_m).map_err(|e| anyhow!("{e}"))?;
    if !feedloop_model::job::valid_name(&a.axis, false) {
        return Err(anyhow!(
            "--axis `{}`: an axis name is letters, digits and underscores, starting with a letter",
            a.axis
        ));
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let mut dev = SimDevice::new(&a.machine).map_err(|e| anyhow!("{e}"))?;
    let bar = if a.quiet || a.json || !std::io::stderr().is_terminal() {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(600).with_style(
            indicatif::ProgressStyle::with_template(
                "{bar:30} {pos:>3}/{len} s of machine time  {msg}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        )
    };
    let t0 = std::time::Instant::now();
    let mut progress = |name: &str, machine_s: f64| {
        bar.set_position(machine_s as u64);
        bar.set_message(name.to_string());
    };
    let asked = (a.phase_margin_deg, a.gain_margin_db);
    let c = commission(&mut dev, &facts, &a.axis, asked, &a.out, &mut progress)
        .map_err(|e| anyhow!("commissioning stopped: {e}"))?;
    bar.finish_and_clear();
    let compute_s = t0.elapsed().as_secs_f64();
    let mut j = report::json(&c);
    j["compute_s"] = compute_s.into();
    let write = |name: &str, text: &str| {
        let p = a.out.join(name);
        std::fs::write(&p, text).with_context(|| format!("writing {}", p.display()))
    };
    write("commission.json", &serde_json::to_string_pretty(&j)?)?;
    let machine = std::path::absolute(&a.machine)?;
    write("job.toml", &report::job_text(&c, &a.axis, &machine))?;
    write("report.html", &report::html(&c))?;
    let unmet = unmet(&c);
    if a.json {
        println!("{}", serde_json::to_string_pretty(&j)?);
    } else {
        print_text(&c, compute_s, &a.out);
        for u in &unmet {
            println!("NOT MET: {u}");
        }
    }
    Ok(if unmet.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

/// The targets not met, in words.
fn unmet(c: &Commissioning) -> Vec<String> {
    let mut u = Vec::new();
    if !c.identified.credible {
        u.push(format!(
            "the stiffness and load inertia are not credible after {} excitation records: {}",
            c.identified.attempts.len(),
            c.identified.problems.join("; ")
        ));
    }
    let m = &c.tuned.margins;
    if !m.met {
        u.push(format!(
            "margins {:.1} deg / {:.1} dB, asked {} deg / {} dB",
            m.phase_deg, m.gain_db, c.tuned.asked.0, c.tuned.asked.1
        ));
    }
    let v = &c.verification;
    if !v.met {
        u.push(format!(
            "the circle's contour error falls {:.1}x (asked {}x)",
            v.contour_ratio,
            feedloop_analysis::commission::verify::TARGET_RATIO
        ));
    }
    u.extend(c.warnings.iter().cloned());
    u
}

/// The result in a few lines.
fn print_text(c: &Commissioning, compute_s: f64, out: &std::path::Path) {
    let (s, id, t, v) = (&c.survey, &c.identified, &c.tuned, &c.verification);
    let fr = &s.friction;
    println!(
        "friction: Coulomb {:.4} / {:.4} N m (+ / -), static {:.4} / {:.4} N m, Stribeck {:.3} rad/s, viscous {:.2e} N m s/rad; noise at standstill {:.2e} rad/s; total inertia {:.3e} kg m^2",
        fr.positive.coulomb_nm,
        fr.negative.coulomb_nm,
        fr.positive.static_nm,
        fr.negative.static_nm,
        fr.positive.stribeck_rad_per_s,
        fr.positive.viscous_nms_per_rad,
        s.noise_rad_per_s,
        s.total_inertia_kgm2
    );
    println!(
        "KL {:.1} N m/rad (+-{:.2} %), JL {:.4e} kg m^2 (+-{:.2} %), backlash {} after {} excitation records",
        id.kl_nm_per_rad,
        id.kl_ci_pct.unwrap_or(f64::NAN),
        t.jl_kgm2,
        id.jl_ci_pct.unwrap_or(f64::NAN),
        id.backlash_m
            .map_or("none seen".into(), |b| format!("{:.2} um", b * 1e6)),
        id.attempts.len()
    );
    if let Some(ch) = &t.inertia_check {
        println!(
            "load inertia by simulation matching: {:.4e} kg m^2 ({:+.2} % from the fit, tolerance +-{:.2} %){}",
            ch.jl_sim_match_kgm2,
            ch.difference_pct,
            ch.tolerance_pct,
            if ch.agrees {
                ""
            } else {
                "; beyond it, the fit is kept"
            }
        );
    }
    println!(
        "gains: Kp {:.1} 1/s, Kv {:.3} N m s/rad, Tv {:.2} ms; margins {:.1} deg, {:.1} dB",
        t.gains.kp_per_s,
        t.gains.kv_nms_per_rad,
        t.gains.tv_s * 1e3,
        t.margins.phase_deg,
        t.margins.gain_db
    );
    let spikes: Vec<String> = v
        .quadrant_spike_m
        .iter()
        .enumerate()
        .map(|(i, x)| format!("pass {i}: {:.1} nm", x * 1e9))
        .collect();
    println!("quadrant learning: {}", spikes.join(", "));
    println!(
        "circle R {:.0} mm at {:.0} mm/s: contour error {:.3} um before, {:.3} um with the feedforwards, {:.3} um after ({:.1}x); following error {:.1} um -> {:.2} um",
        v.radius_m * 1e3,
        v.feed_m_per_s * 1e3,
        v.before.contour_max_m * 1e6,
        v.feedforward.contour_max_m * 1e6,
        v.after.contour_max_m * 1e6,
        v.contour_ratio,
        v.before.following_max_m * 1e6,
        v.after.following_max_m * 1e6
    );
    println!(
        "{} experiments, {:.0} s of machine time, {:.1} s of compute; written to {}",
        c.experiments.len(),
        c.machine_s,
        compute_s,
        out.display()
    );
}
