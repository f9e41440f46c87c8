//! The learning loop: write the table, run the job, measure, fit the next pass.

use std::path::{Path, PathBuf};

use feedloop_control::controller::REF_DERIVS;
use feedloop_model::job::Job;
use feedloop_model::params::ConfigError;

use feedloop_plugins::quadrant::{
    AxisPulses, Direction, Pulse, QuadrantCompensator, QuadrantTable, MAX_PULSES,
};

use super::curves::{fit_pass, reversal_curves, ReversalCurves, SpikeStart};
use super::options::{
    AxisSpike, LearnError, LearnOptions, LearnReport, PassReport, RunJob, RunRecords,
    MAX_BACKTRACKS,
};

/// A quadrant_compensator stage of the job: (axis index, table axis name, table path).
fn compensated_axes(job: &Job) -> Result<(Vec<(usize, String)>, PathBuf), LearnError> {
    let dir = job.path.parent().unwrap_or(Path::new("."));
    let mut out = Vec::new();
    let mut path: Option<PathBuf> = None;
    for c in job
        .chain
        .iter()
        .filter(|c| c.plugin == QuadrantCompensator::ID)
    {
        let key = format!("{}.params.table", c.key);
        let rel = c
            .params
            .get("table")
            .and_then(|v| v.as_str())
            .ok_or_else(|| {
                ConfigError::new(&job.path, &key, "is required: the table to learn into")
            })?;
        let p = dir.join(rel);
        if let Some(q) = &path {
            if *q != p {
                return Err(LearnError::SeveralTables(q.clone(), p));
            }
        }
        path = Some(p);
        let name = c
            .params
            .get("axis")
            .and_then(|v| v.as_str())
            .unwrap_or(&job.axes[c.axis].name)
            .to_string();
        out.push((c.axis, name));
    }
    match path {
        Some(p) => Ok((out, p)),
        None => Err(LearnError::NoCompensator),
    }
}

/// Commanded velocity (load units/s) of every job axis at cycles 0..n.
fn commanded_velocities(job: &Job, n: usize) -> Result<Vec<Vec<f64>>, ConfigError> {
    let names = job.axis_names();
    let traj = feedloop_motion::build(&job.trajectory, &job.path, &names, job.period_s)?;
    let map: Vec<Option<usize>> = names
        .iter()
        .map(|a| traj.axes().iter().position(|t| t == a))
        .collect();
    let mut out = vec![vec![0.0; n]; names.len()];
    let mut buf = vec![[0.0; REF_DERIVS]; traj.axes().len()];
    for k in 0..n {
        traj.eval(k as f64 * job.period_s, &mut buf);
        for (o, m) in out.iter_mut().zip(&map) {
            if let Some(j) = m {
                o[k] = buf[*j][1];
            }
        }
    }
    Ok(out)
}

/// Learns the quadrant table of `job` in up to `passes` passes.
///
/// `run` runs the job (reading the table file as it stands) and returns its records per axis
/// (`records[axis][cycle]`, job axis order, load units). The table is written before every run:
/// empty before pass 0, then with the pulses of passes 1..=p. Returns the spike of every run.
pub fn learn_quadrant(
    job: &Job,
    passes: usize,
    options: &LearnOptions,
    run: &mut RunJob<'_>,
) -> Result<LearnReport, LearnError> {
    let (axes, job_table) = compensated_axes(job)?;
    let job_table_path = job_table.clone();
    let (table_path, job) = where_to_learn(job, job_table, options)?;
    let mut table = QuadrantTable::default();
    for (_, name) in &axes {
        table.axes.insert(name.clone(), AxisPulses::default());
    }
    let mut runs = Runs {
        job: &job,
        axes: &axes,
        table_path: &table_path,
        options,
        run,
        velocities: None,
    };
    let (mut spikes, mut curves) = runs.evaluate(&table)?;
    let mut reports = vec![PassReport {
        pass: 0,
        axes: spikes.clone(),
        runs: 1,
    }];
    // Span of the first pass' pulse (grid indices), per learned axis and direction.
    let mut spans: Vec<[Option<(usize, usize)>; 2]> = axes.iter().map(|_| [None, None]).collect();
    for pass in 1..=passes {
        if spikes.iter().all(|a| a.spike <= options.accept) {
            break;
        }
        let before = spans.clone();
        let mut fitted = fit_axes(&curves, pass, &mut spans, options, SpikeStart::Threshold);
        let mut tried = 0;
        if pass == 1 {
            tried = runs.choose_spike_start(&table, &curves, before, &mut fitted)?;
        }
        let (cand, s_new, c_new, attempts) = runs.guarded_pass(&table, &fitted, &spikes)?;
        table = cand;
        spikes = s_new;
        curves = c_new;
        reports.push(PassReport {
            pass,
            axes: spikes.clone(),
            runs: tried + attempts,
        });
    }
    Ok(LearnReport {
        table_path,
        job_table: job_table_path,
        passes: reports,
        table,
    })
}

/// Where the table is learned (`options.table`, else in `options.out_dir`, else the job's own
/// table `job_table`) and the job that reads it there.
fn where_to_learn(
    job: &Job,
    job_table: PathBuf,
    options: &LearnOptions,
) -> Result<(PathBuf, Job), LearnError> {
    let elsewhere = match (&options.table, &options.out_dir) {
        (Some(t), _) => Some(t.clone()),
        (None, Some(dir)) => Some(dir.join(job_table.file_name().unwrap_or_default())),
        (None, None) => None,
    };
    Ok(match elsewhere {
        // the stages resolve a relative `table` against the job's folder: give them the path
        // as seen from here
        Some(p) => {
            let p = std::path::absolute(&p).map_err(|source| LearnError::Write {
                path: p.clone(),
                source,
            })?;
            let j = retarget(job, &p);
            (p, j)
        }
        None => (job_table, job.clone()),
    })
}

/// The runs of the learning loop: the job (reading the table at `table_path`), its learned
/// axes (job axis index, table axis name), and the commanded velocities of the last run's
/// length.
struct Runs<'a, 'r> {
    job: &'a Job,
    axes: &'a [(usize, String)],
    table_path: &'a Path,
    options: &'a LearnOptions,
    run: &'a mut RunJob<'r>,
    velocities: Option<Vec<Vec<f64>>>,
}

impl Runs<'_, '_> {
    /// Writes `t`, runs the job, and measures every learned axis.
    fn evaluate(
        &mut self,
        t: &QuadrantTable,
    ) -> Result<(Vec<AxisSpike>, Vec<ReversalCurves>), LearnError> {
        let job = self.job;
        t.save(self.table_path)
            .map_err(|source| LearnError::Write {
                path: self.table_path.to_path_buf(),
                source,
            })?;
        let records = (self.run)(job).map_err(LearnError::Run)?;
        if records.len() != job.axes.len() {
            return Err(LearnError::RecordShape {
                got: records.len(),
                want: job.axes.len(),
            });
        }
        let n = records.iter().map(Vec::len).min().unwrap_or(0);
        if self.velocities.as_ref().map(|v| v[0].len()) != Some(n) {
            self.velocities = Some(commanded_velocities(job, n)?);
        }
        let vel = self.velocities.as_ref().expect("just computed");
        Ok(measure(job, self.axes, &records, vel, t, self.options))
    }

    /// Where the spike's pulse starts is tried both ways (at the threshold point, as `fitted`,
    /// and at the reversal, where the friction flips, from the spans `before` the pass), and
    /// kept per axis as it ran better; returns the runs this took.
    fn choose_spike_start(
        &mut self,
        table: &QuadrantTable,
        curves: &[ReversalCurves],
        mut before: Vec<[Option<(usize, usize)>; 2]>,
        fitted: &mut [[Vec<Pulse>; 2]],
    ) -> Result<usize, LearnError> {
        let other = fit_axes(curves, 1, &mut before, self.options, SpikeStart::Reversal);
        let ones = vec![1.0; self.axes.len()];
        let (s_a, _) = self.evaluate(&candidate(table, self.axes, fitted, &ones))?;
        let (s_b, _) = self.evaluate(&candidate(table, self.axes, &other, &ones))?;
        for (i, o) in other.into_iter().enumerate() {
            if s_b[i].spike < s_a[i].spike {
                fitted[i] = o;
            }
        }
        Ok(2)
    }

    /// Step (6) with a guard: an axis whose spike grows gets its new pulses halved (twice),
    /// then dropped, so a pass never leaves an axis worse than the pass before. Returns the
    /// table kept, its spikes and curves, and the runs this took.
    #[allow(clippy::type_complexity)]
    fn guarded_pass(
        &mut self,
        table: &QuadrantTable,
        fitted: &[[Vec<Pulse>; 2]],
        spikes: &[AxisSpike],
    ) -> Result<(QuadrantTable, Vec<AxisSpike>, Vec<ReversalCurves>, usize), LearnError> {
        let mut scale = vec![1.0; self.axes.len()];
        let mut attempt = 0;
        loop {
            let cand = candidate(table, self.axes, fitted, &scale);
            let (s_new, c_new) = self.evaluate(&cand)?;
            let worse: Vec<usize> = (0..self.axes.len())
                .filter(|&i| scale[i] > 0.0 && s_new[i].spike > spikes[i].spike)
                .collect();
            if worse.is_empty() || attempt == MAX_BACKTRACKS {
                return Ok((cand, s_new, c_new, attempt + 1));
            }
            for i in worse {
                scale[i] = if attempt + 1 < MAX_BACKTRACKS {
                    scale[i] * 0.5
                } else {
                    0.0
                };
            }
            attempt += 1;
        }
    }
}

/// The spike and mean reversal curves of every learned axis (`axes`: job axis index, table
/// axis name) in `records`, as run with table `t`; `vel` is the commanded velocity per job axis.
fn measure(
    job: &Job,
    axes: &[(usize, String)],
    records: &RunRecords,
    vel: &[Vec<f64>],
    t: &QuadrantTable,
    options: &LearnOptions,
) -> (Vec<AxisSpike>, Vec<ReversalCurves>) {
    let mut spikes = Vec::new();
    let mut curves = Vec::new();
    for (ax, name) in axes {
        let rec = &records[*ax];
        let cmd: Vec<f64> = rec.iter().map(|r| r.cmd).collect();
        let load: Vec<f64> = rec.iter().map(|r| r.load).collect();
        let c = reversal_curves(
            &cmd,
            &load,
            &vel[*ax],
            job.period_s,
            (options.lead_s, options.window_s),
        );
        spikes.push(AxisSpike {
            axis: job.axes[*ax].name.clone(),
            spike: c.spike,
            reversals: c.events[0] + c.events[1],
            pulses: t
                .axes
                .get(name)
                .map_or(0, |p| p.to_positive.len() + p.to_negative.len()),
        });
        curves.push(c);
    }
    (spikes, curves)
}

/// The pass' pulses per learned axis and direction, fitted to `curves`; updates `spans` (the
/// first pass' pulse span per axis and direction).
fn fit_axes(
    curves: &[ReversalCurves],
    pass: usize,
    spans: &mut [[Option<(usize, usize)>; 2]],
    options: &LearnOptions,
    start: SpikeStart,
) -> Vec<[Vec<Pulse>; 2]> {
    let mut fitted: Vec<[Vec<Pulse>; 2]> = Vec::new();
    for (i, c) in curves.iter().enumerate() {
        let mut per_dir: [Vec<Pulse>; 2] = [Vec::new(), Vec::new()];
        for dir in Direction::ALL {
            let d = dir.index();
            let (pulses, span) = fit_pass(
                &c.curves[d],
                (c.period_s, c.lead),
                (pass as u32, start),
                spans[i][d],
                options,
            );
            spans[i][d] = span;
            per_dir[d] = pulses;
        }
        fitted.push(per_dir);
    }
    fitted
}

/// `table` with the `fitted` pulses of every learned axis added, their amplitudes times the
/// axis' `scale` (an axis at scale 0 gets none), up to [`MAX_PULSES`] per direction.
fn candidate(
    table: &QuadrantTable,
    axes: &[(usize, String)],
    fitted: &[[Vec<Pulse>; 2]],
    scale: &[f64],
) -> QuadrantTable {
    let mut cand = table.clone();
    for (i, (_, name)) in axes.iter().enumerate() {
        if scale[i] == 0.0 {
            continue;
        }
        let entry = cand.axes.entry(name.clone()).or_default();
        for dir in Direction::ALL {
            let list = entry.get_mut(dir);
            let room = MAX_PULSES.saturating_sub(list.len());
            list.extend(fitted[i][dir.index()].iter().take(room).map(|p| Pulse {
                amplitude: p.amplitude * scale[i],
                ..*p
            }));
        }
    }
    cand
}

/// `job` with every quadrant_compensator stage reading `table`.
fn retarget(job: &Job, table: &Path) -> Job {
    let mut j = job.clone();
    for c in j
        .chain
        .iter_mut()
        .filter(|c| c.plugin == QuadrantCompensator::ID)
    {
        c.params.insert(
            "table".into(),
            toml::Value::String(table.to_string_lossy().into_owned()),
        );
    }
    j
}
