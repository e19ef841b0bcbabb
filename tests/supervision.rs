//! The supervisor against the simulated Alice on real pseudo-terminals: each fault
//! injected is detected within a bound, named with its cause, reported, the other
//! devices keep working, and recovery or a safe stop follows.

mod common;

use adrive::config::ALICE_TOML;
use adrive::exit::Exit;
use adrive::safety::Reject;
use adrive::snapshot::FaultKind;
use adrive::value::Command;
use common::{wait_for, Rig};
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

fn set(v: f64) -> Command {
    Command::Set(v)
}

/// Alice with a faster supervisor for tests.
fn alice(supervisor: &str) -> String {
    format!("{ALICE_TOML}\n[supervisor]\nperiod = \"50ms\"\n{supervisor}\n")
}

fn fault_within(rig: &Rig, kind: FaultKind, device: Option<&str>, bound: Duration) -> String {
    let t = Instant::now();
    wait_for(&format!("{kind} on {device:?}"), || {
        rig.vehicle.supervision.has(kind, device)
    });
    let took = t.elapsed();
    assert!(
        took < bound,
        "{kind} took {took:?} to detect (bound {bound:?})"
    );
    let f = rig
        .vehicle
        .supervision
        .faults()
        .into_iter()
        .find(|f| f.kind == kind && f.device.as_deref() == device)
        .unwrap();
    assert!(!f.cause.is_empty());
    f.describe()
}

/// Steering still takes and executes commands (the other devices are unaffected).
fn steering_still_works(rig: &Rig, v: f64) {
    let steer = rig.device("steer");
    rig.gate.supervise(rig.id("steer"), set(v));
    wait_for("steering to execute", || {
        steer.slot.executed() == Some(set(v))
    });
    assert!(!steer.is_faulty());
}

#[test]
fn a_silent_device_is_named_with_its_cause_and_the_vehicle_stops_safely() {
    let rig = Rig::supervised(&alice(""));
    rig.engage();
    rig.sim.apply("silent gas on").unwrap();
    // status_max_age 500 ms + reply timeout 100 ms + a supervisor turn + margin.
    let what = fault_within(
        &rig,
        FaultKind::Silent,
        Some("gas"),
        Duration::from_millis(600 + 50 + 1000),
    );
    assert!(
        what.contains("no status") && what.contains("no reply"),
        "{what}"
    );
    wait_for("disengaged", || !rig.gate.is_engaged());
    assert!(rig.gate.reason().contains("gas"), "{}", rig.gate.reason());
    let brake = rig.device("brake");
    wait_for("brake on", || brake.slot.executed() == Some(set(1.0)));
    steering_still_works(&rig, 0.2);
    // Reported: the broadcast carries the supervisor's snapshot.
    let snap = serde_json::to_value(rig.vehicle.supervision.snapshot()).unwrap();
    assert_eq!(snap["faults"][0]["kind"], "silent", "{snap}");
    assert_eq!(snap["faults"][0]["device"], "gas", "{snap}");

    rig.sim.apply("clear gas").unwrap();
    wait_for("the fault to clear", || {
        !rig.vehicle.supervision.has(FaultKind::Silent, Some("gas"))
    });
    assert!(
        rig.history()
            .iter()
            .any(|h| h.starts_with("cleared: gas silent")),
        "{:?}",
        rig.history()
    );
}

#[test]
fn garbage_shows_as_an_error_rate() {
    let rig = Rig::supervised(&alice(""));
    rig.engage();
    rig.sim.apply("garbage brake on").unwrap();
    let what = fault_within(
        &rig,
        FaultKind::ErrorRate,
        Some("brake"),
        Duration::from_secs(4),
    );
    assert!(what.contains("failed"), "{what}");
    wait_for("disengaged", || !rig.gate.is_engaged());
    steering_still_works(&rig, -0.2);
}

#[test]
fn a_value_out_of_range_is_a_fault() {
    let rig = Rig::supervised(&alice(""));
    wait_for("steering to report", || {
        rig.device("steer").cached().at.is_some()
    });
    rig.sim.apply("bias steer 1.5").unwrap();
    let what = fault_within(
        &rig,
        FaultKind::OutOfRange,
        Some("steer"),
        Duration::from_secs(2),
    );
    assert!(what.contains("1.5"), "{what}");
    rig.sim.apply("bias steer 0").unwrap();
    wait_for("cleared", || {
        !rig.vehicle
            .supervision
            .has(FaultKind::OutOfRange, Some("steer"))
    });
}

/// A stuck steering motor whose drive does not notice: the command is not followed.
/// The steering procedure cycles the drive and homes it, and steering then holds
/// where it is — it does not jump back to the stale command.
#[test]
fn steering_that_does_not_follow_is_recovered_without_a_jump() {
    let rig = Rig::supervised(&alice("follow_time = \"600ms\""));
    rig.engage();
    let steer = rig.device("steer");
    rig.gate
        .submit(rig.id("steer"), set(0.6), Instant::now())
        .unwrap();
    wait_for("steering under way", || {
        steer.cached().reading.get(0).unwrap() > 0.15
    });
    rig.sim.apply("stuck steer on").unwrap();
    let what = fault_within(
        &rig,
        FaultKind::NotFollowing,
        Some("steer"),
        Duration::from_secs(3),
    );
    assert!(what.contains("commanded 0.600"), "{what}");
    wait_for("disengaged", || !rig.gate.is_engaged());
    wait_for("the steering procedure to finish", || {
        rig.vehicle
            .supervision
            .snapshot()
            .last_outcome
            .is_some_and(|o| o.contains("steering done"))
    });
    let h = rig.history();
    let steps: Vec<&String> = h.iter().filter(|l| l.starts_with("steering ")).collect();
    let names: Vec<&str> = steps
        .iter()
        .map(|l| l.split(": ").nth(1).unwrap_or(""))
        .collect();
    assert_eq!(
        names,
        ["disable", "enable", "home", "hold position"],
        "{h:?}"
    );
    // Held at the measured position, not the stale 0.6.
    let held = steer.slot.executed().and_then(Command::set_point).unwrap();
    let pos = steer.cached().reading.get(0).unwrap();
    assert!(
        held < 0.5 && (held - pos).abs() < 0.05,
        "held {held}, at {pos}"
    );
    let sent: Vec<Command> = rig
        .received()
        .iter()
        .filter(|e| e.name == "steer")
        .map(|e| e.command)
        .collect();
    assert_eq!(sent.last(), Some(&set(held)), "{sent:?}");
    wait_for("not following to clear", || {
        !rig.vehicle
            .supervision
            .has(FaultKind::NotFollowing, Some("steer"))
    });
}

/// A servo drive that latches a fault reports it in its status word; disable → enable
/// clears the latch, as on real drives.
#[test]
fn a_latched_steering_drive_fault_is_cleared_by_the_procedure() {
    let rig = Rig::supervised(&alice(""));
    rig.engage();
    rig.sim.apply("jam steer").unwrap();
    let what = fault_within(
        &rig,
        FaultKind::DeviceFault,
        Some("steer"),
        Duration::from_secs(1),
    );
    assert!(what.contains("0x0001"), "{what}");
    wait_for("the steering procedure to finish", || {
        rig.vehicle
            .supervision
            .snapshot()
            .last_outcome
            .is_some_and(|o| o.contains("steering done"))
    });
    wait_for("the latch to clear", || {
        rig.device("steer").cached().reading.fault == 0
    });
    let m = rig.sim.model().lock();
    assert!(!m.device(m.find("steer").unwrap()).fault_latched);
}

/// The paper's example, end to end and step by step: the engine stalls in drive; gas
/// off, brake, stopped, park, starter, back in drive, release. Meanwhile the planner's
/// gas is refused; afterwards nothing jumps back to its old set point.
#[test]
fn an_engine_stall_is_recovered_step_by_step() {
    let rig = Rig::supervised(&alice(""));
    rig.engage();
    let v = &rig.vehicle;
    let trans = rig.device("trans");
    rig.gate
        .submit(rig.id("trans"), rig.state("trans", "drive"), Instant::now())
        .unwrap();
    wait_for("drive", || trans.cached().reading.get(0) == Some(3.0));
    rig.gate.submit_accel(0.3, Instant::now()).unwrap();
    wait_for("brake released", || {
        rig.device("brake").slot.executed() == Some(set(0.0))
    });
    rig.gate.submit_accel(0.3, Instant::now()).unwrap();
    wait_for("gas", || {
        rig.device("gas").slot.executed() == Some(set(0.3))
    });

    rig.sim.apply("stall").unwrap();
    fault_within(&rig, FaultKind::EngineStall, None, Duration::from_secs(2));
    wait_for("the procedure to start", || {
        v.supervision.snapshot().recovery.is_some()
    });
    assert_eq!(
        rig.gate.submit(rig.id("gas"), set(0.5), Instant::now()),
        Err(Reject::Recovering)
    );
    assert!(
        rig.gate.is_engaged(),
        "an engine stall is recovered without disengaging"
    );
    wait_for("the procedure to finish", || {
        v.supervision
            .snapshot()
            .last_outcome
            .is_some_and(|o| o.contains("engine_stall done"))
    });
    let h = rig.history();
    let steps: Vec<&str> = h
        .iter()
        .filter(|l| l.starts_with("engine_stall "))
        .filter_map(|l| l.split(": ").nth(1))
        .collect();
    assert_eq!(
        steps,
        [
            "gas off",
            "brake",
            "wait stopped",
            "park",
            "starter",
            "back in drive",
            "release"
        ],
        "{h:?}"
    );
    assert_eq!(trans.cached().reading.get(0), Some(3.0), "drive");
    assert!(rig.sim.model().lock().running);
    // The trans device saw park, the starter, drive — in that order.
    let t: Vec<String> = rig
        .received()
        .iter()
        .filter(|e| e.name == "trans")
        .map(|e| e.text.clone())
        .collect();
    let tail: Vec<&str> = t
        .iter()
        .map(String::as_str)
        .skip_while(|c| *c != "park")
        .collect();
    assert_eq!(tail, ["park", "start", "drive"], "{t:?}");
    // No stale set point: gas stays 0 and the brake on until the planner says otherwise.
    assert_eq!(rig.device("gas").slot.latest(), Some(set(0.0)));
    assert_eq!(rig.device("brake").slot.latest(), Some(set(1.0)));
    // Control is back.
    assert_eq!(
        rig.gate.submit(rig.id("steer"), set(0.1), Instant::now()),
        Ok(())
    );
}

/// When the starter never catches, the procedure tries its configured number of times,
/// then gives up: safe state, disengaged, and a fatal device error asks the process
/// to end.
#[test]
fn a_recovery_that_cannot_succeed_gives_up_safely() {
    let rig = Rig::supervised(&alice("attempts = 2\nstep_timeout = \"1500ms\""));
    rig.engage();
    let trans = rig.device("trans");
    rig.gate
        .submit(rig.id("trans"), rig.state("trans", "drive"), Instant::now())
        .unwrap();
    wait_for("drive", || trans.cached().reading.get(0) == Some(3.0));
    rig.sim.apply("nostart on").unwrap();
    rig.sim.apply("stall").unwrap();
    let exit = rig
        .exits
        .as_ref()
        .unwrap()
        .recv_timeout(common::DEADLINE)
        .expect("the supervisor asks the process to end");
    match exit {
        Exit::Fatal(why) => assert!(
            why.contains("engine_stall gave up") && why.contains("try 2/2"),
            "{why}"
        ),
        other => panic!("expected a fatal device error, got {other:?}"),
    }
    assert!(!rig.gate.is_engaged());
    assert!(
        rig.gate.reason().contains("gave up"),
        "{}",
        rig.gate.reason()
    );
    let h = rig.history();
    assert_eq!(
        h.iter()
            .filter(|l| l.contains("engine_stall 5/7: starter"))
            .count(),
        2,
        "{h:?}"
    );
    wait_for("safe state", || {
        rig.device("brake").slot.executed() == Some(set(1.0))
            && rig.device("gas").slot.executed() == Some(set(0.0))
    });
}

#[test]
fn estop_pause_disengages_and_holds_the_brake() {
    let rig = Rig::supervised(&alice(""));
    rig.engage();
    rig.gate
        .submit(rig.id("brake"), set(0.0), Instant::now())
        .unwrap();
    let brake = rig.device("brake");
    wait_for("brake released", || brake.slot.executed() == Some(set(0.0)));
    rig.sim.apply("estop pause").unwrap();
    fault_within(&rig, FaultKind::EstopPause, None, Duration::from_secs(1));
    wait_for("disengaged", || !rig.gate.is_engaged());
    wait_for("brake on", || brake.slot.executed() == Some(set(1.0)));
    assert_eq!(rig.device("gas").slot.latest(), Some(set(0.0)));
    let refused = rig.gate.engage("test").unwrap_err().join("; ");
    assert!(refused.contains("e-stop"), "{refused}");
}

#[test]
fn a_vanished_device_is_reconnected_by_its_procedure() {
    let rig = Rig::supervised(&alice(""));
    rig.engage();
    rig.sim
        .faults("brake")
        .unwrap()
        .vanish(Duration::from_millis(1500));
    fault_within(
        &rig,
        FaultKind::Disconnected,
        Some("brake"),
        Duration::from_secs(2),
    );
    wait_for("disengaged", || !rig.gate.is_engaged());
    wait_for("the reconnect procedure to finish", || {
        rig.vehicle
            .supervision
            .snapshot()
            .last_outcome
            .is_some_and(|o| o.contains("reconnect brake done"))
    });
    let brake = rig.device("brake");
    assert!(brake.port_health.opens.load(Relaxed) >= 2);
    wait_for("cleared", || {
        !rig.vehicle
            .supervision
            .has(FaultKind::Disconnected, Some("brake"))
    });
    steering_still_works(&rig, 0.3);
}
