//! The learned table of `quadrant_compensator`: its TOML file format (written by
//! [`QuadrantTable::to_toml`], read and validated by [`QuadrantTable::load`]):
//!
//! ```toml
//! format = "feedloop-quadrant-table-1"
//! [[axes.x.to_positive]]
//! pass = 1            # learning pass that added it
//! start_s = 0.0       # model start, s after the reversal
//! peak_s = 0.0041     # end of the rise model / start of the fall model, s
//! end_s = 0.019       # end of the fall model, s
//! rise_split = 0.31   # where the rise model's velocity peaks, fraction of its span
//! fall_split = 0.22   # where the fall model's velocity peaks, fraction of its span
//! amplitude = 2.1e-6  # offset at the peak, m (rad on a rotary axis)
//! profile = "sine_acceleration"  # shape of both models; optional, default
//!                                # "constant_acceleration" (tables learned before 2026-11-25)
//! ```
//!
//! A table holds, per axis name, the pulses played after a reversal to positive and to negative
//! velocity (at most [`MAX_PULSES`] each); see [`super`] for what a pulse is.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use feedloop_model::params::{read_toml_file, ConfigError, Fields, Range};

use super::{Direction, Profile, Pulse};

/// The `format` value of a table file.
pub const TABLE_FORMAT: &str = "feedloop-quadrant-table-1";

/// Most pulses per direction an axis may carry.
pub const MAX_PULSES: usize = 64;

/// The learned pulses of one axis, per reversal direction.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AxisPulses {
    /// Played after a reversal to positive velocity.
    pub to_positive: Vec<Pulse>,
    /// Played after a reversal to negative velocity.
    pub to_negative: Vec<Pulse>,
}

impl AxisPulses {
    /// Pulses of `dir`.
    pub fn get(&self, dir: Direction) -> &Vec<Pulse> {
        match dir {
            Direction::ToPositive => &self.to_positive,
            Direction::ToNegative => &self.to_negative,
        }
    }

    /// Pulses of `dir`, mutable.
    pub fn get_mut(&mut self, dir: Direction) -> &mut Vec<Pulse> {
        match dir {
            Direction::ToPositive => &mut self.to_positive,
            Direction::ToNegative => &mut self.to_negative,
        }
    }
}

/// A learned quadrant table: pulses per axis name.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct QuadrantTable {
    /// Pulses per axis.
    pub axes: BTreeMap<String, AxisPulses>,
}

impl QuadrantTable {
    /// Reads and validates a table file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let t = read_toml_file(path)?;
        Self::from_table(&t, path)
    }

    /// Validates a parsed table (`path` for messages).
    pub fn from_table(t: &toml::Table, path: &Path) -> Result<Self, ConfigError> {
        let mut f = Fields::new(t, path, "");
        let format = f.str("format")?;
        if format != TABLE_FORMAT {
            return Err(f.error(
                "format",
                format!("unknown table format `{format}` (expected `{TABLE_FORMAT}`)"),
            ));
        }
        let mut table = QuadrantTable::default();
        if let Some(axes) = f.opt_table("axes")? {
            for (name, v) in axes {
                let key = format!("axes.{name}");
                let at = v
                    .as_table()
                    .ok_or_else(|| ConfigError::new(path, &key, "must be a table"))?;
                let mut af = Fields::new(at, path, &key);
                let mut pulses = AxisPulses::default();
                for dir in Direction::ALL {
                    let Some(arr) = af.raw(dir.id()) else {
                        continue;
                    };
                    let dkey = format!("{key}.{}", dir.id());
                    let arr = arr.as_array().ok_or_else(|| {
                        ConfigError::new(path, &dkey, "must be an array of tables ([[...]])")
                    })?;
                    if arr.len() > MAX_PULSES {
                        return Err(ConfigError::new(
                            path,
                            &dkey,
                            format!("at most {MAX_PULSES} pulses, got {}", arr.len()),
                        ));
                    }
                    for (i, p) in arr.iter().enumerate() {
                        let pkey = format!("{dkey}[{i}]");
                        let pt = p
                            .as_table()
                            .ok_or_else(|| ConfigError::new(path, &pkey, "must be a table"))?;
                        pulses.get_mut(dir).push(parse_pulse(pt, path, &pkey)?);
                    }
                }
                af.finish()?;
                table.axes.insert(name.clone(), pulses);
            }
        }
        f.finish()?;
        Ok(table)
    }

    /// The table as commented TOML text.
    pub fn to_toml(&self) -> String {
        let mut s = String::new();
        s.push_str("# Quadrant-crossing compensation table (feedloop `quadrant_compensator`).\n");
        s.push_str("# Each pulse is a position offset after a reversal: an acceleration-planned rise from\n");
        s.push_str(
            "# start_s to peak_s and fall to end_s (s after the reversal), velocity peaking at\n",
        );
        s.push_str("# rise_split / fall_split of each span; amplitude in load units (m, or rad on a rotary axis).\n");
        let _ = writeln!(s, "format = \"{TABLE_FORMAT}\"");
        for (name, pulses) in &self.axes {
            let _ = writeln!(s, "\n[axes.{name}]");
            for dir in Direction::ALL {
                for p in pulses.get(dir) {
                    let _ = writeln!(s, "\n[[axes.{name}.{}]]", dir.id());
                    let _ = writeln!(s, "pass = {}", p.pass);
                    let _ = writeln!(s, "start_s = {:?}", p.start_s);
                    let _ = writeln!(s, "peak_s = {:?}", p.peak_s);
                    let _ = writeln!(s, "end_s = {:?}", p.end_s);
                    let _ = writeln!(s, "rise_split = {:?}", p.rise_split);
                    let _ = writeln!(s, "fall_split = {:?}", p.fall_split);
                    let _ = writeln!(s, "amplitude = {:?}", p.amplitude);
                    let _ = writeln!(s, "profile = \"{}\"", p.profile.id());
                }
            }
        }
        s
    }

    /// Writes the table to `path`.
    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        std::fs::write(path, self.to_toml())
    }
}

fn parse_pulse(t: &toml::Table, path: &Path, key: &str) -> Result<Pulse, ConfigError> {
    let mut f = Fields::new(t, path, key);
    let pass = f.opt_i64("pass", 0, 1000)?.unwrap_or(1) as u32;
    let start_s = f.f64("start_s", Range::Within(-10.0, 10.0))?;
    let peak_s = f.f64("peak_s", Range::Within(-10.0, 10.0))?;
    let end_s = f.f64("end_s", Range::Within(-10.0, 10.0))?;
    let rise_split = f.f64("rise_split", Range::Within(1e-3, 1.0 - 1e-3))?;
    let fall_split = f.f64("fall_split", Range::Within(1e-3, 1.0 - 1e-3))?;
    let amplitude = f.f64("amplitude", Range::Within(-1e3, 1e3))?;
    let options = Profile::ALL.map(|p| (p.id(), p));
    let profile = f.choice("profile", "profile", &options, Profile::default())?;
    if peak_s < start_s {
        return Err(f.error(
            "peak_s",
            format!("must be >= start_s = {start_s}, got {peak_s}"),
        ));
    }
    if end_s < peak_s {
        return Err(f.error(
            "end_s",
            format!("must be >= peak_s = {peak_s}, got {end_s}"),
        ));
    }
    f.finish()?;
    Ok(Pulse {
        pass,
        start_s,
        peak_s,
        end_s,
        rise_split,
        fall_split,
        amplitude,
        profile,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadrant::tests::pulse;

    #[test]
    fn table_survives_a_write_and_read_exactly() {
        let mut t = QuadrantTable::default();
        let mut ap = AxisPulses::default();
        ap.to_positive.push(pulse());
        ap.to_negative.push(Pulse {
            amplitude: -1.234567890123e-6,
            pass: 2,
            profile: Profile::SineAcceleration,
            ..pulse()
        });
        t.axes.insert("x".into(), ap);
        t.axes.insert("y".into(), AxisPulses::default());
        let text = t.to_toml();
        let parsed: toml::Table = text.parse().unwrap();
        let back = QuadrantTable::from_table(&parsed, Path::new("t.toml")).unwrap();
        assert_eq!(back, t);
    }

    #[test]
    fn table_with_end_before_peak_is_refused_naming_the_pulse() {
        let text = format!(
            "format = \"{TABLE_FORMAT}\"\n[[axes.x.to_positive]]\nstart_s = 0\npeak_s = 0.01\nend_s = 0.005\nrise_split = 0.5\nfall_split = 0.5\namplitude = 1e-6\n"
        );
        let parsed: toml::Table = text.parse().unwrap();
        let e = QuadrantTable::from_table(&parsed, Path::new("t.toml")).unwrap_err();
        assert_eq!(e.key, "axes.x.to_positive[0].end_s");
    }

    #[test]
    fn table_without_profile_keys_reads_as_constant_acceleration_and_an_unknown_one_is_named() {
        let body = "[[axes.x.to_positive]]\nstart_s = 0\npeak_s = 0.005\nend_s = 0.01\nrise_split = 0.5\nfall_split = 0.5\namplitude = 1e-6\n";
        let text = format!("format = \"{TABLE_FORMAT}\"\n{body}");
        let t = QuadrantTable::from_table(&text.parse().unwrap(), Path::new("t.toml")).unwrap();
        assert_eq!(
            t.axes["x"].to_positive[0].profile,
            Profile::ConstantAcceleration
        );
        let text = format!("format = \"{TABLE_FORMAT}\"\n{body}profile = \"cubic\"\n");
        let e = QuadrantTable::from_table(&text.parse().unwrap(), Path::new("t.toml")).unwrap_err();
        assert_eq!(e.key, "axes.x.to_positive[0].profile");
        assert!(e.to_string().contains("sine_acceleration"), "{e}");
    }
}
