//! A driver's override against the simulated Alice on real pseudo-terminals: a hand
//! (`override DEVICE X` in the simulator) that moves the wheel or a pedal in a way its
//! command cannot explain is named `override` within its `override_time`; the vehicle
//! is handed to the driver (disengaged, gas 0 and the brake released, the steering no
//! longer commanded); engaging is refused until the override is cleared, and clearing
//! is refused while the hand is still on. A full-range sweep at the steering's top
//! rate, the end stops and settling pedals never trip it.

mod common;

use adrive::config::ALICE_TOML;
use adrive::snapshot::{Blocker, FaultKind};
use adrive::value::Command;
use common::{wait_for, Rig};
use std::time::{Duration, Instant};

fn set(v: f64) -> Command {
    Command::Set(v)
}

/// Alice with a faster supervisor for tests; her steer, gas and brake keep the default
/// `override_threshold` (a tenth of the range) and `override_time` (300 ms). Her
/// devices' timing is tolerant ([`common::tolerant_text`]): these tests hold her
/// engaged for seconds to prove overrides, and a loaded machine's 200 ms stall would
/// rightly find the e-stop silent and disengage her under them.
fn alice() -> String {
    common::tolerant_text(&format!("{ALICE_TOML}\n[supervisor]\nperiod = \"50ms\"\n"))
}

const OVERRIDE_TIME: Duration = Duration::from_millis(300);

fn overrides(rig: &Rig) -> Vec<String> {
    rig.history()
        .into_iter()
        .filter(|l| l.starts_with("fault: ") && l.contains("override"))
        .collect()
}

/// Push `device` toward `to` and wait for the override; returns how long it took.
fn push_until_named(rig: &Rig, device: &str, to: f64) -> Duration {
    let t = Instant::now();
    rig.sim.apply(&format!("override {device} {to}")).unwrap();
    wait_for(&format!("override on {device}"), || {
        rig.vehicle
            .supervision()
            .has(FaultKind::Override, Some(device))
    });
    t.elapsed()
}

/// The vehicle is the driver's: disengaged, gas 0 and brake 0 acknowledged.
fn in_manual(rig: &Rig) {
    wait_for("disengaged", || !rig.gate.is_engaged());
    for pedal in ["gas", "brake"] {
        let d = rig.device(pedal);
        wait_for(&format!("{pedal} released"), || {
            d.slot().executed() == Some(set(0.0))
        });
    }
}

/// The override named within its time (plus the push's travel past the threshold, a
/// status period and a supervisor turn, with room for a loaded machine), the vehicle
/// in manual, engaging refused, clearing refused while the hand is on, then both
/// allowed once it lets go.
fn detected_handed_over_and_cleared(device: &str, to: f64) {
    let rig = Rig::supervised(&alice());
    rig.engage();
    let took = push_until_named(&rig, device, to);
    assert!(
        took < OVERRIDE_TIME + Duration::from_millis(700),
        "{device}: override named after {took:?}"
    );
    in_manual(&rig);
    assert_eq!(rig.gate.overridden(), vec![device.to_string()]);
    let said = rig.gate.reason();
    assert!(
        said.contains(&format!("driver override on {device}")),
        "{said}"
    );

    // Nothing more goes to the steering while the driver has it.
    let _ = rig.received();
    let blockers = rig.gate.engage("test").unwrap_err();
    assert!(
        blockers
            .iter()
            .any(|b| matches!(b, Blocker::Overridden { device: d } if d == device)),
        "{blockers:?}"
    );
    let still = rig.gate.clear_overrides().unwrap_err();
    assert!(still.contains(&format!("still moving {device}")), "{still}");
    assert!(rig.gate.engage("test").is_err());

    rig.sim.apply(&format!("override {device} off")).unwrap();
    wait_for("the hand to be off", || {
        !rig.vehicle
            .supervision()
            .has(FaultKind::Override, Some(device))
    });
    assert_eq!(rig.gate.clear_overrides(), Ok(vec![device.to_string()]));
    assert!(rig.gate.overridden().is_empty());
    let steered: Vec<_> = rig
        .received()
        .into_iter()
        .filter(|e| e.name == "steer")
        .collect();
    assert!(
        steered.is_empty(),
        "steering commanded in manual: {steered:?}"
    );
    rig.engage();
    assert!(rig.gate.is_engaged());
}

#[test]
fn a_hand_on_the_wheel_is_an_override_that_hands_over_until_cleared_and_let_go() {
    detected_handed_over_and_cleared("steer", -0.7);
}

#[test]
fn a_foot_on_the_throttle_is_an_override_that_hands_over_until_cleared_and_let_go() {
    detected_handed_over_and_cleared("gas", 0.6);
}

#[test]
fn a_foot_on_the_brake_is_an_override_and_adrive_releases_the_brake() {
    // Engaged, the brake is held full: the driver's foot lifts it away from that.
    detected_handed_over_and_cleared("brake", 0.3);
}

/// The steering swept over its whole range at its declared top rate (1 a second), held
/// at each end stop, and the brake stepped full on and off (settling with its lag), for
/// two sweeps: no override. The barrier: a real push afterwards is the first override
/// the supervisor names.
#[test]
fn a_full_range_sweep_end_stops_and_settling_pedals_never_trip_an_override() {
    let rig = Rig::supervised(&alice());
    rig.engage();
    let steer = rig.device("steer");
    let (period, rate) = (Duration::from_millis(10), 1.0);
    let mut brake_on = true;
    let mut next_brake = Instant::now();
    for _ in 0..2 {
        for (from, to) in [(0.0, 1.0), (1.0, -1.0), (-1.0, 0.0)] {
            let start = Instant::now();
            let span = f64::abs(to - from) / rate;
            loop {
                let t = start.elapsed().as_secs_f64();
                let x = from + (to - from) * (t / span).min(1.0);
                rig.submit("steer", set(x)).unwrap();
                if Instant::now() >= next_brake {
                    brake_on = !brake_on;
                    rig.submit("brake", set(if brake_on { 1.0 } else { 0.0 }))
                        .unwrap();
                    next_brake = Instant::now() + Duration::from_millis(250);
                }
                if t >= span {
                    break;
                }
                std::thread::sleep(period);
            }
            // At the end stop (or centre) until it is there.
            wait_for("the steering to arrive", || {
                steer
                    .cached()
                    .reading
                    .get(0)
                    .is_some_and(|p| (p - to).abs() < 0.02)
            });
        }
    }
    assert!(rig.gate.is_engaged(), "{}", rig.gate.reason());
    // Barrier: a real push is named, and it is the first override of the run.
    push_until_named(&rig, "steer", 0.8);
    let named = overrides(&rig);
    assert_eq!(named.len(), 1, "{named:?}");
    assert!(named[0].contains("steer"), "{named:?}");
}

/// An operator's STOP is a person's decision: with the wheel in the driver's hands it
/// still disengages into the full safe state — gas 0, brake full — while the stops
/// adrive makes on its own (a disengage) keep the manual state, brake released.
#[test]
fn an_operator_stop_during_an_override_brakes_while_adrive_s_own_stops_do_not() {
    let rig = Rig::supervised(&alice());
    rig.engage();
    push_until_named(&rig, "steer", -0.7);
    in_manual(&rig);
    // A stop of adrive's own while the override is latched: what the brake will have
    // next is still the released brake.
    rig.gate
        .disengage(adrive::snapshot::DisengageCause::Stopping { why: None });
    assert_eq!(rig.device("brake").slot().latest(), Some(set(0.0)));
    rig.gate.stop(adrive::snapshot::DisengageCause::Stop {
        by: "console".into(),
    });
    assert_eq!(rig.device("brake").slot().latest(), Some(set(1.0)));
    for (pedal, want) in [("gas", 0.0), ("brake", 1.0)] {
        let d = rig.device(pedal);
        wait_for(&format!("{pedal} at {want}"), || {
            d.slot().executed() == Some(set(want))
        });
    }
    assert!(!rig.gate.is_engaged());
    assert_eq!(rig.gate.overridden(), vec!["steer".to_string()]);
}
