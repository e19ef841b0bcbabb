//! The crate's layers, as docs/architecture.md draws them, checked in the source: the
//! core (value, can, config, driver, vehicle, safety, engine, snapshot, supervisor) never
//! imports a front end (console, net, ros2, record, socket, foxglove, headless, cli,
//! sim), tests included, and inside the core every import points down the order
//! below. Doc links are not imports; the few parts a lower layer carries from a higher
//! one are listed in [`CARRIED`], each with its reason.

use std::fs;
use std::path::{Path, PathBuf};

/// The core, bottom first: a module may import those before it (and itself).
const CORE: &[&str] = &[
    "value",
    "can",
    "config",
    "snapshot",
    "driver",
    "vehicle",
    "safety",
    "engine",
    "supervisor",
];

/// Front ends and tools: the core never imports them.
const FRONT: &[&str] = &[
    "console", "net", "ros2", "record", "socket", "foxglove", "headless", "cli", "sim",
];

/// Imports up the order that are by design: (file, path imported, why).
const CARRIED: &[(&str, &str, &str)] = &[
    (
        "src/vehicle/device.rs",
        "crate::engine::port",
        "a device carries its port (the engine's leaf: driver, config, trace only)",
    ),
    (
        "src/vehicle/device.rs",
        "crate::engine::slot",
        "a device carries its command slot (the engine's leaf: value and driver only)",
    ),
    (
        "src/vehicle/mod.rs",
        "crate::engine::port",
        "the vehicle is built with each device's port opener",
    ),
    (
        "src/safety/facts.rs",
        "crate::engine::slot",
        "the wire check reads what each slot has on its way (its WireState)",
    ),
];

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
    let mut wrong = Vec::new();
    for f in &all {
        let m = module(f);
        let Some(rank) = CORE.iter().position(|c| *c == m) else {
            continue;
        };
        let text = fs::read_to_string(f).unwrap();
        for (line, path) in imports(&text) {
            let target = path.split("::").nth(1).unwrap_or("");
            let file = f.display().to_string();
            if FRONT.contains(&target) {
                wrong.push(format!(
                    "{file}:{line}: the core imports a front end: {path}"
                ));
                continue;
            }
            let Some(to) = CORE.iter().position(|c| *c == target) else {
                continue;
            };
            let carried = CARRIED
                .iter()
                .any(|(cf, cp, _)| *cf == file && path.starts_with(cp));
            if to > rank && !carried {
                wrong.push(format!("{file}:{line}: {m} imports {path}, above it"));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "imports pointing up:\n{}",
        wrong.join("\n")
    );
}
