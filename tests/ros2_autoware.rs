//! adrive as an Autoware vehicle interface, driven by a third party: a Python ROS 2
//! peer (Eclipse Zenoh's Python API with rosbags, knowing only the message definitions
//! and rmw_zenoh's conventions) against the real `adrive --sim --headless --ros2`.
//! Every endpoint is on loopback on a free port, multicast scouting off, so the tests
//! never meet a running adrive or each other.
#![cfg(feature = "ros2")]

mod common;
#[path = "support/ros2_env.rs"]
mod ros2_env;

use common::{lines, tempdir, Reaped, DEADLINE};
use std::process::{Command as Process, Stdio};
use std::sync::mpsc::Receiver;
use std::time::Instant;
use tempfile::TempDir;

const BIN: &str = env!("CARGO_BIN_EXE_adrive");

/// A TCP port free on loopback right now (Zenoh listens on TCP).
fn free_tcp_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A headless simulated Alice with ROS 2 on, under `namespace`, listening for Zenoh
/// peers on its own loopback port.
struct Vehicle {
    child: Reaped,
    endpoint: String,
    log: Receiver<String>,
    /// Standard output: the summary at exit.
    out: Receiver<String>,
    _dir: TempDir,
}

impl Vehicle {
    fn start(namespace: &str) -> Vehicle {
        let dir = tempdir("ros2");
        let endpoint = format!("tcp/127.0.0.1:{}", free_tcp_port());
        let alice = adrive::config::ALICE_TOML;
        assert!(
            alice.contains("[ros2]\n"),
            "the built-in Alice has a [ros2] table"
        );
        let config = alice.replace(
            "[ros2]\n",
            &format!(
                "[ros2]\nnamespace = \"{namespace}\"\nconnect = []\nlisten = [\"{endpoint}\"]\nmulticast_scouting = false\n"
            ),
        );
        let path = dir.path().join("alice.toml");
        std::fs::write(&path, config).unwrap();
        let mut child = Process::new(BIN)
            .args([
                "--sim",
                "--headless",
                "--ros2",
                "--listen",
                "127.0.0.1:0",
                "--config",
            ])
            .arg(&path)
            .arg("--log-dir")
            .arg(dir.path().join("log"))
            .env("XDG_RUNTIME_DIR", dir.path().join("log"))
            .env("RUST_LOG", "adrive=info")
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("adrive starts");
        let log = lines(child.stderr.take().unwrap());
        let out = lines(child.stdout.take().unwrap());
        let child = Reaped(child);
        let mut v = Vehicle {
            child,
            endpoint,
            log,
            out,
            _dir: dir,
        };
        v.until("ros2 up");
        v
    }

    /// Read adrive's log until a line contains `pattern`; every line read.
    fn until(&mut self, pattern: &str) -> Vec<String> {
        common::until(&self.log, pattern)
    }
}

/// Alice's radians of tire angle per unit of steering, as the peer expects them in
/// her steering report.
fn tire_angle_per_unit() -> String {
    adrive::config::VehicleConfig::alice()
        .ros2
        .tire_angle_per_unit
        .to_string()
}

/// Run the peer to its end; its output, asserting it passed.
fn peer(args: &[&str]) -> String {
    let mut child = Process::new(ros2_env::python())
        .arg(ros2_env::PEER)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start the ROS 2 peer");
    let out = lines(child.stdout.take().unwrap());
    let err = lines(child.stderr.take().unwrap());
    let mut child = Reaped(child);
    let end = Instant::now() + 4 * DEADLINE;
    let mut seen = Vec::new();
    while let Ok(l) = out.recv_timeout(end.saturating_duration_since(Instant::now())) {
        seen.push(l);
    }
    let status = child.wait().unwrap();
    let stderr: Vec<String> = err.try_iter().collect();
    let text = seen.join("\n");
    assert!(
        status.success() && seen.last().is_some_and(|l| l == "PASS"),
        "the peer did not pass ({status}):\n{text}\n{}",
        stderr.join("\n")
    );
    text
}

#[test]
fn a_zenoh_peer_drives_alice_through_autoware_topics_and_silence_emergency_and_a_stale_stream_stop_her(
) {
    let mut alice = Vehicle::start("/alice");
    let text = peer(&["drive", &alice.endpoint, "/alice", &tire_angle_per_unit()]);
    for step in [
        "ok engaged /alice",
        "ok moving",
        "ok diagnostics of every device",
        "ok stopped",
        "ok disengaged by the emergency",
        "ok stopped again",
        "ok disengaged on the stale stream",
        "ok stopped a third time",
    ] {
        assert!(text.contains(step), "{step}:\n{text}");
    }
    // It was the network watchdog that stopped her, on the ROS 2 stream's silence,
    // then the emergency command.
    let log = alice.until("; safe state commanded");
    assert!(
        log.last()
            .unwrap()
            .contains("watchdog: no valid command from ros2"),
        "{}",
        log.join("\n")
    );
    alice.until("ros2: emergency command: safe state");
    alice.until("watchdog: the rolling counter of ros2 stopped advancing");
    // She stops cleanly, ROS 2 node and all; the summary counts the ROS 2 stream's
    // refusals by reason, as the NETWORK panel does: the command sent before engaging,
    // the repeats of the stale stream.
    common::signal(&alice.child, libc::SIGTERM);
    assert_eq!(common::wait_exit(&mut alice.child), Some(0));
    let out = common::until(&alice.out, "network ");
    let summary = out.last().unwrap();
    let (datagrams, commands) = summary.split_once("; commands refused: ").unwrap();
    assert!(
        datagrams.contains(", refused whole: ")
            && datagrams.contains("replayed ")
            && commands.contains("disengaged ")
            && commands.contains("watchdog tripped: the rolling counter of ros2 stopped advancing"),
        "{summary}"
    );
}

#[test]
fn two_adrives_with_different_namespaces_never_cross_talk_and_watch_sees_both() {
    let mut a = Vehicle::start("/fleet/a");
    let mut b = Vehicle::start("/fleet/b");
    // adrive watch --ros2, connected to both, lists both and follows b.
    let watch = Process::new(BIN)
        .args([
            "watch",
            "--ros2",
            "--connect",
            &a.endpoint,
            "--connect",
            &b.endpoint,
            "--namespace",
            "/fleet/b",
            "--count",
            "200",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("adrive watch starts");
    let mut watch = Reaped(watch);
    let watched = lines(watch.stdout.take().unwrap());

    let tire = tire_angle_per_unit();
    let text = peer(&[
        "two",
        &a.endpoint,
        "/fleet/a",
        &b.endpoint,
        "/fleet/b",
        &tire,
    ]);
    assert!(text.contains("ok engaged /fleet/b"), "{text}");
    // b was engaged and driven; a never was: its log never says so.
    let b_log = b.until("engaged by=\"ros2\"");
    assert!(!b_log.is_empty());
    common::signal(&a.child, libc::SIGTERM);
    assert_eq!(common::wait_exit(&mut a.child), Some(0));
    // Everything a logged, up to its last word on stopping.
    let a_log = a.until("safe state acknowledged");
    assert!(
        !a_log
            .iter()
            .any(|l| l.contains("engaged by") || l.contains("rejected")),
        "commands reached /fleet/a:\n{}",
        a_log.join("\n")
    );

    let seen = common::until(&watched, "AUTONOMOUS");
    let all = seen.join("\n");
    assert!(all.contains("vehicle /fleet/a"), "{all}");
    assert!(all.contains("vehicle /fleet/b"), "{all}");
    assert!(all.contains("following /fleet/b"), "{all}");
    assert!(!all.contains("following /fleet/a"), "{all}");
}
