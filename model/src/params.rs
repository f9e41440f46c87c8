//! Typed, validated reading of TOML parameter tables with errors that name file, key and reason.
//!
//! Every config surface of feedloop (model files, job files, plugin and effect parameters) goes
//! through [`Fields`], so unknown keys, wrong types and out-of-range values are all reported the
//! same way: `FILE: key `a.b`: reason`.

use std::collections::BTreeSet;
use std::fmt;
use std::path::{Path, PathBuf};

use crate::units::exact;

/// What kind of configuration error it is, for callers that react to some kinds (the message
/// is the same whatever the kind).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ConfigErrorKind {
    /// A required key is absent.
    Missing,
    /// A key nobody reads (a typo, or a key of another version).
    UnknownKey,
    /// A value of the right type outside its range (negative, non-finite, past a bound).
    OutOfRange,
    /// A value of the wrong type (a string for a number, a table for an array, ...).
    WrongType,
    /// Anything else: unreadable file, bad syntax, inconsistent values.
    Invalid,
}

/// A configuration error: which file, which key (dotted path), and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct ConfigError {
    /// File the value came from (empty when it came from elsewhere, e.g. a control request).
    pub file: PathBuf,
    /// Dotted key path, e.g. `axes.x.model` or `effects.backlash.gap_m`; empty for file-level errors.
    pub key: String,
    /// What is wrong, in words.
    pub reason: String,
    /// What kind of error it is (not part of the message).
    pub kind: ConfigErrorKind,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let file = self.file.display();
        match (self.file.as_os_str().is_empty(), self.key.is_empty()) {
            (true, true) => write!(f, "{}", self.reason),
            (true, false) => write!(f, "key `{}`: {}", self.key, self.reason),
            (false, true) => write!(f, "{file}: {}", self.reason),
            (false, false) => write!(f, "{file}: key `{}`: {}", self.key, self.reason),
        }
    }
}

impl ConfigError {
    /// Builds an error of kind [`ConfigErrorKind::Invalid`].
    pub fn new(file: &Path, key: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::of_kind(ConfigErrorKind::Invalid, file, key, reason)
    }

    /// Builds an error of `kind`.
    pub fn of_kind(
        kind: ConfigErrorKind,
        file: &Path,
        key: impl Into<String>,
        reason: impl Into<String>,
    ) -> Self {
        Self {
            file: file.to_path_buf(),
            key: key.into(),
            reason: reason.into(),
            kind,
        }
    }

    /// `key` is required but missing.
    pub fn missing(file: &Path, key: impl Into<String>) -> Self {
        Self::of_kind(ConfigErrorKind::Missing, file, key, MISSING)
    }

    /// `key` is not known here; `reason` says so (e.g. from [`unknown_key_reason`]).
    pub fn unknown_key(file: &Path, key: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::of_kind(ConfigErrorKind::UnknownKey, file, key, reason)
    }

    /// The value of `key` is out of its range.
    pub fn out_of_range(file: &Path, key: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::of_kind(ConfigErrorKind::OutOfRange, file, key, reason)
    }

    /// The value of `key` has the wrong type.
    pub fn wrong_type(file: &Path, key: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::of_kind(ConfigErrorKind::WrongType, file, key, reason)
    }
}

/// The reason of a [`ConfigErrorKind::Missing`] error.
const MISSING: &str = "is required but missing";

/// Largest TOML file read, bytes (jobs, models and tables are kilobytes). A file named in a
/// request's parameters (a swap's `table`) may be anything: `/dev/zero` must not be read until
/// memory runs out.
pub const MAX_TOML_BYTES: u64 = 64 << 20;

/// Reads a TOML file into a table; a syntax error names the file and the line, a file larger
/// than [`MAX_TOML_BYTES`] is refused after reading that much.
pub fn read_toml_file(path: &Path) -> Result<toml::Table, ConfigError> {
    use std::io::Read;
    let cannot = |e: std::io::Error| ConfigError::new(path, "", format!("cannot read file: {e}"));
    let mut text = String::new();
    std::fs::File::open(path)
        .map_err(cannot)?
        .take(MAX_TOML_BYTES + 1)
        .read_to_string(&mut text)
        .map_err(cannot)?;
    if text.len() as u64 > MAX_TOML_BYTES {
        return Err(ConfigError::new(
            path,
            "",
            format!(
                "cannot read file: larger than {} MiB (not a TOML file)",
                MAX_TOML_BYTES >> 20
            ),
        ));
    }
    parse_toml(path, &text)
}

/// Parses TOML text that came from `path` (used in messages only).
pub fn parse_toml(path: &Path, text: &str) -> Result<toml::Table, ConfigError> {
    text.parse::<toml::Table>().map_err(|e| {
        let line = e
            .span()
            .map(|s| text[..s.start.min(text.len())].lines().count().max(1));
        let msg = e.message().to_string();
        match line {
            Some(l) => ConfigError::new(path, "", format!("line {l}: invalid TOML: {msg}")),
            None => ConfigError::new(path, "", format!("invalid TOML: {msg}")),
        }
    })
}

/// Range check applied to a number.
#[derive(Debug, Clone, Copy)]
pub enum Range {
    /// Any finite value.
    Finite,
    /// Finite and > 0.
    Positive,
    /// Finite and >= 0.
    NonNegative,
    /// Finite and within [lo, hi].
    Within(f64, f64),
}

impl Range {
    /// Checks `v`: the error says how it is outside the range (the reason of a
    /// [`ConfigErrorKind::OutOfRange`] error).
    pub fn check(self, v: f64) -> Result<(), RangeError> {
        if !v.is_finite() {
            return Err(RangeError(format!("must be a finite number, got {v}")));
        }
        let (got, x) = (exact(v), exact);
        match self {
            Range::Finite => Ok(()),
            Range::Positive if v > 0.0 => Ok(()),
            Range::Positive => Err(RangeError(format!("must be > 0, got {got}"))),
            Range::NonNegative if v >= 0.0 => Ok(()),
            Range::NonNegative => Err(RangeError(format!("must be >= 0, got {got}"))),
            Range::Within(lo, hi) if (lo..=hi).contains(&v) => Ok(()),
            Range::Within(lo, hi) => Err(RangeError(format!(
                "must be within [{}, {}], got {got}",
                x(lo),
                x(hi)
            ))),
        }
    }
}

/// Why a number failed its [`Range`], e.g. `must be > 0, got -1`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct RangeError(pub String);

/// A closed set of spellings for one key: the value each names, and the value when the key is
/// absent. Read with [`Fields::choose`]; implemented with [`key_choice!`](crate::key_choice).
pub trait KeyChoice: Copy + 'static {
    /// What the key names, in messages (`unknown WHAT ...`).
    const WHAT: &'static str;
    /// Each spelling with its value.
    const SPELLINGS: &'static [(&'static str, Self)];
    /// The value when the key is absent.
    const DEFAULT: Self;
}

/// Implements [`KeyChoice`](crate::params::KeyChoice) for an enum:
/// `key_choice!(Type, "what", default Variant, ["spelling" => Variant, ...]);`.
#[macro_export]
macro_rules! key_choice {
    ($t:ty, $what:literal, default $d:ident, [$($name:literal => $v:ident),+ $(,)?]) => {
        impl $crate::params::KeyChoice for $t {
            const WHAT: &'static str = $what;
            const SPELLINGS: &'static [(&'static str, Self)] = &[$(($name, Self::$v)),+];
            const DEFAULT: Self = Self::$d;
        }
    };
}

/// A view of one TOML table that remembers which keys were read, so unknown keys can be refused.
pub struct Fields<'a> {
    table: &'a toml::Table,
    file: &'a Path,
    prefix: String,
    /// Keys present in the table and read.
    used: BTreeSet<String>,
    /// Every key asked for, present or not: the keys this table accepts.
    asked: BTreeSet<String>,
}

impl<'a> Fields<'a> {
    /// Wraps `table`, found in `file` under the dotted `prefix` ("" for the top level).
    pub fn new(table: &'a toml::Table, file: &'a Path, prefix: &str) -> Self {
        Self {
            table,
            file,
            prefix: prefix.to_string(),
            used: BTreeSet::new(),
            asked: BTreeSet::new(),
        }
    }

    /// The table itself.
    pub fn table(&self) -> &'a toml::Table {
        self.table
    }

    /// The file this table came from.
    pub fn file(&self) -> &'a Path {
        self.file
    }

    /// Dotted path of `key` inside this table.
    pub fn path(&self, key: &str) -> String {
        if self.prefix.is_empty() {
            key.to_string()
        } else {
            format!("{}.{key}", self.prefix)
        }
    }

    /// An error about `key` of this table (kind [`ConfigErrorKind::Invalid`]).
    pub fn error(&self, key: &str, reason: impl Into<String>) -> ConfigError {
        self.error_of(ConfigErrorKind::Invalid, key, reason)
    }

    /// An error of `kind` about `key` of this table.
    pub fn error_of(
        &self,
        kind: ConfigErrorKind,
        key: &str,
        reason: impl Into<String>,
    ) -> ConfigError {
        ConfigError::of_kind(kind, self.file, self.path(key), reason)
    }

    /// `key` of this table is required but missing. Keys of the table that nothing has read
    /// yet and that are close to `key` (a misspelling, a unit suffix left out) are named.
    pub fn missing(&self, key: &str) -> ConfigError {
        let close: Vec<String> = self
            .table
            .keys()
            .filter(|k| !self.asked.contains(*k) && !self.used.contains(*k))
            .filter(|k| is_close(k, key))
            .map(|k| format!("`{}`", self.path(k)))
            .collect();
        if close.is_empty() {
            return ConfigError::missing(self.file, self.path(key));
        }
        let it = if close.len() == 1 {
            "is it"
        } else {
            "is one of them"
        };
        self.error_of(
            ConfigErrorKind::Missing,
            key,
            format!(
                "{MISSING}; the table has {} close to it: {it} a misspelling of `{key}`?",
                close.join(", ")
            ),
        )
    }

    /// The value of `key` of this table has the wrong type.
    pub fn wrong_type(&self, key: &str, reason: impl Into<String>) -> ConfigError {
        self.error_of(ConfigErrorKind::WrongType, key, reason)
    }

    /// The value of `key` of this table is out of its range.
    pub fn out_of_range(&self, key: &str, reason: impl Into<String>) -> ConfigError {
        self.error_of(ConfigErrorKind::OutOfRange, key, reason)
    }

    /// The raw value of `key`, marking it used.
    pub fn raw(&mut self, key: &str) -> Option<&'a toml::Value> {
        self.asked.insert(key.to_string());
        let v = self.table.get(key);
        if v.is_some() {
            self.used.insert(key.to_string());
        }
        v
    }

    /// Whether `key` is present (does not mark it used).
    pub fn has(&self, key: &str) -> bool {
        self.table.contains_key(key)
    }

    /// An optional number (integers are accepted as numbers) checked against `range`.
    pub fn opt_f64(&mut self, key: &str, range: Range) -> Result<Option<f64>, ConfigError> {
        let Some(v) = self.raw(key) else {
            return Ok(None);
        };
        let x = match v {
            toml::Value::Float(f) => *f,
            toml::Value::Integer(i) => *i as f64,
            other => {
                return Err(
                    self.wrong_type(key, format!("must be a number, got {}", other.type_str()))
                )
            }
        };
        range.check(x).map_err(|r| self.out_of_range(key, r.0))?;
        Ok(Some(x))
    }

    /// A required number.
    pub fn f64(&mut self, key: &str, range: Range) -> Result<f64, ConfigError> {
        self.opt_f64(key, range)?.ok_or_else(|| self.missing(key))
    }

    /// A number with a default.
    pub fn f64_or(&mut self, key: &str, range: Range, default: f64) -> Result<f64, ConfigError> {
        Ok(self.opt_f64(key, range)?.unwrap_or(default))
    }

    /// An optional integer within [lo, hi].
    pub fn opt_i64(&mut self, key: &str, lo: i64, hi: i64) -> Result<Option<i64>, ConfigError> {
        let Some(v) = self.raw(key) else {
            return Ok(None);
        };
        let x = match v {
            toml::Value::Integer(i) => *i,
            toml::Value::Float(f) if f.fract() == 0.0 && f.is_finite() => *f as i64,
            other => {
                return Err(self.wrong_type(
                    key,
                    format!("must be a whole number, got {}", describe(other)),
                ))
            }
        };
        if x < lo || x > hi {
            return Err(self.out_of_range(key, format!("must be within [{lo}, {hi}], got {x}")));
        }
        Ok(Some(x))
    }

    /// An optional string.
    pub fn opt_str(&mut self, key: &str) -> Result<Option<&'a str>, ConfigError> {
        match self.raw(key) {
            None => Ok(None),
            Some(toml::Value::String(s)) => Ok(Some(s.as_str())),
            Some(other) => {
                Err(self.wrong_type(key, format!("must be a string, got {}", other.type_str())))
            }
        }
    }

    /// One of a few named options: `default` when `key` is absent, else the value paired with
    /// its name in `options`; another name is refused as `unknown WHAT `name` (the names)`.
    pub fn choice<T: Copy>(
        &mut self,
        key: &str,
        what: &str,
        options: &[(&str, T)],
        default: T,
    ) -> Result<T, ConfigError> {
        let Some(name) = self.opt_str(key)? else {
            return Ok(default);
        };
        match options.iter().find(|(n, _)| *n == name) {
            Some((_, v)) => Ok(*v),
            None => {
                let names: Vec<&str> = options.iter().map(|(n, _)| *n).collect();
                Err(self.error(
                    key,
                    format!("unknown {what} `{name}` ({})", names.join(", ")),
                ))
            }
        }
    }

    /// A [`KeyChoice`] under `key`: its default when absent, else the value its spelling names
    /// (see [`Fields::choice`]).
    pub fn choose<T: KeyChoice>(&mut self, key: &str) -> Result<T, ConfigError> {
        self.choice(key, T::WHAT, T::SPELLINGS, T::DEFAULT)
    }

    /// A required string.
    pub fn str(&mut self, key: &str) -> Result<&'a str, ConfigError> {
        self.opt_str(key)?.ok_or_else(|| self.missing(key))
    }

    /// An optional boolean.
    pub fn opt_bool(&mut self, key: &str) -> Result<Option<bool>, ConfigError> {
        match self.raw(key) {
            None => Ok(None),
            Some(toml::Value::Boolean(b)) => Ok(Some(*b)),
            Some(other) => Err(self.wrong_type(
                key,
                format!("must be true or false, got {}", other.type_str()),
            )),
        }
    }

    /// An optional sub-table.
    pub fn opt_table(&mut self, key: &str) -> Result<Option<&'a toml::Table>, ConfigError> {
        match self.raw(key) {
            None => Ok(None),
            Some(toml::Value::Table(t)) => Ok(Some(t)),
            Some(other) => {
                Err(self.wrong_type(key, format!("must be a table, got {}", other.type_str())))
            }
        }
    }

    /// An optional array of numbers.
    pub fn opt_f64_array(&mut self, key: &str) -> Result<Option<Vec<f64>>, ConfigError> {
        self.opt_array(key, "numbers", |f, i, x| {
            let v = match x {
                toml::Value::Float(v) => *v,
                toml::Value::Integer(n) => *n as f64,
                other => {
                    return Err(f.wrong_type(
                        key,
                        format!("element {i} must be a number, got {}", other.type_str()),
                    ))
                }
            };
            if !v.is_finite() {
                return Err(f.out_of_range(key, format!("element {i} must be finite, got {v}")));
            }
            Ok(v)
        })
    }

    /// An optional array of strings.
    pub fn opt_str_array(&mut self, key: &str) -> Result<Option<Vec<String>>, ConfigError> {
        self.opt_array(key, "strings", |f, i, x| {
            x.as_str().map(str::to_string).ok_or_else(|| {
                f.wrong_type(
                    key,
                    format!("element {i} must be a string, got {}", x.type_str()),
                )
            })
        })
    }

    /// An optional array of `what` (e.g. "numbers"), each element read by `elem` (given this
    /// table, the element's index and its value); the first element refused ends the reading.
    fn opt_array<T>(
        &mut self,
        key: &str,
        what: &str,
        elem: impl Fn(&Self, usize, &toml::Value) -> Result<T, ConfigError>,
    ) -> Result<Option<Vec<T>>, ConfigError> {
        let Some(v) = self.raw(key) else {
            return Ok(None);
        };
        let arr = v.as_array().ok_or_else(|| {
            self.wrong_type(
                key,
                format!("must be an array of {what}, got {}", v.type_str()),
            )
        })?;
        arr.iter()
            .enumerate()
            .map(|(i, x)| elem(self, i, x))
            .collect::<Result<Vec<_>, _>>()
            .map(Some)
    }

    /// Marks `key` as known without reading it (it is read elsewhere).
    pub fn allow(&mut self, key: &str) {
        self.used.insert(key.to_string());
        self.asked.insert(key.to_string());
    }

    /// Refuses any key that was not read: the error suggests the nearest accepted key and lists
    /// the keys this table accepts (every key asked for, whether the file has it or not).
    pub fn finish(self) -> Result<(), ConfigError> {
        for key in self.table.keys() {
            if !self.used.contains(key) {
                let reason = unknown_key_reason(key, self.asked.iter().map(String::as_str));
                return Err(self.error_of(ConfigErrorKind::UnknownKey, key, reason));
            }
        }
        Ok(())
    }
}

/// Edit distance between `a` and `b`: the fewest insertions, deletions, substitutions of one
/// character, or swaps of two adjacent characters, that turn one into the other (Levenshtein's
/// distance with the swap counted as one edit, as typing slips go; no substring is edited twice).
pub fn edit_distance(a: &str, b: &str) -> usize {
    let a: Vec<char> = a.chars().collect();
    let b: Vec<char> = b.chars().collect();
    // d[i][j]: distance between the first i characters of `a` and the first j of `b`
    let mut d = vec![vec![0usize; b.len() + 1]; a.len() + 1];
    for (i, row) in d.iter_mut().enumerate() {
        row[0] = i;
    }
    for (j, cell) in d[0].iter_mut().enumerate() {
        *cell = j;
    }
    for i in 1..=a.len() {
        for j in 1..=b.len() {
            let same = a[i - 1] == b[j - 1];
            let mut best = (d[i - 1][j - 1] + usize::from(!same))
                .min(d[i - 1][j] + 1)
                .min(d[i][j - 1] + 1);
            if i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] {
                best = best.min(d[i - 2][j - 2] + 1);
            }
            d[i][j] = best;
        }
    }
    d[a.len()][b.len()]
}

/// Whether `typed` is close enough to `accepted` to be a slip for it: equal but for case, at
/// most a third of the longer name's characters apart (at least 1, at most 3), or one of them
/// the other with a `_suffix` left out (`mass` for `mass_kg`).
fn is_close(typed: &str, accepted: &str) -> bool {
    let (t, a) = (typed.to_lowercase(), accepted.to_lowercase());
    if t == a {
        return true;
    }
    let longer = t.chars().count().max(a.chars().count());
    if edit_distance(&t, &a) <= (longer / 3).clamp(1, 3) {
        return true;
    }
    let unit_left_out = |short: &str, long: &str| {
        long.strip_prefix(short)
            .is_some_and(|rest| rest.starts_with('_'))
    };
    unit_left_out(&t, &a) || unit_left_out(&a, &t)
}

/// The accepted name nearest to `typed` by edit distance, when it is close enough to be a slip
/// (see the rules of the private `is_close`); the first of equally near ones.
pub fn nearest<'a>(typed: &str, accepted: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    accepted
        .into_iter()
        .filter(|a| is_close(typed, a))
        .min_by_key(|a| edit_distance(&typed.to_lowercase(), &a.to_lowercase()))
}

/// The reason of an unknown-name error: `unknown key; did you mean `x`? (accepted here: ...)`,
/// the suggestion only when one is close. Shared by every reader of names (table keys, grid
/// parameters, flag values) so they all suggest the same way.
pub fn unknown_key_reason<'a>(typed: &str, accepted: impl IntoIterator<Item = &'a str>) -> String {
    unknown_name_reason("key", typed, accepted)
}

/// As [`unknown_key_reason`] for any kind of name (`key`, `parameter`, `effect`, ...).
pub fn unknown_name_reason<'a>(
    what: &str,
    typed: &str,
    accepted: impl IntoIterator<Item = &'a str>,
) -> String {
    let accepted: Vec<&str> = accepted.into_iter().collect();
    let mut s = format!("unknown {what}");
    if let Some(n) = nearest(typed, accepted.iter().copied()) {
        s.push_str(&format!("; did you mean `{n}`?"));
    }
    if accepted.is_empty() {
        s.push_str(&format!(" (no {what}s are accepted here)"));
    } else {
        s.push_str(&format!(" (accepted here: {})", accepted.join(", ")));
    }
    s
}

fn describe(v: &toml::Value) -> String {
    match v {
        toml::Value::Float(f) => format!("{f}"),
        other => other.type_str().to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_without_end_is_refused_after_the_limit_not_read_until_memory_runs_out() {
        let e = super::read_toml_file(Path::new("/dev/zero")).unwrap_err();
        assert!(e.to_string().contains("larger than 64 MiB"), "{e}");
        let e = super::read_toml_file(Path::new("/no/such/file.toml")).unwrap_err();
        assert!(e.to_string().contains("cannot read file"), "{e}");
    }

    fn table(s: &str) -> toml::Table {
        s.parse().unwrap()
    }

    #[test]
    fn unknown_key_is_named_with_file_and_prefix() {
        let t = table("a = 1.0\nbogus = 2");
        let mut f = Fields::new(&t, Path::new("m.toml"), "plant");
        f.f64("a", Range::Positive).unwrap();
        let e = f.finish().unwrap_err();
        assert_eq!(e.key, "plant.bogus");
        assert!(e
            .to_string()
            .starts_with("m.toml: key `plant.bogus`: unknown key"));
    }

    /// The refusal of number `key` of the top-level table `text` within `range`.
    fn f64_refused(text: &str, key: &str, range: Range) -> ConfigError {
        let t = table(text);
        let mut f = Fields::new(&t, Path::new("m.toml"), "");
        f.f64(key, range).unwrap_err()
    }

    #[test]
    fn negative_value_is_refused_with_the_value() {
        let e = f64_refused("jl_kgm2 = -1.0", "jl_kgm2", Range::NonNegative);
        assert!(e.reason.contains("-1"), "{e}");
    }

    #[test]
    fn nan_is_refused() {
        f64_refused("x = nan", "x", Range::Finite);
    }

    #[test]
    fn wrong_type_is_named() {
        let e = f64_refused("x = \"fast\"", "x", Range::Finite);
        assert!(e.reason.contains("string"), "{e}");
    }

    #[test]
    fn toml_syntax_error_names_the_line() {
        let e = parse_toml(Path::new("j.toml"), "a = 1\nb = = 2\n").unwrap_err();
        assert!(e.reason.contains("line 2"), "{e}");
    }

    fn kind<T>(r: Result<T, ConfigError>) -> ConfigErrorKind {
        r.map(|_| ()).unwrap_err().kind
    }

    #[test]
    fn each_kind_can_be_matched_on() {
        let t = table("n = -1.0\ns = 3\nb = \"yes\"\narr = [1.0, \"a\"]\nk = 12\nextra = 1");
        let mut f = Fields::new(&t, Path::new("m.toml"), "plant");
        assert_eq!(
            kind(f.f64("absent", Range::Finite)),
            ConfigErrorKind::Missing
        );
        assert_eq!(kind(f.str("absent_too")), ConfigErrorKind::Missing);
        assert_eq!(
            kind(f.f64("n", Range::Positive)),
            ConfigErrorKind::OutOfRange
        );
        assert_eq!(kind(f.opt_i64("k", 0, 10)), ConfigErrorKind::OutOfRange);
        assert_eq!(kind(f.opt_str("s")), ConfigErrorKind::WrongType);
        assert_eq!(kind(f.opt_bool("b")), ConfigErrorKind::WrongType);
        assert_eq!(kind(f.opt_f64_array("arr")), ConfigErrorKind::WrongType);
        let e = f.finish().unwrap_err();
        assert_eq!(e.kind, ConfigErrorKind::UnknownKey);
        assert_eq!(e.key, "plant.extra");
        let e = parse_toml(Path::new("j.toml"), "a = = 1").unwrap_err();
        assert_eq!(e.kind, ConfigErrorKind::Invalid);
        assert_eq!(
            ConfigError::new(Path::new(""), "k", "bad").kind,
            ConfigErrorKind::Invalid
        );
    }

    #[test]
    fn kind_constructors_keep_the_message() {
        let file = Path::new("j.toml");
        let e = ConfigError::missing(file, "axes.x.model");
        assert_eq!(e.kind, ConfigErrorKind::Missing);
        assert_eq!(
            e.to_string(),
            "j.toml: key `axes.x.model`: is required but missing"
        );
        for (e, kind) in [
            (
                ConfigError::unknown_key(file, "k", "r"),
                ConfigErrorKind::UnknownKey,
            ),
            (
                ConfigError::out_of_range(file, "k", "r"),
                ConfigErrorKind::OutOfRange,
            ),
            (
                ConfigError::wrong_type(file, "k", "r"),
                ConfigErrorKind::WrongType,
            ),
            (ConfigError::new(file, "k", "r"), ConfigErrorKind::Invalid),
        ] {
            assert_eq!(e.kind, kind);
            assert_eq!(e.to_string(), "j.toml: key `k`: r");
        }
        let t = table("");
        let f = Fields::new(&t, file, "axes.x");
        let e = f.missing("model");
        assert_eq!(e, ConfigError::missing(file, "axes.x.model"));
    }

    #[test]
    fn messages_are_unchanged_by_the_kind() {
        let t = table("n = -1.0\ns = 3");
        let mut f = Fields::new(&t, Path::new("m.toml"), "");
        assert_eq!(
            f.f64("n", Range::Positive).unwrap_err().to_string(),
            "m.toml: key `n`: must be > 0, got -1"
        );
        assert_eq!(
            f.opt_str("s").unwrap_err().to_string(),
            "m.toml: key `s`: must be a string, got integer"
        );
        assert_eq!(
            f.f64("gone", Range::Finite).unwrap_err().to_string(),
            "m.toml: key `gone`: is required but missing"
        );
    }

    #[test]
    fn edit_distance_counts_single_character_edits() {
        assert_eq!(edit_distance("", ""), 0);
        assert_eq!(edit_distance("abc", ""), 3);
        assert_eq!(edit_distance("", "ab"), 2);
        assert_eq!(edit_distance("kitten", "sitting"), 3);
        assert_eq!(edit_distance("jm_kgm", "jm_kgm2"), 1);
        assert_eq!(edit_distance("kv_nms_per_rad", "kp_nms_per_rad"), 1);
        assert_eq!(edit_distance("flaw", "lawn"), 2);
        // symmetric
        assert_eq!(edit_distance("lawn", "flaw"), 2);
        // two adjacent characters swapped count as one slip
        assert_eq!(edit_distance("mdoe", "mode"), 1);
        assert_eq!(edit_distance("ab", "ba"), 1);
    }

    #[test]
    fn nearest_suggests_slips_only() {
        let keys = ["jm_kgm2", "kl_nm_per_rad", "lead_m", "mass_kg"];
        assert_eq!(nearest("jm_kgm", keys), Some("jm_kgm2"));
        assert_eq!(nearest("Lead_M", keys), Some("lead_m"));
        assert_eq!(nearest("mass", keys), Some("mass_kg"));
        assert_eq!(nearest("kl_nm_per_deg", keys), Some("kl_nm_per_rad"));
        assert_eq!(nearest("speed", keys), None);
        assert_eq!(nearest("x", keys), None);
    }

    #[test]
    fn unknown_key_lists_the_accepted_keys_and_suggests_the_nearest() {
        // the file has only `kp_per_s` and a misspelled `tv_ss`: the accepted keys include the
        // ones it leaves out
        let t = table("kp_per_s = 1.0\ntv_ss = 0.01");
        let mut f = Fields::new(&t, Path::new("m.toml"), "controller");
        f.f64("kp_per_s", Range::Positive).unwrap();
        f.opt_f64("kv_nms_per_rad", Range::Positive).unwrap();
        f.opt_f64("tv_s", Range::NonNegative).unwrap();
        let e = f.finish().unwrap_err();
        assert_eq!(e.key, "controller.tv_ss");
        assert!(e.reason.contains("did you mean `tv_s`?"), "{e}");
        assert!(
            e.reason
                .contains("accepted here: kp_per_s, kv_nms_per_rad, tv_s"),
            "{e}"
        );
    }

    #[test]
    fn a_misspelled_required_key_is_named_with_the_missing_one() {
        let t = table("jm_kgm = 1.0\nlead_m = 0.01");
        let mut f = Fields::new(&t, Path::new("m.toml"), "");
        f.f64("lead_m", Range::Positive).unwrap();
        let e = f.f64("jm_kgm2", Range::Positive).unwrap_err();
        assert_eq!(e.kind, ConfigErrorKind::Missing);
        assert_eq!(e.key, "jm_kgm2");
        assert!(
            e.reason.contains("`jm_kgm`") && e.reason.contains("misspelling of `jm_kgm2`"),
            "{e}"
        );
        // a key already read is not offered as the slip
        let t = table("jl_kgm2 = 1.0");
        let mut f = Fields::new(&t, Path::new("m.toml"), "");
        f.f64("jl_kgm2", Range::Positive).unwrap();
        let e = f.f64("jm_kgm2", Range::Positive).unwrap_err();
        assert_eq!(
            e.to_string(),
            "m.toml: key `jm_kgm2`: is required but missing"
        );
    }
    #[test]
    fn a_choice_is_its_default_when_absent_and_names_the_options_when_unknown() {
        let t: toml::Table = "a = \"two\"\nb = \"five\"\nc = 3".parse().unwrap();
        let mut f = Fields::new(&t, Path::new("j.toml"), "");
        let opts = [("one", 1), ("two", 2)];
        assert_eq!(f.choice("a", "count", &opts, 1).unwrap(), 2);
        assert_eq!(f.choice("z", "count", &opts, 1).unwrap(), 1);
        let e = f.choice("b", "count", &opts, 1).unwrap_err().to_string();
        assert!(
            e.contains("unknown count `five` (one, two)") && e.contains("b"),
            "{e}"
        );
        assert_eq!(
            kind(f.choice("c", "count", &opts, 1)),
            ConfigErrorKind::WrongType
        );
    }
}
