//! The live line of `feedloop run` on standard error: cycles done of the planned ones, the
//! run's time, and the plant overruns and deadline misses so far. It reads `plant.log`, which
//! the plant's recorder thread writes anyway (in the period's slack), so the loop does nothing
//! more for it; drawn only when standard error is a terminal, and not with `--quiet`/`--json`.

use std::path::Path;
use std::time::{Duration, Instant};

use feedloop_model::units::si;
use feedloop_trace::log::{is_deadline_miss, LogTail, PlantRecord, REC_OVERRUN};

/// How often the log is read and the line redrawn.
const EVERY: Duration = Duration::from_millis(500);

/// The live line of a running loop.
pub(super) struct RunProgress {
    bar: indicatif::ProgressBar,
    tail: LogTail,
    period_s: f64,
    realtime: bool,
    cycles: u64,
    overruns: u64,
    misses: u64,
    last: Option<Instant>,
}

impl RunProgress {
    /// The line of a run of `planned` cycles of `period_s` logging into `out`; hidden unless
    /// `shown` and standard error is a terminal.
    pub(super) fn new(
        out: &Path,
        planned: u64,
        period_s: f64,
        realtime: bool,
        shown: bool,
    ) -> Self {
        let bar = if shown {
            indicatif::ProgressBar::new(planned).with_style(
                indicatif::ProgressStyle::with_template(
                    "run {bar:12} {pos}/{len} cycles, {wide_msg}",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            )
        } else {
            indicatif::ProgressBar::hidden()
        };
        Self {
            bar,
            tail: LogTail::new(&out.join("plant.log")),
            period_s,
            realtime,
            cycles: 0,
            overruns: 0,
            misses: 0,
            last: None,
        }
    }

    /// Reads what the plant logged since the last look and redraws (at most every [`EVERY`]).
    pub(super) fn tick(&mut self) {
        if self.bar.is_hidden() || self.last.is_some_and(|t| t.elapsed() < EVERY) {
            return;
        }
        self.last = Some(Instant::now());
        for r in self.tail.read_new::<PlantRecord>() {
            self.cycles += 1;
            self.overruns += u64::from(r.flags & REC_OVERRUN != 0);
            self.misses += u64::from(is_deadline_miss(r.flags));
        }
        self.bar.set_message(self.message());
        self.bar.set_position(self.cycles);
    }

    /// The figures after the bar.
    fn message(&self) -> String {
        let total = self.bar.length().unwrap_or(0);
        let time = format!(
            "{} of {}",
            si(self.cycles as f64 * self.period_s, "s"),
            si(total as f64 * self.period_s, "s")
        );
        if !self.realtime {
            return time;
        }
        let pct = |n: u64| 100.0 * n as f64 / self.cycles.max(1) as f64;
        format!(
            "{time}, plant overruns {} ({:.1} %), deadline misses {} ({:.1} %)",
            self.overruns,
            pct(self.overruns),
            self.misses,
            pct(self.misses)
        )
    }

    /// Takes the line away (the summary follows).
    pub(super) fn finish(&self) {
        self.bar.finish_and_clear();
    }
}
