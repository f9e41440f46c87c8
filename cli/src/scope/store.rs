//! What the scope holds: a bounded ring of the last cycles (one column per signal), the events
//! found in them, the trigger and its capture. Live blocks and recorded traces land in the same
//! store, so the page draws both the same way.

use std::collections::VecDeque;

use feedloop_model::units::si;
use feedloop_trace::log::{
    is_deadline_miss, PlantRecord, SchedRecord, REC_OVERRUN, REC_STALL, REC_STOPPING,
};
use serde::Serialize;

/// Per-axis signals of a live loop: (suffix, unit, what).
pub const AXIS_SIGNALS: [(&str, &str, &str); 10] = [
    ("cmd", "m", "commanded position"),
    ("load", "m", "measured load position"),
    ("following_error", "m", "following error (cmd - load)"),
    ("motor", "rad", "measured motor position"),
    ("motor_vel", "rad/s", "measured motor velocity"),
    ("torque", "N m", "torque applied by the drive"),
    ("torque_cmd", "N m", "torque the chain commanded"),
    (
        "vel_cmd",
        "rad/s",
        "velocity command (position stage + feedforward)",
    ),
    (
        "torque_ff",
        "N m",
        "torque feedforward (feedforward + compensator stages)",
    ),
    ("reference", "m", "position reference the chain used"),
];

/// Column of the round-trip latency, us.
pub const LATENCY: &str = "latency_us";
/// Column of the contour error (distance of the measured point to the commanded path), m.
pub const CONTOUR: &str = "contour_error";

/// Computes a cycle's contour error from its time (s) and its axes' rows.
pub type ContourFn = Box<dyn FnMut(f64, &[feedloop_trace::log::AxisRecord]) -> Option<f64> + Send>;

/// Kinds of loop events the scope marks and can trigger on.
pub const EVENT_KINDS: [&str; 6] = [
    "deadline_miss",
    "plant_overrun",
    "stall",
    "swap",
    "rollback",
    "safety_stop",
];

/// One loop event.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Event {
    /// One of [`EVENT_KINDS`].
    pub kind: &'static str,
    /// Cycle.
    pub cycle: u64,
    /// Its time, s.
    pub t_s: f64,
    /// Words (a swap's plugins and torque step, a refusal's reason).
    pub detail: String,
}

/// Most events kept (oldest dropped; the cycles they mark are counted per kind in `window`).
const MAX_EVENTS: usize = 2000;

/// A trigger condition.
#[derive(Debug, Clone, PartialEq)]
pub enum Condition {
    /// A signal crosses `level` upwards (`rising`) or downwards.
    Level {
        /// Column index.
        column: usize,
        /// Level, in the signal's unit.
        level: f64,
        /// Rising or falling.
        rising: bool,
    },
    /// A loop event of this kind.
    Event(&'static str),
}

/// An armed trigger.
#[derive(Debug, Clone)]
pub struct Trigger {
    /// What fires it.
    pub condition: Condition,
    /// Capture before the trigger, s.
    pub pre_s: f64,
    /// Capture after the trigger, s.
    pub post_s: f64,
    /// How it was described to the page.
    pub describe: String,
}

/// A captured stretch of cycles.
#[derive(Debug, Clone)]
pub struct Capture {
    /// What fired it.
    pub describe: String,
    /// Trigger cycle and time, s.
    pub trigger_cycle: u64,
    /// Trigger time, s.
    pub trigger_t_s: f64,
    /// First cycle.
    pub first_cycle: u64,
    /// Control period, s.
    pub period_s: f64,
    /// Column names (same as the store's).
    pub columns: Vec<String>,
    /// Values, one vector per column.
    pub data: Vec<Vec<f64>>,
    /// Events inside.
    pub events: Vec<Event>,
    /// Cells held from the cycle before because a record was lost.
    pub held_cells: u64,
}

/// The bounded ring of cycles.
pub struct Store {
    /// Control period, s (0 until known).
    pub period_s: f64,
    /// Time of cycle 0, s (a trace's first time; 0 for a live loop).
    pub t0_s: f64,
    /// Axis names.
    pub axes: Vec<String>,
    /// Column names.
    pub columns: Vec<String>,
    /// Units per column.
    pub units: Vec<String>,
    capacity: usize,
    /// Ring storage, column-major: `data[c][slot]`.
    data: Vec<Vec<f64>>,
    /// Cycle held in each slot for the plant's and the scheduler's columns (u64::MAX: none).
    plant_seq: Vec<u64>,
    sched_seq: Vec<u64>,
    /// Newest plant cycle seen.
    pub newest: Option<u64>,
    /// First plant cycle seen.
    first: Option<u64>,
    /// Newest scheduler cycle seen.
    pub newest_sched: Option<u64>,
    /// Events, oldest first.
    pub events: VecDeque<Event>,
    /// Per slot, the kinds of event of the cycle it holds (bit `i`: `EVENT_KINDS[i]`).
    marks: Vec<u8>,
    /// Marks of cycles whose records have not come yet: (kind index, cycle).
    pending: Vec<(usize, u64)>,
    /// Cycles held in the ring with an event of each kind, in [`EVENT_KINDS`] order: the counts
    /// over the window the ring holds (a deadline miss, an overrun, a stall cycle each counted
    /// per cycle, as `summary.json` counts them).
    pub window: [u64; EVENT_KINDS.len()],
    /// Plant cycles missing from the records (gaps in the cycle numbers).
    pub lost_plant: u64,
    /// Scheduler cycles missing (cycles it never answered, or records lost), beyond the samples
    /// it skipped on purpose.
    pub lost_sched: u64,
    /// Blocks the scope's queue overwrote before they were read (the scope fell behind), plant
    /// and scheduler.
    pub lost_blocks: [u64; 2],
    /// The next expected block number of each source.
    pub next_block: [Option<u32>; 2],
    /// Records the loop's own recorders dropped (reported by the loop).
    pub ring_dropped: u64,
    /// Latencies, ns (realtime runs).
    pub latency: hdrhistogram::Histogram<u64>,
    /// Cycles without a command.
    pub missed_cycles: u64,
    /// Armed trigger.
    pub trigger: Option<Trigger>,
    /// Cycle at which the armed trigger fired, waiting for its post-trigger part.
    fired: Option<(u64, String)>,
    /// The last capture.
    pub capture: Option<Capture>,
    /// Whether the data come from a loop (else from a trace).
    pub live: bool,
    /// Previous plant flags (edges).
    prev_flags: u8,
    /// The contour error of a cycle, when the job's path is known.
    pub contour: Option<ContourFn>,
    /// When the newest plant cycle's sample was published (monotonic clock shared with the
    /// loop, ns): where the loop's periods start.
    pub last_published_ns: u64,
}

impl Store {
    /// An empty store for `axes`, holding `capacity` cycles.
    pub fn live(axes: &[String], capacity: usize) -> Self {
        let mut columns = Vec::new();
        let mut units = Vec::new();
        for a in axes {
            for (s, u, _) in AXIS_SIGNALS {
                columns.push(format!("{a}.{s}"));
                units.push(u.to_string());
            }
        }
        columns.push(CONTOUR.to_string());
        units.push("m".into());
        columns.push(LATENCY.to_string());
        units.push("us".into());
        Self::with_columns(axes, columns, units, capacity, true)
    }

    fn with_columns(
        axes: &[String],
        columns: Vec<String>,
        units: Vec<String>,
        capacity: usize,
        live: bool,
    ) -> Self {
        let capacity = capacity.max(16);
        Self {
            period_s: 0.0,
            t0_s: 0.0,
            axes: axes.to_vec(),
            data: vec![vec![f64::NAN; capacity]; columns.len()],
            columns,
            units,
            capacity,
            plant_seq: vec![u64::MAX; capacity],
            sched_seq: vec![u64::MAX; capacity],
            newest: None,
            first: None,
            newest_sched: None,
            events: VecDeque::new(),
            marks: vec![0; capacity],
            pending: Vec::new(),
            window: [0; EVENT_KINDS.len()],
            lost_plant: 0,
            lost_sched: 0,
            lost_blocks: [0; 2],
            next_block: [None; 2],
            ring_dropped: 0,
            latency: hdrhistogram::Histogram::new_with_bounds(1, 10_000_000_000, 3)
                .expect("valid histogram bounds"),
            missed_cycles: 0,
            trigger: None,
            fired: None,
            capture: None,
            live,
            prev_flags: 0,
            contour: None,
            last_published_ns: 0,
        }
    }

    /// A store holding a recorded trace (every row; `following_error` added per axis when absent).
    pub fn from_trace(tr: &feedloop_trace::Trace) -> Self {
        let axes = tr.axes();
        let mut columns: Vec<String> = tr.columns.iter().filter(|c| *c != "t").cloned().collect();
        for a in &axes {
            let fe = format!("{a}.following_error");
            if !columns.contains(&fe) {
                columns.push(fe);
            }
        }
        let units = columns.iter().map(|c| unit_of(c).to_string()).collect();
        let n = tr.len();
        let mut s = Self::with_columns(&axes, columns, units, n, false);
        s.period_s = tr.period_s();
        s.t0_s = tr.t().first().copied().unwrap_or(0.0);
        for (c, name) in s.columns.iter().enumerate() {
            let col: Vec<f64> = match tr.column(name) {
                Some(v) => v.to_vec(),
                None => {
                    let a = name.trim_end_matches(".following_error");
                    let cmd = tr.column(&format!("{a}.cmd")).unwrap_or(&[]);
                    let load = tr.column(&format!("{a}.load")).unwrap_or(&[]);
                    cmd.iter().zip(load).map(|(c, l)| c - l).collect()
                }
            };
            s.data[c][..col.len()].copy_from_slice(&col);
        }
        for k in 0..n {
            s.plant_seq[k] = k as u64;
            s.sched_seq[k] = k as u64;
        }
        if n > 0 {
            s.newest = Some(n as u64 - 1);
            s.newest_sched = s.newest;
        }
        s
    }

    /// Cycles the ring holds.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Index of column `name`.
    pub fn column(&self, name: &str) -> Option<usize> {
        self.columns.iter().position(|c| c == name)
    }

    fn slot(&self, seq: u64) -> usize {
        (seq % self.capacity as u64) as usize
    }

    /// Times of the oldest and the newest cycle held, s.
    pub fn span_s(&self) -> Option<(f64, f64)> {
        let t = |k: u64| self.t0_s + k as f64 * self.period_s;
        Some((t(self.oldest()?), t(self.newest?)))
    }

    /// The oldest cycle still held (the ring's first one while it has not filled).
    pub fn oldest(&self) -> Option<u64> {
        self.newest.map(|n| {
            n.saturating_sub(self.capacity as u64 - 1)
                .max(self.first.unwrap_or(0))
        })
    }

    /// Gives the axes of a live ring their names (the loop's status tells them after the first
    /// blocks came), keeping what it holds.
    pub fn rename_axes(&mut self, names: &[String]) {
        if !self.live || names.len() != self.axes.len() {
            return;
        }
        let per = AXIS_SIGNALS.len();
        for (i, a) in names.iter().enumerate() {
            for (j, (s, _, _)) in AXIS_SIGNALS.iter().enumerate() {
                self.columns[i * per + j] = format!("{a}.{s}");
            }
        }
        self.axes = names.to_vec();
    }

    /// Counts a cycle with an event of `kind` in the window, once per cycle and kind; only while
    /// the ring holds that cycle.
    fn mark(&mut self, kind: &'static str, cycle: u64) {
        let i = EVENT_KINDS.iter().position(|k| *k == kind).unwrap_or(0);
        let held = self.plant_seq[self.slot(cycle)] == cycle;
        if !held && self.newest.is_none_or(|n| cycle > n) {
            // a swap answered before its cycle's record came: marked when it comes
            self.pending.push((i, cycle));
            return;
        }
        self.mark_index(i, cycle);
    }

    fn mark_index(&mut self, i: usize, cycle: u64) {
        let slot = self.slot(cycle);
        if self.plant_seq[slot] == cycle && self.marks[slot] & (1 << i) == 0 {
            self.marks[slot] |= 1 << i;
            self.window[i] += 1;
        }
    }

    /// The window's counts over the cycles held before `end` (all held when `end` is past the
    /// newest), and how many cycles that is: the counts as of the cycle a status was made in.
    pub fn window_before(&self, end: u64) -> ([u64; EVENT_KINDS.len()], u64) {
        let (Some(oldest), Some(newest)) = (self.oldest(), self.newest) else {
            return ([0; EVENT_KINDS.len()], 0);
        };
        let end = end.clamp(oldest, newest + 1);
        let mut counts = self.window;
        for k in end..=newest {
            let slot = self.slot(k);
            if self.plant_seq[slot] == k {
                for (i, n) in counts.iter_mut().enumerate() {
                    if self.marks[slot] & (1 << i) != 0 {
                        *n -= 1;
                    }
                }
            }
        }
        (counts, end - oldest)
    }

    /// Takes the marks of the cycle `slot` held out of the window (the slot is reused).
    fn unmark(&mut self, slot: usize) {
        let m = std::mem::take(&mut self.marks[slot]);
        for (i, n) in self.window.iter_mut().enumerate() {
            if m & (1 << i) != 0 {
                *n -= 1;
            }
        }
    }

    fn event(&mut self, kind: &'static str, cycle: u64, detail: String) {
        self.mark(kind, cycle);
        if self.events.len() >= MAX_EVENTS {
            self.events.pop_front();
        }
        let ev = Event {
            kind,
            cycle,
            t_s: cycle as f64 * self.period_s,
            detail,
        };
        if let (Some(t), None) = (&self.trigger, &self.fired) {
            if t.condition == Condition::Event(kind) {
                self.fired = Some((cycle, format!("{} at cycle {cycle}", t.describe)));
            }
        }
        self.events.push_back(ev);
    }

    /// Counts the blocks of `source` (0 plant, 1 scheduler) skipped before block number `n`.
    pub fn block_seen(&mut self, source: usize, n: u32) {
        if let Some(want) = self.next_block[source] {
            let gap = n.wrapping_sub(want);
            if gap < u32::MAX / 2 {
                self.lost_blocks[source] += u64::from(gap);
            }
        }
        self.next_block[source] = Some(n.wrapping_add(1));
    }

    /// Adds the plant's records of one block.
    pub fn push_plant(&mut self, recs: &[PlantRecord]) {
        let n = self.axes.len();
        let per = AXIS_SIGNALS.len();
        let lat = self.columns.len() - 1;
        let contour_col = self.columns.len() - 2;
        for r in recs {
            if let Some(prev) = self.newest {
                if r.seq <= prev {
                    continue;
                }
                self.lost_plant += r.seq - prev - 1;
                // the slots of lost cycles leave the window too
                for k in (prev + 1..r.seq).take(self.capacity) {
                    let slot = self.slot(k);
                    self.unmark(slot);
                    self.plant_seq[slot] = u64::MAX;
                }
            }
            let slot = self.slot(r.seq);
            self.unmark(slot);
            self.plant_seq[slot] = r.seq;
            if !self.pending.is_empty() {
                let mut due = Vec::new();
                self.pending.retain(|&(i, c)| {
                    if c == r.seq {
                        due.push(i);
                    }
                    c > r.seq
                });
                for i in due {
                    self.mark_index(i, r.seq);
                }
            }
            for (i, a) in r.axes.iter().take(n).enumerate() {
                let base = i * per;
                self.data[base][slot] = a.cmd;
                self.data[base + 1][slot] = a.load;
                self.data[base + 2][slot] = a.cmd - a.load;
                self.data[base + 3][slot] = a.motor;
                self.data[base + 4][slot] = a.motor_vel;
                self.data[base + 5][slot] = a.torque;
            }
            if let Some(f) = self.contour.as_mut() {
                let t = r.seq as f64 * self.period_s;
                self.data[contour_col][slot] =
                    f(t, &r.axes[..n.min(r.axes.len())]).unwrap_or(f64::NAN);
            }
            if r.latency_ns == u64::MAX {
                self.data[lat][slot] = f64::NAN;
                self.missed_cycles += 1;
            } else {
                self.data[lat][slot] = r.latency_ns as f64 * 1e-3;
                let _ = self.latency.record(r.latency_ns.max(1));
            }
            self.check_level(r.seq, false);
            let rising = r.flags & !self.prev_flags;
            if is_deadline_miss(r.flags) {
                self.event("deadline_miss", r.seq, String::new());
            }
            // every overrun and stall cycle counts; a run of them is marked once on the plot
            for (kind, flag) in [("plant_overrun", REC_OVERRUN), ("stall", REC_STALL)] {
                if r.flags & flag != 0 {
                    self.mark(kind, r.seq);
                }
                if rising & flag != 0 {
                    self.event(
                        kind,
                        r.seq,
                        format!("woke {} us late", r.wake_late_ns / 1000),
                    );
                }
            }
            if rising & REC_STOPPING != 0 {
                self.event(
                    "safety_stop",
                    r.seq,
                    "the plant brings the axes to a safe stop".into(),
                );
            }
            self.prev_flags = r.flags;
            self.last_published_ns = r.published_ns;
            self.newest = Some(r.seq);
            self.first.get_or_insert(r.seq);
            self.finish_capture();
        }
    }

    /// Adds the scheduler's records of one block.
    pub fn push_sched(&mut self, recs: &[SchedRecord]) {
        let n = self.axes.len();
        let per = AXIS_SIGNALS.len();
        for r in recs {
            if let Some(prev) = self.newest_sched {
                if r.seq <= prev {
                    continue;
                }
                self.lost_sched += (r.seq - prev - 1).saturating_sub(u64::from(r.skipped));
            }
            let slot = self.slot(r.seq);
            self.sched_seq[slot] = r.seq;
            for i in 0..n {
                let base = i * per;
                self.data[base + 6][slot] = r.axes[i].0;
                self.data[base + 7][slot] = r.stages[i].0;
                self.data[base + 8][slot] = r.stages[i].1;
                self.data[base + 9][slot] = r.axes[i].1;
            }
            self.newest_sched = Some(r.seq);
            self.check_level(r.seq, true);
        }
        self.finish_capture();
    }

    /// A swap (or its rollback) the control service reported.
    pub fn push_swap(&mut self, ev: &feedloop_runtime::scheduler::control::protocol::SwapEvent) {
        let detail = format!(
            "{} {}: {} -> {}, torque step {} (bound {}){}",
            ev.axis,
            ev.stage,
            ev.from,
            ev.to,
            si(ev.torque_step, "N m"),
            si(ev.allowed_step, "N m"),
            ev.reason
                .as_deref()
                .map(|r| format!("; {r}"))
                .unwrap_or_default()
        );
        self.event("swap", ev.cycle, detail.clone());
        if ev.rolled_back {
            self.event("rollback", ev.cycle, detail);
        }
    }

    /// Whether a value of the plant's or scheduler's columns is held for `seq` in `column`.
    fn has(&self, column: usize, seq: u64) -> bool {
        let slot = self.slot(seq);
        if self.is_sched_column(column) {
            self.sched_seq[slot] == seq
        } else {
            self.plant_seq[slot] == seq
        }
    }

    /// The value of `column` at `seq`, when held.
    pub fn value(&self, column: usize, seq: u64) -> Option<f64> {
        if column >= self.data.len() || !self.has(column, seq) {
            return None;
        }
        Some(self.data[column][self.slot(seq)]).filter(|v| v.is_finite())
    }

    /// Whether `column` is one the scheduler's records fill.
    fn is_sched_column(&self, column: usize) -> bool {
        let per = AXIS_SIGNALS.len();
        self.live && column < self.axes.len() * per && column % per >= 6
    }

    /// Fires a level trigger whose column crossed its level between `seq - 1` and `seq`; looked
    /// at as each source's records arrive (`sched`: the scheduler's).
    fn check_level(&mut self, seq: u64, sched: bool) {
        let Some(t) = &self.trigger else { return };
        if self.fired.is_some() || seq == 0 {
            return;
        }
        let Condition::Level {
            column,
            level,
            rising,
        } = t.condition
        else {
            return;
        };
        if self.is_sched_column(column) != sched {
            return;
        }
        let (Some(before), Some(now)) = (self.value(column, seq - 1), self.value(column, seq))
        else {
            return;
        };
        let crossed = if rising {
            before < level && now >= level
        } else {
            before > level && now <= level
        };
        if crossed {
            self.fired = Some((seq, t.describe.clone()));
        }
    }

    /// Completes a fired trigger's capture once its post-trigger part is in.
    fn finish_capture(&mut self) {
        let (Some((at, describe)), Some(t), Some(newest)) =
            (&self.fired, &self.trigger, self.newest)
        else {
            return;
        };
        if self.period_s <= 0.0 {
            return;
        }
        let post = (t.post_s / self.period_s).round() as u64;
        let pre = (t.pre_s / self.period_s).round() as u64;
        // the scheduler's columns of the last cycles come a block later
        let ready = self.newest_sched.unwrap_or(0).min(newest);
        if ready < at + post {
            return;
        }
        let first = at.saturating_sub(pre).max(self.oldest().unwrap_or(0));
        let (at, describe) = (*at, describe.clone());
        self.capture = Some(self.cut(first, at + post, at, describe));
        self.fired = None;
        self.trigger = None;
    }

    /// The cycles `first..=last` as a capture (missing cells held from the cycle before).
    pub fn cut(&self, first: u64, last: u64, trigger_cycle: u64, describe: String) -> Capture {
        let mut held = 0u64;
        let data: Vec<Vec<f64>> = (0..self.columns.len())
            .map(|c| {
                let mut prev = f64::NAN;
                let mut col: Vec<f64> = (first..=last)
                    .map(|k| match self.value(c, k) {
                        Some(v) => {
                            prev = v;
                            v
                        }
                        None => {
                            held += 1;
                            prev
                        }
                    })
                    .collect();
                // leading gaps take the first value held
                let first_ok = col.iter().copied().find(|v| v.is_finite()).unwrap_or(0.0);
                for v in col.iter_mut().take_while(|v| !v.is_finite()) {
                    *v = first_ok;
                }
                col
            })
            .collect();
        Capture {
            describe,
            trigger_cycle,
            trigger_t_s: trigger_cycle as f64 * self.period_s,
            first_cycle: first,
            period_s: self.period_s,
            columns: self.columns.clone(),
            data,
            events: self
                .events
                .iter()
                .filter(|e| e.cycle >= first && e.cycle <= last)
                .cloned()
                .collect(),
            held_cells: held,
        }
    }

    /// Min/max of `column` over `cols` equal spans of cycles between `t0_s` and `t1_s`: the
    /// envelope a pixel column shows, so no spike is lost to decimation. `None` for an empty span.
    pub fn envelope(
        &self,
        column: usize,
        t0_s: f64,
        t1_s: f64,
        cols: usize,
    ) -> Vec<Option<(f64, f64)>> {
        let mut out = vec![None; cols];
        let (Some(newest), Some(oldest)) = (self.newest, self.oldest()) else {
            return out;
        };
        if self.period_s <= 0.0 || cols == 0 || t1_s <= t0_s {
            return out;
        }
        let k0 = (((t0_s - self.t0_s) / self.period_s).floor().max(0.0) as u64).max(oldest);
        let k1 = (((t1_s - self.t0_s) / self.period_s).ceil().max(0.0) as u64).min(newest);
        let span = (t1_s - t0_s) / cols as f64;
        let mut k = k0;
        while k <= k1 {
            let t = self.t0_s + k as f64 * self.period_s;
            let i = (((t - t0_s) / span).floor().max(0.0) as usize).min(cols - 1);
            if let Some(v) = self.value(column, k) {
                out[i] = Some(match out[i] {
                    None => (v, v),
                    Some((lo, hi)) => (lo.min(v), hi.max(v)),
                });
            }
            k += 1;
        }
        out
    }
}

/// The unit a trace column is in, from its name (trace format v1).
pub fn unit_of(column: &str) -> &'static str {
    let signal = column.rsplit('.').next().unwrap_or(column);
    AXIS_SIGNALS
        .iter()
        .find(|(s, _, _)| *s == signal)
        .map(|(_, u, _)| *u)
        .unwrap_or(match column {
            LATENCY => "us",
            CONTOUR | "contour_err" => "m",
            _ => "",
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use feedloop_trace::log::{AxisRecord, REC_MISSED};

    /// Scheduler records of cycles 0..n (all else default).
    fn sched(n: u64) -> Vec<SchedRecord> {
        (0..n)
            .map(|seq| SchedRecord {
                seq,
                ..Default::default()
            })
            .collect()
    }

    fn plant(seq: u64, load: f64, flags: u8) -> PlantRecord {
        let mut r = PlantRecord {
            seq,
            latency_ns: 2_000,
            flags,
            ..Default::default()
        };
        r.axes[0] = AxisRecord {
            cmd: 1.0,
            load,
            ..Default::default()
        };
        r
    }

    fn store() -> Store {
        let mut s = Store::live(&["x".to_string()], 1000);
        s.period_s = 1e-3;
        s
    }

    #[test]
    fn a_one_cycle_spike_survives_the_envelope_of_a_much_longer_span() {
        let mut s = store();
        let recs: Vec<PlantRecord> = (0..900)
            .map(|k| plant(k, if k == 457 { 5.0 } else { 0.0 }, 0))
            .collect();
        s.push_plant(&recs);
        let c = s.column("x.load").unwrap();
        let env = s.envelope(c, 0.0, 0.9, 30);
        let max = env.iter().flatten().map(|e| e.1).fold(f64::MIN, f64::max);
        assert_eq!(max, 5.0);
        assert_eq!(env.iter().flatten().filter(|e| e.1 == 5.0).count(), 1);
    }

    #[test]
    fn the_ring_keeps_the_newest_cycles_and_counts_the_lost_ones() {
        let mut s = store();
        let recs: Vec<PlantRecord> = (0..2500)
            .filter(|k| k % 1000 != 7)
            .map(|k| plant(k, 0.0, 0))
            .collect();
        s.push_plant(&recs);
        assert_eq!(s.oldest(), Some(1500));
        assert_eq!(s.lost_plant, 3, "cycles 7, 1007 and 2007");
        let c = s.column("x.load").unwrap();
        assert_eq!(s.value(c, 1400), None);
        assert_eq!(s.value(c, 2006), Some(0.0));
        assert_eq!(s.value(c, 2007), None);
    }

    #[test]
    fn the_window_counts_every_marked_cycle_the_ring_holds_and_forgets_older_ones() {
        let mut s = store();
        // cycles 100..150 overrun (one run: one mark on the plot, 50 cycles counted); 120 also
        // goes without a command, which is the overrun's, not a deadline miss, as in the run's
        // summary; 300 misses its deadline
        let flags = |k: u64| match k {
            100..150 => REC_OVERRUN | if k == 120 { REC_MISSED } else { 0 },
            300 => REC_MISSED,
            _ => 0,
        };
        let recs: Vec<PlantRecord> = (0..2600)
            .filter(|k| *k != 1200)
            .map(|k| plant(k, 0.0, flags(k)))
            .collect();
        s.push_plant(&recs[..10]);
        // a swap answered before its cycle's record came
        s.push_swap(&feedloop_runtime::scheduler::control::protocol::SwapEvent {
            t_s: 0.02,
            cycle: 20,
            axis: "x".into(),
            stage: "velocity".into(),
            from: "a".into(),
            to: "b".into(),
            torque_step: 0.0,
            allowed_step: 1.0,
            rolled_back: false,
            reason: None,
            phase_margin_deg: None,
            gain_margin_db: None,
            forced: false,
            warnings: vec![],
            changed: vec![],
            origin: None,
        });
        assert_eq!(s.window[3], 0);
        s.push_plant(&recs[..500]);
        assert_eq!(s.window[3], 1, "the swap, once its cycle came");
        assert_eq!(s.oldest(), Some(0));
        s.rename_axes(&["q".to_string()]);
        assert_eq!(s.value(s.column("q.load").unwrap(), 3), Some(0.0));
        let kind = |k: &str| EVENT_KINDS.iter().position(|e| *e == k).unwrap();
        assert_eq!(s.window[kind("plant_overrun")], 50);
        assert_eq!(s.window[kind("deadline_miss")], 1);
        let overrun_marks = s
            .events
            .iter()
            .filter(|e| e.kind == "plant_overrun")
            .count();
        assert_eq!(overrun_marks, 1, "a run of overruns is one event");
        // the ring (1000 cycles) moves past them: they leave the window
        s.push_plant(&recs[500..1100]);
        assert_eq!(s.oldest(), Some(100));
        assert_eq!(s.window[kind("plant_overrun")], 50);
        // as of an earlier cycle: the cycles from it on are not counted
        let (w, cycles) = s.window_before(140);
        assert_eq!((w[kind("plant_overrun")], cycles), (40, 40));
        assert_eq!(s.window_before(u64::MAX).0, s.window);
        s.push_plant(&recs[1100..1200]);
        assert_eq!(s.window[kind("plant_overrun")], 0);
        assert_eq!(s.window[kind("deadline_miss")], 1);
        s.push_plant(&recs[1200..]);
        assert_eq!(s.window, [0; EVENT_KINDS.len()]);
    }

    #[test]
    fn an_event_trigger_captures_its_pre_and_post_cycles() {
        let mut s = store();
        s.trigger = Some(Trigger {
            condition: Condition::Event("deadline_miss"),
            pre_s: 0.010,
            post_s: 0.020,
            describe: "deadline miss".into(),
        });
        let recs: Vec<PlantRecord> = (0..200)
            .map(|k| plant(k, k as f64, if k == 100 { REC_MISSED } else { 0 }))
            .collect();
        s.push_plant(&recs[..110]);
        assert!(s.capture.is_none(), "waits for the post-trigger part");
        s.push_sched(&sched(200));
        s.push_plant(&recs[110..]);
        let cap = s.capture.as_ref().expect("captured");
        assert_eq!((cap.first_cycle, cap.trigger_cycle), (90, 100));
        let load = &cap.data[s.column("x.load").unwrap()];
        assert_eq!(load.len(), 31);
        assert_eq!((load[0], load[30]), (90.0, 120.0));
        assert_eq!(cap.events.len(), 1);
        assert_eq!(s.window[0], 1);
        assert!(s.trigger.is_none(), "a trigger fires once");
    }

    #[test]
    fn a_level_trigger_fires_on_the_crossing_in_its_direction_only() {
        for (rising, at) in [(true, 50u64), (false, 150)] {
            let mut s = store();
            s.trigger = Some(Trigger {
                condition: Condition::Level {
                    column: s.column("x.load").unwrap(),
                    level: 0.5,
                    rising,
                },
                pre_s: 0.0,
                post_s: 0.0,
                describe: "level".into(),
            });
            s.push_sched(&sched(300));
            let recs: Vec<PlantRecord> = (0..300)
                .map(|k| plant(k, if (50..150).contains(&k) { 1.0 } else { 0.0 }, 0))
                .collect();
            s.push_plant(&recs);
            assert_eq!(s.capture.as_ref().unwrap().trigger_cycle, at);
        }
    }
}
