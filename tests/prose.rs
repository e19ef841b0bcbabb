//! The front ends read the engine's state by type, never by its words. The snapshot
//! carries each cause twice: as a type (`gate.cause`, `gate.blocked_by`,
//! `gate.watchdog.trip`, `supervisor.outcome`) for programs, and in words (`reason`,
//! `blockers`, `last_trip`, `last_outcome`, `last_refused`, `history`) for people. The
//! words are rendered in one place and may change; a front end that decides anything by
//! them (`reason.starts_with("disengaged: ")`, `last_trip.contains("deadman")`) breaks
//! silently when they do. This test reads the front ends' code (their tests aside,
//! which may assert the words a person sees) and fails on any statement that holds one
//! of the words' fields and tests it against a string literal.

use std::fs;
use std::path::{Path, PathBuf};

/// The front ends: everything that reads the engine's state from the snapshot or the
/// gate and shows it, answers with it, or acts on it.
const FRONT_ENDS: &[&str] = &[
    "src/console",
    "src/socket",
    "src/controls",
    "src/ros2",
    "src/foxglove",
    "src/record",
    "src/net",
    "src/headless.rs",
    "src/cli.rs",
];

/// The snapshot's fields (and the gate's method) that hold the engine's words.
const WORDS: &[&str] = &[
    ".reason",
    ".blockers",
    ".last_trip",
    ".last_outcome",
    ".last_refused",
    ".history",
];

/// Ways to decide by a string's content.
const MATCHERS: &[&str] = &[
    "starts_with(\"",
    "ends_with(\"",
    "contains(\"",
    "trim_start_matches(\"",
    "trim_end_matches(\"",
    "strip_prefix(\"",
    "strip_suffix(\"",
    "find(\"",
    "split(\"",
    "replace(\"",
    "== \"",
    "!= \"",
];

fn files(path: &Path, out: &mut Vec<PathBuf>) {
    if path.is_file() {
        out.push(path.to_path_buf());
        return;
    }
    for e in fs::read_dir(path).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            // A directory of tests (`update/tests/`) holds no front end's code.
            if p.file_name().is_some_and(|n| n != "tests") {
                files(&p, out);
            }
        } else if p.extension().is_some_and(|x| x == "rs") && !p.ends_with("tests.rs") {
            out.push(p);
        }
    }
}

/// The code of `text` without its inline `#[cfg(test)]` module (which by the crate's
/// habit closes the file) and without comments.
fn code(text: &str) -> String {
    let lines: Vec<&str> = text.lines().collect();
    let end = lines
        .windows(2)
        .position(|w| w[0].trim() == "#[cfg(test)]" && w[1].starts_with("mod "))
        .unwrap_or(lines.len());
    lines[..end]
        .iter()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The statements of `code` (split at `;`, `{` and `}`) that decide by the engine's
/// words, with the line each begins on.
fn deciding_by_words(code: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut line = 1;
    for piece in code.split([';', '{', '}']) {
        let flat: String = piece.split_whitespace().collect::<Vec<_>>().join(" ");
        let words = WORDS.iter().any(|w| {
            flat.match_indices(w).any(|(i, _)| {
                // `.reason` and `.reason()`, not `.reasons` nor `.reason_wants`.
                !flat[i + w.len()..].starts_with(|c: char| c.is_alphanumeric() || c == '_')
            })
        });
        if words && MATCHERS.iter().any(|m| flat.contains(m)) {
            let first = piece
                .chars()
                .take_while(|c| c.is_whitespace())
                .collect::<String>();
            out.push((line + first.matches('\n').count(), flat));
        }
        line += piece.matches('\n').count();
    }
    out
}

#[test]
fn no_front_end_decides_by_the_engine_s_words() {
    let mut all = Vec::new();
    for f in FRONT_ENDS {
        files(Path::new(f), &mut all);
    }
    assert!(all.len() > 50, "the front ends' files: {}", all.len());
    let mut found = Vec::new();
    for f in &all {
        let text = fs::read_to_string(f).unwrap();
        for (n, s) in deciding_by_words(&code(&text)) {
            found.push(format!("{}:{n}: {s}", f.display()));
        }
    }
    assert!(
        found.is_empty(),
        "front ends decide by the engine's words; match on the snapshot's types \
         (gate.cause, gate.blocked_by, gate.watchdog.trip, supervisor.outcome) instead:\n{}",
        found.join("\n")
    );
}

/// The check sees what it is for: the console's old header, which stripped the gate's
/// words of their state, and a deadman told by its words.
#[test]
fn the_check_finds_a_decision_by_words() {
    let old = r#"
        let why = if s.gate.engaged {
            who.as_str()
        } else {
            s.gate.reason.trim_start_matches("disengaged: ")
        };
        let tripped = w
            .last_trip
            .as_deref()
            .is_some_and(|t| t.starts_with("deadman"));
        // s.gate.reason.contains("x") in a comment is no code
        let shown = g.reason.clone();
        let n = s.reason_wants.find("x");
    "#;
    let found = deciding_by_words(&code(old));
    assert_eq!(found.len(), 2, "{found:#?}");
    assert_eq!(found[0].0, 5, "{found:#?}");
    assert!(
        found[1].1.contains("starts_with(\"deadman\")"),
        "{found:#?}"
    );
}
