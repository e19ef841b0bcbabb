//! Interoperability: the real `adrive --headless` drives an SLCAN adapter played by a
//! Python script on a real pseudo-terminal (`tests/support/slcan_adapter_peer.py`), with
//! an OSCC kit behind it that reports at 50 Hz. The script decodes every frame adrive
//! sends with cantools against `vehicles/oscc.dbc` and reports what adrive did; the test
//! drives adrive from outside (a planner's datagrams, SIGTERM) and judges: every frame
//! as the DBC describes it, each module's enable after its safe command and never
//! before the engage, the commands resent at `command_timeout` while engaged, the set
//! points on the wire, and after the disengage (and at exit) the safe command and then
//! the disable message as the last word. In the second test the bus goes into error
//! (the adapter hears nothing, refuses every frame and says "bus error"): every device
//! on it is faulted, engage is refused and no module is enabled until the bus heals.

mod common;
#[path = "support/python_can_env.rs"]
mod python_can_env;
#[path = "support/python_env.rs"]
mod python_env;

use common::headless::{Watch, BIN};
use common::{free_port, lines, tempdir, wait_exit, Reaped, DEADLINE};
use python_can_env::python;
use serde_json::Value;
use std::io::Write;
use std::net::UdpSocket;
use std::process::{ChildStdin, Command as Process, Stdio};
use std::sync::mpsc::Receiver;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Each module's safe command (OSCC's module names, as the DBC's messages begin).
const SAFE: &str = r#"{"BRAKE": 1.0, "STEERING": 0.0, "THROTTLE": 0.0}"#;
const MODULES: [&str; 3] = ["BRAKE", "STEERING", "THROTTLE"];
/// `command_timeout` of every module in `vehicles/oscc.toml`.
const COMMAND_TIMEOUT_MS: f64 = 50.0;

/// The Python adapter: its port, what it says, and its standard input.
struct Peer {
    child: Reaped,
    stdin: Option<ChildStdin>,
    out: Receiver<String>,
    err: Arc<Mutex<Vec<String>>>,
    port: String,
    /// Status requests the adapter answered, as far as read.
    statuses: u64,
    /// adrive's log, shown when the adapter waits in vain.
    adrive_log: Arc<Mutex<Vec<String>>>,
}

impl Peer {
    fn start() -> Peer {
        let mut child = Process::new(python())
            .arg(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/tests/support/slcan_adapter_peer.py"
            ))
            .args([&dbc_path(), SAFE])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start the Python adapter");
        let out = lines(child.stdout.take().unwrap());
        let err = keep(lines(child.stderr.take().unwrap()));
        let stdin = child.stdin.take();
        let mut peer = Peer {
            child: Reaped(child),
            stdin,
            out,
            err,
            port: String::new(),
            statuses: 0,
            adrive_log: Arc::default(),
        };
        let first = peer.until("the adapter's port", |v| v.get("port").is_some());
        peer.port = first["port"].as_str().unwrap().to_string();
        peer
    }

    /// Read the script's lines until one satisfies `want`.
    fn until(&mut self, what: &str, mut want: impl FnMut(&Value) -> bool) -> Value {
        let end = Instant::now() + DEADLINE;
        loop {
            let left = end.saturating_duration_since(Instant::now());
            let Ok(line) = self.out.recv_timeout(left) else {
                let err = self.err.lock().unwrap().join("\n");
                let log = self.adrive_log.lock().unwrap().clone();
                panic!(
                    "the Python adapter: no {what}; it said on stderr:\n{err}\n\
                     adrive's log (the end):\n{}",
                    log[log.len().saturating_sub(60)..].join("\n")
                );
            };
            let v = self.read(&line);
            if want(&v) {
                return v;
            }
        }
    }

    fn read(&mut self, line: &str) -> Value {
        let v: Value = serde_json::from_str(line)
            .unwrap_or_else(|e| panic!("the Python adapter wrote {line:?}: {e}"));
        if let Some(n) = v["status"].as_u64() {
            self.statuses = n;
        }
        v
    }

    /// Read what the script said so far.
    fn drain(&mut self) {
        while let Ok(line) = self.out.try_recv() {
            self.read(&line);
        }
    }

    fn say(&mut self, line: &str) {
        let stdin = self.stdin.as_mut().expect("the script's stdin");
        writeln!(stdin, "{line}").expect("the Python adapter reads its stdin");
    }

    /// Note the instant before an outside request, once the script has it.
    fn mark(&mut self, name: &str) {
        self.say(&format!("MARK {name}"));
        self.until(&format!("mark {name}"), |v| v["marked"] == name);
    }

    /// Wait until every module has had a frame of `kind` (and `value`, when given).
    fn each_module(&mut self, kind: &str, values: &[(&str, f64)], count: usize) {
        let mut seen = [0usize; 3];
        self.until(&format!("{count} {kind} frames for every module"), |v| {
            if v["kind"] == kind {
                let m = v["module"].as_str().unwrap();
                let i = MODULES.iter().position(|&n| n == m).unwrap();
                let want = values.iter().find(|(n, _)| *n == m).map(|(_, x)| *x);
                if want.is_none_or(|x| (v["value"].as_f64().unwrap() - x).abs() < 1e-6) {
                    seen[i] += 1;
                }
            }
            seen.iter().all(|&n| n >= count)
        });
    }

    /// End the adapter: its judgement of everything adrive sent.
    fn verdict(mut self) -> Value {
        self.say("END");
        let v = self.until("verdict", |v| v.get("verdict").is_some());
        self.stdin.take();
        assert_eq!(wait_exit(&mut self.child), Some(0), "the Python adapter");
        v["verdict"].clone()
    }
}

/// Keep a child's lines as they come.
fn keep(rx: Receiver<String>) -> Arc<Mutex<Vec<String>>> {
    let kept = Arc::new(Mutex::new(Vec::new()));
    let k = kept.clone();
    std::thread::spawn(move || {
        for l in rx {
            k.lock().unwrap().push(l);
        }
    });
    kept
}

fn dbc_path() -> String {
    concat!(env!("CARGO_MANIFEST_DIR"), "/vehicles/oscc.dbc").to_string()
}

/// `vehicles/oscc.toml` on `port`, its DBC by absolute path, the network on loopback,
/// every device's `status_max_age` 1 s.
fn vehicle(port: &str, listen: &str, broadcast: &str) -> String {
    let mut text = include_str!("../vehicles/oscc.toml").to_string();
    for (from, to) in [
        (
            "port = \"/dev/serial/by-id/usb-CANable_slcan-if00\"",
            format!("port = \"{port}\""),
        ),
        ("dbc = \"oscc.dbc\"", format!("dbc = \"{}\"", dbc_path())),
        (
            "[network]\nallow_engage = true\n",
            format!(
                "[network]\nallow_engage = true\nlisten = \"{listen}\"\n\
                 broadcast_to = [\"{broadcast}\"]\nwatchdog_timeout = \"2s\"\n"
            ),
        ),
    ] {
        assert_eq!(
            text.matches(from).count(),
            1,
            "vehicles/oscc.toml has {from}"
        );
        text = text.replace(from, &to);
    }
    // A report 100 ms late on a loaded machine would fault its device and disengage
    // the vehicle; what is judged here is the frames adrive sends, not the peer's
    // report timing.
    let lines: Vec<String> = text
        .lines()
        .map(|l| {
            if l.starts_with("status_max_age = ") {
                "status_max_age = \"1s\"".to_string()
            } else {
                l.to_string()
            }
        })
        .collect();
    assert_eq!(
        lines
            .iter()
            .filter(|l| l.starts_with("status_max_age"))
            .count(),
        4,
        "vehicles/oscc.toml gives each of its four devices a status_max_age"
    );
    lines.join("\n") + "\n"
}

/// The real binary, headless, on the peer's port.
struct Adrive {
    child: Reaped,
    listen: String,
    broadcast: String,
    log: Arc<Mutex<Vec<String>>>,
    /// Its vehicle file, log and socket; removed when the test ends.
    _dir: tempfile::TempDir,
}

impl Adrive {
    fn start(tag: &str, port: &str) -> Adrive {
        let dir = tempdir(tag);
        let listen = format!("127.0.0.1:{}", free_port());
        let broadcast = format!("127.0.0.1:{}", free_port());
        let path = dir.path().join("oscc.toml");
        std::fs::write(&path, vehicle(port, &listen, &broadcast)).unwrap();
        let mut child = Process::new(BIN)
            .args(["--headless", "--config"])
            .arg(&path)
            .arg("--log-dir")
            .arg(dir.path().join("log"))
            .arg("--socket")
            .arg(dir.path().join("adrive.sock"))
            .env("XDG_RUNTIME_DIR", dir.path())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start adrive");
        let log = keep(lines(child.stderr.take().unwrap()));
        Adrive {
            child: Reaped(child),
            listen,
            broadcast,
            log,
            _dir: dir,
        }
    }

    /// A planner's socket on its command listener: every datagram from one sender,
    /// the commander once it engaged.
    fn planner(&self) -> UdpSocket {
        let s = UdpSocket::bind("127.0.0.1:0").unwrap();
        s.connect(&self.listen).unwrap();
        s.set_read_timeout(Some(DEADLINE)).unwrap();
        s
    }

    fn log(&self) -> String {
        self.log.lock().unwrap().join("\n")
    }
}

/// Send `lines` in one datagram from `planner`; with `reply`, wait for adrive's reply
/// and check that it has `reply` in it.
fn send(adrive: &Adrive, planner: &UdpSocket, lines: &str, reply: Option<&str>) {
    planner.send(lines.as_bytes()).unwrap();
    let Some(want) = reply else { return };
    let mut buf = [0u8; 2048];
    let said = match planner.recv(&mut buf) {
        Ok(n) => String::from_utf8_lossy(&buf[..n]).into_owned(),
        Err(e) => format!("no reply: {e}"),
    };
    assert!(
        said.contains(want),
        "{lines:?}: adrive replied {said:?}, not {want:?}; its log:\n{}",
        adrive.log()
    );
}

/// What keeps a broadcast from showing every device reporting and engage possible:
/// the gate's blockers, a device stale or faulty, a fault the supervisor still holds
/// (it disengages at once while one does).
fn not_reporting(s: &adrive::snapshot::Snapshot) -> Vec<String> {
    let mut missing = s.gate.blockers.clone();
    for d in &s.devices {
        if d.stale || d.health.faulty {
            missing.push(format!("{}: stale or faulty", d.name));
        }
    }
    missing.extend(s.supervisor.faults.iter().map(|f| f.describe()));
    missing
}

fn num(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} is no number in {v:#}"))
}

#[test]
fn adrive_drives_a_python_slcan_adapter_and_every_frame_follows_the_dbc_and_the_gate() {
    let mut peer = Peer::start();
    let adrive = Adrive::start("can-peer", &peer.port);
    peer.adrive_log = adrive.log.clone();
    let watch = Watch::start(&adrive.broadcast);
    watch.until_complete("every device reporting", not_reporting);
    peer.mark("engage");
    let planner = adrive.planner();
    send(&adrive, &planner, "engage\n", Some("engaged"));
    peer.each_module("ENABLE", &[], 1);
    send(&adrive, &planner, "brake 0\ngas 0.2\nsteer 0.3\n", None);
    let set = [("BRAKE", 0.0), ("THROTTLE", 0.2), ("STEERING", 0.3)];
    // The pause: twenty resends of each set point (a second; the network watchdog
    // is 2 s).
    peer.each_module("COMMAND", &set, 20);

    peer.mark("disengage");
    send(&adrive, &planner, "disengage\n", Some("disengaged"));
    peer.each_module("DISABLE", &[], 2);
    peer.mark("exit");
    common::signal(&adrive.child, libc::SIGTERM);
    let mut child = adrive.child;
    assert_eq!(
        wait_exit(&mut child),
        Some(0),
        "adrive stops cleanly; its log:\n{}",
        adrive.log.lock().unwrap().join("\n")
    );
    drop(child);

    let verdict = peer.verdict();
    let report = format!("the adapter's verdict: {verdict:#}");
    // (a) Every frame is a message of the DBC, decoded by cantools, magic bytes 05 CC,
    // reserved bytes zero; the adapter's protocol kept (bring-up, S6, frames only open).
    assert_eq!(verdict["problems"], serde_json::json!([]), "{report}");
    for m in MODULES {
        for kind in ["COMMAND", "ENABLE", "DISABLE"] {
            let name = format!("{m}_{kind}");
            assert!(
                verdict["names"][&name].as_u64() > Some(0),
                "{name}: {report}"
            );
        }
    }
    assert!(
        verdict["statuses"].as_u64() > Some(0),
        "status asked: {report}"
    );

    let mut figures = Vec::new();
    for (m, value) in set {
        let v = &verdict["modules"][m];
        // Before the engage (adrive sends nothing at start, so perhaps nothing): only
        // the safe command, each followed by the disable message; never the enable
        // message.
        assert_eq!(
            v["unsafe_before_engage"],
            serde_json::json!([]),
            "{m}: {report}"
        );
        assert_eq!(v["enables_before_engage"], 0, "{m}: {report}");
        assert_eq!(
            v["commands_without_disable_before_engage"], 0,
            "{m}: {report}"
        );
        // (b) Engage: the safe command first, then the enable message, nothing else.
        assert_eq!(v["safe_command_before_enable"], true, "{m}: {report}");
        assert_eq!(
            v["unsafe_before_enable"],
            serde_json::json!([]),
            "{m}: {report}"
        );
        assert_eq!(v["enables_while_engaged"], 1, "{m}: {report}");
        assert_eq!(v["disables_while_engaged"], 0, "{m}: {report}");
        // (c) Engaged: the command resent every command_timeout (the median), never
        // much later (the worst gap, with room for a loaded machine).
        let (p50, max) = (num(v, "gap_p50_ms"), num(v, "gap_max_ms"));
        assert!(num(v, "commands_while_engaged") >= 20.0, "{m}: {report}");
        assert!(
            p50 <= COMMAND_TIMEOUT_MS + 15.0,
            "{m}: median gap {p50} ms: {report}"
        );
        assert!(
            max <= COMMAND_TIMEOUT_MS + 250.0,
            "{m}: worst gap {max} ms: {report}"
        );
        // (e) The set point on the wire.
        let values: Vec<f64> = v["values_while_engaged"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        assert!(
            values.iter().any(|x| (x - value).abs() < 1e-6),
            "{m}: {value} on the wire: {report}"
        );
        // (d) Disengage: the safe command, then the disable message; never the enable
        // message again; every command from then on safe and followed by the disable
        // message, which is the last frame the module gets.
        assert_eq!(v["disable_after_safe_command"], true, "{m}: {report}");
        assert_eq!(v["enables_after_disengage"], 0, "{m}: {report}");
        assert_eq!(
            v["unsafe_after_disable"],
            serde_json::json!([]),
            "{m}: {report}"
        );
        assert_eq!(
            v["commands_without_disable_after_disengage"], 0,
            "{m}: {report}"
        );
        assert_eq!(v["last"], "DISABLE", "{m}: {report}");
        // At exit: the safe state once more, and the disable message after it.
        let exit = &verdict["after"]["exit"][m];
        assert!(
            exit["COMMAND"].as_u64() > Some(0) && exit["DISABLE"].as_u64() > Some(0),
            "{m}: the safe state at exit: {report}"
        );
        figures.push(format!(
            "{m}: enable {} ms after the engage request, disable {} ms after the \
             disengage request; resend gap p50 {p50} ms, max {max} ms over {} commands",
            v["enable_after_engage_ms"],
            v["disable_after_disengage_ms"],
            v["commands_while_engaged"]
        ));
    }
    figures.push(format!(
        "the adapter's worst gap between two reports: {} ms",
        verdict["report_gap_max_ms"]
    ));
    println!("{}", figures.join("\n"));
}

#[test]
fn a_bus_in_error_faults_every_device_on_it_and_no_module_is_enabled_while_the_adapter_refuses() {
    let mut peer = Peer::start();
    let adrive = Adrive::start("can-peer-refuse", &peer.port);
    peer.adrive_log = adrive.log.clone();
    let watch = Watch::start(&adrive.broadcast);
    watch.until_complete("every device reporting", not_reporting);
    let planner = adrive.planner();
    send(&adrive, &planner, "engage\n", Some("engaged"));
    peer.each_module("ENABLE", &[], 1);
    send(&adrive, &planner, "brake 0\ngas 0.2\nsteer 0.3\n", None);
    let set = [("BRAKE", 0.0), ("THROTTLE", 0.2), ("STEERING", 0.3)];
    peer.each_module("COMMAND", &set, 2);

    // The bus goes into error: nothing heard, every frame refused, "bus error" flags.
    peer.mark("refuse");
    peer.say("MODE refuse");
    peer.until("the bus in error", |v| v["mode"] == "refuse");
    // Every device on the bus faulted with the adapter's words, the vehicle
    // disengaged; and so in every broadcast from then on while the adapter refuses.
    let faulted = |s: &adrive::snapshot::Snapshot| -> Vec<String> {
        let mut wrong = Vec::new();
        if s.gate.engaged {
            wrong.push("engaged".to_string());
        }
        for d in &s.devices {
            let named = s.gate.blockers.iter().any(|b| {
                b.starts_with(&format!("{} is faulty", d.name))
                    && b.contains("adapter reports bus error")
            });
            if !d.health.faulty || !named {
                wrong.push(format!("{} not faulted by the adapter", d.name));
            }
            // The supervisor names the fault, with the adapter's words.
            let supervised = s.supervisor.faults.iter().any(|f| {
                f.device.as_deref() == Some(d.name.as_str())
                    && f.cause.contains("adapter reports bus error")
            });
            if !supervised {
                wrong.push(format!("{}: no fault of the supervisor's", d.name));
            }
        }
        wrong
    };
    let first = watch.until_complete("every device faulted by the adapter", faulted);
    println!(
        "faults: {:?}; gate: {}",
        first
            .supervisor
            .faults
            .iter()
            .map(|f| f.describe())
            .collect::<Vec<_>>(),
        first.gate.reason
    );
    let mut flickers = Vec::new();
    for _ in 0..20 {
        let (s, _) = watch.until("a broadcast", |_| true);
        let wrong = faulted(&s);
        if !wrong.is_empty() {
            flickers.push(format!("seq {}: {}", s.seq, wrong.join(", ")));
        }
    }
    assert!(
        flickers.is_empty(),
        "while the adapter refuses: {flickers:#?}"
    );
    // Engage is refused while the adapter refuses, naming the devices.
    send(&adrive, &planner, "engage\n", Some("refused engage"));
    // Three more status requests answered "bus error": still faulted, still refused.
    peer.drain();
    let asked = peer.statuses;
    peer.until("three more status requests", |v| {
        v["status"].as_u64().is_some_and(|n| n >= asked + 3)
    });
    send(&adrive, &planner, "engage\n", Some("refused engage"));

    // The bus heals: the devices report again, and an engage enables the modules
    // after their safe command once more.
    peer.mark("heal");
    peer.say("MODE strict");
    peer.until("the bus healed", |v| v["mode"] == "strict");
    watch.until_complete("every device reporting again", not_reporting);
    send(&adrive, &planner, "engage\n", Some("engaged"));
    peer.each_module("ENABLE", &[], 1);
    // Two resends of the safe state engaged (adrive replies to one sender at most
    // every 20 ms).
    let safe = [("BRAKE", 1.0), ("THROTTLE", 0.0), ("STEERING", 0.0)];
    peer.each_module("COMMAND", &safe, 2);
    send(&adrive, &planner, "disengage\n", Some("disengaged"));
    peer.each_module("DISABLE", &[], 1);
    common::signal(&adrive.child, libc::SIGTERM);
    let mut child = adrive.child;
    assert_eq!(wait_exit(&mut child), Some(0), "adrive stops cleanly");
    drop(child);

    let verdict = peer.verdict();
    let report = format!("the adapter's verdict: {verdict:#}");
    assert_eq!(verdict["problems"], serde_json::json!([]), "{report}");
    assert!(
        verdict["refused"].as_u64() > Some(0),
        "frames refused: {report}"
    );
    for m in MODULES {
        let after = |mark: &str, kind: &str| verdict["after"][mark][m][kind].as_u64().unwrap();
        // While the adapter refused: the safe command and the disable message (refused
        // too), never the enable message.
        assert_eq!(
            after("refuse", "ENABLE") - after("heal", "ENABLE"),
            0,
            "{m}: {report}"
        );
        assert!(
            after("refuse", "DISABLE") > after("heal", "DISABLE"),
            "{m}: the disable message tried: {report}"
        );
        assert_eq!(after("heal", "ENABLE"), 1, "{m}: {report}");
        assert_eq!(verdict["modules"][m]["last"], "DISABLE", "{m}: {report}");
    }
}
