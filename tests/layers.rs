//! The crate's layers, as docs/architecture.md draws them, checked in the source: the
//! core (value, can, config, snapshot, driver, port, vehicle, safety, engine,
//! supervisor, and the test kit at its top) never imports a front end, tests included,
//! and inside the core every import points down the order below — with no exception.
//! Above the core, the front ends stand in layers of peers: the simulator, the
//! network and the bench's characterization; the control interface the consoles share, the recorder, ROS 2, headless;
//! the consoles (embedded and attached: `console`, `socket`) and the live view; the
//! fleet; the command line. A front end imports the core and the layers below its own, never a
//! peer: the attached console's client and server reach the vehicle through
//! `controls`, as the embedded console does, not through the console. Doc links are
//! not imports. A module's tests (its `#[cfg(test)]` module, or a file only tests
//! compile) are checked like its code, except that they may use the test kit: the
//! vehicle at rest that every layer's tests share, which builds the whole core and so
//! sits at its top, where no code but a test reaches it.

use std::fs;
use std::path::{Path, PathBuf};

/// The core, bottom first: a module may import those before it (and itself).
const CORE: &[&str] = &[
    "value",
    "can",
    "config",
    "snapshot",
    "driver",
    "port",
    "vehicle",
    "safety",
    "engine",
    "supervisor",
    "testkit",
];

/// The fixtures of every layer's tests, at the top of the core.
const TESTKIT: &str = "testkit";

/// Front ends and tools, in layers of peers, bottom first: the core never imports
/// them; each imports the core and the layers before its own, never one of its own.
const FRONT: &[&[&str]] = &[
    &["sim", "net", "characterize"],
    &["controls", "record", "ros2", "headless"],
    &["console", "socket", "foxglove"],
    &["fleet"],
    &["cli"],
];

/// The layer of a front end, bottom first.
fn front_layer(m: &str) -> Option<usize> {
    FRONT.iter().position(|layer| layer.contains(&m))
}

fn files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The top-level module a file of `src/` belongs to.
fn module(path: &Path) -> String {
    let rel = path.strip_prefix("src").unwrap();
    let first = rel
        .components()
        .next()
        .unwrap()
        .as_os_str()
        .to_string_lossy();
    first.trim_end_matches(".rs").to_string()
}

/// Every `crate::<module>` path in code (not in comments) of `text`, with its line.
fn imports(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let code = line.split("//").next().unwrap_or("");
        let mut rest = code;
        while let Some(i) = rest.find("crate::") {
            let tail = &rest[i + "crate::".len()..];
            let end = tail
                .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
                .unwrap_or(tail.len());
            out.push((n + 1, format!("crate::{}", &tail[..end])));
            rest = &tail[end..];
        }
    }
    out
}

/// Where the tests of `text` begin: the first line of a `#[cfg(test)]` module written
/// inline (`mod tests {`), which by the crate's habit closes the file; `None` when it
/// has none.
fn tests_from(text: &str) -> Option<usize> {
    let lines: Vec<&str> = text.lines().collect();
    lines
        .windows(2)
        .position(|w| {
            w[0].trim() == "#[cfg(test)]"
                && w[1].starts_with("mod ")
                && w[1].trim_end().ends_with('{')
        })
        .map(|i| i + 1)
}

/// The files only tests compile: those of modules declared `#[cfg(test)] mod NAME;`.
fn test_files(all: &[PathBuf]) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for f in all {
        let text = fs::read_to_string(f).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        for w in lines.windows(2) {
            let Some(name) = w[1]
                .trim()
                .strip_prefix("mod ")
                .and_then(|m| m.strip_suffix(';'))
            else {
                continue;
            };
            if w[0].trim() != "#[cfg(test)]" {
                continue;
            }
            // `a/mod.rs` or `a.rs` declares `a/NAME.rs`.
            let dir = match f.file_name().and_then(|n| n.to_str()) {
                Some("mod.rs" | "lib.rs") => f.parent().unwrap().to_path_buf(),
                _ => f.with_extension(""),
            };
            out.push(dir.join(format!("{name}.rs")));
        }
    }
    out
}

#[test]
fn the_core_never_imports_a_front_end_and_imports_point_down() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    std::env::set_current_dir(env!("CARGO_MANIFEST_DIR")).unwrap();
    let mut all = Vec::new();
    files(Path::new("src"), &mut all);
    assert!(
        all.len() > 50,
        "read {} files under {}",
        all.len(),
        src.display()
    );
    let tests_only = test_files(&all);
    assert!(
        tests_only.iter().all(|f| all.contains(f)),
        "test modules declared and not found: {tests_only:?}"
    );
    let mut wrong = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for f in &all {
        let m = module(f);
        let core = CORE.iter().position(|c| *c == m);
        let front = front_layer(&m);
        if core.is_none() && front.is_none() {
            continue;
        }
        seen.insert(m.clone());
        let text = fs::read_to_string(f).unwrap();
        let tests = if tests_only.contains(f) {
            Some(0)
        } else {
            tests_from(&text)
        };
        for (line, path) in imports(&text) {
            let target = path.split("::").nth(1).unwrap_or("");
            let file = f.display().to_string();
            if target == m {
                continue;
            }
            let in_tests = tests.is_some_and(|t| line > t);
            match (core, front, front_layer(target)) {
                (Some(_), _, Some(_)) => wrong.push(format!(
                    "{file}:{line}: the core imports a front end: {path}"
                )),
                (Some(rank), _, None) => {
                    let Some(to) = CORE.iter().position(|c| *c == target) else {
                        continue;
                    };
                    if to > rank && !(in_tests && target == TESTKIT) {
                        wrong.push(format!("{file}:{line}: {m} imports {path}, above it"));
                    }
                }
                (None, Some(layer), Some(to)) if to == layer => wrong.push(format!(
                    "{file}:{line}: {m} imports {path}, a front end of its own layer"
                )),
                (None, Some(layer), Some(to)) if to > layer => {
                    wrong.push(format!("{file}:{line}: {m} imports {path}, above it"))
                }
                _ => {}
            }
        }
    }
    let missing: Vec<&&str> = CORE
        .iter()
        .chain(FRONT.iter().flat_map(|l| l.iter()))
        .filter(|c| !seen.contains(**c))
        .collect();
    assert!(missing.is_empty(), "no source for {missing:?}");
    assert!(
        wrong.is_empty(),
        "imports pointing up:\n{}",
        wrong.join("\n")
    );
}

/// The test's own reading of the source: a module's tests start at its inline
/// `#[cfg(test)]` module, and a file declared `#[cfg(test)] mod NAME;` is all tests.
#[test]
fn tests_are_told_from_code() {
    let text =
        "use crate::value::Command;\n\n#[cfg(test)]\nmod tests {\n    use crate::testkit;\n}\n";
    assert_eq!(tests_from(text), Some(3));
    assert_eq!(tests_from("#[cfg(test)]\nmod tests;\n"), None);
    let here = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut all = Vec::new();
    files(&here, &mut all);
    let t = test_files(&all);
    assert!(
        t.iter().any(|f| f.ends_with("console/update/tests.rs")),
        "{t:?}"
    );
}
