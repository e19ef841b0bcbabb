//! The supervisor against the simulated Alice on real pseudo-terminals: each fault
//! injected is detected within a bound, named with its cause, reported, the other
//! devices keep working, and recovery or a safe stop follows.

mod common;

use adrive::config::ALICE_TOML;
use adrive::exit::Exit;
use adrive::safety::Reject;
use adrive::snapshot::{DisengageCause, FaultKind, GateCause};
use adrive::value::{Command, Control};
use common::{wait_for, Rig};
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

fn set(v: f64) -> Command {
    Command::Set(v)
}

/// Alice with a faster supervisor (`supervisor`: lines of its table), her devices'
/// timing made tolerant ([`common::tolerant_text`]): for the tests that hold her
/// engaged for seconds to prove something other than device timing. On a shared
/// machine that stalls for 200 ms, her own deadlines rightly find the e-stop silent
/// and disengage, and the recovery or the sweep under test then waits for an engage
/// that never comes.
fn alice(supervisor: &str) -> String {
    common::tolerant_text(&strict_alice(supervisor))
}

/// Alice with a faster supervisor and her own deadlines: for the tests of device
/// timing (silence, late replies, a port that vanishes).
fn strict_alice(supervisor: &str) -> String {
    format!("{ALICE_TOML}\n[supervisor]\nperiod = \"50ms\"\n{supervisor}\n")
}

fn fault_within(rig: &Rig, kind: FaultKind, device: Option<&str>, bound: Duration) -> String {
    let t = Instant::now();
    wait_for(&format!("{kind} on {device:?}"), || {
        rig.vehicle.supervision().has(kind, device)
    });
    let took = t.elapsed();
    assert!(
        took < bound,
        "{kind} took {took:?} to detect (bound {bound:?})"
    );
    let f = rig
        .vehicle
        .supervision()
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
        steer.slot().executed() == Some(set(v))
    });
    assert!(!steer.is_faulty());
}

#[test]
fn a_silent_device_is_named_with_its_cause_and_the_vehicle_stops_safely() {
    let rig = Rig::supervised(&strict_alice(""));
    rig.engage();
    rig.sim.apply("silent gas on").unwrap();
    // Within twice its status_max_age of 500 ms.
    let what = fault_within(
        &rig,
        FaultKind::Silent,
        Some("gas"),
        Duration::from_millis(2 * 500),
    );
    assert!(
        what.contains("no answer") && what.contains("no reply"),
        "{what}"
    );
    wait_for("disengaged", || !rig.gate.is_engaged());
    assert!(rig.gate.reason().contains("gas"), "{}", rig.gate.reason());
    let brake = rig.device("brake");
    wait_for("brake on", || brake.slot().executed() == Some(set(1.0)));
    steering_still_works(&rig, 0.2);
    // Reported: the broadcast carries the supervisor's snapshot.
    let snap = serde_json::to_value(rig.vehicle.supervision().snapshot()).unwrap();
    assert_eq!(snap["faults"][0]["kind"], "silent", "{snap}");
    assert_eq!(snap["faults"][0]["device"], "gas", "{snap}");

    rig.sim.apply("clear gas").unwrap();
    wait_for("the fault to clear", || {
        !rig.vehicle
            .supervision()
            .has(FaultKind::Silent, Some("gas"))
    });
    assert!(
        rig.history()
            .iter()
            .any(|h| h.starts_with("cleared: gas silent")),
        "{:?}",
        rig.history()
    );
}

/// The e-stop's silence was detected 421–514 ms after it stopped answering, more than
/// twice its `status_max_age`: the threshold added the reply timeout, and then the
/// supervisor's period. Silence is now the device's own rule — no answer for longer
/// than `status_max_age` — which the gate monitor checks every 10 ms.
#[test]
fn a_silent_estop_is_detected_within_twice_its_status_max_age() {
    let rig = Rig::supervised(&strict_alice(""));
    rig.engage();
    let estop = rig.device("estop");
    let bound = 2 * estop.config().status_max_age;
    rig.sim.apply("silent estop on").unwrap();
    let silent_since = Instant::now();
    wait_for("disengaged", || !rig.gate.is_engaged());
    let disengaged = silent_since.elapsed();
    wait_for("the supervisor to name it", || {
        rig.vehicle
            .supervision()
            .has(FaultKind::Silent, Some("estop"))
    });
    let named = silent_since.elapsed();
    assert!(
        disengaged <= bound,
        "disengaged {disengaged:?} after the e-stop fell silent (bound {bound:?})"
    );
    assert!(
        named <= bound,
        "named silent {named:?} after the e-stop fell silent (bound {bound:?})"
    );
    // The gate monitor disengaged, in its words: the supervisor, which names the same
    // silence, leaves a blocker's disengage to it (once, before, it got there first).
    let why = rig.gate.reason();
    assert!(why.contains("estop is faulty (no answer for"), "{why}");
    let brake = rig.device("brake");
    wait_for("brake on", || brake.slot().executed() == Some(set(1.0)));
}

#[test]
fn garbage_shows_as_an_error_rate() {
    let rig = Rig::supervised(&strict_alice(""));
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
            .supervision()
            .has(FaultKind::OutOfRange, Some("steer"))
    });
}

/// The steps of procedure `name` in the supervisor's history, in order.
fn steps_of<'a>(history: &'a [String], name: &str) -> Vec<&'a str> {
    history
        .iter()
        .filter(|l| l.starts_with(&format!("{name} ")))
        .filter_map(|l| l.split(": ").nth(1))
        .collect()
}

/// The simulated steering drive has a fault latched.
fn steer_fault_latched(rig: &Rig) -> bool {
    let m = rig.sim.model().lock();
    m.device(m.find("steer").unwrap()).fault_latched
}

/// Every command `device`'s simulated device received since the last look.
fn received_by(rig: &Rig, device: &str) -> Vec<Command> {
    rig.received()
        .iter()
        .filter(|e| e.name == device)
        .map(|e| e.command)
        .collect()
}

/// Engage and shift into drive; the gearbox.
fn engaged_in_drive(rig: &Rig) -> &adrive::vehicle::Device {
    rig.engage();
    let trans = rig.device("trans");
    rig.gate
        .submit(rig.id("trans"), rig.state("trans", "drive"), Instant::now())
        .unwrap();
    wait_for("drive", || trans.cached().reading.get(0) == Some(3.0));
    trans
}

/// The outcome the supervisor shows contains `what`.
fn outcome(rig: &Rig, what: &str) {
    let end = std::time::Instant::now() + common::DEADLINE;
    loop {
        let s = rig.vehicle.supervision().snapshot();
        if s.last_outcome.as_ref().is_some_and(|o| o.contains(what)) {
            return;
        }
        assert!(
            std::time::Instant::now() < end,
            "timed out waiting for {what}: gate {}, supervisor {s:?}",
            rig.gate.reason()
        );
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// A stuck steering motor whose drive does not notice: the command is not followed.
/// The vehicle disengages; once it is engaged again, steering holds where it is — it
/// does not jump back to the stale command.
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
    outcome(&rig, "recovery steering waits for engage");
    rig.engage();
    // Engaging holds the steering where it stands, so it follows again (the steering
    // procedure may run meanwhile; it ends holding there too).
    wait_for("not following to clear and no recovery running", || {
        let snap = rig.vehicle.supervision().snapshot();
        !rig.vehicle
            .supervision()
            .has(FaultKind::NotFollowing, Some("steer"))
            && snap.recovery.is_none()
            && matches!(steer.slot().executed(), Some(Command::Set(_)))
    });
    // Held at the measured position, not the stale 0.6.
    let held = steer
        .slot()
        .executed()
        .and_then(Command::set_point)
        .unwrap();
    let pos = steer.cached().reading.get(0).unwrap();
    assert!(
        held < 0.5 && (held - pos).abs() < 0.05,
        "held {held}, at {pos}"
    );
    let sent: Vec<Command> = received_by(&rig, "steer");
    assert_eq!(sent.last(), Some(&set(held)), "{sent:?}");
    assert!(rig.gate.is_engaged());
}

/// A servo drive that latches a fault reports it in its status word; disable → enable
/// clears the latch, as on real drives. The fault disengages the vehicle; the steering
/// procedure waits for it to be engaged again, then stands the vehicle (gas off, brake)
/// and resets the drive.
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
    wait_for("disengaged", || !rig.gate.is_engaged());
    outcome(&rig, "recovery steering waits for engage");
    rig.engage();
    outcome(&rig, "steering done");
    wait_for("the latch to clear", || {
        rig.device("steer").cached().reading.fault == 0
    });
    assert!(!steer_fault_latched(&rig));
    let h = rig.history();
    assert_eq!(
        steps_of(&h, "steering"),
        [
            "gas off",
            "brake",
            "disable",
            "enable",
            "home",
            "hold position"
        ],
        "{h:?}"
    );
    assert!(rig.gate.is_engaged(), "{}", rig.gate.reason());
    // The vehicle stood while its steering was reset.
    assert_eq!(rig.device("brake").slot().latest(), Some(set(1.0)));
}

/// With `jam steer` in `adrive sim` and adrive never engaged, the steering drive
/// received disable, enable, home and a set point from the recovery procedure, while
/// the operator's own `e` key was refused. A disengaged vehicle is never moved by
/// adrive on its own: the fault is named and shown, and the procedure waits.
#[test]
fn a_jammed_steering_drive_while_disengaged_receives_nothing_from_the_supervisor() {
    let rig = Rig::supervised(&alice(""));
    wait_for("every device to report", || rig.gate.blockers().is_empty());
    rig.sim.apply("jam steer").unwrap();
    fault_within(
        &rig,
        FaultKind::DeviceFault,
        Some("steer"),
        Duration::from_secs(1),
    );
    outcome(
        &rig,
        "recovery steering waits for engage: steer device_fault",
    );
    // Ten more supervisor turns (50 ms each) with the fault standing…
    wait_for("the fault to stand for 500 ms", || {
        rig.vehicle
            .supervision()
            .snapshot()
            .faults
            .iter()
            .any(|f| f.kind == FaultKind::DeviceFault && f.age_ms > 500.0)
    });
    // …then a sentinel through the supervisor's own path: anything it had stored for
    // the steering would have reached the drive first, or been counted as replaced.
    let steer = rig.device("steer");
    rig.gate.supervise(rig.id("steer"), set(0.05));
    wait_for("the sentinel to execute", || {
        steer.slot().executed() == Some(set(0.05))
    });
    let got: Vec<Command> = received_by(&rig, "steer");
    assert_eq!(got, [set(0.05)], "the steering drive received {got:?}");
    let s = steer.stats().counters();
    assert_eq!((s.received, s.superseded), (1, 0), "{s:?}");
    assert!(rig.vehicle.supervision().snapshot().recovery.is_none());
    assert!(steer_fault_latched(&rig), "still latched");
}

/// A planner that keeps sending `accel 0.3` through an engine stall (as a planner at
/// 20 Hz does) once released the brake 18 ms after the procedure's brake step, every
/// time: the step never completed and the procedure gave up, on a vehicle left
/// unbraked. The procedure takes the brake too: intake refuses its release meanwhile.
#[test]
fn a_planner_accel_during_a_stall_recovery_cannot_release_the_brake() {
    let rig = Rig::supervised(&alice(""));
    let v = &rig.vehicle;
    engaged_in_drive(&rig);
    rig.gate.submit_accel(0.3, Instant::now()).unwrap();
    wait_for("gas", || {
        rig.device("gas").slot().executed() == Some(set(0.3))
    });
    rig.sim.apply("stall").unwrap();
    wait_for("the procedure to start", || {
        v.supervision().snapshot().recovery.is_some()
    });
    assert_eq!(
        rig.gate.submit_accel(0.3, Instant::now()),
        Err(Reject::Recovering)
    );
    // The planner, until the procedure is done (or the wait for it failed).
    struct Stop<'a>(&'a std::sync::atomic::AtomicBool);
    impl Drop for Stop<'_> {
        fn drop(&mut self) {
            self.0.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    }
    let done = std::sync::atomic::AtomicBool::new(false);
    std::thread::scope(|s| {
        s.spawn(|| {
            while !done.load(std::sync::atomic::Ordering::Relaxed) {
                let _ = rig.gate.submit_accel(0.3, Instant::now());
                std::thread::sleep(Duration::from_millis(50));
            }
        });
        let _stop = Stop(&done);
        outcome(&rig, "engine_stall done");
    });
    let h = rig.history();
    assert!(
        !h.iter().any(|l| l.contains("did not complete")),
        "every step completed the first time: {h:?}"
    );
}

/// The paper's example, end to end and step by step: the engine stalls in drive; gas
/// off, brake, stopped, park, starter, back in drive, release. Meanwhile the planner's
/// gas is refused; afterwards nothing jumps back to its old set point.
#[test]
fn an_engine_stall_is_recovered_step_by_step() {
    let rig = Rig::supervised(&alice(""));
    let v = &rig.vehicle;
    let trans = engaged_in_drive(&rig);
    rig.gate.submit_accel(0.3, Instant::now()).unwrap();
    wait_for("gas", || {
        rig.device("gas").slot().executed() == Some(set(0.3))
    });

    rig.sim.apply("stall").unwrap();
    fault_within(&rig, FaultKind::EngineStall, None, Duration::from_secs(2));
    wait_for("the procedure to start", || {
        v.supervision().snapshot().recovery.is_some()
    });
    assert_eq!(
        rig.gate.submit(rig.id("gas"), set(0.5), Instant::now()),
        Err(Reject::Recovering)
    );
    // The planner cannot release the brake while the vehicle is held for the restart.
    assert_eq!(
        rig.gate.submit(rig.id("brake"), set(0.0), Instant::now()),
        Err(Reject::Recovering)
    );
    assert!(
        rig.gate.is_engaged(),
        "an engine stall is recovered without disengaging"
    );
    outcome(&rig, "engine_stall done");
    let h = rig.history();
    assert_eq!(
        steps_of(&h, "engine_stall"),
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
    assert_eq!(trans.cached().reading.get(0), Some(3.0));
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
    assert_eq!(rig.device("gas").slot().latest(), Some(set(0.0)));
    assert_eq!(rig.device("brake").slot().latest(), Some(set(1.0)));
    // Control is back.
    assert_eq!(
        rig.gate.submit(rig.id("steer"), set(0.1), Instant::now()),
        Ok(())
    );
}

/// When the starter never catches, the procedure tries its configured number of times,
/// then gives up: safe state, disengaged — and the run goes on: a later engage finds
/// the stall again and the procedure runs again from the top. Only when the operator
/// asked for it (`give_up_after`) is a recovery that gave up a fatal device error that
/// asks the process to end.
#[test]
fn a_recovery_that_cannot_succeed_gives_up_safely() {
    for give_up in [false, true] {
        let extra = if give_up {
            "\ngive_up_after = \"1s\""
        } else {
            ""
        };
        let rig = Rig::supervised(&alice(&format!(
            "attempts = 2\nstep_timeout = \"1500ms\"{extra}"
        )));
        engaged_in_drive(&rig);
        rig.sim.apply("nostart on").unwrap();
        rig.sim.apply("stall").unwrap();
        outcome(&rig, "engine_stall gave up");
        assert!(!rig.gate.is_engaged());
        // The procedure gave up, and then the run (give_up_after), whichever is last.
        let why = match rig.gate.cause() {
            GateCause::Disengaged { why } => why,
            other => panic!("{other}"),
        };
        assert!(
            matches!(&why, DisengageCause::GaveUp { recovery, .. } if recovery == "engine_stall")
                || matches!(why, DisengageCause::GivingUp { .. }),
            "{why}"
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
            rig.device("brake").slot().executed() == Some(set(1.0))
                && rig.device("gas").slot().executed() == Some(set(0.0))
        });
        let exits = rig.exits.as_ref().unwrap();
        if give_up {
            match exits.recv_timeout(common::DEADLINE) {
                Ok(Exit::Fatal(why)) => assert!(
                    why.contains("engine_stall gave up")
                        && why.contains("try 2/2")
                        && why.contains("longer than give_up_after (1s)"),
                    "{why}"
                ),
                other => panic!("expected a fatal device error, got {other:?}"),
            }
            continue;
        }
        // Engaged again and back in drive with the engine still stopped: the procedure
        // runs again, from the top — the run went on.
        let running = || rig.vehicle.supervision().snapshot().recovery.is_some();
        assert!(!running());
        engaged_in_drive(&rig);
        wait_for("the procedure to run again", running);
        assert!(
            exits.try_recv().is_err(),
            "a recovery that gave up ended the run"
        );
    }
}

/// A procedure that moves actuators stops the moment the vehicle disengages (here the
/// operator's STOP in the middle of an engine-stall recovery): nothing more is sent.
#[test]
fn a_recovery_stops_when_the_vehicle_is_disengaged() {
    let rig = Rig::supervised(&alice(""));
    let v = &rig.vehicle;
    let trans = engaged_in_drive(&rig);
    rig.sim.apply("nostart on").unwrap();
    rig.sim.apply("stall").unwrap();
    wait_for("the starter to run", || {
        trans.slot().executed() == Some(Command::Control(Control::Start))
    });
    let before = rig.received().len();
    rig.gate
        .disengage(adrive::snapshot::DisengageCause::Disengage {
            by: "console".into(),
        });
    outcome(&rig, "engine_stall stopped: the vehicle is disengaged");
    assert!(v.supervision().snapshot().recovery.is_none());
    assert!(!rig.gate.is_recovering(rig.id("trans")) && !rig.gate.is_recovering(rig.id("gas")));
    // With the procedure gone, nothing of it is on its way: a sentinel through the
    // supervisor's path is all the gearbox gets after the STOP.
    rig.gate
        .supervise(rig.id("trans"), rig.state("trans", "park"));
    wait_for("the sentinel", || {
        trans.slot().executed() == Some(rig.state("trans", "park"))
    });
    let after = received_by(&rig, "trans");
    assert_eq!(
        after,
        [rig.state("trans", "park")],
        "after the STOP ({before} events before)"
    );
}

#[test]
fn estop_pause_disengages_and_holds_the_brake() {
    let rig = Rig::supervised(&alice(""));
    rig.engage();
    rig.gate
        .submit(rig.id("brake"), set(0.0), Instant::now())
        .unwrap();
    let brake = rig.device("brake");
    wait_for("brake released", || {
        brake.slot().executed() == Some(set(0.0))
    });
    rig.sim.apply("estop pause").unwrap();
    fault_within(&rig, FaultKind::EstopPause, None, Duration::from_secs(1));
    wait_for("disengaged", || !rig.gate.is_engaged());
    wait_for("brake on", || brake.slot().executed() == Some(set(1.0)));
    assert_eq!(rig.device("gas").slot().latest(), Some(set(0.0)));
    let refused = rig.gate.engage("test").unwrap_err();
    assert!(
        refused
            .iter()
            .any(|b| matches!(b, adrive::snapshot::Blocker::Estop { .. })),
        "{refused:?}"
    );
}

#[test]
fn a_vanished_device_is_waited_for_and_back_when_its_port_is() {
    let rig = Rig::supervised(&strict_alice(""));
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
    wait_for("the brake back", || {
        rig.vehicle
            .supervision()
            .snapshot()
            .last_outcome
            .is_some_and(|o| o.contains("brake is back on"))
    });
    let brake = rig.device("brake");
    assert!(brake.port_health().opens.load(Relaxed) >= 2);
    wait_for("cleared", || {
        !rig.vehicle
            .supervision()
            .has(FaultKind::Disconnected, Some("brake"))
    });
    steering_still_works(&rig, 0.3);
    // Back on its port, it had its own status_max_age to answer: it was not named
    // silent or failing the moment the port reopened (false faults beside "brake is
    // back", cleared a moment later, as once).
    let history = rig.history();
    let gone = history
        .iter()
        .position(|l| l.starts_with("fault: brake disconnected"))
        .expect("the disconnect is in the history");
    let after: Vec<&String> = history[gone..]
        .iter()
        .filter(|l| {
            l.starts_with("fault: brake silent") || l.starts_with("fault: brake error_rate")
        })
        .collect();
    assert!(after.is_empty(), "{after:?}\n{history:#?}");
}

/// The incident: a Modbus drive answering later than its reply timeout had its late
/// reply taken as the answer to the next request about half the time — the panel
/// showed a fresh age, and only `error_rate` fired. The simulated steering answers 220
/// ms after each request (its reply timeout here 200 ms): every late reply is drained,
/// none is taken as another request's answer — its reading is never refreshed while it
/// is slow — and it is named silent, slower than its reply timeout. Fast again, it
/// answers again.
///
/// The drain waits a whole reply timeout of quiet (steer's `status_max_age` is raised
/// so that its silence rule affords it: the port's `drain_quiet`): the reply, 20 ms
/// after the deadline, has 180 ms for the scheduler to be late on a loaded machine
/// before it would be the later reply no drain can tell. Alice's own steering (100 ms,
/// 250 ms) would leave it 55.
#[test]
fn a_drive_slower_than_its_reply_timeout_is_named_slow_and_no_reply_is_taken_for_another() {
    let steer_at = ALICE_TOML.find("name = \"steer\"").unwrap();
    let (before, after) = ALICE_TOML.split_at(steer_at);
    let after = after
        .replacen("status_max_age = \"250ms\"", "status_max_age = \"1s\"", 1)
        .replacen("reply_timeout = \"100ms\"", "reply_timeout = \"200ms\"", 1);
    let vehicle = strict_alice("").replacen(ALICE_TOML, &format!("{before}{after}"), 1);
    assert_ne!(vehicle, strict_alice(""));
    let rig = Rig::supervised(&vehicle);
    let steer = rig.device("steer");
    assert_eq!(steer.config().reply_timeout, Duration::from_millis(200));
    wait_for("steer answering", || steer.cached().at.is_some());
    rig.sim.apply("slow steer 220").unwrap();
    let slow = |rig: &Rig| {
        rig.vehicle
            .supervision()
            .faults()
            .into_iter()
            .find(|f| f.kind == FaultKind::Silent && f.device.as_deref() == Some("steer"))
            .filter(|f| f.cause.contains("slower than its reply_timeout"))
    };
    wait_for("steer named silent and slow", || slow(&rig).is_some());
    // From here, poll after poll, no reply is taken.
    let read_at = steer.cached().at;
    let polls = steer.stats().polls.load(Relaxed);
    wait_for("ten more polls", || {
        steer.stats().polls.load(Relaxed) >= polls + 10
    });
    assert_eq!(
        steer.cached().at,
        read_at,
        "a late reply was taken for another request's answer"
    );
    let cause = slow(&rig).expect("still silent").cause;
    assert!(cause.contains("no answer for"), "{cause}");
    rig.sim.apply("slow steer 0").unwrap();
    wait_for("steer answering again", || steer.cached().at != read_at);
    wait_for("silent cleared", || {
        !rig.vehicle
            .supervision()
            .has(FaultKind::Silent, Some("steer"))
    });
}

/// With a declared response the stuck motor is judged by the estimate: no headway for
/// `stall_time` (500 ms), not a fixed tolerance for `follow_time` (2.5 s).
#[test]
fn a_stuck_motor_is_named_within_the_stall_time_not_the_follow_time() {
    let rig = Rig::supervised(&alice(""));
    rig.engage();
    let steer = rig.device("steer");
    rig.submit("steer", set(-0.8)).unwrap();
    wait_for("steering under way", || {
        steer.cached().reading.get(0).unwrap() < -0.1
    });
    rig.sim.apply("stuck steer on").unwrap();
    let what = fault_within(
        &rig,
        FaultKind::NotFollowing,
        Some("steer"),
        Duration::from_millis(1500),
    );
    assert!(
        what.contains("commanded -0.800") && what.contains("its response promises"),
        "{what}"
    );
}

/// A drive at half its declared rate is slow but healthy: a full-range sweep never
/// names it (the fixed tolerance would have, after 2.5 s away from its command).
#[test]
fn a_slow_but_healthy_drive_is_never_named_not_following() {
    let slow = alice("").replace(
        "rate = 1.0                # full range a second",
        "rate = 0.5",
    );
    assert_ne!(slow, alice(""));
    let rig = Rig::supervised(&slow);
    rig.engage();
    let steer = rig.device("steer");
    for target in [-1.0, 1.0] {
        rig.submit("steer", set(target)).unwrap();
        wait_for("the sweep to reach its end", || {
            (steer.cached().reading.get(0).unwrap() - target).abs() < 0.01
        });
    }
    let history = rig.history();
    assert!(
        !history.iter().any(|h| h.contains("not_following")),
        "{history:?}"
    );
    assert!(rig.gate.is_engaged());
}
