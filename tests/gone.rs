//! A device gone never ends the run: the real binary on the utility cart, its ports
//! `adrive sim`'s, some of them absent at the start (a path that appears later, as a
//! `/dev/serial/by-id/…` link does when the adapter is plugged in) or vanishing for
//! longer than the old give-up time. adrive keeps the vehicle safe — engage refused
//! while a device the rules need is gone, naming it and its port; a horn holds up
//! nothing — keeps every other device polled and commanded, says what it waits for,
//! and reopens each device when its port is back.

mod common;

use common::simproc::SimProcess;
use common::{free_port, lines, signal, tempdir, until_within, wait_exit, Reaped};
use std::path::{Path, PathBuf};
use std::process::{Command as Process, Output, Stdio};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_adrive");
const CART: &str = include_str!("../vehicles/cart.toml");

/// The old give-up time: `reconnect` tried 3 × 4 s, then adrive exited.
const OLD_GIVE_UP: Duration = Duration::from_secs(13);

/// Longer than a device is away in these tests, with room for a loaded machine.
const LONG: Duration = Duration::from_secs(90);

/// `adrive sim` on the cart: its ten ports.
fn cart_sim() -> SimProcess {
    let cart = Path::new(env!("CARGO_MANIFEST_DIR")).join("vehicles/cart.toml");
    SimProcess::start_with(&["--config", cart.to_str().unwrap()], 10)
}

/// The cart with each device on the simulator's port, but those in `elsewhere` on the
/// path given there; planners may engage, on ports of this test's own.
fn cart_file(dir: &Path, sim: &SimProcess, elsewhere: &[(&str, &Path)]) -> PathBuf {
    let mut paths = sim.paths.iter();
    let mut device = String::new();
    let mut text = String::new();
    for line in CART.lines() {
        if let Some(name) = line.strip_prefix("name = \"") {
            device = name.split('"').next().unwrap().to_string();
        }
        if line.starts_with("port = ") {
            let sim_path = paths.next().unwrap();
            let port = elsewhere
                .iter()
                .find(|(d, _)| *d == device)
                .map_or_else(|| sim_path.clone(), |(_, p)| p.display().to_string());
            text.push_str(&format!("port = \"{port}\"\n"));
        } else if line.starts_with("listen = ") {
            text.push_str(&format!("listen = \"127.0.0.1:{}\"\n", free_port()));
        } else if line.starts_with("broadcast_to = ") {
            text.push_str(&format!("broadcast_to = [\"127.0.0.1:{}\"]\n", free_port()));
        } else {
            text.push_str(line);
            text.push('\n');
        }
    }
    let path = dir.join("cart.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// `adrive --headless` on `vehicle`, its runtime directory (the control socket) and log
/// in `dir`; its log lines.
fn headless(dir: &Path, vehicle: &Path) -> (Reaped, Receiver<String>) {
    let mut child = Reaped(
        Process::new(BIN)
            .args(["--headless", "--config"])
            .arg(vehicle)
            .arg("--log-dir")
            .arg(dir.join("log"))
            .env("XDG_RUNTIME_DIR", dir)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let err = lines(child.stderr.take().unwrap());
    (child, err)
}

/// `adrive ctl ARGS` on the adrive whose runtime directory is `dir`.
fn ctl(dir: &Path, args: &[&str]) -> Output {
    Process::new(BIN)
        .arg("ctl")
        .args(args)
        .env("XDG_RUNTIME_DIR", dir)
        .output()
        .unwrap()
}

/// The snapshot, through `adrive ctl status --json`.
fn status(dir: &Path) -> serde_json::Value {
    let out = ctl(dir, &["status", "--json"]);
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "{e}: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    })
}

/// Wait until the snapshot satisfies `cond`; that snapshot.
fn snapshot_until(
    dir: &Path,
    what: &str,
    within: Duration,
    cond: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let end = Instant::now() + within;
    loop {
        let s = status(dir);
        if cond(&s) {
            return s;
        }
        assert!(Instant::now() < end, "never {what}:\n{s:#}");
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// How long the snapshot says `device` has been gone, ms (0 when it is not).
fn gone_ms(s: &serde_json::Value, device: &str) -> f64 {
    s["supervisor"]["waiting"]
        .as_array()
        .into_iter()
        .flatten()
        .find(|w| w["device"] == device)
        .and_then(|w| w["gone_ms"].as_f64())
        .unwrap_or(0.0)
}

/// The incident: the cart with a port absent made the `reconnect` recovery give up
/// after 3 × 4 s, and adrive exited (status 4) with every other device. Here the brake
/// (which the rules need) and the horn (which they do not) are absent at the start:
/// adrive says what it waits for, refuses engage naming the brake and its port (not the
/// horn), runs on past the old give-up time with the other devices polled, reopens
/// each device when its port appears — a link to the simulator's port, created later —
/// and then engages with the horn still gone. A stop is still a clean one.
#[test]
fn the_cart_runs_on_with_ports_absent_and_reopens_them_when_they_appear() {
    let sim = cart_sim();
    let dir = tempdir("gone-start");
    let brake = dir.path().join("usb-FTDI_cart_brake-if00-port0");
    let horn = dir.path().join("usb-cart_body-if00");
    let vehicle = cart_file(dir.path(), &sim, &[("brake", &brake), ("horn", &horn)]);
    let (mut adrive, err) = headless(dir.path(), &vehicle);
    let started = Instant::now();
    let mut said = until_within(
        &err,
        &format!(
            "waiting for brake on {}: No such file or directory",
            brake.display()
        ),
        LONG,
    );
    said.extend(until_within(
        &err,
        &format!(
            "waiting for horn on {}: No such file or directory",
            horn.display()
        ),
        LONG,
    ));
    // Past the old give-up time, gone all along, the other devices polled: the
    // snapshot says so (the process answering is the proof it runs).
    let s = snapshot_until(
        dir.path(),
        "the brake gone past the old give-up time",
        LONG,
        |s| gone_ms(s, "brake") > (OLD_GIVE_UP + Duration::from_secs(3)).as_millis() as f64,
    );
    assert!(started.elapsed() > OLD_GIVE_UP);
    assert!(matches!(adrive.try_wait(), Ok(None)));
    let waiting = s["supervisor"]["waiting"].to_string();
    assert!(
        waiting.contains("\"needed\":true") && waiting.contains("\"needed\":false"),
        "{waiting}"
    );
    for device in ["steer", "throttle", "direction", "wheels", "estop"] {
        let d = s["devices"]
            .as_array()
            .unwrap()
            .iter()
            .find(|d| d["name"] == device)
            .unwrap();
        assert_eq!(d["health"]["faulty"], false, "{device}: {d}");
        assert!(
            d["counters"]["polls"].as_u64().unwrap() > 10,
            "{device}: {d}"
        );
    }
    // Engage is refused for the brake, with its port; the horn holds up nothing.
    let refused = ctl(dir.path(), &["engage"]);
    let text = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(1), "{text}");
    assert!(
        text.contains("brake") && text.contains(&brake.display().to_string()),
        "{text}"
    );
    assert!(!text.contains("horn"), "{text}");
    // The brake's adapter is plugged in: its link appears.
    std::os::unix::fs::symlink(&sim.paths[2], &brake).unwrap();
    said.extend(until_within(
        &err,
        &format!("brake is back on {}", brake.display()),
        LONG,
    ));
    snapshot_until(dir.path(), "the brake answering", LONG, |s| {
        s["gate"]["blockers"]
            .as_array()
            .is_some_and(|b| b.is_empty())
    });
    // Engaged with the horn still gone; then the horn comes too.
    let engaged = ctl(dir.path(), &["engage"]);
    assert_eq!(
        engaged.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&engaged.stderr)
    );
    std::os::unix::fs::symlink(&sim.paths[5], &horn).unwrap();
    said.extend(until_within(
        &err,
        &format!("horn is back on {}", horn.display()),
        LONG,
    ));
    assert!(ctl(dir.path(), &["disengage"]).status.success());
    assert!(signal(&adrive, libc::SIGTERM));
    said.extend(until_within(&err, "safe state acknowledged", LONG));
    assert_eq!(wait_exit(&mut adrive), Some(0), "{}", said.join("\n"));
    let text = said.join("\n");
    assert!(!text.contains("gave up"), "{text}");
    sim.stop();
}

/// The incident: a cart on `adrive sim` whose horn adapter vanished for 25 s exited.
/// The horn vanishes for 25 s (`vanish horn 25s`): adrive waits for it, the vehicle is
/// engaged and commanded meanwhile (the horn holds up nothing), and the horn is back on
/// its port once the simulator brings it back.
#[test]
fn a_horn_that_vanishes_for_25_s_is_waited_for_while_the_cart_drives_on() {
    let mut sim = cart_sim();
    let dir = tempdir("gone-vanish");
    let vehicle = cart_file(dir.path(), &sim, &[]);
    let (mut adrive, err) = headless(dir.path(), &vehicle);
    let mut said = until_within(&err, "running headless", LONG);
    snapshot_until(dir.path(), "every device answering", LONG, |s| {
        s["gate"]["blockers"]
            .as_array()
            .is_some_and(|b| b.is_empty())
    });
    sim.say("vanish horn 25s");
    let vanished = Instant::now();
    let horn = &sim.paths[5];
    said.extend(until_within(
        &err,
        &format!("waiting for horn on {horn}"),
        LONG,
    ));
    // A planner engages and steers while it is gone.
    let mark = sim.mark();
    let listen = std::fs::read_to_string(&vehicle)
        .unwrap()
        .lines()
        .find_map(|l| {
            l.strip_prefix("listen = \"")
                .map(|r| r.trim_end_matches('"').to_string())
        })
        .unwrap();
    let planner = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    planner.send_to(b"engage\nsteer 5\n", &listen).unwrap();
    sim.wait_after(mark, &["steer", "<-", "5.000"]);
    // Back after its 25 s, the run never ended meanwhile.
    said.extend(until_within(&err, &format!("horn is back on {horn}"), LONG));
    assert!(vanished.elapsed() > OLD_GIVE_UP);
    assert!(matches!(adrive.try_wait(), Ok(None)));
    assert!(signal(&adrive, libc::SIGTERM));
    said.extend(until_within(&err, "safe state acknowledged", LONG));
    assert_eq!(wait_exit(&mut adrive), Some(0), "{}", said.join("\n"));
    sim.stop();
}
