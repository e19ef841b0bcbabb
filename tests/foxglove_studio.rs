//! Foxglove Studio's own reader against what the real binary writes. The test installs
//! Studio's published code (`@foxglove/studio-base` on npm, with the `@mcap/core` MCAP
//! reader Studio uses; `tests/support/foxglove_studio/`) and runs, under Node.js, its
//! `parseChannel` and `parseJsonSchema` — the strictest of the viewers' JSON Schema
//! readers, which drops a whole channel on a schema it does not take — over every
//! channel of a real recording (finished, and cut by `kill -9`) and every channel the
//! live view advertises, and deserializes every message with what it returns. The
//! guide's "a Plot panel with `/steer/command.value` against `/steer/reading.position`,
//! with no configuration" holds only if every channel survives.

mod common;
#[path = "support/node_env.rs"]
mod node_env;

use adrive::record::read::Recording;
use common::headless::{Adrive, Watch};
use common::DEADLINE;
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::process::Command as Process;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// The installed packages.
fn modules() -> &'static Path {
    static DIR: OnceLock<std::path::PathBuf> = OnceLock::new();
    DIR.get_or_init(|| node_env::modules("foxglove_studio"))
}

/// Studio's verdict, from tests/support/foxglove_studio.js.
fn studio(mode: &str, file: &Path) -> Value {
    let out = Process::new("node")
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/support/foxglove_studio.js"
        ))
        .arg(modules())
        .arg(mode)
        .arg(file)
        .output()
        .expect("node runs");
    assert!(
        out.status.success(),
        "Studio's reader failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("its JSON report")
}

/// Every channel Studio read, none dropped, every message deserialized.
fn every_channel_taken(v: &Value) -> BTreeMap<String, u64> {
    let mut counts = BTreeMap::new();
    for (topic, c) in v["channels"].as_object().unwrap() {
        assert_eq!(c["ok"], true, "Studio drops {topic}: {}", c["error"]);
        assert_eq!(c["deserialized"], c["messages"], "{topic}: {v}");
        counts.insert(topic.clone(), c["messages"].as_u64().unwrap());
    }
    assert_eq!(v["errors"], json!([]), "{v}");
    counts
}

/// The field `field` of Studio's type `ty` on `topic`.
fn field<'a>(v: &'a Value, topic: &str, ty: &str, field: &str) -> &'a Value {
    &v["channels"][topic]["types"][ty][field]
}

/// Alice, simulated, recording to `file` (raw traffic too), driven by a planner that
/// engages, once she can be, and steers for two seconds. She is made tolerant of this
/// shared machine's stalls ([`common::tolerant_text`]): what is proved is the
/// recording, not device timing. The planner's status is not asked: its `accel` may
/// still be refused at its end, the gearbox shifting.
fn recorded_drive(tag: &str, file: &Path) -> Adrive {
    let file = file.display().to_string();
    let a = Adrive::start_with(
        tag,
        &common::tolerant_text(adrive::config::ALICE_TOML),
        "",
        &["--record", &file, "--record-raw"],
    );
    Watch::start(&a.broadcast).until("every device reporting", |v| v.gate.blockers.is_empty());
    let out = a.send(&[
        "--rate", "20", "--count", "40", "engage", "trans", "drive", "steer", "0.2", "accel", "0.2",
    ]);
    let replies = String::from_utf8_lossy(&out.stdout);
    assert!(replies.contains("ok engaged"), "{out:?}");
    a
}

/// Messages per channel, as adrive's own reader reads the file.
fn ours(file: &Path) -> BTreeMap<String, u64> {
    let rec = Recording::open(file).unwrap();
    let mut n = BTreeMap::new();
    rec.for_each(|m| *n.entry(m.topic.to_string()).or_default() += 1);
    n
}

#[test]
fn foxglove_studio_opens_every_channel_of_a_real_recording_and_plots_a_command_against_its_reading()
{
    let dir = common::tempdir("studio-rec");
    let file = dir.path().join("drive.mcap");
    let mut a = recorded_drive("studio-rec", &file);
    common::stop(&mut a.child);
    let v = studio("mcap", &file);
    assert_eq!(v["how"], "indexed", "a finished file is read by its index");
    let counts = every_channel_taken(&v);
    assert_eq!(counts, ours(&file));
    for topic in [
        "/snapshot",
        "/commands",
        "/gate",
        "/log",
        "/record",
        "/steer/raw",
    ] {
        assert!(counts.contains_key(topic), "{topic} in {counts:?}");
    }
    // The guide's plot, and the shipped layout's estimate, by the types Studio made.
    assert_eq!(
        field(&v, "/steer/command", "adrive.Written", "value"),
        "float64"
    );
    assert_eq!(
        field(&v, "/steer/reading", "adrive.steer.Reading", "position"),
        "float64"
    );
    assert_eq!(
        field(&v, "/obd/reading", "adrive.obd.Reading", "running"),
        "bool"
    );
    let snap = "adrive.Snapshot.devices";
    assert_eq!(
        field(&v, "/snapshot", &format!("{snap}.readings"), "position"),
        "float64"
    );
    assert_eq!(
        field(&v, "/snapshot", &format!("{snap}.estimate"), "position"),
        "float64"
    );
    assert_eq!(
        field(&v, "/snapshot", "adrive.Snapshot.gate.roles", "steering"),
        "string"
    );
    assert_eq!(field(&v, "/log", "foxglove.Log", "level"), "uint32");
}

#[test]
fn foxglove_studio_reads_every_channel_of_a_recording_cut_by_kill_9() {
    let dir = common::tempdir("studio-cut");
    let file = dir.path().join("cut.mcap");
    let a = recorded_drive("studio-cut", &file);
    common::wait_for("two whole chunks", || {
        Recording::open(&file).is_ok_and(|r| r.chunks >= 2)
    });
    common::signal(&a.child, libc::SIGKILL);
    let pid = a.child.id();
    drop(a);
    // Killed, it could not remove its simulated devices' directory: the test does.
    for e in std::fs::read_dir(std::env::temp_dir()).unwrap().flatten() {
        if e.file_name()
            .to_string_lossy()
            .starts_with(&format!("adrive-sim-{pid}-"))
        {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
    let v = studio("mcap", &file);
    assert_eq!(v["how"], "streamed", "no index: read from the start");
    assert_eq!(v["stream_error"], Value::Null, "{v}");
    assert_eq!(v["stream_done"], true, "it reads to the file's end: {v}");
    assert_eq!(every_channel_taken(&v), ours(&file));
}

/// A viewer of the live view: the advertisement, and a few messages of each channel
/// that has some within the deadline.
fn live(addr: SocketAddr, want: &[&str]) -> Value {
    let stream = TcpStream::connect(addr).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let mut req =
        tungstenite::client::IntoClientRequest::into_client_request(format!("ws://{addr}"))
            .unwrap();
    req.headers_mut()
        .insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
    let (mut ws, _) = tungstenite::client::client(req, stream).expect("the handshake");
    let mut adv = Value::Null;
    let mut messages: BTreeMap<String, Vec<String>> = BTreeMap::new();
    let mut topic_of: BTreeMap<u32, String> = BTreeMap::new();
    let end = Instant::now() + DEADLINE;
    while want
        .iter()
        .any(|t| messages.get(*t).is_none_or(|m| m.len() < 3))
    {
        assert!(
            Instant::now() < end,
            "messages by the deadline: {:?}",
            messages.keys()
        );
        match ws.read() {
            Ok(tungstenite::Message::Text(t)) => {
                let v: Value = serde_json::from_str(&t).unwrap();
                if v["op"] == "advertise" {
                    let subs: Vec<Value> = v["channels"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|c| {
                            let id = c["id"].as_u64().unwrap() as u32;
                            topic_of.insert(id, c["topic"].as_str().unwrap().to_string());
                            json!({ "id": id, "channelId": id })
                        })
                        .collect();
                    ws.send(tungstenite::Message::text(
                        json!({ "op": "subscribe", "subscriptions": subs }).to_string(),
                    ))
                    .unwrap();
                    adv = v;
                }
            }
            Ok(tungstenite::Message::Binary(b)) => {
                let sub = u32::from_le_bytes(b[1..5].try_into().unwrap());
                let payload = String::from_utf8(b[13..].to_vec()).unwrap();
                messages
                    .entry(topic_of[&sub].clone())
                    .or_default()
                    .push(payload);
            }
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => panic!("the live view: {e}"),
        }
    }
    adv["messages"] = json!(messages);
    adv
}

#[test]
fn foxglove_studio_takes_every_channel_the_live_view_advertises() {
    // Held engaged while Studio reads, to prove what it takes, not device timing: on
    // the tolerant Alice.
    let a = Adrive::start_with(
        "studio-live",
        &common::tolerant_text(adrive::config::ALICE_TOML),
        "watchdog_timeout = \"2s\"",
        &["--foxglove", "127.0.0.1:0"],
    );
    let addr: SocketAddr = a
        .startup
        .iter()
        .find_map(|l| l.split("live view at ws://").nth(1))
        .and_then(|rest| rest.split_whitespace().next()?.parse().ok())
        .expect("the live view's address");
    let planner = a.planner();
    let sender = std::thread::spawn(move || {
        for seq in 1..=60 {
            let _ = planner.send(format!("seq {seq}\nengage\nsteer 0.1\n").as_bytes());
            std::thread::sleep(Duration::from_millis(50));
        }
    });
    let adv = live(
        addr,
        &[
            "/snapshot",
            "/steer/reading",
            "/steer/command",
            "/obd/reading",
        ],
    );
    sender.join().unwrap();
    let dir = common::tempdir("studio-live-adv");
    let file = dir.path().join("advertise.json");
    std::fs::write(&file, adv.to_string()).unwrap();
    let v = studio("advertise", &file);
    let counts = every_channel_taken(&v);
    assert!(counts.len() > 10, "{counts:?}");
    assert!(counts["/snapshot"] >= 3, "{v}");
    assert_eq!(
        field(
            &v,
            "/snapshot",
            "adrive.Snapshot.devices.readings",
            "position"
        ),
        "float64"
    );
    assert_eq!(
        field(&v, "/steer/command", "adrive.Written", "value"),
        "float64"
    );
}
