//! Interoperability: the simulated SLCAN adapter and OSCC kit of the real `adrive sim
//! --config vehicles/oscc.toml` against python-can (its `slcan` interface, on the
//! adapter's pseudo-terminal as `adrive sim` prints it) with cantools encoding and
//! decoding from the same `vehicles/oscc.dbc`. Every frame the kit sends is decoded by both
//! cantools and adrive's DBC module, and they must agree on every signal; the frames
//! python-can sends must enable, command and disable the kit. A second test has cantools
//! decode random frames of every layout a DBC can write (`tests/support/layouts.dbc`)
//! and adrive decode them too. The tests provide their own Python environment (pinned
//! python-can, cantools, pyserial) as the other peer tests do, and fail loudly — never
//! skip — when that is impossible.

mod common;
#[path = "support/python_can_env.rs"]
mod python_can_env;
#[path = "support/python_env.rs"]
mod python_env;

use adrive::can::dbc::Database;
use adrive::can::{Frame, Id};
use common::simproc::SimProcess;
use common::DEADLINE;
use python_can_env::python;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::process::{Command as Process, Stdio};
use std::sync::mpsc;
use std::time::Instant;

fn dbc_path() -> String {
    concat!(env!("CARGO_MANIFEST_DIR"), "/vehicles/oscc.dbc").to_string()
}

#[test]
fn python_can_and_cantools_drive_the_simulated_oscc_kit_and_agree_on_every_frame() {
    let db = Database::load(Path::new(&dbc_path())).unwrap_or_else(|e| panic!("{e}"));
    // The real `adrive sim` with the OSCC vehicle: its one port is the bus's adapter.
    let sim = SimProcess::start_with(
        &[
            "--config",
            concat!(env!("CARGO_MANIFEST_DIR"), "/vehicles/oscc.toml"),
        ],
        1,
    );
    let path = sim.paths[0].clone();
    assert!(path.ends_with("/kit"), "the bus's adapter: {path}");

    let mut child = Process::new(python())
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/support/python_can_peer.py"
        ))
        .arg(&path)
        .arg(dbc_path())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start the python-can peer");
    let (tx, lines) = mpsc::channel();
    let stdout = child.stdout.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut seen = Vec::new();
    let end = Instant::now() + DEADLINE;
    while seen.last().map(String::as_str) != Some("DONE") {
        match lines.recv_timeout(end.saturating_duration_since(Instant::now())) {
            Ok(line) => seen.push(line),
            Err(_) => break,
        }
    }
    let status = child.wait().expect("the peer ends");
    let mut stderr = String::new();
    let _ = child.stderr.take().unwrap().read_to_string(&mut stderr);
    assert!(
        status.success() && seen.last().map(String::as_str) == Some("DONE"),
        "the python-can peer failed ({status}):\n{stderr}\nlast lines: {:?}",
        &seen[seen.len().saturating_sub(5)..]
    );
    assert!(seen.contains(&"ENABLED".to_string()) && seen.contains(&"DISABLED".to_string()));

    // Every frame: adrive's decoding of the bytes equals cantools'.
    let mut names = std::collections::BTreeMap::<String, usize>::new();
    for line in seen.iter().filter(|l| l.starts_with('{')) {
        let v: serde_json::Value = serde_json::from_str(line).expect("a JSON frame line");
        let frame = frame_of(&v);
        let id = frame.id();
        let message = db.by_id(id).unwrap_or_else(|| panic!("adrive knows {id}"));
        assert_eq!(message.name(), v["name"].as_str().unwrap());
        let theirs = v["signals"].as_object().unwrap();
        let ours: Vec<_> = message.decode(&frame).collect();
        assert_eq!(ours.len(), theirs.len(), "{frame}: {line}");
        for (signal, value) in ours {
            let other = theirs[signal.name()].as_f64().unwrap();
            assert!(
                (value - other).abs() <= 1e-9 * value.abs().max(1.0),
                "{frame} {}: adrive {value}, cantools {other}",
                signal.name()
            );
        }
        *names.entry(message.name().to_string()).or_default() += 1;
    }
    for name in [
        "BRAKE_REPORT",
        "STEERING_REPORT",
        "THROTTLE_REPORT",
        "KIA_SOUL_WHEEL_SPEED",
        "KIA_SOUL_STEERING_WHEEL_ANGLE",
        "KIA_SOUL_BRAKE_PRESSURE",
    ] {
        assert!(
            names.get(name).is_some_and(|&n| n >= 10),
            "{name}: {names:?}"
        );
    }

    // And the frames cantools encoded did what they say to the kit, as the simulator
    // printed it: the throttle module enabled, the gas at 0.25, the module disabled.
    let (_, mark) = sim.wait_after(0, &["gas", "throttle module: enabled"]);
    let (_, mark) = sim.wait_after(mark, &["gas", "<-", "0.250"]);
    sim.wait_after(mark, &["gas", "throttle module: disabled"]);
    sim.stop();
}

/// The bytes of a JSON frame line's `data`, and its identifier.
fn frame_of(v: &serde_json::Value) -> Frame {
    let raw = v["id"].as_u64().unwrap() as u32;
    let id = if v["extended"].as_bool().unwrap() {
        Id::Extended(raw)
    } else {
        Id::Standard(raw as u16)
    };
    let hex = v["data"].as_str().unwrap();
    let data: Vec<u8> = (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
        .collect();
    Frame::new(id, &data).unwrap()
}

#[test]
fn cantools_and_adrive_agree_on_every_layout_a_dbc_can_write() {
    // Intel and Motorola signals of odd widths crossing bytes, signed and scaled with
    // negative factors, IEEE floats of both byte orders and a double, a multiplexed
    // message, an extended identifier, a short frame: 200 random frames of each,
    // decoded by cantools and by adrive.
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/support/layouts.dbc");
    let db = Database::load(Path::new(path)).unwrap_or_else(|e| panic!("{e}"));
    let out = Process::new(python())
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/support/cantools_layouts.py"
        ))
        .args([path, "2005", "200"])
        .output()
        .expect("run cantools");
    assert!(
        out.status.success(),
        "cantools failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    assert_eq!(text.lines().last(), Some("DONE"));
    let mut frames = 0;
    for line in text.lines().filter(|l| l.starts_with('{')) {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let frame = frame_of(&v);
        let message = db.by_id(frame.id()).unwrap();
        let theirs = v["signals"].as_object().unwrap();
        let ours: Vec<_> = message.decode(&frame).collect();
        let names: Vec<&str> = ours.iter().map(|(s, _)| s.name()).collect();
        let mut want: Vec<&str> = theirs.keys().map(String::as_str).collect();
        let mut have = names.clone();
        want.sort_unstable();
        have.sort_unstable();
        assert_eq!(have, want, "{frame}");
        for (signal, value) in &ours {
            match theirs[signal.name()].as_f64() {
                Some(other) => assert!(
                    (value - other).abs() <= 1e-9 * value.abs().max(1.0),
                    "{} {frame} {}: adrive {value}, cantools {other}",
                    message.name(),
                    signal.name()
                ),
                None => assert!(!value.is_finite(), "{frame} {}", signal.name()),
            }
        }
        // Integer layouts: encoding the decoded values gives the bytes back (bit 56 of
        // MOTOROLA belongs to no signal and encodes as 0).
        if ["INTEL", "MOTOROLA", "SHORT"].contains(&message.name()) {
            let values: Vec<(&str, f64)> = ours.iter().map(|(s, v)| (s.name(), *v)).collect();
            let back = message.encode(&values).unwrap();
            let mut want = frame.data().to_vec();
            if message.name() == "MOTOROLA" {
                want[7] &= !1;
            }
            assert_eq!(back.data(), &*want, "{} {frame}", message.name());
        }
        frames += 1;
    }
    assert_eq!(frames, 6 * 200);
}
