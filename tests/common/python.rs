//! A Python interpreter with pinned third-party packages, for the interoperability
//! tests: the system's `python3` when it already has them, else a virtual environment
//! of the test's own under `target/tmp/`, made once and reused. When neither can be
//! had, the test fails loudly, saying what it needs — it never skips.

use std::path::PathBuf;
use std::process::{Command as Process, Stdio};

/// Run a setup step; its output when it fails.
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

/// `python` runs `check` (Python code that exits non-zero without the packages).
fn ready(python: &str, check: &str) -> bool {
    Process::new(python)
        .args(["-c", check])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// A Python that passes `check`: `python3` itself when it does, else the virtual
/// environment `target/tmp/VENV` with `packages` (pinned, `name==version`) installed.
/// `what` names the test for the failure message.
pub fn with(venv: &str, packages: &[&str], check: &str, what: &str) -> String {
    if ready("python3", check) {
        return "python3".into();
    }
    let venv = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(venv);
    let py = venv.join("bin/python").display().to_string();
    if !ready(&py, check) {
        let setup = run(Process::new("python3").args(["-m", "venv"]).arg(&venv)).and_then(|_| {
            run(Process::new(&py)
                .args(["-m", "pip", "install", "--quiet"])
                .args(packages))
        });
        if let Err(e) = setup {
            panic!(
                "the {what} needs Python 3 with {}; setting up {} failed: {e}",
                packages.join(" and "),
                venv.display()
            );
        }
        assert!(
            ready(&py, check),
            "{py} still cannot import {}",
            packages.join(" and ")
        );
    }
    py
}
