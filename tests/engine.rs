//! The engine against simulated devices on real pseudo-terminals: latest-wins
//! commands, resends, the cache, the port rule, faults and interlocks.

mod common;

use adrive::config::ALICE_TOML;
use adrive::safety::Reject;
use adrive::value::Command;
use common::{steer_only, wait_for, Rig};
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

fn set(v: f64) -> Command {
    Command::Set(v)
}

/// The paper's example: commands arrive at twice the rate the device can execute
/// them. The first is executed, the second is superseded by the third, and the third
/// goes out as soon as the port frees.
#[test]
fn commands_at_twice_the_execution_rate_keep_only_the_latest() {
    // Each command transaction takes ~400 ms; status polls are rare.
    let rig = Rig::start(&steer_only(
        "status_period = \"10s\"\nstatus_max_age = \"10s\"\ncommand_timeout = \"10s\"\nreply_timeout = \"1s\"",
        "command_delay = \"400ms\"",
    ));
    rig.engage();
    let steer = rig.device("steer");
    wait_for("the engage hold to execute", || {
        steer.stats().executed.load(Relaxed) == 1
    });
    rig.received();

    let t = Instant::now();
    rig.gate.submit(rig.id("steer"), set(0.1), t).unwrap();
    wait_for("the first command on the wire", || {
        steer.slot().last() == Some(set(0.1))
    });
    rig.gate
        .submit(rig.id("steer"), set(0.2), Instant::now())
        .unwrap();
    let third = Instant::now();
    rig.gate.submit(rig.id("steer"), set(0.3), third).unwrap();
    wait_for("the third command to execute", || {
        steer.slot().executed() == Some(set(0.3))
    });

    let got: Vec<Command> = rig.received().iter().map(|e| e.command).collect();
    assert_eq!(
        got,
        vec![set(0.1), set(0.3)],
        "the device got the first and the latest"
    );
    let s = steer.stats().counters();
    assert_eq!((s.received, s.executed, s.superseded), (4, 3, 1));
    // The third waited only for the rest of the first transaction on the wire (~400
    // ms), not for a second (~800): the bound halfway, so that neither a loaded
    // machine's late wake-up nor a second transaction's wait comes near it.
    let max = steer.stats().command_delay.summary().max_us.unwrap();
    assert!(max < 600_000.0, "third command waited {max} µs");
}

#[test]
fn the_last_command_is_resent_after_command_timeout() {
    let rig = Rig::start(&steer_only("command_timeout = \"50ms\"", ""));
    rig.engage();
    let steer = rig.device("steer");
    rig.gate
        .submit(rig.id("steer"), set(-0.4), Instant::now())
        .unwrap();
    wait_for("three resends", || steer.stats().resent.load(Relaxed) >= 3);
    let got: Vec<Command> = rig.received().iter().map(|e| e.command).collect();
    let resends = got.iter().rev().take_while(|c| **c == set(-0.4)).count();
    assert!(resends >= 4, "device received {got:?}");
    // Resends do not count as fresh commands.
    assert_eq!(steer.stats().received.load(Relaxed), 2);
}

#[test]
fn a_sensor_has_only_a_status_thread() {
    let rig = Rig::start(ALICE_TOML);
    let names = rig.engine.as_ref().unwrap().thread_names();
    for d in rig.vehicle.devices() {
        let r = d.name();
        assert!(names.contains(&format!("{r}/status").as_str()), "{names:?}");
        assert_eq!(
            names.contains(&format!("{r}/command").as_str()),
            d.is_actuator(),
            "{names:?}"
        );
    }
}

/// Readers only read the cache: they get the last reading at once even while the
/// status thread is stuck in a long transaction.
#[test]
fn readers_see_the_cache_without_waiting_for_the_port() {
    let rig = Rig::start(&steer_only(
        "status_period = \"10ms\"\nstatus_max_age = \"2s\"\nreply_timeout = \"2s\"",
        "poll_delay = \"400ms\"",
    ));
    let steer = rig.device("steer");
    wait_for("a first reading", || steer.cached().at.is_some());
    let polls = steer.stats().polls.load(Relaxed);
    // The status thread is now in its next 400 ms poll.
    let t = Instant::now();
    for _ in 0..1000 {
        assert!(steer.cached().reading.get(0).is_some());
    }
    assert!(
        t.elapsed() < Duration::from_millis(200),
        "{:?}",
        t.elapsed()
    );
    assert_eq!(
        steer.stats().polls.load(Relaxed),
        polls,
        "reading the cache polled"
    );
}

/// Runs 100 Hz commands against a device whose status transactions take ~100 ms and
/// returns the largest receipt → first-byte delay, in ms.
fn max_delay_under_100hz_commands(port_rule: &str) -> f64 {
    let rig = Rig::start(&steer_only(
        &format!(
            "port_rule = \"{port_rule}\"\nstatus_period = \"100ms\"\nstatus_max_age = \"500ms\"\nreply_timeout = \"500ms\""
        ),
        "poll_delay = \"95ms\"",
    ));
    rig.engage();
    let steer = rig.device("steer");
    let start = Instant::now();
    let mut i = 0u32;
    while start.elapsed() < Duration::from_millis(1500) {
        let v = (i % 100) as f64 / 100.0;
        rig.gate
            .submit(rig.id("steer"), set(v), Instant::now())
            .unwrap();
        i += 1;
        std::thread::sleep(Duration::from_millis(10));
    }
    let s = steer.stats().counters();
    assert!(s.polls >= 3, "status polls kept happening: {}", s.polls);
    let status_txn = steer.stats().status_txn.summary().p50_us.unwrap() / 1000.0;
    assert!(
        status_txn > 90.0,
        "status transactions take {status_txn} ms"
    );
    steer.stats().command_delay.summary().max_us.unwrap() / 1000.0
}

/// Regression for the paper's cued-command stall: with status polls of 100 ms and
/// commands at 100 Hz, the paper's plain lock makes a command wait behind a whole
/// status poll and then sends that stale command; adrive's rule sends the newest
/// command, which never waited longer than the one transaction on the wire.
#[test]
fn cued_command_stall_is_gone_with_the_priority_rule() {
    let priority = max_delay_under_100hz_commands("priority");
    assert!(
        priority < 100.0 + 30.0,
        "priority rule: a command waited {priority:.1} ms"
    );
    let paper = max_delay_under_100hz_commands("paper");
    assert!(
        paper > 80.0,
        "paper rule should show the stall, worst delay was {paper:.1} ms"
    );
}

/// Commands keep the port busy, yet the status is still polled at least every
/// `status_max_age`.
#[test]
fn status_is_polled_within_max_age_under_a_command_flood() {
    let rig = Rig::start(&steer_only(
        "status_period = \"20ms\"\nstatus_max_age = \"300ms\"",
        "command_delay = \"40ms\"",
    ));
    rig.engage();
    let steer = rig.device("steer");
    let start = Instant::now();
    let mut worst = Duration::ZERO;
    let mut i = 0u32;
    while start.elapsed() < Duration::from_millis(2000) {
        rig.gate
            .submit(rig.id("steer"), set((i % 10) as f64 / 10.0), Instant::now())
            .unwrap();
        i += 1;
        std::thread::sleep(Duration::from_millis(5));
        worst = worst.max(steer.cached().age().unwrap());
    }
    // max age + one command transaction + one poll + scheduling margin.
    assert!(
        worst < Duration::from_millis(300 + 50 + 20 + 150),
        "status went {worst:?} stale"
    );
    let s = steer.stats().counters();
    assert!(s.executed > 20, "commands flowed: {}", s.executed);
}

#[test]
fn a_silent_device_counts_errors_and_the_others_keep_flowing() {
    let toml = format!(
        "{}\n[[device]]\nname = \"gas\"\nkind = \"setpoint\"\nrange = [0.0, 1.0]\ndriver = \"line\"\nreply_timeout = \"50ms\"\nstatus_period = \"20ms\"\n",
        steer_only("", "")
    );
    let rig = Rig::start(&toml);
    rig.engage();
    rig.sim.faults("gas").unwrap().silent.store(true, Relaxed);
    let gas = rig.device("gas");
    wait_for("gas to be marked faulty", || gas.is_faulty());
    wait_for("status errors to be counted", || {
        gas.stats().status_errors.load(Relaxed) >= 3
    });
    assert_eq!(gas.health().status_error.load(Relaxed), 1, "timeout code");

    let steer = rig.device("steer");
    for v in [0.2, -0.2, 0.5] {
        rig.gate
            .submit(rig.id("steer"), set(v), Instant::now())
            .unwrap();
        wait_for("steering to execute", || {
            steer.slot().executed() == Some(set(v))
        });
    }
    assert!(!steer.is_faulty());
    assert!(rig.received().iter().any(|e| e.command == set(0.5)));

    // The gas device comes back: errors stop and it is healthy again.
    rig.sim.faults("gas").unwrap().silent.store(false, Relaxed);
    wait_for("gas to recover", || !gas.is_faulty());
}

/// The interlocks at intake, on the whole simulated Alice: each forbidden command is
/// rejected, counted, and never reaches the device.
#[test]
fn interlocks_reject_and_never_send() {
    let rig = Rig::start(ALICE_TOML);
    let now = Instant::now;
    rig.engage();
    let gas = rig.device("gas");
    let brake = rig.device("brake");
    wait_for("the safe state", || {
        brake.slot().executed() == Some(set(1.0))
    });

    // Gas while braking.
    assert_eq!(
        rig.gate.submit(rig.id("gas"), set(0.3), now()),
        Err(Reject::GasWhileBraking)
    );
    // Gas in park.
    rig.gate.submit(rig.id("brake"), set(0.0), now()).unwrap();
    wait_for("brake released", || {
        brake.slot().executed() == Some(set(0.0))
    });
    assert_eq!(
        rig.gate.submit(rig.id("gas"), set(0.3), now()),
        Err(Reject::GasNotInGear)
    );
    // Shift without the brake.
    assert_eq!(
        rig.gate
            .submit(rig.id("trans"), rig.state("trans", "drive"), now()),
        Err(Reject::ShiftWithoutBrake)
    );

    // Get moving properly: brake, shift, release, gas.
    rig.gate.submit(rig.id("brake"), set(1.0), now()).unwrap();
    wait_for("brake applied", || {
        brake.slot().executed() == Some(set(1.0))
    });
    rig.gate
        .submit(rig.id("trans"), rig.state("trans", "drive"), now())
        .unwrap();
    let trans = rig.device("trans");
    wait_for("drive engaged", || {
        trans.cached().reading.get(0) == Some(3.0)
    });
    rig.gate.submit(rig.id("brake"), set(0.0), now()).unwrap();
    wait_for("brake released", || {
        brake.slot().executed() == Some(set(0.0))
    });
    rig.gate.submit(rig.id("gas"), set(0.6), now()).unwrap();
    wait_for("the vehicle to move", || {
        rig.reading("obd", "speed").unwrap_or(0.0) > 0.5
    });
    // Shift while moving (even with the brake on).
    rig.gate.submit(rig.id("gas"), set(0.0), now()).unwrap();
    rig.gate.submit(rig.id("brake"), set(0.5), now()).unwrap();
    assert_eq!(
        rig.gate
            .submit(rig.id("trans"), rig.state("trans", "park"), now()),
        Err(Reject::ShiftWhileMoving)
    );

    let counts: std::collections::HashMap<_, _> = rig.gate.rejections().into_iter().collect();
    assert_eq!(counts[&Reject::GasWhileBraking], 1);
    assert_eq!(counts[&Reject::GasNotInGear], 1);
    assert_eq!(counts[&Reject::ShiftWithoutBrake], 1);
    assert_eq!(counts[&Reject::ShiftWhileMoving], 1);
    assert_eq!(gas.stats().rejected.load(Relaxed), 2);

    let sent = rig.received();
    assert!(!sent
        .iter()
        .any(|e| e.name == "gas" && e.command == set(0.3)));
    assert!(!sent.iter().any(|e| e.command == rig.state("trans", "park")));
    assert!(sent
        .iter()
        .any(|e| e.name == "gas" && e.command == set(0.6)));
}

#[test]
fn disengaged_commands_are_counted_and_not_executed() {
    let rig = Rig::start(&steer_only("", ""));
    let steer = rig.device("steer");
    assert_eq!(
        rig.gate.submit(rig.id("steer"), set(0.5), Instant::now()),
        Err(Reject::Disengaged)
    );
    assert_eq!(steer.stats().rejected.load(Relaxed), 1);
    assert_eq!(steer.slot().latest(), None);
}

/// Alice engaged (gas 0, brake full) and in drive.
fn alice_in_drive() -> Rig {
    let rig = Rig::start(ALICE_TOML);
    rig.engage();
    let brake = rig.device("brake");
    wait_for("the safe state", || {
        brake.slot().executed() == Some(set(1.0))
    });
    rig.gate
        .submit(rig.id("trans"), rig.state("trans", "drive"), Instant::now())
        .unwrap();
    let trans = rig.device("trans");
    wait_for("drive", || trans.cached().reading.get(0) == Some(3.0));
    rig
}

/// `c 0.3` in the console, from full brake, released the brake and never gave gas:
/// the gas waited for a second `accel`. One is enough now, from any source: the gas is
/// held back at its command thread until the brake release has reached the brake.
#[test]
fn one_accel_from_full_brake_gives_gas_once_the_brake_is_released() {
    let rig = alice_in_drive();
    rig.received();
    rig.gate.submit_accel(0.3, Instant::now()).unwrap();
    let gas = rig.device("gas");
    wait_for("gas", || gas.slot().executed() == Some(set(0.3)));
    assert_eq!(rig.device("brake").slot().executed(), Some(set(0.0)));
    let mut got = rig.received();
    got.sort_by_key(|e| e.at);
    let order: Vec<(&str, Command)> = got
        .iter()
        .filter(|e| matches!(e.name.as_str(), "gas" | "brake"))
        .map(|e| (e.name.as_str(), e.command))
        .collect();
    assert_eq!(
        order,
        [("brake", set(0.0)), ("gas", set(0.3))],
        "the brake was released first, then the gas given"
    );
    assert_eq!(
        rig.gate
            .rejections()
            .into_iter()
            .find(|(r, _)| *r == Reject::GasWhileBraking),
        Some((Reject::GasWhileBraking, 0))
    );
}

#[test]
fn accel_never_applies_gas_and_brake_together() {
    let rig = alice_in_drive();
    let brake = rig.device("brake");
    rig.gate.submit_accel(0.4, Instant::now()).unwrap();
    let gas = rig.device("gas");
    wait_for("gas", || gas.slot().executed() == Some(set(0.4)));
    rig.gate.submit_accel(-0.7, Instant::now()).unwrap();
    wait_for("brake", || brake.slot().executed() == Some(set(0.7)));
    assert_eq!(gas.slot().executed(), Some(set(0.0)));
    assert_eq!(
        rig.gate.submit_accel(1.5, Instant::now()),
        Err(Reject::OutOfRange)
    );
    assert_eq!(
        rig.gate.submit_accel(f64::NAN, Instant::now()),
        Err(Reject::NotFinite)
    );
}
