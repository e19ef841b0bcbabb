//! Recording and replay, with the real binary driving `adrive sim` in another process:
//! a drive recorded to MCAP (a planner engages and drives, the engine stalls and is
//! recovered, the planner stops and the watchdog disengages) holds every kind of event;
//! `record info`, `export --csv`, the console's replay and `replay --broadcast` read it;
//! the third-party Python `mcap` reader decodes every message and checks it against its
//! channel's JSON Schema. And the ways a recording fails: `kill -9` mid-recording
//! leaves a file every reader reads up to its last chunk, and `record repair` makes a
//! finished copy of it (or of a file cut inside a chunk); a full disk (a file size
//! limit, as `ulimit -f` sets) stops the recording, visibly, and never the vehicle.

mod common;
#[path = "support/python_env.rs"]
mod python_env;

use adrive::console::replay::Player;
use adrive::record::read::{Ending, Recording};
use adrive::snapshot::Snapshot;
use common::pty::Master;
use common::simproc::{vehicle_file, SimProcess};
use common::{free_port, DEADLINE};
use serde_json::Value;
use std::collections::BTreeMap;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command as Process, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_adrive");

/// A directory under `target/tmp` for this run of the test binary (a recording shared
/// by several tests outlives each of them; `target/` is the build's, not `/tmp`).
/// Earlier runs' directories are removed.
fn scratch(name: &str) -> PathBuf {
    let tmp = PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
    let prefix = format!("record-{name}-");
    for old in std::fs::read_dir(&tmp).into_iter().flatten().flatten() {
        if old.file_name().to_string_lossy().starts_with(&prefix) {
            let _ = std::fs::remove_dir_all(old.path());
        }
    }
    let dir = tmp.join(format!("{prefix}{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// adrive, headless, on the simulator's ports, recording with `record_args`. Alice is
/// made tolerant of this shared machine's stalls ([`common::tolerant`]): the planners
/// here hold her engaged for seconds to prove what is recorded, not device timing.
fn adrive(sim: &SimProcess, dir: &Path, port: u16, record_args: &[&str]) -> Process {
    let config = common::tolerant(vehicle_file(dir, sim, ""));
    let mut cmd = Process::new(BIN);
    cmd.arg("--config")
        .arg(&config)
        .args(["--headless", "--listen", &format!("127.0.0.1:{port}")])
        .arg("--log-dir")
        .arg(dir.join("log"))
        .env("XDG_RUNTIME_DIR", dir.join("log"))
        .args(record_args);
    cmd
}

fn send(port: u16, words: &[&str]) -> Output {
    Process::new(BIN)
        .args(["send", "--to", &format!("127.0.0.1:{port}")])
        .args(words)
        .output()
        .unwrap()
}

/// Wait until adrive listens: a command before engaging is refused as `disengaged`
/// (and recorded so).
fn wait_listening(port: u16) {
    common::wait_for("adrive to listen", || {
        String::from_utf8_lossy(&send(port, &["gas", "0.2"]).stdout).contains("disengaged")
    });
}

/// A planner sending `engage trans drive accel 0.3` 20 times a second, `count` times.
fn planner(port: u16, count: u32) -> common::Reaped {
    common::Reaped(
        Process::new(BIN)
            .args(["send", "--to", &format!("127.0.0.1:{port}"), "--rate", "20"])
            .args(["--count", &count.to_string()])
            .args(["engage", "trans", "drive", "accel", "0.3"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    )
}

/// The recorded drive, made once for every test that reads it.
fn drive() -> &'static Path {
    static DRIVE: OnceLock<PathBuf> = OnceLock::new();
    DRIVE.get_or_init(|| {
        let dir = scratch("drive");
        let file = dir.join("drive.mcap");
        let mut sim = SimProcess::start();
        let port = free_port();
        let mut cmd = adrive(&sim, &dir, port, &["--record-raw", "--record"]);
        let mut a = common::Reaped(
            cmd.arg(&file)
                .stdout(std::fs::File::create(dir.join("out.txt")).unwrap())
                .stderr(Stdio::null())
                .spawn()
                .unwrap(),
        );
        wait_listening(port);
        let mut p = planner(port, 240);
        sim.wait_for(&["gas", "<-", "0.300"]);
        let stalled = sim.mark();
        sim.say("stall");
        // The recovery: park, the starter, back in drive.
        let (_, started) = sim.wait_after(stalled, &["trans", "<-", "start"]);
        sim.wait_after(started, &["trans", "<-", "drive"]);
        // The planner stops; the watchdog brings the vehicle to the safe state.
        assert_eq!(common::wait_exit(&mut p), Some(0), "the planner");
        let stopped = sim.mark();
        sim.wait_after(stopped, &["brake", "<-", "1.000"]);
        common::signal(&a, libc::SIGTERM);
        assert_eq!(common::wait_exit(&mut a), Some(0), "adrive's exit status");
        let out = std::fs::read_to_string(dir.join("out.txt")).unwrap();
        assert!(
            out.contains("recorded ") && out.contains("drive.mcap"),
            "{out}"
        );
        file
    })
}

/// Every message of a recording as JSON, by topic.
fn by_topic(rec: &Recording) -> BTreeMap<String, Vec<Value>> {
    let (msgs, _) = rec.json();
    let mut m: BTreeMap<String, Vec<Value>> = BTreeMap::new();
    for (topic, _, v) in msgs {
        m.entry(topic).or_default().push(v);
    }
    m
}

#[test]
fn a_recorded_drive_holds_every_kind_of_event() {
    let rec = Recording::open(drive()).unwrap();
    assert!(rec.complete && rec.cut.is_none(), "{:?}", rec.cut);
    assert_eq!(rec.json().1, None, "the stream reads to its end");
    assert_eq!(
        rec.metadata.get("vehicle").map(String::as_str),
        Some("Alice")
    );
    let t = by_topic(&rec);
    let topics: Vec<&str> = t.keys().map(String::as_str).collect();
    for want in [
        "/snapshot",
        "/commands",
        "/gate",
        "/faults",
        "/supervisor",
        "/log",
        "/record",
        "/gas/command",
        "/gas/reading",
        "/steer/reading",
        "/trans/command",
        "/gas/raw",
    ] {
        assert!(topics.contains(&want), "no {want} in {topics:?}");
    }
    // The snapshot as broadcast, at its rate.
    let snaps: Vec<Snapshot> = t["/snapshot"]
        .iter()
        .map(|v| serde_json::from_value(v.clone()).unwrap())
        .collect();
    assert!(
        snaps.windows(2).all(|w| w[1].seq == w[0].seq + 1),
        "consecutive"
    );
    assert!(snaps.iter().any(|s| s.gate.engaged));
    // Commands received: the planner's accepted, the early one refused with its reason.
    let cmds = &t["/commands"];
    assert!(cmds.iter().any(|c| c["accepted"] == true
        && c["device"] == "accel"
        && c["source"]
            .as_str()
            .unwrap()
            .starts_with("network 127.0.0.1:")));
    assert!(cmds
        .iter()
        .any(|c| c["accepted"] == false && c["device"] == "gas" && c["reason"] == "disengaged"));
    // Commands written, with their delay; readings by name.
    let gas = &t["/gas/command"];
    assert!(gas
        .iter()
        .any(|c| c["value"] == 0.3 && c["ok"] == true && c["delay_us"].is_number()));
    assert!(t["/steer/reading"]
        .iter()
        .all(|r| r["ok"] == true && r["position"].is_number()));
    assert!(t["/trans/command"].iter().any(|c| c["command"] == "drive"));
    // The gate, the stall and its recovery, the watchdog.
    let gate: Vec<&str> = t["/gate"]
        .iter()
        .map(|g| g["event"].as_str().unwrap())
        .collect();
    assert!(
        gate.contains(&"engaged") && gate.contains(&"disengaged"),
        "{gate:?}"
    );
    assert!(t["/gate"]
        .iter()
        .any(|g| g["reason"].as_str().unwrap().contains("watchdog")));
    assert!(t["/faults"]
        .iter()
        .any(|f| f["event"] == "raised" && f["kind"] == "engine_stall"));
    let notes: Vec<&str> = t["/supervisor"]
        .iter()
        .map(|n| n["text"].as_str().unwrap())
        .collect();
    assert!(
        notes
            .iter()
            .any(|n| n.contains("engine_stall") && n.contains("park")),
        "{notes:?}"
    );
    assert!(
        notes
            .iter()
            .any(|n| n.contains("recovery engine_stall done")),
        "{notes:?}"
    );
    // Log lines, as Foxglove's Log; raw traffic, hex.
    assert!(t["/log"]
        .iter()
        .any(|l| l["level"] == 3 && l["message"].as_str().unwrap().contains("fault")));
    assert!(
        t["/gas/raw"].iter().any(|r| r["dir"] == "out")
            && t["/gas/raw"].iter().any(|r| r["dir"] == "in")
    );
    assert!(
        t["/record"].iter().all(|r| r["dropped"] == 0),
        "nothing left out"
    );
}

#[test]
fn record_info_names_the_channels_counts_and_faults() {
    let out = Process::new(BIN)
        .args(["record", "info"])
        .arg(drive())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    for want in [
        "complete,",
        "vehicle Alice",
        "/snapshot",
        "adrive.Snapshot",
        "/gas/command",
        "adrive.Written",
        "refused",
        "fault raised engine_stall",
        "engaged by network",
    ] {
        assert!(text.contains(want), "no {want:?} in:\n{text}");
    }
    // The early command refused, counted by its reason.
    let received = text.lines().find(|l| l.starts_with("commands received"));
    assert!(
        received.is_some_and(|l| l.contains("refused") && l.contains("disengaged ")),
        "{text}"
    );
}

#[test]
fn export_writes_one_csv_per_channel_with_a_column_per_field() {
    let dir = common::tempdir("export");
    let out = Process::new(BIN)
        .arg("export")
        .arg(drive())
        .arg("--csv")
        .arg(dir.path().join("csv"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let read = |name: &str| std::fs::read_to_string(dir.path().join("csv").join(name)).unwrap();
    let gas = read("gas.command.csv");
    let mut lines = gas.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(&header[..2], ["time_s", "log_time_ns"]);
    let value = header
        .iter()
        .position(|h| *h == "value")
        .expect("a value column");
    assert!(
        lines.any(|l| l.split(',').nth(value) == Some("0.3")),
        "{gas}"
    );
    let snap = read("snapshot.csv");
    assert!(snap
        .lines()
        .next()
        .unwrap()
        .contains("devices.steer.readings.position"));
    let rec = Recording::open(drive()).unwrap();
    let (msgs, _) = rec.json();
    let snapshots = msgs.iter().filter(|(t, _, _)| t == "/snapshot").count();
    assert_eq!(snap.lines().count(), snapshots + 1, "a row per snapshot");
}

/// A Python interpreter with the pinned `mcap` reader and `jsonschema`.
fn python() -> &'static str {
    static PYTHON: OnceLock<String> = OnceLock::new();
    PYTHON.get_or_init(|| {
        python_env::python(
            "mcap-venv",
            &["mcap==1.3.0", "jsonschema==4.23.0"],
            "mcap, jsonschema",
        )
    })
}

#[test]
fn the_python_mcap_reader_decodes_and_validates_every_message_of_a_real_recording() {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/support/mcap_read.py");
    let out = Process::new(python())
        .arg(script)
        .arg(drive())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The channels it lists, with their message counts, are ours.
    let rec = Recording::open(drive()).unwrap();
    let mut ours: BTreeMap<String, u64> = BTreeMap::new();
    rec.for_each(|m| *ours.entry(m.topic.to_string()).or_default() += 1);
    let theirs: BTreeMap<String, u64> = text
        .lines()
        .filter_map(|l| l.strip_prefix("channel "))
        .map(|l| {
            let (topic, n) = l.rsplit_once(' ').unwrap();
            (topic.to_string(), n.parse().unwrap())
        })
        .collect();
    assert_eq!(theirs, ours, "{text}");
    let total: u64 = ours.values().sum();
    assert!(
        text.contains(&format!(
            "decoded {total} messages, each valid against its schema"
        )),
        "{text}"
    );
}

/// The screen of a terminal program, as a terminal shows it.
fn screen(bytes: &[u8], cols: u16, rows: u16) -> vt100::Parser {
    let nz = |n: u16| std::num::NonZeroU16::new(n).unwrap();
    let mut p = vt100::Parser::new(nz(rows), nz(cols), 0);
    p.process(bytes);
    p
}

#[test]
fn replay_plays_the_drive_in_the_console_with_pause_step_and_seek() {
    let rec = Recording::open(drive()).unwrap();
    let player = Player::load(&rec).unwrap();
    let frames = player.len();
    // The first snapshot with the stall named, counted from the first.
    let (msgs, _) = rec.json();
    let stall = msgs
        .iter()
        .filter(|(t, _, _)| t == "/snapshot")
        .position(|(_, _, v)| {
            v["supervisor"]["faults"]
                .to_string()
                .contains("engine_stall")
        })
        .expect("a snapshot with the stall");
    let (cols, rows) = (100, 30);
    let mut cmd = Process::new(BIN);
    cmd.arg("replay")
        .arg(drive())
        .env("TERM", "xterm-256color")
        .env_remove("NO_COLOR");
    let (mut child, mut term) = Master::spawn(&mut cmd, cols, rows, true);
    let shows = |term: &Master, what: &str, ok: &dyn Fn(&str) -> bool| -> vt100::Parser {
        let end = Instant::now() + DEADLINE;
        loop {
            let p = screen(&term.bytes(), cols, rows);
            if ok(&p.screen().contents()) {
                return p;
            }
            assert!(
                Instant::now() < end,
                "no {what}; screen:\n{}",
                p.screen().contents()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    shows(&term, "the replay", &|s| {
        s.contains("REPLAY drive.mcap") && s.contains("ADRIVE Alice")
    });
    let keys = |term: &mut Master, k: &str| term.write(k.as_bytes());
    // Pause at the start, then step to the stall.
    keys(&mut term, " ");
    shows(&term, "paused", &|s| s.contains("❚❚"));
    keys(&mut term, "\x1b[H"); // Home
    shows(&term, "the first frame", &|s| {
        s.contains(&format!(" 1/{frames} "))
    });
    keys(&mut term, &".".repeat(stall));
    let at = format!(" {}/{frames} ", stall + 1);
    let p = shows(&term, "the stall", &|s| {
        s.contains(&at) && s.contains("engine_stall")
    });
    // Faults are red, as they were.
    let (row, col) = find(&p, "FAULT engine_stall").expect("the stall's fault line");
    for c in col..col + "FAULT engine_stall".len() as u16 {
        let cell = p.screen().cell(row, c).unwrap();
        assert_eq!(
            cell.fgcolor(),
            vt100::Color::Idx(1),
            "the fault line in red"
        );
    }
    // Back one, forward ten seconds, to the end.
    keys(&mut term, ",");
    shows(&term, "one back", &|s| {
        s.contains(&format!(" {stall}/{frames} "))
    });
    keys(&mut term, "\x1b[F"); // End
    shows(&term, "the end", &|s| {
        s.contains(&format!(" {frames}/{frames} ")) && s.contains("watchdog")
    });
    // Read-only: an engage key changes nothing and says so.
    keys(&mut term, "E");
    shows(&term, "read-only", &|s| s.contains("read-only"));
    keys(&mut term, "q");
    assert_eq!(common::wait_exit(&mut child), Some(0));
}

fn find(p: &vt100::Parser, text: &str) -> Option<(u16, u16)> {
    let (rows, _) = p.screen().size();
    (0..rows.get()).find_map(|r| {
        let line = p.screen().rows(0, 200).nth(r as usize)?;
        let col = line.find(text)?;
        Some((r, line[..col].chars().count() as u16))
    })
}

#[test]
fn replay_broadcast_resends_the_recorded_snapshots_in_order() {
    let rec = Recording::open(drive()).unwrap();
    let (msgs, _) = rec.json();
    let recorded: Vec<u64> = msgs
        .iter()
        .filter(|(t, _, _)| t == "/snapshot")
        .map(|(_, _, v)| v["seq"].as_u64().unwrap())
        .collect();
    let sock = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    sock.set_read_timeout(Some(DEADLINE)).unwrap();
    let to = sock.local_addr().unwrap().to_string();
    let mut child = common::Reaped(
        Process::new(BIN)
            .arg("replay")
            .arg(drive())
            .args(["--headless", "--speed", "32", "--broadcast", &to])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let mut got = Vec::new();
    let mut buf = vec![0u8; 65536];
    while got.len() < recorded.len() {
        let n = sock.recv(&mut buf).expect("a broadcast");
        let s: Snapshot = serde_json::from_slice(&buf[..n]).expect("a snapshot");
        assert_eq!(s.vehicle, "Alice");
        got.push(s.seq);
    }
    assert_eq!(got, recorded);
    assert_eq!(
        common::wait_exit(&mut child),
        Some(0),
        "ends with the recording"
    );
}

/// `adrive replay FILE --headless --broadcast ADDR` printed nothing: whether it sent
/// anything, and where, could only be seen on the receiving end. It says what it
/// plays and, at the end, how many snapshots it sent.
#[test]
fn headless_replay_says_what_it_plays_and_what_it_sent() {
    let rec = Recording::open(drive()).unwrap();
    let (msgs, _) = rec.json();
    let n = msgs.iter().filter(|(t, _, _)| t == "/snapshot").count();
    let sock = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let to = sock.local_addr().unwrap().to_string();
    let out = Process::new(BIN)
        .arg("replay")
        .arg(drive())
        .args(["--headless", "--speed", "32", "--broadcast", &to])
        .stderr(Stdio::null())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0));
    let text = String::from_utf8_lossy(&out.stdout);
    let name = drive().display().to_string();
    assert!(
        text.starts_with(&format!("replaying {name}: {n} snapshots")),
        "{text}"
    );
    assert!(text.contains(&format!("to {to} at ×32")), "{text}");
    assert!(
        text.trim_end()
            .ends_with(&format!("sent {n} of {n} snapshots to {to}")),
        "{text}"
    );
}

/// Wait until a recording being written holds `chunks` whole chunks.
fn wait_chunks(file: &Path, chunks: usize) {
    common::wait_for("the recording's chunks", || {
        Recording::open(file).is_ok_and(|r| r.chunks >= chunks)
    });
}

/// The third-party Python `mcap` reader's verdict on `file`, read the ordinary way
/// (`make_reader(f).iter_messages()`) or, with `nonseeking`, from the start only.
fn python_reads(file: &Path, how: &str) -> Value {
    let out = Process::new(python())
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/support/mcap_ordinary.py"
        ))
        .arg(file)
        .arg(how)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("its JSON report")
}

/// Messages per channel, as adrive reads `file`.
fn counts(file: &Path) -> Value {
    let rec = Recording::open(file).unwrap();
    let mut n: BTreeMap<String, u64> = BTreeMap::new();
    rec.for_each(|m| *n.entry(m.topic.to_string()).or_default() += 1);
    serde_json::to_value(n).unwrap()
}

fn record_cmd(args: &[&str], file: &Path) -> (bool, String) {
    let out = Process::new(BIN)
        .arg("record")
        .args(args)
        .arg(file)
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

/// A recording of a drive, its recorder killed with `kill -9` once `chunks` whole
/// chunks are written, and the directory it is in.
fn killed(tag: &str, chunks: usize) -> (tempfile::TempDir, PathBuf) {
    let dir = common::tempdir(tag);
    let file = dir.path().join("cut.mcap");
    let sim = SimProcess::start();
    let port = free_port();
    let mut a = common::Reaped(
        adrive(&sim, dir.path(), port, &["--record"])
            .arg(&file)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    wait_listening(port);
    let _p = planner(port, 1000);
    sim.wait_for(&["gas", "<-", "0.300"]);
    wait_chunks(&file, chunks);
    // Being written: said so, not taken for a file cut off.
    let (ok, info) = record_cmd(&["info"], &file);
    assert!(
        ok && info.contains("being written by a running adrive"),
        "{info}"
    );
    assert!(
        !info.contains("CUT OFF") && !info.contains("NOT FINISHED"),
        "{info}"
    );
    common::signal(&a, libc::SIGKILL);
    assert_eq!(common::wait_exit(&mut a), None, "killed");
    (dir, file)
}

/// `kill -9` mid-recording leaves a whole file without an index: the ordinary reader
/// of Python `mcap` reads every message adrive reads (it failed with no message before,
/// as it looked for the footer at the end), `record info` says it was not finished, and
/// `record repair` writes a finished copy beside it, never over an existing file.
#[test]
fn kill_9_mid_recording_leaves_a_file_every_mcap_reader_reads() {
    let (_dir, file) = killed("kill9", 3);
    let rec = Recording::open(&file).expect("still an MCAP file");
    assert_eq!(rec.ending, Ending::Checkpoint, "{:?}", rec.cut);
    assert!(!rec.complete && !rec.writing);
    let t = by_topic(&rec);
    assert!(t["/snapshot"].len() >= 10, "snapshots up to the cut");
    assert!(
        t["/gas/command"].iter().any(|c| c["value"] == 0.3),
        "the drive is there"
    );
    let theirs = python_reads(&file, "make_reader");
    assert_eq!(theirs["error"], Value::Null, "{theirs}");
    assert_eq!(theirs["summary"], false, "{theirs}");
    assert_eq!(
        theirs["counts"],
        counts(&file),
        "every message, as adrive reads it"
    );
    let (ok, info) = record_cmd(&["info"], &file);
    assert!(ok && info.contains("NOT FINISHED"), "{info}");
    assert!(info.contains("every MCAP reader reads it"), "{info}");
    assert!(Player::load(&rec).is_ok(), "it replays");
    // A finished copy beside it, with its index.
    let (ok, said) = record_cmd(&["repair"], &file);
    let copy = file.with_file_name("cut.repaired.mcap");
    assert!(ok && said.contains(&copy.display().to_string()), "{said}");
    let repaired = python_reads(&copy, "make_reader");
    assert_eq!(repaired["summary"], true, "{repaired}");
    assert!(repaired["chunk_indexes"].as_u64() >= Some(1), "{repaired}");
    assert_eq!(repaired["counts"], theirs["counts"]);
    let back = Recording::open(&copy).unwrap();
    assert!(back.complete, "{:?}", back.ending);
    assert!(back.metadata["repaired_from"].contains("cut.mcap"));
    assert_eq!(back.metadata["vehicle"], "Alice");
    // Never over an existing file.
    let before = std::fs::read(&copy).unwrap();
    let (ok, said) = record_cmd(&["repair"], &file);
    assert!(!ok && said.contains("is not overwritten"), "{said}");
    assert_eq!(std::fs::read(&copy).unwrap(), before);
    let (ok, said) = record_cmd(&["repair", "--out", copy.to_str().unwrap()], &file);
    assert!(!ok && said.contains("is not overwritten"), "{said}");
}

/// A file cut inside a chunk (a power loss mid-write; here the same killed recording
/// cut in the middle of its last chunk): the ordinary Python reader refuses it — it
/// looks for the footer at the end — and only its reader from the start gets the whole
/// chunks; `record info` says so and names `record repair`, whose copy every reader
/// reads.
#[test]
fn a_file_cut_inside_a_chunk_is_repaired_into_one_every_reader_reads() {
    let (_dir, file) = killed("cut-chunk", 3);
    let whole = Recording::open(&file).unwrap();
    let len = whole.size();
    // Into the last chunk: past the ending (50 bytes) and the message indexes after
    // the chunk, until one whole chunk fewer reads.
    let bytes = std::fs::read(&file).unwrap();
    let mut cut = len - 50;
    let rec = loop {
        cut -= 64;
        std::fs::write(&file, &bytes[..cut as usize]).unwrap();
        let rec = Recording::open(&file).unwrap();
        if rec.chunks < whole.chunks {
            break rec;
        }
    };
    assert!(matches!(rec.ending, Ending::Cut(_)), "{:?}", rec.ending);
    assert_eq!(rec.chunks, whole.chunks - 1);
    let ordinary = python_reads(&file, "make_reader");
    assert!(ordinary["error"].is_string(), "{ordinary}");
    let from_start = python_reads(&file, "nonseeking");
    assert!(from_start["messages"].as_u64() > Some(0), "{from_start}");
    let (ok, info) = record_cmd(&["info"], &file);
    assert!(
        ok && info.contains("CUT OFF") && info.contains("record repair"),
        "{info}"
    );
    let out = file.with_file_name("elsewhere.mcap");
    let (ok, said) = record_cmd(&["repair", "--out", out.to_str().unwrap()], &file);
    assert!(ok, "{said}");
    let repaired = python_reads(&out, "make_reader");
    assert_eq!(repaired["error"], Value::Null, "{repaired}");
    assert_eq!(
        repaired["counts"],
        counts(&file),
        "every whole chunk's message"
    );
    assert_eq!(repaired["messages"], from_start["messages"]);
}

#[allow(unsafe_code)]
#[test]
fn a_full_disk_stops_the_recording_not_the_vehicle() {
    // A file size limit fails writes past it as a full disk does (EFBIG for ENOSPC);
    // adrive must not die of SIGXFSZ either. The log file stays under it.
    const LIMIT: u64 = 256 * 1024;
    let dir = common::tempdir("full");
    let file = dir.path().join("full.mcap");
    let sim = SimProcess::start();
    let port = free_port();
    let mut cmd = adrive(&sim, dir.path(), port, &["--record-raw", "--record"]);
    cmd.arg(&file).stdout(Stdio::piped()).stderr(Stdio::piped());
    // SAFETY: setrlimit between fork and exec, on the child only.
    unsafe {
        cmd.pre_exec(|| {
            let lim = libc::rlimit {
                rlim_cur: LIMIT,
                rlim_max: LIMIT,
            };
            match libc::setrlimit(libc::RLIMIT_FSIZE, &lim) {
                0 => Ok(()),
                _ => Err(std::io::Error::last_os_error()),
            }
        });
    }
    let mut child = cmd.spawn().unwrap();
    let stderr = common::lines(child.stderr.take().unwrap());
    let stdout = child.stdout.take().unwrap();
    let mut a = common::Reaped(child);
    wait_listening(port);
    let _p = planner(port, 100_000);
    let stopped = common::until(&stderr, "recording stopped");
    let line = stopped.last().unwrap();
    assert!(
        line.contains("full.mcap") && line.contains("the vehicle runs on"),
        "{line}"
    );
    // The vehicle runs on: the planner's gas keeps reaching the device.
    let mark = sim.mark();
    sim.wait_after(mark, &["gas", "<-", "0.300"]);
    common::signal(&a, libc::SIGTERM);
    assert_eq!(common::wait_exit(&mut a), Some(0), "a clean stop");
    let mut summary = String::new();
    std::io::Read::read_to_string(&mut { stdout }, &mut summary).unwrap();
    assert!(summary.contains("recording stopped"), "{summary}");
    assert!(std::fs::metadata(&file).unwrap().len() <= LIMIT);
    // Ended at its last whole chunk, which every reader reads.
    let rec = Recording::open(&file).expect("what was written is MCAP");
    assert!(rec.chunks >= 1, "{:?}", rec.ending);
    assert_eq!(rec.ending, Ending::Checkpoint, "ended at the limit");
    assert!(!by_topic(&rec)["/snapshot"].is_empty());
    let theirs = python_reads(&file, "make_reader");
    assert_eq!(theirs["counts"], counts(&file), "{theirs}");
    // The summary's account is what the file holds, not what was handed to the writer
    // after its last chunk (it said 1334 messages of a file that held 1062).
    let held: u64 = counts(&file)
        .as_object()
        .unwrap()
        .values()
        .map(|n| n.as_u64().unwrap())
        .sum();
    let size = bytesize::ByteSize::b(std::fs::metadata(&file).unwrap().len())
        .display()
        .si()
        .to_string();
    let said = format!("recorded {held} messages ({size}) to {}", file.display());
    assert!(summary.contains(&said), "{said:?} in {summary}");
}

#[test]
fn a_record_table_rolls_to_a_new_file_by_age_and_keeps_the_newest() {
    let dir = common::tempdir("roll");
    let sim = SimProcess::start();
    let port = free_port();
    let mut cmd = adrive(&sim, dir.path(), port, &[]);
    // The vehicle file records every run itself: rolling at the shortest age allowed,
    // keeping one file.
    let config = dir.path().join("vehicle.toml");
    let mut text = std::fs::read_to_string(&config).unwrap();
    text.push_str("\n[record]\ndir = \"rec\"\nroll_age = \"10s\"\nkeep = 1\n");
    std::fs::write(&config, text).unwrap();
    let mut a = common::Reaped(
        cmd.stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let rec = dir.path().join("rec");
    let files = || -> Vec<PathBuf> {
        let mut f: Vec<PathBuf> = std::fs::read_dir(&rec)
            .into_iter()
            .flatten()
            .map(|e| e.unwrap().path())
            .collect();
        f.sort();
        f
    };
    common::wait_for("the first recording", || files().len() == 1);
    let first = files().remove(0);
    let name = first.file_name().unwrap().to_string_lossy().to_string();
    assert!(
        name.starts_with("alice-") && name.ends_with("Z.mcap"),
        "{name}"
    );
    // Ten seconds on, the next file; the first is deleted (keep = 1).
    let end = Instant::now() + Duration::from_secs(10) + DEADLINE;
    while files() == [first.clone()] {
        assert!(Instant::now() < end, "no second file in {}", rec.display());
        std::thread::sleep(Duration::from_millis(100));
    }
    common::wait_for("the first file pruned", || !first.exists());
    // Stop once the new file has a snapshot in a whole chunk: stopped sooner, right
    // after the roll, it would rightly hold none yet.
    common::wait_for("a snapshot in the new file", || {
        files().last().is_some_and(|f| {
            Recording::open(f).is_ok_and(|r| by_topic(&r).contains_key("/snapshot"))
        })
    });
    common::signal(&a, libc::SIGTERM);
    assert_eq!(common::wait_exit(&mut a), Some(0));
    let left = files();
    assert_eq!(left.len(), 1, "{left:?}");
    assert!(left[0] > first, "the newer file is kept");
    let second = Recording::open(&left[0]).unwrap();
    assert!(second.complete, "{:?}", second.cut);
    assert!(
        !by_topic(&second)["/snapshot"].is_empty(),
        "each file stands alone, with its channels"
    );
}
