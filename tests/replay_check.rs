//! Replay as a safety check, on every test run: `adrive replay FILE --check
//! VEHICLE.toml` over a small corpus of short drives recorded from the simulator
//! (`tests/drives/`). Each drive decided again under the vehicle file it was driven
//! with is decided as it was (status 0): a change to a rule that alters any of its
//! decisions fails here, naming them. Under a changed limit, the decisions that would
//! differ are listed with their times (status 1).
//!
//! The drives are the real binary's, driven as a planner drives it (datagrams at 20 Hz
//! over UDP) on simulated devices, and recorded. To record them again — after a change
//! to what a recording holds, or a rule changed on purpose (review what the check
//! listed first) —
//!
//! ```sh
//! UPDATE_DRIVES=1 cargo test --release --test replay_check
//! ```
//!
//! rewrites `tests/drives/*.mcap` and then checks them.

mod common;

use common::headless::{Adrive, Watch};
use std::path::{Path, PathBuf};
use std::process::Command as Process;
use std::time::Duration;

const BIN: &str = env!("CARGO_BIN_EXE_adrive");

/// A recorded drive: its file in `tests/drives/`, the vehicle file it was driven with,
/// and what the planner sent, one datagram's lines and how many times (at 20 Hz).
struct Drive {
    name: &'static str,
    vehicle: &'static str,
    script: &'static [(&'static str, u32)],
}

const DRIVES: &[Drive] = &[
    // Alice: a command while disengaged; engage and shift to drive while giving gas
    // (refused until the shift is through); steer hard right for three datagrams;
    // brake; disengage.
    Drive {
        name: "alice",
        vehicle: "vehicles/alice.toml",
        script: &[
            ("gas 0.2", 1),
            ("engage\ntrans drive\nsteer 0.1\naccel 0.3", 24),
            ("steer 0.5\naccel 0.3", 3),
            ("steer 0.2\naccel -0.5", 10),
            ("disengage", 1),
        ],
    },
    // The cart: no gearbox, a direction switch; forward and throttle, then stop.
    Drive {
        name: "cart",
        vehicle: "vehicles/cart.toml",
        script: &[
            ("engage\ndirection forward\nsteer 5\naccel 0.4", 24),
            ("steer -10\naccel -0.6", 10),
            ("disengage", 1),
        ],
    },
];

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// A drive of the corpus; with `UPDATE_DRIVES` set, every drive is recorded again
/// first (once, whichever test asks first).
fn corpus(name: &str) -> PathBuf {
    static RECORDED: std::sync::OnceLock<()> = std::sync::OnceLock::new();
    RECORDED.get_or_init(|| {
        if std::env::var_os("UPDATE_DRIVES").is_some() {
            for d in DRIVES {
                record(d);
            }
        }
    });
    root().join("tests/drives").join(format!("{name}.mcap"))
}

/// Drive `d` on simulated devices, recorded, and keep the recording in the corpus.
fn record(d: &Drive) {
    let out = common::tempdir("drives");
    let file = out.path().join(format!("{}.mcap", d.name));
    let text = std::fs::read_to_string(root().join(d.vehicle)).unwrap();
    let a = Adrive::start_with(
        &format!("drive-{}", d.name),
        &text,
        // Fewer snapshots: a small file.
        "broadcast_rate = 2",
        &["--record", file.to_str().unwrap()],
    );
    let watch = Watch::start(&a.broadcast);
    watch.until("every device reporting", |s| s.gate.blockers.is_empty());
    let planner = a.planner();
    let mut seq = 0;
    for (lines, times) in d.script {
        for _ in 0..*times {
            seq += 1;
            planner
                .send(format!("seq {seq}\n{lines}\n").as_bytes())
                .unwrap();
            // The planner's pace.
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    drop(watch);
    drop(a);
    let drives = root().join("tests/drives");
    std::fs::create_dir_all(&drives).unwrap();
    std::fs::copy(&file, drives.join(format!("{}.mcap", d.name))).unwrap();
}

/// `adrive replay FILE --check VEHICLE`: its exit status and what it printed.
fn check(file: &Path, vehicle: &Path) -> (i32, String) {
    let out = Process::new(BIN)
        .arg("replay")
        .arg(file)
        .arg("--check")
        .arg(vehicle)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.is_empty(), "{stderr}");
    (
        out.status.code().expect("an exit status"),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

#[test]
fn every_recorded_drive_is_decided_again_as_it_was_under_its_own_vehicle_file() {
    for d in DRIVES {
        let file = corpus(d.name);
        let size = std::fs::metadata(&file)
            .unwrap_or_else(|e| panic!("{}: {e} (UPDATE_DRIVES=1 records it)", file.display()))
            .len();
        assert!(
            size < 100_000,
            "{}: {size} bytes: keep the corpus small",
            file.display()
        );
        let (status, out) = check(&file, &root().join(d.vehicle));
        let first = out.lines().next().unwrap_or_default();
        assert!(
            status == 0 && first.ends_with("none would be decided otherwise"),
            "{}: status {status}:\n{out}",
            d.name
        );
        // A drive that decides nothing checks nothing.
        let decided: usize = first
            .split(": ")
            .nth(1)
            .and_then(|r| r.split(' ').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or(0);
        assert!(decided >= 20, "{}: {first}", d.name);
    }
}

/// A limit changed — Alice's steering narrowed to ±0.4 — and the three `steer 0.5` the
/// planner sent, accepted then, are listed as refused now, with their times.
#[test]
fn a_changed_limit_lists_the_decisions_it_would_change() {
    let dir = common::tempdir("check");
    let narrow = dir.path().join("narrow.toml");
    let alice = std::fs::read_to_string(root().join("vehicles/alice.toml")).unwrap();
    assert!(alice.contains("range = [-1.0, 1.0]"));
    std::fs::write(
        &narrow,
        alice.replacen("range = [-1.0, 1.0]", "range = [-0.4, 0.4]", 1),
    )
    .unwrap();
    let (status, out) = check(&corpus("alice"), &narrow);
    assert_eq!(status, 1, "{out}");
    let listed: Vec<&str> = out.lines().filter(|l| l.contains(" s  ")).collect();
    assert_eq!(listed.len(), 3, "{out}");
    for l in &listed {
        assert!(
            l.contains("steer 0.500: accepted then, refused now: out_of_range"),
            "{l}"
        );
    }
    assert!(
        out.lines()
            .next()
            .unwrap()
            .ends_with("3 would be decided otherwise"),
        "{out}"
    );
}
