//! What a user reads speaks the user's language and points at files the repository has: no
//! internal bookkeeping (session or issue numbers, "the brief", numbered seeds) in the README,
//! the docs or the command line's help; every table has one header row; every shipped record a
//! doc names is in the repository, and nothing points outside it.

use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The files a user reads: the README, the docs and the command line's sources (its help texts
/// and messages are written there).
fn user_files() -> Vec<PathBuf> {
    let mut v = vec![root().join("README.md")];
    let mut dirs = vec![root().join("docs"), root().join("cli/src")];
    while let Some(d) = dirs.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                dirs.push(p);
            } else if p
                .extension()
                .is_some_and(|x| x == "md" || x == "rs" || x == "html" || x == "js")
            {
                v.push(p);
            }
        }
    }
    v.sort();
    v
}

/// Where `word` stands in `line` followed by a space and a digit ("session 13", "issue 7").
fn numbered(line: &str, word: &str) -> bool {
    let lower = line.to_ascii_lowercase();
    lower.match_indices(word).any(|(i, _)| {
        let before_ok = i == 0 || !lower.as_bytes()[i - 1].is_ascii_alphanumeric();
        let rest = &lower.as_bytes()[i + word.len()..];
        before_ok && rest.len() >= 2 && rest[0] == b' ' && rest[1].is_ascii_digit()
    })
}

/// The internal words of `line`, if any.
fn internal_words(line: &str) -> Option<&'static str> {
    let lower = line.to_ascii_lowercase();
    if numbered(line, "session") {
        return Some("a session number");
    }
    if numbered(line, "issue") || numbered(line, "issues") {
        return Some("an issue number");
    }
    if lower.contains("the brief") {
        return Some("\"the brief\"");
    }
    if ["seed 00", "seeds 00", "seed-00", "seed 003", "seed 004"]
        .iter()
        .any(|w| lower.contains(w))
    {
        return Some("a numbered seed (name the method and its source, docs/sources.md)");
    }
    None
}

#[test]
fn what_users_read_names_no_session_issue_or_seed_number() {
    let mut found = Vec::new();
    for p in user_files() {
        let text = std::fs::read_to_string(&p).unwrap();
        for (i, line) in text.lines().enumerate() {
            if let Some(what) = internal_words(line) {
                found.push(format!(
                    "{}:{}: {what}: {}",
                    p.display(),
                    i + 1,
                    line.trim()
                ));
            }
        }
    }
    assert!(found.is_empty(), "internal language:\n{}", found.join("\n"));
}

#[test]
fn the_internal_word_check_catches_what_it_is_for() {
    assert!(internal_words("as session 13 showed").is_some());
    assert!(internal_words("(issue 7)").is_some());
    assert!(internal_words("Issues 29 and 30").is_some());
    assert!(internal_words("the brief's figure").is_some());
    assert!(internal_words("seed 004's learning").is_some());
    assert!(internal_words("noise seeds 1..5, a 10-minute session of work").is_none());
    assert!(internal_words("tissue 4").is_none());
}

fn is_separator(line: &str) -> bool {
    let t = line.trim();
    t.starts_with('|') && t.len() > 2 && t.chars().all(|c| matches!(c, '|' | '-' | ':' | ' '))
}

#[test]
fn every_table_of_the_docs_has_exactly_one_header_row() {
    let mut bad = Vec::new();
    for p in user_files()
        .into_iter()
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
    {
        let text = std::fs::read_to_string(&p).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        let mut i = 0;
        while i < lines.len() {
            if !lines[i].starts_with('|') {
                i += 1;
                continue;
            }
            // one table: the run of lines that start with '|'
            let start = i;
            while i < lines.len() && lines[i].starts_with('|') {
                i += 1;
            }
            let table = &lines[start..i];
            if !table.get(1).is_some_and(|l| is_separator(l)) {
                bad.push(format!(
                    "{}:{}: a table without a header row",
                    p.display(),
                    start + 1
                ));
            }
            let seps = table.iter().filter(|l| is_separator(l)).count();
            if seps > 1 {
                bad.push(format!(
                    "{}:{}: a table with {seps} header rows",
                    p.display(),
                    start + 1
                ));
            }
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

/// The paths under `examples/data/` that `text` names.
fn data_paths(text: &str) -> Vec<String> {
    let mut v = Vec::new();
    for (i, _) in text.match_indices("examples/data/") {
        let rest = &text[i..];
        let end = rest
            .find(|c: char| c.is_whitespace() || matches!(c, '`' | ')' | '"' | '\'' | ',' | ';'))
            .unwrap_or(rest.len());
        let p = rest[..end].trim_end_matches(['.', ':']);
        if p.ends_with(".csv") || p.ends_with('/') || p.ends_with("README.md") {
            v.push(p.to_string());
        }
    }
    v
}

#[test]
fn the_real_records_the_docs_use_are_shipped_with_their_source_and_nothing_points_outside() {
    let mut missing = Vec::new();
    let mut outside = Vec::new();
    let mut named = 0;
    for p in user_files() {
        let text = std::fs::read_to_string(&p).unwrap();
        for d in data_paths(&text) {
            named += 1;
            // `kuka_b_jN.csv` stands for each joint's record
            let exists = |q: &str| root().join(q).exists();
            let placeholder =
                d.contains("jN") && (1..=3).all(|j| exists(&d.replace("jN", &format!("j{j}"))));
            if !exists(&d) && !placeholder {
                missing.push(format!("{}: {d}", p.display()));
            }
        }
        for (i, line) in text.lines().enumerate() {
            if line.contains("../shared/data") {
                outside.push(format!("{}:{}: {}", p.display(), i + 1, line.trim()));
            }
        }
    }
    assert!(named >= 5, "the docs name only {named} shipped records");
    assert!(
        missing.is_empty(),
        "named but not shipped:\n{}",
        missing.join("\n")
    );
    assert!(
        outside.is_empty(),
        "pointing outside the repository:\n{}",
        outside.join("\n")
    );
    for set in ["emps", "kuka"] {
        let readme =
            std::fs::read_to_string(root().join("examples/data").join(set).join("README.md"))
                .unwrap_or_else(|e| panic!("examples/data/{set}/README.md: {e}"));
        for word in ["licence", "cite", "source"] {
            assert!(
                readme.to_lowercase().contains(word),
                "examples/data/{set}/README.md says nothing of its {word}"
            );
        }
    }
}
