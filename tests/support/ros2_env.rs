//! The third-party ROS 2 peer's Python environment: Eclipse Zenoh's Python API, rosbags
//! and xxhash, pinned, in a virtual environment under `target/` that the test builds
//! itself from PyPI. It fails loudly, never skips, when that is impossible.

use std::path::PathBuf;
use std::process::{Command as Process, Stdio};
use std::sync::OnceLock;

pub const PACKAGES: [&str; 3] = ["eclipse-zenoh==1.10.2", "rosbags==0.11.9", "xxhash==3.5.0"];

/// The peer script.
pub const PEER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/support/ros2_peer.py");

fn ready(python: &str) -> bool {
    Process::new(python)
        .args([
            "-c",
            "import zenoh, rosbags, xxhash, sys; from importlib.metadata import version as v; \
             sys.exit(0 if (v('eclipse-zenoh'), v('rosbags'), v('xxhash')) == ('1.10.2', '0.11.9', '3.5.0') else 1)",
        ])
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

/// A Python interpreter with the pinned packages.
pub fn python() -> &'static str {
    static PYTHON: OnceLock<String> = OnceLock::new();
    PYTHON.get_or_init(|| {
        let venv = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("ros2-venv");
        let py = venv.join("bin/python").display().to_string();
        if !ready(&py) {
            let setup = run(Process::new("python3").args(["-m", "venv"]).arg(&venv)).and_then(|_| {
                run(Process::new(&py)
                    .args(["-m", "pip", "install", "--quiet"])
                    .args(PACKAGES))
            });
            if let Err(e) = setup {
                panic!(
                    "the ROS 2 interoperability tests need Python 3 with {}; setting up {} failed: {e}",
                    PACKAGES.join(", "),
                    venv.display()
                );
            }
            assert!(ready(&py), "{py} still cannot import {}", PACKAGES.join(", "));
        }
        py
    })
}
