//! `delay`: pure transport delay between the torque command and the applied torque.
//!
//! Equation: `T_applied[k] = T_cmd[k - delay_cycles]` (commands before the start count as 0).
//! It comes on top of the loop's own one-cycle delay (a command computed from the sample of
//! cycle k is applied during period k).
//!
//! Keys: `delay_cycles` (integer, 0 .. 10000).
//!
//! Typical values: 1 .. 3 cycles (fieldbus, drive PWM update, computation).
//!
//! Signature: the cross-correlation between the torque command and the motor acceleration
//! (velocity increments) peaks `delay_cycles` later than without the effect; in closed loop, a
//! phase loss of `omega delay_cycles period` and a lower stability margin.
//!
//! Integration: a ring buffer allocated when the model is built.

use feedloop_model::params::{ConfigError, Fields};

use super::{check_keys, Ctx, EffectTable};

/// The key of the delay in whole control periods.
pub const DELAY_CYCLES: &str = "delay_cycles";

/// The delay line: the commands of the last `delay_cycles` periods (allocated when the model is
/// built).
#[derive(Debug, Clone)]
pub(crate) struct DelayLine {
    buf: Vec<f64>,
    pos: usize,
}

impl DelayLine {
    /// An empty line of `cycles` periods (0: no delay).
    pub fn new(cycles: usize) -> Self {
        Self {
            buf: vec![0.0; cycles],
            pos: 0,
        }
    }

    /// Puts command `u` in and returns the one of `delay_cycles` periods ago (`u` itself without
    /// a delay).
    #[inline]
    pub fn push(&mut self, u: f64) -> f64 {
        let len = self.buf.len();
        match self.buf.get_mut(self.pos) {
            Some(slot) => {
                let out = std::mem::replace(slot, u);
                self.pos += 1;
                if self.pos >= len {
                    self.pos = 0;
                }
                out
            }
            None => u,
        }
    }

    /// Length in periods.
    pub fn len(&self) -> usize {
        self.buf.len()
    }

    /// Empties the line (commands before count as 0).
    pub fn clear(&mut self) {
        self.buf.iter_mut().for_each(|d| *d = 0.0);
        self.pos = 0;
    }

    /// Fills the line with the last commands of `past` (oldest first, each through `fin`);
    /// missing ones count as the oldest given, or 0.
    pub fn restore(&mut self, past: &[f64], fin: impl Fn(f64) -> f64) {
        // the line holds the commands of the last `len` periods; the next one read is the oldest
        let len = self.buf.len();
        let oldest = past.first().copied().map(&fin).unwrap_or(0.0);
        for i in 0..len {
            // slot i (read i periods from now) holds the command of `len - i` periods ago
            let back = len - i;
            let v = if back <= past.len() {
                fin(past[past.len() - back])
            } else {
                oldest
            };
            self.buf[i] = v;
        }
        self.pos = 0;
    }
}

/// `[effects.delay]`: whole control periods (`delay_cycles`, 0 .. 10,000).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DelayParams {
    /// Periods of delay.
    pub cycles: i64,
}

impl EffectTable for DelayParams {
    /// Reads `[effects.delay]`.
    fn read(f: &mut Fields<'_>, _ctx: &Ctx) -> Result<Self, ConfigError> {
        check_keys(f, &[DELAY_CYCLES])?;
        let n = f.opt_i64(DELAY_CYCLES, 0, 10_000)?.ok_or_else(|| {
            f.error(
                DELAY_CYCLES,
                "is required but missing (a whole number of cycles)",
            )
        })?;
        Ok(Self { cycles: n })
    }

    /// The model-file table.
    fn to_table(&self, _ctx: &Ctx) -> toml::Table {
        let mut t = toml::Table::new();
        t.insert(DELAY_CYCLES.into(), toml::Value::Integer(self.cycles));
        t
    }
}

impl DelayParams {
    /// The delay line's length in periods (a negative count is no delay).
    pub(crate) fn motor(&self) -> usize {
        self.cycles.max(0) as usize
    }
}
