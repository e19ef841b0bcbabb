//! Interoperability: the simulated SLCAN adapter and OSCC kit against python-can (its
//! `slcan` interface, on a real pseudo-terminal) with cantools encoding and decoding
//! from the same `vehicles/oscc.dbc`. Every frame the kit sends is decoded by both
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
use adrive::sim::oscc::{Kit, Module};
use adrive::sim::slcan::SlcanPort;
use common::DEADLINE;
use parking_lot::Mutex;
use python_can_env::python;
use serialport::{SerialPort, TTYPort};
use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;
use std::process::{Command as Process, Stdio};
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

fn dbc_path() -> String {
    concat!(env!("CARGO_MANIFEST_DIR"), "/vehicles/oscc.dbc").to_string()
}

/// The simulated adapter and kit served on the master end of a pseudo-terminal, as
/// the simulator's port loop will: read what the host sends, let the bus run, write
/// back, never waiting past the kit's next report.
fn serve(
    mut device: TTYPort,
    port: Arc<Mutex<SlcanPort<Kit>>>,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<()> {
    std::thread::Builder::new()
        .name("test/slcan".into())
        .spawn(move || {
            let mut chunk = [0u8; 256];
            let mut out = Vec::new();
            while !stop.load(Relaxed) {
                let wait = port.lock().wait(Instant::now());
                let _ = device
                    .set_timeout(wait.clamp(Duration::from_millis(1), Duration::from_millis(5)));
                let n = match device.read(&mut chunk) {
                    Ok(n) => n,
                    Err(e) if e.kind() == std::io::ErrorKind::TimedOut => 0,
                    Err(_) => return,
                };
                out.clear();
                {
                    let mut p = port.lock();
                    let now = Instant::now();
                    p.input(&chunk[..n], now, &mut out);
                    p.tick(now, &mut out);
                }
                if !out.is_empty() && device.write_all(&out).is_err() {
                    return;
                }
            }
        })
        .expect("spawn the port loop")
}

#[test]
fn python_can_and_cantools_drive_the_simulated_oscc_kit_and_agree_on_every_frame() {
    let db = Database::load(Path::new(&dbc_path())).unwrap_or_else(|e| panic!("{e}"));
    let (device, host_end) = TTYPort::pair().expect("a pseudo-terminal pair");
    let path = host_end.name().expect("the pty's path");
    let kit = Kit::new(&db, None, Instant::now()).unwrap();
    let port = Arc::new(Mutex::new(SlcanPort::new(kit, Instant::now())));
    port.lock().node.set_speed(18.0);
    let stop = Arc::new(AtomicBool::new(false));
    let server = serve(device, port.clone(), stop.clone());

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
    stop.store(true, Relaxed);
    server.join().expect("the port loop");
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
    ] {
        assert!(
            names.get(name).is_some_and(|&n| n >= 10),
            "{name}: {names:?}"
        );
    }

    // And the frames cantools encoded did what they say to the kit.
    let mut p = port.lock();
    let notes: Vec<(Module, String)> = p
        .node
        .take_notes()
        .into_iter()
        .map(|n| (n.module, n.what))
        .collect();
    assert_eq!(
        notes,
        vec![
            (Module::Throttle, "enabled".to_string()),
            (Module::Throttle, "disabled".to_string())
        ]
    );
    assert_eq!(p.node.state(Module::Throttle).request, 0.25);
    drop(host_end);
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
