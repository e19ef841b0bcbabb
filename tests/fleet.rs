//! A fleet on one Zenoh network, on the real binary: the test runs a Zenoh router
//! itself (`common::zenoh_router`: on a loopback port it picks, multicast scouting
//! off, so it never meets another network), three `adrive --sim --headless
//! --fleet` vehicles join it, and `adrive fleet` lists them with their states, shows
//! one gone when it is killed, and a fourth vehicle under a taken id is refused;
//! `adrive ctl --vehicle ID` reaches that vehicle alone; a console attached over the
//! fleet with the vehicle's key drives it alone, and its process killed brakes it.
#![cfg(feature = "fleet")]

mod common;

use common::attached::Attached;
use common::headless::{Adrive, BIN};
use common::terminal_player::Play;
use common::{lines, output_within, signal, until, wait_exit, Reaped, DEADLINE};
use serde_json::Value;
use std::path::Path;
use std::process::{Command as Process, Stdio};
use std::time::{Duration, Instant};

/// A simulated Alice in the fleet at `endpoint` as `id`.
fn vehicle(id: &str, endpoint: &str) -> Adrive {
    vehicle_with(id, endpoint, "", "")
}

/// [`vehicle`], with `network` in its `[network]` and `fleet` in a `[fleet]` section.
/// Alice is made tolerant of this shared machine's stalls ([`common::tolerant_text`]):
/// consoles over the fleet hold her engaged for seconds to prove who commands her and
/// what a lost link does, not device timing.
fn vehicle_with(id: &str, endpoint: &str, network: &str, fleet: &str) -> Adrive {
    let toml = format!(
        "{}\n[fleet]\n{fleet}\n",
        common::tolerant_text(adrive::config::ALICE_TOML)
    );
    let v = Adrive::start_with(
        "fleet",
        &toml,
        network,
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
        // The health of its link: a round trip to it and back, answered.
        let rtt = v["rtt_ms"].as_f64().unwrap_or(f64::NAN);
        assert!((0.0..1000.0).contains(&rtt), "{v:#}");
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
    // A vehicle that takes no command from the fleet: watching only, and every
    // other operation is refused, with the reason, and changes nothing.
    let out = ctl(&endpoint, "car3", &["engage"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("engage: car3 takes no command from the fleet (its [fleet] command = false)"),
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

/// The gate of the vehicle `id`, asked over the fleet.
fn gate(endpoint: &str, id: &str) -> Value {
    let out = ctl(endpoint, id, &["status", "--json"]);
    assert!(out.status.success(), "{out:?}");
    let snap: Value = serde_json::from_slice(&out.stdout).unwrap();
    snap["gate"].clone()
}

/// What the vehicle `id` last commanded its device `device`, asked over the fleet.
fn commanded(endpoint: &str, id: &str, device: &str) -> Value {
    let out = ctl(endpoint, id, &["status", "--json"]);
    assert!(out.status.success(), "{out:?}");
    let snap: Value = serde_json::from_slice(&out.stdout).unwrap();
    let d = snap["devices"]
        .as_array()
        .unwrap()
        .iter()
        .find(|d| d["name"] == device)
        .unwrap_or_else(|| panic!("{device} in {snap:#}"));
    d["commanded"].clone()
}

/// `adrive attach --vehicle ID` through `endpoint`, with the key in `key` if given.
fn attach(endpoint: &str, id: &str, key: Option<&Path>) -> Attached {
    let mut cmd = Process::new(BIN);
    cmd.args(["attach", "--vehicle", id, "--connect", endpoint]);
    if let Some(k) = key {
        cmd.arg("--key").arg(k);
    }
    Attached::spawn(&mut cmd, Play::default())
}

/// Ask `gate_of` vehicle `id`'s gate until it says it is disengaged; that gate.
fn until_disengaged(id: &str, gate_of: impl Fn() -> Value) -> Value {
    let end = Instant::now() + DEADLINE;
    loop {
        let g = gate_of();
        if g["engaged"] == false {
            return g;
        }
        assert!(Instant::now() < end, "{id} still engaged: {g:#}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Three vehicles at `endpoint`: car1 and car2 take commands from the fleet with the
/// key in the file returned (in the directory returned), car3 takes none.
fn three(tag: &str, endpoint: &str) -> (tempfile::TempDir, std::path::PathBuf, Vec<Adrive>) {
    let dir = common::tempdir(tag);
    let key = dir.path().join("fleet.key");
    std::fs::write(&key, "0123456789abcdef0123456789abcdef\n").unwrap();
    let keyed = format!("key_file = \"{}\"", key.display());
    let cars = vec![
        vehicle_with("car1", endpoint, &keyed, "command = true"),
        vehicle_with("car2", endpoint, &keyed, "command = true"),
        vehicle("car3", endpoint),
    ];
    (dir, key, cars)
}

/// The issue's scene: three vehicles on one router; a console on another machine
/// (here, another process with only the router's address) attaches to car1 with its
/// key, engages it and steers it, while car2 — which takes commands from the fleet,
/// under the same key — and car3 stay untouched; killing that console brakes car1
/// (its link's token is its watchdog), and car1 only. Without the key, or with
/// another, the fleet watches and is refused with the reason.
#[test]
fn a_console_over_the_fleet_with_the_key_drives_one_vehicle_and_its_loss_brakes_it_alone() {
    let (_router, endpoint) = common::zenoh_router::start();
    let (dir, key, _cars) = three("fleet-key", &endpoint);
    let other = dir.path().join("other.key");
    std::fs::write(&other, "fedcba9876543210fedcba9876543210\n").unwrap();

    // Without the key, or with another, a link watches: its engage is refused, why.
    for (k, why) in [
        (
            None,
            "over the fleet, car1 takes commands only from a link that proves its key",
        ),
        (Some(&other), "this link's key is not car1's"),
    ] {
        let mut args = vec!["engage"];
        let kp;
        if let Some(k) = k {
            kp = k.display().to_string();
            args.extend(["--key", &kp]);
        }
        let out = ctl(&endpoint, "car1", &args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains(why), "{err}");
    }
    assert_eq!(gate(&endpoint, "car1")["engaged"], false);

    // With it, an operator's one-shot engage and stop, as on the vehicle.
    let k = key.display().to_string();
    // (Once every device is ready — reported, the OBD adapter done searching: a
    // vehicle engages no sooner.)
    let end = Instant::now() + DEADLINE;
    loop {
        let out = ctl(&endpoint, "car1", &["engage", "--key", &k]);
        if out.status.success() {
            break;
        }
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(Instant::now() < end, "{err}");
        std::thread::sleep(Duration::from_millis(200));
    }
    let g = gate(&endpoint, "car1");
    assert_eq!(g["engaged"], true, "{g:#}");
    assert!(
        g["commander"]
            .as_str()
            .unwrap()
            .starts_with("fleet operator"),
        "{g:#}"
    );
    let out = ctl(&endpoint, "car1", &["stop", "--key", &k]);
    assert!(out.status.success(), "{out:?}");
    assert_eq!(gate(&endpoint, "car1")["engaged"], false);

    // A console over the fleet with the key: engages car1 and steers it.
    let mut console = attach(&endpoint, "car1", Some(&key));
    console.engage();
    let me = gate(&endpoint, "car1")["commander"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(me.starts_with("console #"), "{me}");
    console.steer("0.5");
    common::wait_for("car1's steering at 0.5", || {
        commanded(&endpoint, "car1", "steer") == serde_json::json!(0.5)
    });
    // The others heard nothing of it.
    for id in ["car2", "car3"] {
        let g = gate(&endpoint, id);
        assert_eq!(g["engaged"], false, "{id}: {g:#}");
        assert!(g["commander"].is_null(), "{id}: {g:#}");
        assert_ne!(
            commanded(&endpoint, id, "steer"),
            serde_json::json!(0.5),
            "{id}"
        );
    }

    // The console's process killed (no goodbye): car1 brakes and disengages, its
    // link's loss the commander's watchdog; the others are as they were.
    let killed = Instant::now();
    assert!(signal(&console.child, libc::SIGKILL));
    let _ = wait_exit(&mut console.child);
    let g = until_disengaged("car1", || gate(&endpoint, "car1"));
    let took = killed.elapsed();
    let reason = g["reason"].as_str().unwrap();
    assert!(
        reason.contains(&format!(
            "{me} lost its link over the fleet (its token was withdrawn"
        )),
        "{reason}"
    );
    assert_eq!(g["cause"]["why"]["trip"], "gone", "{g:#}");
    assert_eq!(
        commanded(&endpoint, "car1", "brake"),
        serde_json::json!(1.0)
    );
    assert_eq!(commanded(&endpoint, "car1", "gas"), serde_json::json!(0.0));
    eprintln!("car1 disengaged {took:?} after its console was killed");
    for id in ["car2", "car3"] {
        let g = gate(&endpoint, id);
        assert_eq!(g["reason"], "not engaged yet", "{id}: {g:#}");
    }
}

/// `adrive fleet --router` listening on `endpoint`, a process of its own (killed on
/// drop), once it says it listens.
fn router_process(endpoint: &str) -> Reaped {
    let mut child = Process::new(BIN)
        .args(["fleet", "--router", "--listen", endpoint])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let err = lines(child.stderr.take().unwrap());
    let said = until(&err, "listens on");
    assert!(said.last().unwrap().contains(endpoint), "{said:?}");
    Reaped(child)
}

/// The status of `v`, asked at its own control socket (on the vehicle: the fleet may
/// be down).
fn local_gate(v: &Adrive) -> Value {
    let out = output_within(
        Process::new(BIN)
            .args(["ctl", "status", "--json"])
            .env("XDG_RUNTIME_DIR", v.dir.path()),
    );
    assert!(out.status.success(), "{out:?}");
    let snap: Value = serde_json::from_slice(&out.stdout).unwrap();
    snap["gate"].clone()
}

/// The router (`adrive fleet --router`) crashes under an engaged vehicle commanded
/// from the fleet: the vehicle
/// loses the console's link with the router, and the console was its watchdog — the
/// safe state, at once; the other vehicle is untouched. The router back on its
/// address, every vehicle rejoins (Zenoh's client retries its router) and is listed
/// again, within a bound; the vehicle commanded before stays disengaged (nothing
/// engages it again on its own).
#[test]
fn the_router_gone_cuts_a_fleet_commander_off_into_the_safe_state_and_back_every_vehicle_rejoins() {
    // The router: adrive's own, a process that can crash.
    let endpoint = common::zenoh_router::free_endpoint();
    let mut router = router_process(&endpoint);
    let dir = common::tempdir("fleet-router");
    let key = dir.path().join("fleet.key");
    std::fs::write(&key, "0123456789abcdef0123456789abcdef\n").unwrap();
    let keyed = format!("key_file = \"{}\"", key.display());
    let car1 = vehicle_with("car1", &endpoint, &keyed, "command = true");
    let car2 = vehicle("car2", &endpoint);

    let mut console = attach(&endpoint, "car1", Some(&key));
    console.engage();
    assert_eq!(local_gate(&car1)["engaged"], true);

    // The router crashes (SIGKILL: no goodbye to anyone).
    let cut = Instant::now();
    assert!(signal(&router.0, libc::SIGKILL));
    router.0.wait().unwrap();
    let g = until_disengaged("car1", || local_gate(&car1));
    let took = cut.elapsed();
    let reason = g["reason"].as_str().unwrap();
    assert!(reason.contains("lost its link over the fleet"), "{reason}");
    assert_eq!(g["cause"]["why"]["trip"], "gone", "{g:#}");
    assert_eq!(local_gate(&car2)["reason"], "not engaged yet");
    eprintln!("car1 in the safe state {took:?} after its router went");

    // Back: both vehicles listed again.
    let _router = router_process(&endpoint);
    let back = Instant::now();
    let end = back + DEADLINE;
    loop {
        let list = fleet(&endpoint, "500ms");
        let live: Vec<&str> = list
            .iter()
            .filter(|v| v["status"] == "live")
            .map(|v| v["id"].as_str().unwrap())
            .collect();
        if live == ["car1", "car2"] {
            break;
        }
        assert!(Instant::now() < end, "{list:#?}");
    }
    eprintln!(
        "every vehicle listed again {:?} after the router came back",
        back.elapsed()
    );
    assert_eq!(local_gate(&car1)["engaged"], false);
    assert_eq!(gate(&endpoint, "car1")["engaged"], false);
}

/// `adrive fleet --pick`: the fleet in the console, live; the operator picks car2,
/// the console attaches to it over the fleet with the key and engages it (car1 and car3
/// untouched); quitting that console disengages car2 (a commander gone) and comes back
/// to the list, which says so; `q` leaves.
#[test]
fn the_fleet_in_the_console_picks_a_vehicle_attaches_to_it_and_comes_back() {
    let (_router, endpoint) = common::zenoh_router::start();
    let (_dir, key, _cars) = three("fleet-pick", &endpoint);

    let mut cmd = Process::new(BIN);
    cmd.args(["fleet", "--pick", "--connect", &endpoint])
        .arg("--key")
        .arg(&key);
    let mut c = Attached::open(&mut cmd, Play::default());
    let wait = |c: &Attached, what: &str, ok: &dyn Fn(&str) -> bool| c.wait_for(what, ok);
    let row = |s: &str, id: &str| -> Option<String> {
        s.lines()
            .find(|l| l.contains(&format!("│{id} ")))
            .map(str::to_string)
    };
    let listed = |s: &str| {
        ["car1", "car2", "car3"]
            .iter()
            .all(|id| row(s, id).is_some_and(|r| r.contains("live") && r.contains(" ms")))
    };
    let s = wait(
        &c,
        "the three vehicles, live, with their round trips",
        &listed,
    );
    assert!(s.contains("3 vehicles through"), "{s}");
    assert!(s.contains("commanding where a vehicle allows it"), "{s}");

    // The second row, and Enter: the console, on car2.
    c.keys("j\r");
    c.wait_devices();
    c.engage();
    let g = gate(&endpoint, "car2");
    assert_eq!(g["engaged"], true, "{g:#}");
    assert!(
        g["commander"].as_str().unwrap().starts_with("console #"),
        "{g:#}"
    );
    for id in ["car1", "car3"] {
        assert_eq!(gate(&endpoint, id)["engaged"], false, "{id}");
    }

    // Quit the console: back to the list; car2 in the safe state, its commander gone.
    c.keys("q");
    let s = wait(&c, "the list again", &|s: &str| {
        s.contains("left car2") && listed(s)
    });
    let g = until_disengaged("car2", || gate(&endpoint, "car2"));
    assert!(
        g["reason"].as_str().unwrap().contains("went away"),
        "{g:#}\n{s}"
    );
    c.keys("q");
    assert_eq!(c.wait_exit(), Some(0));
}

/// A vehicle that would take commands from the fleet without a key to prove is
/// refused before it starts, at the line that asks for it.
#[test]
fn a_vehicle_commanded_from_the_fleet_without_a_key_is_refused_at_its_line() {
    let dir = common::tempdir("fleet-nokey");
    let file = dir.path().join("v.toml");
    let text = format!("{}\n[fleet]\ncommand = true\n", adrive::config::ALICE_TOML);
    let line = text.lines().count();
    std::fs::write(&file, &text).unwrap();
    let out = output_within(
        Process::new(BIN)
            .args(["--sim", "--headless", "--listen", "127.0.0.1:0", "--config"])
            .arg(&file)
            .arg("--log-dir")
            .arg(dir.path().join("log"))
            .env("XDG_RUNTIME_DIR", dir.path()),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains(&format!(
            "v.toml:{line}: [fleet] command: a vehicle commanded from the fleet needs its key"
        )),
        "{err}"
    );
    assert!(!err.contains("running headless"), "{err}");
}
