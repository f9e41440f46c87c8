//! Reading a part program: comments, words, modal state (G90/G91, motion mode, feed) and the
//! segments they make, in metres and seconds.

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use crate::path_index::segment_distance;

/// A G-code error: file, 1-based line and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: line {line}: {reason}", path.display())]
pub struct GcodeError {
    /// The program file.
    pub path: PathBuf,
    /// 1-based line number.
    pub line: usize,
    /// What is wrong.
    pub reason: String,
}

/// One programmed segment, in metres and seconds (program coordinates).
#[derive(Debug, Clone, PartialEq)]
pub enum PathSegment {
    /// A straight line (G0/G1).
    Line {
        /// Start `[x, y, z]`, m.
        from_m: [f64; 3],
        /// End `[x, y, z]`, m.
        to_m: [f64; 3],
        /// Programmed feed, m/s (`inf` for G0: the planner's velocity limit).
        feed_m_per_s: f64,
        /// Source line.
        line: usize,
    },
    /// A circular arc in the X-Y plane at constant Z (G2/G3).
    Arc {
        /// Centre `[x, y]`, m.
        center_m: [f64; 2],
        /// Radius, m.
        radius_m: f64,
        /// Angle of the start point, rad.
        start_angle_rad: f64,
        /// Signed sweep, rad (positive ccw/G3, negative cw/G2).
        sweep_rad: f64,
        /// Z, m.
        z_m: f64,
        /// Programmed feed, m/s.
        feed_m_per_s: f64,
        /// Source line.
        line: usize,
    },
    /// A dwell (G4), s.
    Dwell {
        /// Duration, s.
        duration_s: f64,
        /// Source line.
        line: usize,
    },
}

impl PathSegment {
    /// Path length, m (0 for a dwell).
    pub fn length_m(&self) -> f64 {
        match self {
            PathSegment::Line { from_m, to_m, .. } => dist3(from_m, to_m),
            PathSegment::Arc {
                radius_m,
                sweep_rad,
                ..
            } => radius_m * sweep_rad.abs(),
            PathSegment::Dwell { .. } => 0.0,
        }
    }

    /// Distance (m) from `p = [x, y]` to the segment's X-Y projection.
    pub fn distance_xy_m(&self, p: [f64; 2]) -> f64 {
        match self {
            PathSegment::Line { from_m, to_m, .. } => {
                segment_distance(p, [from_m[0], from_m[1]], [to_m[0], to_m[1]])
            }
            PathSegment::Arc {
                center_m,
                radius_m,
                start_angle_rad,
                sweep_rad,
                ..
            } => {
                let ang = (p[1] - center_m[1]).atan2(p[0] - center_m[0]);
                // Is the angle within the swept range?
                let rel = (ang - start_angle_rad) * sweep_rad.signum();
                let rel = rel.rem_euclid(2.0 * PI);
                if rel <= sweep_rad.abs() {
                    ((p[0] - center_m[0]).hypot(p[1] - center_m[1]) - radius_m).abs()
                } else {
                    let end = start_angle_rad + sweep_rad;
                    let a = [
                        center_m[0] + radius_m * start_angle_rad.cos(),
                        center_m[1] + radius_m * start_angle_rad.sin(),
                    ];
                    let b = [
                        center_m[0] + radius_m * end.cos(),
                        center_m[1] + radius_m * end.sin(),
                    ];
                    (p[0] - a[0])
                        .hypot(p[1] - a[1])
                        .min((p[0] - b[0]).hypot(p[1] - b[1]))
                }
            }
            PathSegment::Dwell { .. } => f64::INFINITY,
        }
    }
}

pub(super) fn dist3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2) + (b[2] - a[2]).powi(2)).sqrt()
}

/// A parsed program.
#[derive(Debug, Clone, PartialEq)]
pub struct Program {
    /// Where it came from.
    pub path: PathBuf,
    /// Segments in order (zero-length moves dropped).
    pub segments: Vec<PathSegment>,
    /// Which of X, Y, Z the program uses.
    pub uses: [bool; 3],
}

impl Program {
    /// Distance (m) from `p = [x, y]` (program coordinates) to the nearest programmed segment's
    /// X-Y projection.
    pub fn distance_xy_m(&self, p: [f64; 2]) -> f64 {
        self.segments
            .iter()
            .map(|s| s.distance_xy_m(p))
            .fold(f64::INFINITY, f64::min)
    }
}

/// Parses G-code `text` (from `path`, for messages) into segments in metres.
pub fn parse_program(path: &Path, text: &str) -> Result<Program, GcodeError> {
    let mut state = Modal::default();
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        let at_line = |reason: String| GcodeError {
            path: path.to_path_buf(),
            line: ln,
            reason,
        };
        let body = strip_comments(raw).map_err(at_line)?;
        let body = body.trim();
        if body.is_empty() || body == "%" {
            continue;
        }
        let words = split_words(body).map_err(at_line)?;
        let block = state.read_words(&words).map_err(at_line)?;
        if state.run(&block, ln).map_err(at_line)? {
            break;
        }
    }
    if !state
        .segments
        .iter()
        .any(|s| !matches!(s, PathSegment::Dwell { .. }))
    {
        return Err(GcodeError {
            path: path.to_path_buf(),
            line: text.lines().count().max(1),
            reason: "the program has no motion".into(),
        });
    }
    Ok(Program {
        path: path.to_path_buf(),
        segments: state.segments,
        uses: state.uses,
    })
}

/// The line without its comments (`( )` and after `;`), upper-cased.
fn strip_comments(raw: &str) -> Result<String, String> {
    let mut body = String::with_capacity(raw.len());
    let mut in_paren = false;
    for c in raw.chars() {
        match c {
            '(' if !in_paren => in_paren = true,
            ')' if in_paren => in_paren = false,
            ';' if !in_paren => break,
            c if !in_paren => body.push(c.to_ascii_uppercase()),
            _ => {}
        }
    }
    if in_paren {
        return Err("comment `(` is not closed on this line".into());
    }
    Ok(body)
}

/// One word of a line: its letter, its value and its text (for messages).
type Word = (char, f64, String);

/// The words (letter + number) of a comment-free line.
fn split_words(body: &str) -> Result<Vec<Word>, String> {
    let bytes = body.as_bytes();
    let mut k = 0;
    let mut words: Vec<Word> = Vec::new();
    while k < bytes.len() {
        let c = bytes[k] as char;
        if c.is_ascii_whitespace() {
            k += 1;
            continue;
        }
        if !c.is_ascii_alphabetic() {
            return Err(format!("unexpected `{c}` (expected a letter)"));
        }
        k += 1;
        while k < bytes.len() && bytes[k].is_ascii_whitespace() {
            k += 1;
        }
        let start = k;
        while k < bytes.len()
            && (bytes[k].is_ascii_digit() || matches!(bytes[k], b'.' | b'-' | b'+'))
        {
            k += 1;
        }
        let num = &body[start..k];
        let v: f64 = num
            .parse()
            .map_err(|_| format!("word `{c}` needs a number, got \"{num}\""))?;
        if !v.is_finite() {
            return Err(format!("word `{c}{num}` is not finite"));
        }
        words.push((c, v, format!("{c}{num}")));
    }
    Ok(words)
}

/// What one line asks for.
#[derive(Debug, Default)]
struct Block {
    /// Motion G-code on this line (0..=3).
    g_motion: Option<u32>,
    /// G4 on this line.
    dwell: bool,
    /// X, Y, Z words, mm.
    coords: [Option<f64>; 3],
    /// I and J words, mm.
    ci: Option<f64>,
    cj: Option<f64>,
    /// P word, s.
    p_word: Option<f64>,
    /// M2/M30 on this line.
    end: bool,
}

/// The interpreter's state between lines, and what it has made so far.
#[derive(Debug)]
struct Modal {
    /// Current position, m.
    pos: [f64; 3],
    /// G90 (true) or G91.
    absolute: bool,
    /// Modal motion mode (G0..G3).
    motion: Option<u32>,
    /// Modal feed, m/s.
    feed: Option<f64>,
    segments: Vec<PathSegment>,
    uses: [bool; 3],
}

impl Default for Modal {
    fn default() -> Self {
        Self {
            pos: [0.0f64; 3],
            absolute: true,
            motion: None,
            feed: None,
            segments: Vec::new(),
            uses: [false; 3],
        }
    }
}

impl Modal {
    /// Reads the words of one line into a block; G90/G91 and F take effect at once.
    fn read_words(&mut self, words: &[Word]) -> Result<Block, String> {
        let mut b = Block::default();
        let mut seen: Vec<char> = Vec::new();
        for (c, v, text) in words {
            if *c != 'G' && *c != 'M' {
                if seen.contains(c) {
                    return Err(format!("word `{c}` appears twice"));
                }
                seen.push(*c);
            }
            match c {
                'G' => self.g_word(&mut b, *v, text)?,
                'M' => match *v as i64 {
                    2 | 30 if v.fract() == 0.0 => b.end = true,
                    _ => return Err(format!("unsupported M-code {text} (supported: M2, M30)")),
                },
                'X' => b.coords[0] = Some(*v),
                'Y' => b.coords[1] = Some(*v),
                'Z' => b.coords[2] = Some(*v),
                'I' => b.ci = Some(*v),
                'J' => b.cj = Some(*v),
                'P' => b.p_word = Some(*v),
                'F' => {
                    if *v <= 0.0 {
                        return Err(format!("feed {text} must be > 0 mm/min"));
                    }
                    self.feed = Some(*v / 60_000.0);
                }
                'N' => {}
                'R' => {
                    return Err(
                        "arcs by radius (R) are not supported: give the centre with I and J".into(),
                    )
                }
                'K' => return Err("K: only X-Y plane arcs (I, J) are supported".into()),
                other => return Err(format!("unsupported word `{text}` (letter {other})")),
            }
        }
        Ok(b)
    }

    /// One G word of a line.
    fn g_word(&mut self, b: &mut Block, v: f64, text: &str) -> Result<(), String> {
        let code = if v.fract() == 0.0 && v >= 0.0 {
            Some(v as u32)
        } else {
            None
        };
        match code {
            Some(m @ 0..=3) => {
                if b.g_motion.is_some() {
                    return Err("two motion G-codes on one line".into());
                }
                b.g_motion = Some(m);
            }
            Some(4) => b.dwell = true,
            Some(17) | Some(21) => {}
            Some(90) => self.absolute = true,
            Some(91) => self.absolute = false,
            Some(18) | Some(19) => {
                return Err(format!("{text}: only the X-Y plane (G17) is supported"))
            }
            Some(20) => return Err("G20: inch units are not supported (use G21, mm)".into()),
            _ => {
                return Err(format!(
                    "unsupported G-code {text} (supported: G0 G1 G2 G3 G4 G17 G21 G90 G91)"
                ))
            }
        }
        Ok(())
    }

    /// Runs the block of line `ln`; returns whether the program ends there.
    fn run(&mut self, b: &Block, ln: usize) -> Result<bool, String> {
        if b.dwell {
            self.dwell(b, ln)?;
            return Ok(b.end);
        }
        if b.p_word.is_some() {
            return Err("P is only used with G4".into());
        }
        if let Some(m) = b.g_motion {
            self.motion = Some(m);
        }
        let has_xyz = b.coords.iter().any(Option::is_some);
        if !has_xyz && b.ci.is_none() && b.cj.is_none() {
            return Ok(b.end);
        }
        let m = self
            .motion
            .ok_or_else(|| "coordinates without a motion mode (G0, G1, G2, G3)".to_string())?;
        let mut target = self.pos;
        for (a, t) in target.iter_mut().enumerate() {
            if let Some(v) = b.coords[a] {
                self.uses[a] = true;
                let v = v * 1e-3;
                *t = if self.absolute { v } else { self.pos[a] + v };
            }
        }
        match m {
            0 | 1 => self.line(b, m, target, ln)?,
            _ => target = self.arc(b, m, target, ln)?,
        }
        self.pos = target;
        Ok(b.end)
    }

    /// G4 P<s>.
    fn dwell(&mut self, b: &Block, ln: usize) -> Result<(), String> {
        if b.g_motion.is_some() || b.coords.iter().any(Option::is_some) {
            return Err("G4 (dwell) must be alone on its line with P".into());
        }
        let p = b.p_word.ok_or_else(|| "G4 needs P<seconds>".to_string())?;
        if p < 0.0 {
            return Err(format!("dwell P{p} must be >= 0 s"));
        }
        if p > 0.0 {
            self.segments.push(PathSegment::Dwell {
                duration_s: p,
                line: ln,
            });
        }
        Ok(())
    }

    /// G0/G1 to `target`.
    fn line(&mut self, b: &Block, m: u32, target: [f64; 3], ln: usize) -> Result<(), String> {
        if b.ci.is_some() || b.cj.is_some() {
            return Err("I and J are only used with G2/G3".into());
        }
        let f = if m == 0 {
            f64::INFINITY
        } else {
            self.feed.ok_or_else(|| {
                "no feed rate (F, mm/min) programmed before this G1 move".to_string()
            })?
        };
        if dist3(&self.pos, &target) > 1e-12 {
            self.segments.push(PathSegment::Line {
                from_m: self.pos,
                to_m: target,
                feed_m_per_s: f,
                line: ln,
            });
        }
        Ok(())
    }

    /// G2/G3 to `target`; returns the end point landed exactly on the circle.
    fn arc(
        &mut self,
        b: &Block,
        m: u32,
        mut target: [f64; 3],
        ln: usize,
    ) -> Result<[f64; 3], String> {
        let pos = self.pos;
        if b.coords[2].is_some() && (target[2] - pos[2]).abs() > 1e-12 {
            return Err("helical arcs (Z change in G2/G3) are not supported".into());
        }
        let f = self
            .feed
            .ok_or_else(|| format!("no feed rate (F, mm/min) programmed before this G{m} arc"))?;
        if b.ci.is_none() && b.cj.is_none() {
            return Err(format!("G{m} needs the centre offsets I and/or J"));
        }
        self.uses[0] = true;
        self.uses[1] = true;
        let c = [
            pos[0] + b.ci.unwrap_or(0.0) * 1e-3,
            pos[1] + b.cj.unwrap_or(0.0) * 1e-3,
        ];
        let r0 = (pos[0] - c[0]).hypot(pos[1] - c[1]);
        let r1 = (target[0] - c[0]).hypot(target[1] - c[1]);
        if r0 <= 1e-9 {
            return Err("arc radius is zero (I = J = 0)".into());
        }
        if (r1 - r0).abs() > 1e-6 + 1e-4 * r0 {
            return Err(format!(
                "arc end point is not on the circle: radius {:.4} mm at the start, {:.4} mm at the end",
                r0 * 1e3,
                r1 * 1e3
            ));
        }
        let a0 = (pos[1] - c[1]).atan2(pos[0] - c[0]);
        let a1 = (target[1] - c[1]).atan2(target[0] - c[0]);
        let ccw = m == 3;
        let mut sweep = if ccw {
            (a1 - a0).rem_euclid(2.0 * PI)
        } else {
            -(a0 - a1).rem_euclid(2.0 * PI)
        };
        if sweep.abs() < 1e-12 || dist3(&pos, &target) < 1e-12 {
            sweep = if ccw { 2.0 * PI } else { -2.0 * PI };
        }
        // Land exactly on the circle through the start (r0).
        target[0] = c[0] + r0 * (a0 + sweep).cos();
        target[1] = c[1] + r0 * (a0 + sweep).sin();
        self.segments.push(PathSegment::Arc {
            center_m: c,
            radius_m: r0,
            start_angle_rad: a0,
            sweep_rad: sweep,
            z_m: pos[2],
            feed_m_per_s: f,
            line: ln,
        });
        Ok(target)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gcode::tests::parse;

    #[test]
    fn a_program_parses_into_lines_arcs_and_dwells_in_metres() {
        let p = parse(
            "% \n(square with a round corner)\nN10 G21 G17 G90\nG0 X0 Y0\nG1 X10 F600 ; 10 mm/s\nG3 X20 Y10 I0 J10\nG4 P0.5\nG91 G1 Y-10\nM30\nG1 X99\n",
        )
        .unwrap();
        assert_eq!(p.segments.len(), 4, "{:?}", p.segments);
        match &p.segments[0] {
            PathSegment::Line {
                to_m,
                feed_m_per_s,
                line,
                ..
            } => {
                assert_eq!(*to_m, [0.01, 0.0, 0.0]);
                assert!((feed_m_per_s - 0.01).abs() < 1e-15);
                assert_eq!(*line, 5);
            }
            other => panic!("{other:?}"),
        }
        match &p.segments[1] {
            PathSegment::Arc {
                center_m,
                radius_m,
                sweep_rad,
                ..
            } => {
                assert!((center_m[0] - 0.01).abs() < 1e-15 && (center_m[1] - 0.01).abs() < 1e-15);
                assert!((radius_m - 0.01).abs() < 1e-15);
                assert!((sweep_rad - PI / 2.0).abs() < 1e-12);
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(
            p.segments[2],
            PathSegment::Dwell {
                duration_s: 0.5,
                line: 7
            }
        );
        match &p.segments[3] {
            PathSegment::Line { from_m, to_m, .. } => {
                assert!((from_m[0] - 0.02).abs() < 1e-15 && (from_m[1] - 0.01).abs() < 1e-15);
                assert!((to_m[1]).abs() < 1e-15, "incremental Y-10 from 10");
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(p.uses, [true, true, false]);
    }

    #[test]
    fn bad_programs_are_refused_with_file_and_line() {
        for (text, line, what) in [
            ("G1 X10\n", 1, "no feed rate"),
            ("G1 F100 X1\nG20\n", 2, "inch"),
            ("G1 F100 X1\nG41 X2\n", 2, "unsupported G-code G41"),
            ("F100\nG2 X10 Y0 I4 J1\n", 2, "not on the circle"),
            ("G1 F100 X1 X2\n", 1, "appears twice"),
            ("G1 F100 X1\nT1\n", 2, "unsupported word `T1`"),
            ("G1 F100 X1 (open\n", 1, "not closed"),
            ("G1 F100 Xabc\n", 1, "needs a number"),
            ("G2 F100 X1 R5\n", 1, "R"),
            ("G4\n", 1, "P<seconds>"),
            ("(nothing)\n", 1, "no motion"),
            ("G1 F100 X1\nG3 X0 Y0 Z1 I1 J0\n", 2, "helical"),
        ] {
            let e = parse(text).unwrap_err();
            assert_eq!(e.line, line, "{text:?}: {e}");
            assert!(
                e.to_string()
                    .starts_with(&format!("part.nc: line {line}: ")),
                "{e}"
            );
            assert!(e.reason.contains(what), "{text:?}: {e}");
        }
    }
}
