//! The network clients as a user runs them, against the real `adrive --sim
//! --headless`: the guide's planner stand-in (docs/network.md) (`adrive send --rate 20 …`) engages,
//! shifts and drives while `adrive watch` shows it, and the watchdog stops the vehicle
//! when the sender stops; one-shot `send`, its replies and exit status; `--key`.

mod common;

use adrive::config::ALICE_TOML;
use adrive::snapshot::{Snapshot, WatchdogState};
use adrive::value::Value;
use common::headless::{Adrive, Watch, BIN};
use common::{free_port, lines, signal, tempdir, DEADLINE};
use std::net::UdpSocket;
use std::process::{Command as Process, Stdio};
use std::time::{Duration, Instant};

/// A device's reading, as a number (NaN when missing).
fn f(v: &Snapshot, device: &str, reading: &str) -> f64 {
    v.device(device)
        .and_then(|d| d.number(reading))
        .unwrap_or(f64::NAN)
}

/// A device's command (pending or last sent), or what it acknowledged.
fn cmd(v: &Snapshot, device: &str, executed: bool) -> Option<Value> {
    let d = v.device(device)?;
    if executed {
        d.executed.clone()
    } else {
        d.commanded.clone()
    }
}

fn watchdog(v: &Snapshot) -> WatchdogState {
    v.gate.watchdog.as_ref().expect("the watchdog").state
}

/// The planner stand-in of docs/network.md: a planner stand-in engages, shifts to drive and holds gas
/// at 0.3; `watch` shows gas at 0.3 and the speed rising; the sender stops and the
/// watchdog brings the vehicle to a safe stop within its timeout.
#[test]
fn the_readme_planner_stand_in_drives_and_the_watchdog_stops_it() {
    // Held engaged for seconds to prove the network watchdog, not device timing: on
    // the tolerant Alice.
    let adrive = Adrive::start(
        "planner",
        &common::tolerant_text(ALICE_TOML),
        "watchdog_timeout = \"500ms\"",
    );
    let watch = Watch::start(&adrive.broadcast);
    watch.until("every device reporting", |v| v.gate.blockers.is_empty());
    let mut sender = common::Reaped(
        Process::new(BIN)
            .args(["send", "--to", &adrive.listen, "--rate", "20"])
            .args(["engage", "trans", "drive", "accel", "0.3"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let replies = lines(sender.stdout.take().unwrap());
    let (v, _) = watch.until("gas at 0.3 in drive", |v| {
        v.gate.engaged
            && v.device("trans").and_then(|d| d.reading("state").cloned())
                == Some(Value::Text("drive".into()))
            && cmd(v, "gas", false) == Some(Value::Number(0.3))
            && f(v, "gas", "position") > 0.28
    });
    assert_eq!(watchdog(&v), WatchdogState::Armed);
    let speed = |v: &Snapshot| f(v, "obd", "speed");
    let s0 = speed(&v);
    let (v, _) = watch.until("the speed rising", |v| speed(v) > s0 + 0.5);
    assert_eq!(cmd(&v, "brake", false), Some(Value::Number(0.0)));
    let first = replies.recv_timeout(DEADLINE).unwrap();
    assert!(first.ends_with("ok engaged"), "{first}");

    // Stop the planner: the watchdog commands the safe state and disengages.
    signal(&sender, libc::SIGINT);
    let stopped = Instant::now();
    assert!(sender.wait().unwrap().success());
    let (v, at) = watch.until("the watchdog to trip", |v| !v.gate.engaged);
    let after = at - stopped;
    // 500 ms timeout, plus the last datagram's period, a broadcast period and slack.
    assert!(
        after < Duration::from_millis(500 + 50 + 100 + 400),
        "{after:?}"
    );
    assert_eq!(watchdog(&v), WatchdogState::Tripped);
    let gate = &v.gate.reason;
    assert!(
        gate.starts_with("disengaged: watchdog: no valid command"),
        "{gate}"
    );
    watch.until("gas 0 and brake full at the devices", |v| {
        cmd(v, "gas", true) == Some(Value::Number(0.0))
            && cmd(v, "brake", true) == Some(Value::Number(1.0))
            && f(v, "brake", "position") > 0.9
    });
    watch.until("a standstill", |v| speed(v) < 0.05);
}

#[test]
fn send_once_prints_the_reply_and_its_status_says_whether_it_was_refused() {
    let adrive = Adrive::start("once", ALICE_TOML, "");
    let out = adrive.send(&["steer", "0.2"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("rejected steer 0.2: disengaged"),
        "{stdout}"
    );
    assert_eq!(out.status.code(), Some(1));

    // A line of the wrong shape is caught before sending (status 2); a device the
    // vehicle does not have comes back in adrive's reply (status 1).
    let out = adrive.send(&["steer"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("bad_syntax"), "{stderr}");
    let out = adrive.send(&["stear 0.2"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{stdout}");
    assert!(
        stdout.contains("unknown_device: the devices are steer, gas, brake and trans"),
        "{stdout}"
    );

    let nobody = format!("127.0.0.1:{}", free_port());
    let out = Process::new(BIN)
        .args(["send", "--to", &nobody, "engage"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("nothing is listening"));
}

/// A stream's status is its last reply's: refused to the end (a disengaged vehicle)
/// is status 1, with the refusals counted; an `accel` refused while the gearbox
/// shifts, outlived by the stream, is counted and is not its outcome (status 0), as
/// the guide's planner stand-in is run.
#[test]
fn a_stream_s_status_is_whether_it_was_still_refused_at_its_end() {
    // Held engaged for seconds: on the tolerant Alice.
    let adrive = Adrive::start("stream", &common::tolerant_text(ALICE_TOML), "");
    let watch = Watch::start(&adrive.broadcast);
    watch.until("every device reporting", |v| v.gate.blockers.is_empty());
    // At 10 a second each datagram is answered, and a refusal ends the stream's last
    // 300 ms: 200 ms for a loaded machine to answer late.
    let out = adrive.send(&["--rate", "10", "--count", "5", "steer", "0.2"]);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(
        stdout.contains("rejected steer 0.2: disengaged"),
        "{stdout}"
    );
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains(" refused"), "{stderr}");

    let out = adrive.send(&[
        "--rate", "20", "--count", "60", "engage", "trans", "drive", "accel", "0.3",
    ]);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(stdout.contains("accel_while_shifting"), "{stdout}");
    assert!(stderr.contains(" refused"), "{stderr}");
    assert_eq!(out.status.code(), Some(0), "{stdout}\n{stderr}");
    // Its accel was carried once the shift was through (adrive answers that with
    // nothing).
    watch.until("gas at 0.3 in drive", |v| {
        cmd(v, "gas", true) == Some(Value::Number(0.3))
    });
}

#[test]
fn send_with_a_key_signs_and_unsigned_datagrams_are_rejected() {
    let dir = tempdir("keyfile");
    let key = dir.path().join("adrive.key");
    std::fs::write(&key, "correct horse battery staple\n").unwrap();
    let adrive = Adrive::start(
        "key",
        ALICE_TOML,
        &format!("key_file = \"{}\"", key.display()),
    );
    let out = adrive.send(&["engage"]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("missing_tag"));
    assert_eq!(out.status.code(), Some(1));
    // Refused (with the reasons) until every device has reported.
    let end = Instant::now() + DEADLINE;
    loop {
        let out = adrive.send(&["--key", key.to_str().unwrap(), "engage"]);
        let stdout = String::from_utf8_lossy(&out.stdout);
        if stdout == "ok engaged\n" {
            assert_eq!(out.status.code(), Some(0));
            break;
        }
        assert!(
            stdout.contains("has not reported yet")
                || stdout.contains("obd: the adapter is searching the car's protocols"),
            "{stdout}"
        );
        assert!(Instant::now() < end, "{stdout}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_missing_key_file_or_a_busy_port_stops_adrive_before_it_starts() {
    let dir = tempdir("nokey");
    let path = dir.path().join("v.toml");
    std::fs::write(
        &path,
        "[vehicle]\nname = \"x\"\n\n[network]\nkey_file = \"missing.key\"\n",
    )
    .unwrap();
    let out = Process::new(BIN)
        .args(["--headless", "--config"])
        .arg(&path)
        .arg("--log-dir")
        .arg(dir.path().join("log"))
        .env("XDG_RUNTIME_DIR", dir.path().join("log"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("missing.key"), "{err}");

    let busy = UdpSocket::bind("127.0.0.1:0").unwrap();
    let out = Process::new(BIN)
        .args(["--sim", "--headless", "--listen"])
        .arg(busy.local_addr().unwrap().to_string())
        .arg("--log-dir")
        .arg(dir.path().join("log"))
        .env("XDG_RUNTIME_DIR", dir.path().join("log"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("listen on"), "{err}");
}

/// The incident: `adrive send engage` to an adrive that drops the datagram (this sender
/// not on its allow list) or does not answer (`replies = false`) printed nothing and
/// exited 0, like a success. Now it says so and exits 3, once or at a rate — naming
/// what got no reply (a `release` was said to be an engage or disengage).
#[test]
fn send_says_when_an_engage_got_no_reply_and_exits_3() {
    for network in ["allow = [\"10.9.9.9\"]", "replies = false"] {
        let adrive = Adrive::start("noreply", ALICE_TOML, network);
        for (args, what) in [
            (&["engage"][..], "the engage may not have been applied"),
            (
                &["--rate", "50", "--count", "75", "engage"],
                "the engage may not",
            ),
            (&["release"], "the release may not have been applied"),
            (&["clear"], "the clear may not have been applied"),
        ] {
            let out = adrive.send(args);
            let err = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(3), "{network} {args:?}: {err}");
            assert!(
                err.contains(&format!("no reply from {}", adrive.listen)) && err.contains(what),
                "{network} {args:?}: {err}"
            );
            assert!(out.stdout.is_empty(), "{network} {args:?}");
        }
    }
}

/// The incident: `adrive send --rate 20 steer 0.1` to an address where nothing listens
/// exited 0 (3 with `engage`), while one-shot `send` exits 1 as docs/network.md says. Once
/// or at a rate, nothing listening is status 1, and it is said.
/// A sender at a rate whose adrive stops said "nothing is listening (yet)", as if it
/// had never been there. It says what it knows: adrive replied before and nothing
/// listens any more.
#[test]
fn a_sender_whose_adrive_stops_says_it_replied_before() {
    let mut adrive = Adrive::start("send-gone", ALICE_TOML, "");
    let mut sender = common::Reaped(
        Process::new(BIN)
            .args(["send", "--to", &adrive.listen, "--rate", "50", "disengage"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let replies = lines(sender.stdout.take().unwrap());
    let said = lines(sender.stderr.take().unwrap());
    common::until(&replies, "ok");
    signal(&adrive.child, libc::SIGTERM);
    common::wait_exit(&mut adrive.child);
    let seen = common::until(&said, "nothing is listening");
    let last = seen.last().unwrap();
    assert!(
        last.contains(&format!(
            "nothing is listening at {} any more (it replied before)",
            adrive.listen
        )),
        "{seen:?}"
    );
    signal(&sender, libc::SIGINT);
}

#[test]
fn send_to_nothing_listening_exits_1_once_or_at_a_rate() {
    // Nothing listens on a port just freed.
    let to = format!("127.0.0.1:{}", free_port());
    for args in [
        &["steer", "0.1"][..],
        &["--rate", "50", "--count", "10", "steer", "0.1"],
        &["--rate", "50", "--count", "60", "engage"],
    ] {
        let out = Process::new(BIN)
            .args(["send", "--to", &to])
            .args(args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains(&format!("nothing is listening at {to}")),
            "{args:?}: {err}"
        );
        assert!(!err.contains("no reply"), "{args:?}: {err}");
    }
    let help = Process::new(BIN).args(["send", "--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&help.stdout);
    assert!(
        help.contains("1 something refused, or nothing listening"),
        "{help}"
    );
}

/// The incident: on a disengaged vehicle `adrive send disengage` answered "ok
/// disengaged" and `adrive ctl disengage` "the vehicle was not engaged". Every front end
/// gives the one answer of what the intake did (the network after `ok `).
#[test]
fn disengage_gets_the_same_answer_from_the_network_and_from_ctl() {
    let adrive = Adrive::start("one-answer", ALICE_TOML, "");
    let socket = adrive.dir.path().join("adrive/adrive.sock");
    let ctl = |what: &str| {
        let out = Process::new(BIN)
            .args(["ctl", what, "--socket"])
            .arg(&socket)
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
        )
    };
    let net = |what: &str| String::from_utf8_lossy(&adrive.send(&[what]).stdout).into_owned();
    assert_eq!(net("disengage"), "ok already disengaged\n");
    assert_eq!(ctl("disengage"), (Some(0), "already disengaged\n".into()));
    common::wait_for("ctl engage to be accepted", || ctl("engage").0 == Some(0));
    assert_eq!(net("disengage"), "ok disengaged\n");
    common::wait_for("ctl engage to be accepted", || ctl("engage").0 == Some(0));
    assert_eq!(ctl("disengage"), (Some(0), "disengaged\n".into()));
}

/// The incident: `--to localhost:47576` and `--listen localhost:…` were refused as
/// "invalid socket address syntax", and `watch --from` an address of another host said
/// only "os error 99". Every flag that takes an address takes a host name, and a bind
/// that cannot happen says what the flag is for.
#[test]
fn address_flags_take_host_names_and_say_what_they_are_for() {
    let adrive = Adrive::start("host-names", ALICE_TOML, "");
    let port = adrive.listen.rsplit_once(':').unwrap().1.to_string();
    let to = format!("localhost:{port}");
    let out = Process::new(BIN)
        .args(["send", "--to", &to, "disengage"])
        .output()
        .unwrap();
    assert_eq!(
        String::from_utf8_lossy(&out.stdout),
        "ok already disengaged\n"
    );
    // Options after the commands, as `adrive send NAME VALUE --to ADDR`.
    let out = Process::new(BIN)
        .args(["send", "disengage", "--to", &to])
        .output()
        .unwrap();
    assert_eq!(
        String::from_utf8_lossy(&out.stdout),
        "ok already disengaged\n",
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // A headless adrive listening on a host name.
    let dir = tempdir("listen-host");
    let (mut child, seen, _) = common::headless_sim(
        dir.path(),
        &[
            "--listen",
            "localhost:0",
            "--broadcast-to",
            &format!("localhost:{}", free_port()),
        ],
    );
    assert!(
        seen.iter()
            .any(|l| l.contains("network up listen=127.0.0.1:")),
        "{seen:#?}"
    );
    signal(&child, libc::SIGTERM);
    assert_eq!(common::wait_exit(&mut child), Some(0));

    // Not an address of this host (TEST-NET-1): what --from is.
    let out = Process::new(BIN)
        .args(["watch", "--from", "192.0.2.1:47577"])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{e}");
    assert!(
        e.contains("--from 192.0.2.1:47577: 192.0.2.1 is not an address of this host; --from is where the broadcast is sent to"),
        "{e}"
    );
    assert!(!e.contains("os error"), "{e}");
    let out = Process::new(BIN)
        .args(["send", "--to", "no-such-host.invalid:1", "disengage"])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{e}");
    assert!(e.contains("\"no-such-host.invalid\": no such host"), "{e}");
}
