//! The real binary, headless, as a new user first runs it: on a vehicle file whose
//! ports are not there.

mod common;

use adrive::config::ALICE_TOML;
use common::{lines, signal, tempdir, until, wait_exit, Reaped};
use std::process::{Command as Process, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_adrive");
const DEVICES: [&str; 6] = ["steer", "gas", "brake", "trans", "estop", "obd"];

/// Without hardware, `adrive --headless` printed about 300 warnings in 3 s (`status:
/// port: No such file or directory device=steer`) and never named the path it tried.
/// Each device now says once which path is missing; the supervisor names the fault
/// once (`disconnected`) and says once what it waits for; nothing repeats at the
/// polling rate.
#[test]
fn headless_without_hardware_names_each_missing_port_once() {
    let dir = tempdir("headless");
    let port = |device: &str| dir.path().join(format!("missing-{device}"));
    // Alice, each port pointed at a path that does not exist.
    let mut toml = String::new();
    let mut device = "";
    for line in ALICE_TOML.lines() {
        if let Some(d) = DEVICES
            .iter()
            .find(|d| line.starts_with(&format!("name = \"{d}\"")))
        {
            device = d;
        }
        if line.starts_with("port = ") {
            toml.push_str(&format!("port = {:?}\n", port(device)));
        } else {
            toml.push_str(line);
            toml.push('\n');
        }
    }
    let vehicle = dir.path().join("vehicle.toml");
    std::fs::write(&vehicle, toml).unwrap();
    let mut child = Reaped(
        Process::new(BIN)
            .args(["--headless", "--listen", "127.0.0.1:0", "--config"])
            .arg(&vehicle)
            .arg("--log-dir")
            .arg(dir.path().join("log"))
            .env("XDG_RUNTIME_DIR", dir.path().join("log"))
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let err = lines(child.stderr.take().unwrap());
    let started = Instant::now();
    let mut seen = until(&err, "fault: obd disconnected");
    // Once every device has been gone for 5 s, every port has been tried again and
    // again (the snapshot says so; the process answering it is the barrier).
    let end = Instant::now() + Duration::from_secs(60);
    loop {
        let out = Process::new(BIN)
            .args(["ctl", "status", "--json"])
            .env("XDG_RUNTIME_DIR", dir.path().join("log"))
            .output()
            .unwrap();
        let snap: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_default();
        let waiting = snap["supervisor"]["waiting"]
            .as_array()
            .cloned()
            .unwrap_or_default();
        if waiting.len() == DEVICES.len()
            && waiting
                .iter()
                .all(|w| w["gone_ms"].as_f64().unwrap_or(0.0) > 5000.0)
        {
            break;
        }
        assert!(Instant::now() < end, "never all gone for 5 s: {snap}");
        std::thread::sleep(Duration::from_millis(200));
    }
    assert!(started.elapsed() > Duration::from_secs(5));
    assert!(signal(&child, libc::SIGINT));
    wait_exit(&mut child);
    seen.extend(err.iter());
    let text = seen.join("\n");
    for device in DEVICES {
        let path = port(device).display().to_string();
        let named = format!("cannot open {path}: No such file or directory");
        let status_lines = seen
            .iter()
            .filter(|l| l.contains(&format!("status: port: {named}")))
            .count();
        assert_eq!(status_lines, 1, "{device}: the missing path once:\n{text}");
        let mentions = seen.iter().filter(|l| l.contains(&path)).count();
        assert!(
            mentions <= 3,
            "{device}: {mentions} lines name its path (the error, the fault, what adrive \
             waits for):\n{text}"
        );
    }
    assert!(
        seen.len() < 40,
        "{} lines in {:?}:\n{text}",
        seen.len(),
        started.elapsed()
    );
}
