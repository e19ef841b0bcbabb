//! The live view (`--foxglove`) with the real binary: a third-party Foxglove WebSocket
//! client (Python `websockets`, with `jsonschema`) connects under each subprotocol
//! name, reads `serverInfo` and the advertisement, subscribes and checks live messages
//! against the advertised schemas; and a viewer that stops reading loses messages,
//! counted in the broadcast, while a command still reaches its device (`adrive sim`,
//! in a process of its own) as fast as before.

mod common;
#[path = "support/python_env.rs"]
mod python_env;

use adrive::snapshot::{Snapshot, ViewerView};
use common::headless::Adrive;
use common::simproc::{vehicle_file, SimProcess};
use common::{free_port, lines, DEADLINE};
use serde_json::Value;
use std::net::{SocketAddr, TcpStream, UdpSocket};
use std::process::{Command as Process, Stdio};
use std::sync::{mpsc, Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};
use tungstenite::client::IntoClientRequest;

const BIN: &str = env!("CARGO_BIN_EXE_adrive");
const WEBSOCKETS: &str = "websockets==15.0.1";
const JSONSCHEMA: &str = "jsonschema==4.23.0";

/// A Python interpreter with the pinned `websockets` and `jsonschema`.
fn python() -> &'static str {
    static PYTHON: OnceLock<String> = OnceLock::new();
    PYTHON.get_or_init(|| {
        python_env::python(
            "foxglove-venv",
            &[WEBSOCKETS, JSONSCHEMA],
            "websockets, jsonschema",
        )
    })
}

/// The live view's address, from what adrive logged at start.
fn live_addr(startup: &[String]) -> SocketAddr {
    startup
        .iter()
        .find_map(|l| l.split("live view at ws://").nth(1))
        .and_then(|rest| rest.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("no live view address in:\n{}", startup.join("\n")))
}

/// A planner that engages and keeps commanding `steer` at 20 Hz, so the vehicle stays
/// engaged; `set` changes the value at once, and says when it was sent.
struct Planner {
    set: mpsc::Sender<(f64, mpsc::Sender<Instant>)>,
}

impl Planner {
    fn start(listen: &str) -> Planner {
        let s = UdpSocket::bind("127.0.0.1:0").unwrap();
        s.connect(listen).unwrap();
        let (set, rx) = mpsc::channel::<(f64, mpsc::Sender<Instant>)>();
        std::thread::spawn(move || {
            let mut value = 0.0;
            for seq in 1u64.. {
                let sent = match rx.recv_timeout(Duration::from_millis(50)) {
                    Ok((v, sent)) => {
                        value = v;
                        Some(sent)
                    }
                    Err(mpsc::RecvTimeoutError::Timeout) => None,
                    Err(mpsc::RecvTimeoutError::Disconnected) => return,
                };
                let _ = s.send(format!("seq {seq}\nengage\nsteer {value:.3}\n").as_bytes());
                if let Some(tx) = sent {
                    let _ = tx.send(Instant::now());
                }
            }
        });
        Planner { set }
    }

    /// Command `steer value` now; when it went.
    fn steer(&self, value: f64) -> Instant {
        let (tx, rx) = mpsc::channel();
        self.set.send((value, tx)).unwrap();
        rx.recv_timeout(DEADLINE).expect("the planner sent it")
    }
}

/// Broadcasts until one satisfies `cond`.
fn broadcast_until(rx: &UdpSocket, what: &str, cond: impl Fn(&Snapshot) -> bool) -> Snapshot {
    let end = Instant::now() + DEADLINE;
    let mut buf = vec![0u8; 65536];
    loop {
        assert!(Instant::now() < end, "no broadcast where {what}");
        let Ok(n) = rx.recv(&mut buf) else { continue };
        let Ok(snap) = serde_json::from_slice::<Snapshot>(&buf[..n]) else {
            continue;
        };
        if cond(&snap) {
            return snap;
        }
    }
}

#[test]
fn a_third_party_viewer_reads_live_messages_valid_under_the_advertised_schemas_with_either_subprotocol(
) {
    // Held engaged while the viewers run, to prove what they read, not device timing:
    // on the tolerant Alice.
    let a = Adrive::start_with(
        "foxglove-viewer",
        &common::tolerant_text(adrive::config::ALICE_TOML),
        "",
        &["--foxglove", "127.0.0.1:0"],
    );
    let addr = live_addr(&a.startup);
    let rx = UdpSocket::bind(&a.broadcast).unwrap();
    rx.set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    // Engaged before any viewer comes: the gate's message is the latest state a viewer
    // must get at once, with nothing new on that channel.
    let _planner = Planner::start(&a.listen);
    broadcast_until(&rx, "engaged", |s| s.gate.engaged);
    // Two viewers at once, one under each subprotocol name.
    let viewers: Vec<_> = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
        .into_iter()
        .map(|subprotocol| {
            let child = Process::new(python())
                .arg(concat!(
                    env!("CARGO_MANIFEST_DIR"),
                    "/tests/support/foxglove_viewer.py"
                ))
                .args([&format!("ws://{addr}"), subprotocol, "/steer/reading", "5"])
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap();
            (subprotocol, child)
        })
        .collect();
    for (subprotocol, child) in viewers {
        let out = child.wait_with_output().unwrap();
        assert!(
            out.status.success(),
            "the viewer with {subprotocol}:\n{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        let v: Value = serde_json::from_slice(&out.stdout).expect("its JSON report");
        assert_eq!(v["subprotocol"], subprotocol);
        for topic in [
            "/snapshot",
            "/commands",
            "/gate",
            "/faults",
            "/supervisor",
            "/log",
            "/steer/command",
            "/steer/reading",
            "/estop/reading",
        ] {
            assert!(
                v["channels"].as_array().unwrap().iter().any(|c| c == topic),
                "{topic} advertised: {v}"
            );
        }
        assert!(v["seen"]["/snapshot"].as_u64() >= Some(5), "{v}");
        assert!(v["seen"]["/steer/reading"].as_u64() >= Some(5), "{v}");
        assert_eq!(v["gate"]["engaged"], true, "{v}");
        assert!(
            v["first_s"]["/gate"].as_f64().unwrap() < 1.0,
            "the gate's latest message came at once: {v}"
        );
        assert!(v["device"]["position"].is_number(), "{v}");
    }
}

/// A viewer that subscribes to every channel, then never reads again; its socket
/// takes as little as the kernel allows.
fn stalled_viewer(addr: SocketAddr) -> tungstenite::WebSocket<TcpStream> {
    let sock = socket2::Socket::new(socket2::Domain::IPV4, socket2::Type::STREAM, None).unwrap();
    sock.set_recv_buffer_size(4096).unwrap();
    sock.connect(&addr.into()).unwrap();
    let stream: TcpStream = sock.into();
    stream.set_read_timeout(Some(DEADLINE)).unwrap();
    let mut req = format!("ws://{addr}").into_client_request().unwrap();
    req.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        "foxglove.websocket.v1".parse().unwrap(),
    );
    let (mut ws, _) = tungstenite::client::client(req, stream).expect("the handshake");
    let mut channels = Vec::new();
    while channels.is_empty() {
        if let tungstenite::Message::Text(t) = ws.read().expect("serverInfo, advertise") {
            let v: Value = serde_json::from_str(&t).unwrap();
            if v["op"] == "advertise" {
                channels = v["channels"].as_array().unwrap().clone();
            }
        }
    }
    let subs: Vec<Value> = channels
        .iter()
        .enumerate()
        .map(|(i, c)| serde_json::json!({"id": i, "channelId": c["id"]}))
        .collect();
    let sub = serde_json::json!({"op": "subscribe", "subscriptions": subs});
    ws.send(tungstenite::Message::text(sub.to_string()))
        .unwrap();
    ws
}

/// How long `steer value` takes from the planner to the simulated device.
fn sentinel(planner: &Planner, sim: &SimProcess, value: f64) -> Duration {
    let mark = sim.mark();
    let sent = planner.steer(value);
    let text = format!("{value:.3}");
    let (_, _) = sim.wait_after(mark, &["steer", "<-", &text]);
    sent.elapsed()
}

fn median(mut d: Vec<Duration>) -> Duration {
    d.sort();
    d[d.len() / 2]
}

#[test]
fn a_viewer_that_stops_reading_loses_messages_and_never_delays_a_command() {
    let dir = common::tempdir("foxglove-stall");
    let sim = SimProcess::start();
    // Held engaged for seconds to prove the command path does not wait for a viewer,
    // not device timing: on the tolerant Alice.
    let config = common::tolerant(vehicle_file(dir.path(), &sim, ""));
    let (listen, broadcast) = (
        format!("127.0.0.1:{}", free_port()),
        format!("127.0.0.1:{}", free_port()),
    );
    let rx = UdpSocket::bind(&broadcast).unwrap();
    rx.set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let mut child = common::Reaped(
        Process::new(BIN)
            .arg("--config")
            .arg(&config)
            .args([
                "--headless",
                "--listen",
                &listen,
                "--broadcast-to",
                &broadcast,
            ])
            .args(["--foxglove", "127.0.0.1:0"])
            .arg("--log-dir")
            .arg(dir.path().join("log"))
            .env("XDG_RUNTIME_DIR", dir.path())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let err = lines(child.stderr.take().unwrap());
    let startup = Arc::new(Mutex::new(Vec::new()));
    let log = startup.clone();
    std::thread::spawn(move || {
        for l in err {
            log.lock().unwrap().push(l);
        }
    });
    common::wait_for("the live view's address", || {
        startup
            .lock()
            .unwrap()
            .iter()
            .any(|l| l.contains("live view at"))
    });
    let addr = live_addr(&startup.lock().unwrap());
    let planner = Planner::start(&listen);
    broadcast_until(&rx, "engaged", |s| s.gate.engaged);
    // The usual delay, with no viewer.
    let before = median(
        (1..=5)
            .map(|i| sentinel(&planner, &sim, 0.1 + 0.01 * f64::from(i)))
            .collect(),
    );
    let _viewer = stalled_viewer(addr);
    let viewer = |s: &Snapshot| -> Option<ViewerView> {
        s.net.as_ref()?.foxglove.as_ref()?.viewers.first().cloned()
    };
    let first = broadcast_until(&rx, "the stalled viewer drops messages", |s| {
        viewer(s).is_some_and(|v| v.dropped > 0)
    });
    let dropped = viewer(&first).unwrap().dropped;
    let later = broadcast_until(&rx, "its drop count grows", |s| {
        viewer(s).is_some_and(|v| v.dropped > dropped)
    });
    let v = viewer(&later).unwrap();
    assert_eq!(v.subprotocol, "foxglove.websocket.v1");
    assert!(v.subscriptions > 10, "{v:?}");
    // The vehicle did not wait for it: commands reach the device as fast as before.
    let after = median(
        (1..=5)
            .map(|i| sentinel(&planner, &sim, -0.1 - 0.01 * f64::from(i)))
            .collect(),
    );
    assert!(
        after <= before * 3 + Duration::from_millis(20),
        "a command took {after:?} with a stalled viewer, {before:?} without"
    );
    let still = viewer(&broadcast_until(&rx, "the viewer still counted", |s| {
        viewer(s).is_some()
    }))
    .unwrap();
    assert!(still.dropped >= v.dropped);
}

/// A viewer's WebSocket handshake with the live view, as a client library makes it.
fn handshake(addr: SocketAddr) -> Result<tungstenite::WebSocket<TcpStream>, tungstenite::Error> {
    let stream = TcpStream::connect(addr).unwrap();
    stream.set_read_timeout(Some(DEADLINE)).unwrap();
    let mut req = format!("ws://{addr}").into_client_request().unwrap();
    req.headers_mut()
        .insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
    tungstenite::client::client(req, stream)
        .map(|(ws, _)| ws)
        .map_err(|e| match e {
            tungstenite::HandshakeError::Failure(e) => e,
            tungstenite::HandshakeError::Interrupted(_) => unreachable!("a blocking socket"),
        })
}

/// A viewer past the limit had its connection closed with no answer: it is answered
/// HTTP 503 naming the limit, and served once another has left.
#[test]
fn a_viewer_past_the_limit_is_answered_503_naming_it() {
    let a = Adrive::start_with(
        "foxglove-full",
        adrive::config::ALICE_TOML,
        "",
        &["--foxglove", "127.0.0.1:0"],
    );
    let addr = live_addr(&a.startup);
    let mut viewers: Vec<_> = (0..16)
        .map(|i| handshake(addr).unwrap_or_else(|e| panic!("viewer {i}: {e}")))
        .collect();
    match handshake(addr) {
        Err(tungstenite::Error::Http(resp)) => {
            assert_eq!(resp.status().as_u16(), 503);
            let body = String::from_utf8_lossy(resp.body().as_deref().unwrap_or_default());
            assert!(
                body.contains("at most 16 viewers at once"),
                "the 503 names the limit: {body}"
            );
        }
        other => panic!("a 17th viewer: {:?}", other.map(|_| "connected")),
    }
    // One leaves: the next is served.
    let mut gone = viewers.pop().unwrap();
    gone.close(None).unwrap();
    while gone.read().is_ok() {}
    drop(gone);
    let end = Instant::now() + DEADLINE;
    loop {
        match handshake(addr) {
            Ok(_) => break,
            Err(tungstenite::Error::Http(r)) if r.status().as_u16() == 503 => {
                assert!(Instant::now() < end, "still full after one left");
                std::thread::sleep(Duration::from_millis(50));
            }
            Err(e) => panic!("{e}"),
        }
    }
}
