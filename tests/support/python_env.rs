//! A Python 3 with pinned packages from PyPI, for the interoperability tests that run a
//! third-party implementation (pymodbus; Eclipse Zenoh with rosbags): the system's
//! `python3` when it already has them, else a virtual environment under `target/` that
//! the test builds itself. It fails loudly, with the reason, when neither works: these
//! tests never skip.

use std::path::PathBuf;
use std::process::{Command as Process, Stdio};

/// Whether `python` imports `modules` and has exactly the `pins` installed.
fn ready(python: &str, pins: &[&str], modules: &str) -> bool {
    let wanted: Vec<String> = pins
        .iter()
        .map(|p| {
            let (name, version) = p.split_once("==").expect("a pin is name==version");
            format!("({name:?}, {version:?})")
        })
        .collect();
    let check = format!(
        "import {modules}, sys; from importlib.metadata import version as v; \
         sys.exit(0 if all(v(n) == w for n, w in [{}]) else 1)",
        wanted.join(", ")
    );
    Process::new(python)
        .args(["-c", &check])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn run(cmd: &mut Process) -> Result<(), String> {
    let out = cmd.output().map_err(|e| format!("{cmd:?}: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "{cmd:?} failed ({}):\n{}{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ))
    }
}

/// A Python interpreter that imports `modules` ("serial, pymodbus") with `pins`
/// ("pymodbus==3.8.6") installed; the virtual environment, when one is needed, is
/// `target/tmp/<venv>`.
pub fn python(venv: &str, pins: &[&str], modules: &str) -> String {
    if ready("python3", pins, modules) {
        return "python3".into();
    }
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(venv);
    let py = dir.join("bin/python").display().to_string();
    if !ready(&py, pins, modules) {
        let setup = run(Process::new("python3").args(["-m", "venv"]).arg(&dir)).and_then(|_| {
            run(Process::new(&py)
                .args(["-m", "pip", "install", "--quiet"])
                .args(pins))
        });
        if let Err(e) = setup {
            panic!(
                "this interoperability test needs Python 3 with {}; setting up {} failed: {e}",
                pins.join(", "),
                dir.display()
            );
        }
        assert!(
            ready(&py, pins, modules),
            "{py} still cannot import {modules} at {}",
            pins.join(", ")
        );
    }
    py
}
