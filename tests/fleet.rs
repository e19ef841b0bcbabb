//! A fleet on one Zenoh network, on the real binary: the test runs a Zenoh router
//! itself (`common::zenoh_router`: on a loopback port it picks, multicast scouting
//! off, so it never meets another network), three `adrive --sim --headless
//! --fleet` vehicles join it, and `adrive fleet` lists them with their states, shows
//! one gone when it is killed, and a fourth vehicle under a taken id is refused;
//! `adrive ctl --vehicle ID status` reaches that vehicle alone, and nothing else.
#![cfg(feature = "fleet")]

mod common;

use common::headless::{Adrive, BIN};
use common::{lines, output_within, signal, until, Reaped};
use serde_json::Value;
use std::process::{Command as Process, Stdio};

/// A simulated Alice in the fleet at `endpoint` as `id`.
fn vehicle(id: &str, endpoint: &str) -> Adrive {
    let v = Adrive::start_with(
        "fleet",
        adrive::config::ALICE_TOML,
        "",
        &["--fleet", id, "--fleet-connect", endpoint],
    );
    assert!(
        v.startup
            .iter()
            .any(|l| l.contains(&format!("fleet up: adrive/{id}"))),
        "{id} joined the fleet: {:?}",
        v.startup
    );
    v
}

/// `adrive fleet --json` through `endpoint` after listening for `wait`.
fn fleet(endpoint: &str, wait: &str) -> Vec<Value> {
    let out = output_within(Process::new(BIN).args([
        "fleet",
        "--json",
        "--connect",
        endpoint,
        "--wait",
        wait,
    ]));
    assert!(out.status.success(), "{out:?}");
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stdout)))
}

/// `adrive ctl --vehicle ID ARGS` through `endpoint`.
fn ctl(endpoint: &str, id: &str, args: &[&str]) -> std::process::Output {
    output_within(
        Process::new(BIN)
            .args(["ctl", "--vehicle", id, "--connect", endpoint])
            .args(args),
    )
}

#[test]
fn the_fleet_lists_every_vehicle_ctl_asks_one_alone_and_one_killed_goes() {
    let (_router, endpoint) = common::zenoh_router::start();
    let mut cars: Vec<(String, Adrive)> = ["car1", "car2", "car3"]
        .iter()
        .map(|id| (id.to_string(), vehicle(id, &endpoint)))
        .collect();

    // Once: all three, each with its state.
    let list = fleet(&endpoint, "3s");
    let ids: Vec<&str> = list.iter().map(|v| v["id"].as_str().unwrap()).collect();
    assert_eq!(ids, ["car1", "car2", "car3"], "{list:#?}");
    for v in &list {
        assert_eq!(v["status"], "live", "{v:#}");
        let state = &v["state"];
        assert_eq!(state["vehicle"], "Alice", "{v:#}");
        assert_eq!(state["gate"]["engaged"], false, "{v:#}");
        assert_eq!(state["gate"]["reason"], "not engaged yet", "{v:#}");
        assert!(state["gate"]["commander"].is_null(), "{v:#}");
        assert!(state["supervisor"]["faults"].is_array(), "{v:#}");
        // Compact: the snapshot's head, without the devices.
        assert_eq!(state["devices"], Value::Array(vec![]), "{v:#}");
        let age = v["state_age_ms"].as_f64().unwrap();
        assert!((0.0..3000.0).contains(&age), "{v:#}");
    }

    // One vehicle's whole status, asked by its id: its own, no other's.
    for (id, car) in [&cars[0], &cars[2]] {
        let out = ctl(&endpoint, id, &["status", "--json"]);
        assert!(out.status.success(), "{out:?}");
        let snap: Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(snap["vehicle"], "Alice");
        assert_eq!(
            snap["devices"].as_array().map(Vec::len),
            Some(6),
            "{snap:#}"
        );
        assert_eq!(
            snap["net"]["listen"].as_str(),
            Some(car.listen.as_str()),
            "{id}"
        );
    }
    // Watching only: any other operation is refused, with the reason, and changes
    // nothing.
    let out = ctl(&endpoint, "car3", &["engage"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("engage: over the fleet a vehicle answers status only"),
        "{err}"
    );
    let out = ctl(&endpoint, "car9", &["status"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("no vehicle car9 on the fleet's network"),
        "{err}"
    );

    // Watching: the three come, then the one killed goes, and only it.
    let mut watch = Process::new(BIN)
        .args(["fleet", "--watch", "--json", "--connect", &endpoint])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let rx = lines(watch.stdout.take().unwrap());
    let watch = Reaped(watch);
    let mut seen = Vec::new();
    for id in ["car1", "car2", "car3"] {
        if !seen
            .iter()
            .any(|l: &String| l.contains(&format!("\"event\":\"state\",\"id\":\"{id}\"")))
        {
            seen.extend(until(&rx, &format!("\"event\":\"state\",\"id\":\"{id}\"")));
        }
    }
    let (_, car2) = cars.remove(1);
    let mut car2 = car2;
    // SIGKILL: no goodbye; the router sees its session end.
    assert!(signal(&car2.child, libc::SIGKILL));
    car2.child.wait().unwrap();
    // Its simulator's directory of port links is left behind (nothing runs after
    // SIGKILL): the test's to remove.
    let killed = format!("adrive-sim-{}-", car2.child.id());
    for left in common::sim_dirs(&std::env::temp_dir()) {
        if left.starts_with(&killed) {
            std::fs::remove_dir_all(std::env::temp_dir().join(left)).unwrap();
        }
    }
    let after = until(&rx, "\"event\":\"gone\"");
    let gone: Value = serde_json::from_str(after.last().unwrap()).unwrap();
    assert_eq!(
        (gone["id"].as_str(), gone["status"].as_str()),
        (Some("car2"), Some("gone")),
        "{after:?}"
    );
    drop(watch);

    // Once again: the two left, live.
    let list = fleet(&endpoint, "2s");
    let ids: Vec<&str> = list.iter().map(|v| v["id"].as_str().unwrap()).collect();
    assert_eq!(ids, ["car1", "car3"], "{list:#?}");
    assert_eq!(list[1]["state"]["gate"]["engaged"], false, "{list:#?}");
}

#[test]
fn a_vehicle_under_a_taken_id_is_refused_before_it_starts() {
    let (_router, endpoint) = common::zenoh_router::start();
    let _car1 = vehicle("car1", &endpoint);
    let dir = common::tempdir("fleet-taken");
    let out = output_within(
        Process::new(BIN)
            .args(["--sim", "--headless", "--listen", "127.0.0.1:0"])
            .args(["--fleet", "car1", "--fleet-connect", &endpoint])
            .arg("--log-dir")
            .arg(dir.path().join("log"))
            .env("XDG_RUNTIME_DIR", dir.path()),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains(
            "fleet: the id car1 is taken: another vehicle on the network announces adrive/car1"
        ),
        "{err}"
    );
    assert!(!err.contains("running headless"), "{err}");
}
