//! What the rules need to know, gathered from the bound devices' slots and caches —
//! and only what the command at hand needs: a command to a device no rule looks at
//! gathers nothing, and each fact locks one slot or one cache once.

use super::rules::{Facts, Plays, RELEASED};
use super::wire::Wait;
use crate::config::{Bindings, DeviceConfig};
use crate::port::slot::WireState;
use crate::value::Command;
use crate::vehicle::{Device, Vehicle};

/// A set point as a fraction of its device's range top.
fn fraction(d: &Device, v: f64) -> f64 {
    share(d.config(), v)
}

fn extremes(d: &Device, values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .map(|v| fraction(d, v))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    lo.is_finite().then_some((lo, hi))
}

/// The brake's lowest and highest value pending, in flight, sent or acknowledged —
/// or, with nothing commanded yet, what it reports — and whether its newest command
/// releases it.
fn brake(v: &Vehicle, b: &Bindings) -> Option<(f64, f64, bool)> {
    let d = v.device(b.brake?);
    let w = d.slot().wire();
    let releasing = releases(d, w.latest());
    extremes(d, w.set_points())
        .or_else(|| {
            let p = d.reading(d.config().position()?)?;
            Some((fraction(d, p), fraction(d, p)))
        })
        .map(|(lo, hi)| (lo, hi, releasing))
}

/// Where the brake reports it is, as a fraction of its range: what a driver's foot
/// changes without a command (`None`: no brake bound, or it reports no position yet).
pub(crate) fn brake_reported(v: &Vehicle) -> Option<f64> {
    let d = v.device(v.bindings().brake?);
    Some(fraction(d, d.reading(d.config().position()?)?))
}

/// `c` is a set point of `d` at or below released.
fn releases(d: &Device, c: Option<Command>) -> bool {
    c.and_then(Command::set_point)
        .is_some_and(|x| fraction(d, x) <= RELEASED)
}

/// Every set point of a pedal (throttle or brake) among `cs` is at or below released:
/// the one meaning of a pedal released on the wire.
fn all_released(d: &Device, cs: impl IntoIterator<Item = Option<Command>>) -> bool {
    cs.into_iter()
        .flatten()
        .filter_map(Command::set_point)
        .all(|x| fraction(d, x) <= RELEASED)
}

/// The gear the gearbox is in, whether it drives, and whether a shift is under way.
///
/// What the gearbox reports counts only once it answers for the last gear command it
/// was sent: that command acknowledged — since any other was sent — and the gear
/// reported by a status taken after that. Until then the gear is unknown, so any gear
/// command is a shift and the brake stays on: a gearbox passing through neutral
/// reports neutral mid-shift, and one that went silent after a new gear was sent still
/// reports the old one. A shift is under way while the newest gear command (pending,
/// in flight or last sent) is not the gear known.
fn gear(v: &Vehicle, b: &Bindings) -> (Option<u8>, bool, bool) {
    let Some(g) = &b.gear else {
        return (None, false, false);
    };
    let d = v.device(g.device);
    let reported = d
        .config()
        .state()
        .and_then(|i| d.reading(i))
        .map(|x| x as u8);
    let w = d.slot().wire();
    let settled = match w.flight.or(w.sent) {
        Some(c @ Command::State(_)) => {
            let status_after_ack = match (w.acked_at, d.cached().at) {
                (Some(acked), Some(status)) => status > acked,
                _ => false,
            };
            w.sent == Some(c) && w.acked == Some(c) && status_after_ack
        }
        // Nothing sent to it yet, or a control (the starter): what it reports is what
        // it is in.
        _ => true,
    };
    let known = reported.filter(|_| settled);
    let shifting = match w.latest() {
        Some(Command::State(s)) => known != Some(s),
        _ => false,
    };
    (known, known.is_some_and(|s| g.drives(s)), shifting)
}

/// Facts for an intake check of a command to a device that plays `plays`.
pub(crate) fn gather(v: &Vehicle, plays: Plays) -> Facts {
    if plays.is_free() {
        return Facts::default();
    }
    let b = v.bindings();
    let mut f = Facts::default();
    if plays.throttle || plays.gear {
        if let Some((lo, hi, releasing)) = brake(v, b) {
            f.brake_low = Some(lo);
            f.brake_high = Some(hi);
            f.brake_releasing = releasing;
        }
    }
    if plays.throttle || plays.brake || plays.gear || plays.starter {
        (f.gear, f.in_gear, f.shifting) = gear(v, b);
    }
    if plays.throttle {
        f.running = b
            .engine_running
            .and_then(|r| v.reading(r))
            .map(|x| x != 0.0);
    }
    if plays.throttle || plays.brake {
        f.estop = v.estop();
    }
    if plays.gear {
        f.speed = b.speed.and_then(|r| v.reading(r));
    }
    f
}

/// Facts for the wire check of a command to a device that plays `plays`.
pub(crate) fn gather_wire(v: &Vehicle, plays: Plays) -> Facts {
    let b = v.bindings();
    let mut f = Facts::default();
    if plays.throttle || plays.gear {
        if let Some(id) = b.brake {
            let d = v.device(id);
            let w = d.slot().wire();
            let on_wire = [w.pending, w.flight, w.sent]
                .into_iter()
                .flatten()
                .filter_map(Command::set_point);
            f.brake_high = extremes(d, on_wire).map(|(_, hi)| hi);
            f.brake_low = extremes(d, w.set_points()).map(|(lo, _)| lo);
            f.brake_releasing = releases(d, w.pending.or(w.flight));
        }
    }
    if plays.brake {
        if let Some(id) = b.throttle {
            let d = v.device(id);
            let w = d.slot().wire();
            f.throttle_released = released_on_wire(d, &w);
        }
        if let Some(g) = &b.gear {
            let w = v.device(g.device).slot().wire();
            f.shift_on_its_way = shift_on_its_way(&w);
        }
    }
    if plays.throttle || plays.brake {
        f.estop = v.estop();
    }
    if plays.gear {
        let (gear, _, _) = gear(v, b);
        f.gear = gear;
        f.speed = b.speed.and_then(|r| v.reading(r));
    }
    f
}

/// A pedal (throttle or brake) has nothing above released pending, in flight or last
/// sent.
pub(crate) fn released_on_wire(d: &Device, w: &WireState) -> bool {
    all_released(d, [w.pending, w.flight, w.sent])
}

/// A gear command not on the wire yet: pending or in flight, and not the last one sent
/// (whatever the gearbox reports: it may be passing through that gear). Every one on
/// its way counts, not only the newest: a command pending to the gear last sent does
/// not hide a shift still in flight before it.
fn shift_on_its_way(w: &WireState) -> bool {
    [w.pending, w.flight]
        .into_iter()
        .flatten()
        .any(|c| matches!(c, Command::State(_)) && w.sent != Some(c))
}

/// A set point of `d` as a fraction of its range top (the rules' scale).
pub(crate) fn share(d: &DeviceConfig, v: f64) -> f64 {
    let hi = d.range[1];
    if hi > 0.0 {
        v / hi
    } else {
        v
    }
}

/// The command that releases a pedal: the bottom of its range. What the wire sends in
/// place of throttle it refuses, and what it has the throttle commanded before braking.
pub(crate) fn release(d: &DeviceConfig) -> Command {
    Command::Set(d.range[0])
}

/// The brake's newest command (pending, else in flight) applies it.
fn brake_applied_again(d: &Device, w: &WireState) -> bool {
    !all_released(d, [w.pending.or(w.flight)])
}

/// What a command thread does for a [`Wait`] the wire check asked for: which device it
/// waits for, what it first commands that device, and when the wait is over.
pub(crate) struct Awaited<'a> {
    pub device: &'a Device,
    /// Commanded before the wait: the throttle's release, when throttle above released
    /// is still on its way to it.
    pub first: Option<Command>,
    /// The wait is over when this holds of the device's wire.
    pub over: fn(&Device, &WireState) -> bool,
}

/// Every device a command thread may wait at the wire for: the one each [`Wait`] names,
/// where it is bound. No other device — a sensor, the steering — is ever waited for.
pub(crate) fn awaitable(v: &Vehicle) -> impl Iterator<Item = &Device> {
    Wait::ALL
        .into_iter()
        .filter_map(|w| awaited(v, w))
        .map(|a| a.device)
}

/// What waiting for `w` means on `v` (`None`: the device waited for is not bound).
pub(crate) fn awaited(v: &Vehicle, w: Wait) -> Option<Awaited<'_>> {
    let b = v.bindings();
    Some(match w {
        Wait::ThrottleReleased => {
            let t = v.device(b.throttle?);
            let wire = t.slot().wire();
            Awaited {
                device: t,
                first: (!all_released(t, [wire.pending, wire.flight])).then(|| release(t.config())),
                over: released_on_wire,
            }
        }
        Wait::BrakeReleased => Awaited {
            device: v.device(b.brake?),
            first: None,
            over: |d, w| released_on_wire(d, w) || brake_applied_again(d, w),
        },
        Wait::ShiftOut => Awaited {
            device: v.device(b.gear.as_ref()?.device),
            first: None,
            over: |_, w| !shift_on_its_way(w),
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::value::{EstopState, Reading};
    use crate::vehicle::Cached;
    use std::time::Instant;

    /// The gearbox reports `state` in a status taken now.
    fn reports(d: &Device, state: f64) {
        reports_at(d, state, Instant::now());
    }

    /// A device's first reading is `x`, in a status taken at `at`.
    fn reports_at(d: &Device, x: f64, at: Instant) {
        let mut r = Reading::default();
        r.set(0, x);
        d.store(Cached {
            reading: r,
            at: Some(at),
            asked: None,
        });
    }

    /// Alice with her pedals in percent (range 0 … 100): every fact of a pedal is a
    /// fraction of its range's top, whatever its units.
    fn percent() -> Vehicle {
        let text = crate::config::ALICE_TOML
            .replace(
                "range = [0.0, 1.0]\nreadings = [\"position\", \"pressure\"]",
                "range = [0.0, 100.0]\nreadings = [\"position\", \"pressure\"]",
            )
            .replace(
                "range = [0.0, 1.0]\ndriver = \"modbus\"\nport = \"/dev/serial/by-id/usb-FTDI_gas",
                "range = [0.0, 100.0]\ndriver = \"modbus\"\nport = \"/dev/serial/by-id/usb-FTDI_gas",
            );
        let config = crate::config::parse(&text, "percent.toml").expect("Alice in percent");
        for pedal in ["gas", "brake"] {
            assert_eq!(config.device(pedal).unwrap().range, [0.0, 100.0], "{pedal}");
        }
        crate::testkit::vehicle_of(config, Instant::now())
    }

    fn device<'a>(v: &'a Vehicle, name: &str) -> &'a Device {
        v.find(name).unwrap()
    }

    /// The devices a command may wait for are Alice's throttle, brake and gearbox —
    /// the one device each wait names — and no other: not the steering, not a sensor.
    #[test]
    fn only_the_pedals_and_the_gearbox_are_ever_waited_for() {
        let v = crate::testkit::vehicle(Instant::now());
        let names: Vec<&str> = awaitable(&v).map(|d| d.name()).collect();
        assert_eq!(names, ["gas", "brake", "trans"]);
        for (w, name) in Wait::ALL.into_iter().zip(names) {
            // Exhaustive: a new wait is not compiled until it is listed in `ALL`.
            match w {
                Wait::ThrottleReleased | Wait::BrakeReleased | Wait::ShiftOut => {}
            }
            assert_eq!(awaited(&v, w).unwrap().device.name(), name, "{w:?}");
        }
    }

    /// The device went through a transaction of `c`, acknowledged or not.
    fn went(d: &Device, c: Command, acked: bool) {
        d.slot().fly(c);
        d.slot().finish(c, acked);
    }

    const STARTER: Plays = Plays {
        throttle: false,
        brake: false,
        gear: false,
        starter: true,
    };

    /// Intake's facts: the brake's lowest and highest of every value it has or is about
    /// to have (pending, in flight, sent, acknowledged) and whether its newest releases
    /// it, each a fraction of its range; what the gearbox, the engine and the e-stop
    /// report; each gathered for the devices whose rules ask it, and only those.
    #[test]
    fn intake_gathers_what_each_devices_rules_ask_as_fractions_of_the_range() {
        let v = percent();
        let brake = device(&v, "brake");
        // Nothing commanded: where the brake reports it is (45 of 100).
        reports_at(brake, 45.0, Instant::now());
        assert_eq!(brake_reported(&v), Some(0.45));
        let reported = Facts {
            brake_low: Some(0.45),
            brake_high: Some(0.45),
            gear: Some(0), // park, nothing sent: what it reports
            running: Some(true),
            estop: Some(EstopState::Run),
            ..Facts::default()
        };
        assert_eq!(gather(&v, Plays::THROTTLE), reported);
        // Commanded: 80 acknowledged, 30 sent after it and not, 60 pending.
        went(brake, Command::Set(80.0), true);
        went(brake, Command::Set(30.0), false);
        brake.slot().submit(Command::Set(60.0), Instant::now());
        let commanded = Facts {
            brake_low: Some(0.3),
            brake_high: Some(0.8),
            ..reported
        };
        assert_eq!(gather(&v, Plays::THROTTLE), commanded);
        assert_eq!(
            brake_reported(&v),
            Some(0.45),
            "what it reports, not what it was told"
        );
        // The gearbox's own rules: the brake, the gear and the speed; not the engine
        // nor the e-stop.
        assert_eq!(
            gather(&v, Plays::GEAR),
            Facts {
                running: None,
                estop: None,
                speed: Some(0.0),
                ..commanded
            }
        );
        // The brake's: the gear and the e-stop.
        let gear_and_estop = Facts {
            gear: Some(0),
            estop: Some(EstopState::Run),
            ..Facts::default()
        };
        assert_eq!(gather(&v, Plays::BRAKE), gear_and_estop);
        // The starter's: the gear alone.
        assert_eq!(
            gather(&v, STARTER),
            Facts {
                estop: None,
                ..gear_and_estop
            }
        );
        // A device no rule looks at: nothing.
        assert_eq!(gather(&v, Plays::default()), Facts::default());
        // The newest command releases the brake (1 of 100 is below released) …
        brake.slot().submit(Command::Set(1.0), Instant::now());
        let f = gather(&v, Plays::THROTTLE);
        assert_eq!(
            (f.brake_low, f.brake_high, f.brake_releasing),
            (Some(0.01), Some(0.8), true)
        );
        // … and at exactly released too; above it, not.
        brake
            .slot()
            .submit(Command::Set(100.0 * RELEASED), Instant::now());
        assert!(gather(&v, Plays::THROTTLE).brake_releasing, "at released");
        brake.slot().submit(Command::Set(3.0), Instant::now());
        assert!(!gather(&v, Plays::THROTTLE).brake_releasing, "above it");
        // The engine stopped.
        let obd = device(&v, "obd");
        let mut r = obd.cached().reading;
        r.set(obd.config().reading("running").unwrap(), 0.0);
        obd.store(Cached {
            reading: r,
            at: Some(Instant::now()),
            asked: None,
        });
        assert_eq!(gather(&v, Plays::THROTTLE).running, Some(false));
    }

    /// The wire's facts: the brake's highest on its way or sent (not what it
    /// acknowledged before: that is gone from the wire), its lowest of every value,
    /// whether what is on its way releases it; for the brake's command, whether the
    /// throttle is released on the wire and whether a shift is on its way.
    #[test]
    fn the_wire_gathers_what_is_on_its_way_to_each_device() {
        let v = percent();
        let (brake, gas, trans) = (device(&v, "brake"), device(&v, "gas"), device(&v, "trans"));
        went(brake, Command::Set(80.0), true);
        went(brake, Command::Set(30.0), false);
        brake.slot().submit(Command::Set(60.0), Instant::now());
        let f = gather_wire(&v, Plays::THROTTLE);
        assert_eq!(
            (f.brake_low, f.brake_high, f.brake_releasing, f.estop),
            (Some(0.3), Some(0.6), false, Some(EstopState::Run))
        );
        let g = gather_wire(&v, Plays::GEAR);
        assert_eq!(
            (g.brake_low, g.brake_high, g.gear, g.speed, g.estop),
            (Some(0.3), Some(0.6), Some(0), Some(0.0), None)
        );
        // In flight counts as on its way, and its release as releasing.
        brake.slot().take_newer();
        let f = gather_wire(&v, Plays::THROTTLE);
        assert_eq!((f.brake_high, f.brake_releasing), (Some(0.6), false));
        brake.slot().finish(Command::Set(60.0), true);
        brake.slot().fly(Command::Set(1.0));
        assert!(gather_wire(&v, Plays::THROTTLE).brake_releasing);
        // The brake's command: the throttle on the wire and the gearbox's shifts.
        let f = gather_wire(&v, Plays::BRAKE);
        assert_eq!(
            (
                f.throttle_released,
                f.shift_on_its_way,
                f.estop,
                f.brake_high
            ),
            (true, false, Some(EstopState::Run), None),
            "nothing sent to the throttle: released"
        );
        went(gas, Command::Set(50.0), true);
        assert!(!gather_wire(&v, Plays::BRAKE).throttle_released, "50 sent");
        gas.slot().submit(Command::Set(1.0), Instant::now());
        assert!(
            !gather_wire(&v, Plays::BRAKE).throttle_released,
            "its release pending, 50 still the last sent"
        );
        gas.slot().take_newer();
        gas.slot().finish(Command::Set(1.0), true);
        assert!(gather_wire(&v, Plays::BRAKE).throttle_released, "1 sent");
        went(gas, Command::Set(100.0 * RELEASED), true);
        assert!(
            gather_wire(&v, Plays::BRAKE).throttle_released,
            "released sent"
        );
        went(gas, Command::Set(3.0), true);
        assert!(!gather_wire(&v, Plays::BRAKE).throttle_released, "3 sent");
        let drive = Command::State(trans.config().state_index("drive").unwrap());
        trans.slot().submit(drive, Instant::now());
        assert!(gather_wire(&v, Plays::BRAKE).shift_on_its_way);
        // A device no rule looks at gathers nothing at the wire either.
        assert_eq!(gather_wire(&v, Plays::default()), Facts::default());
    }

    /// A shift is on its way while any gear command pending or in flight is not the
    /// last one sent; the starter's command is no shift.
    #[test]
    fn a_shift_is_on_its_way_until_every_gear_sent_is_the_last_one() {
        let v = percent();
        let trans = device(&v, "trans");
        let state = |w: &str| Command::State(trans.config().state_index(w).unwrap());
        let (drive, reverse) = (state("drive"), state("reverse"));
        let on_its_way = || shift_on_its_way(&trans.slot().wire());
        assert!(!on_its_way(), "nothing sent");
        went(trans, drive, true);
        assert!(!on_its_way(), "drive sent");
        trans.slot().submit(drive, Instant::now());
        assert!(!on_its_way(), "drive again: no shift");
        trans.slot().submit(reverse, Instant::now());
        assert!(on_its_way(), "reverse pending");
        trans.slot().take_newer();
        trans.slot().submit(drive, Instant::now());
        assert!(on_its_way(), "reverse in flight behind drive pending");
        trans.slot().take_newer();
        trans.slot().finish(drive, true);
        assert!(!on_its_way(), "drive the last sent");
        trans.slot().submit(
            Command::Control(crate::value::Control::Start),
            Instant::now(),
        );
        assert!(!on_its_way(), "the starter is no shift");
    }

    /// A status taken at the very instant the gearbox acknowledged its gear is not
    /// known to come after it: the gear stays unknown until a later one.
    #[test]
    fn a_status_of_the_instant_of_the_acknowledgement_is_not_after_it() {
        let v = percent();
        let trans = device(&v, "trans");
        let drive = Command::State(trans.config().state_index("drive").unwrap());
        went(trans, drive, true);
        let acked = trans.slot().wire().acked_at.unwrap();
        reports_at(trans, 3.0, acked);
        assert_eq!(gear(&v, v.bindings()), (None, false, true));
        reports_at(trans, 3.0, acked + std::time::Duration::from_nanos(1));
        assert_eq!(gear(&v, v.bindings()), (Some(3), true, false));
        // What it reports, once known: park drives nothing.
        let park = Command::State(0);
        went(trans, park, true);
        reports(trans, 0.0);
        assert_eq!(gear(&v, v.bindings()), (Some(0), false, false));
        // Reverse acknowledged but the status still the one before: unknown, shifting.
        let reverse = Command::State(trans.config().state_index("reverse").unwrap());
        trans.slot().submit(reverse, Instant::now());
        assert_eq!(gear(&v, v.bindings()), (Some(0), false, true), "pending");
        trans.slot().take_newer();
        trans.slot().finish(reverse, true);
        assert_eq!(
            gear(&v, v.bindings()),
            (None, false, true),
            "not reported yet"
        );
        reports(trans, 1.0);
        assert_eq!(gear(&v, v.bindings()), (Some(1), true, false));
        // Drive sent and not acknowledged: the last answer was for reverse, so the
        // gear is unknown again, whatever the gearbox goes on reporting.
        went(
            trans,
            Command::State(trans.config().state_index("drive").unwrap()),
            false,
        );
        reports(trans, 1.0);
        assert_eq!(gear(&v, v.bindings()), (None, false, true));
    }

    /// What a command thread does for each wait: the throttle released first when
    /// throttle above released is on its way; the brake's wait over once it is
    /// released on the wire or applied again; a shift's once none is on its way.
    #[test]
    fn each_wait_names_its_device_its_first_command_and_its_end() {
        let v = percent();
        let (brake, gas, trans) = (device(&v, "brake"), device(&v, "gas"), device(&v, "trans"));
        // The throttle: 50 pending is released first.
        gas.slot().submit(Command::Set(50.0), Instant::now());
        let a = awaited(&v, Wait::ThrottleReleased).unwrap();
        assert_eq!(a.device.name(), "gas");
        assert_eq!(a.first, Some(Command::Set(0.0)));
        assert!(!(a.over)(gas, &gas.slot().wire()));
        // 1 pending (50 sent before it): nothing to release, and not over until 1 is
        // the last sent.
        gas.slot().take_newer();
        gas.slot().finish(Command::Set(50.0), true);
        gas.slot().submit(Command::Set(1.0), Instant::now());
        let a = awaited(&v, Wait::ThrottleReleased).unwrap();
        assert_eq!(a.first, None);
        assert!(!(a.over)(gas, &gas.slot().wire()));
        gas.slot().take_newer();
        gas.slot().finish(Command::Set(1.0), true);
        assert!((a.over)(gas, &gas.slot().wire()));
        // The brake: 50 sent, its release pending: not over …
        went(brake, Command::Set(50.0), true);
        brake.slot().submit(Command::Set(1.0), Instant::now());
        let a = awaited(&v, Wait::BrakeReleased).unwrap();
        assert_eq!((a.device.name(), a.first), ("brake", None));
        assert!(!(a.over)(brake, &brake.slot().wire()), "releasing");
        // … over when it is applied again (nothing is released after all) …
        brake.slot().submit(Command::Set(60.0), Instant::now());
        assert!((a.over)(brake, &brake.slot().wire()), "applied again");
        // … or when the release has gone out.
        brake.slot().take_newer();
        brake.slot().finish(Command::Set(60.0), true);
        went(brake, Command::Set(1.0), true);
        assert!(
            (a.over)(brake, &brake.slot().wire()),
            "released on the wire"
        );
        // A shift: over when no gear is on its way.
        let drive = Command::State(trans.config().state_index("drive").unwrap());
        trans.slot().submit(drive, Instant::now());
        let a = awaited(&v, Wait::ShiftOut).unwrap();
        assert_eq!((a.device.name(), a.first), ("trans", None));
        assert!(!(a.over)(trans, &trans.slot().wire()));
        trans.slot().take_newer();
        trans.slot().finish(drive, true);
        assert!((a.over)(trans, &trans.slot().wire()));
    }

    /// A set point as a fraction of its range's top; a range whose top is not above
    /// zero is its own scale.
    #[test]
    fn a_share_is_of_the_range_top() {
        let of = |range: &str| {
            crate::config::one_device(&format!(
                "name = \"d\"\nkind = \"setpoint\"\nrange = {range}\ndriver = \"line\""
            ))
        };
        assert_eq!(share(&of("[0.0, 100.0]"), 50.0), 0.5);
        assert_eq!(share(&of("[-4.0, 4.0]"), -1.0), -0.25);
        assert_eq!(share(&of("[-1.0, 0.0]"), -0.5), -0.5, "top 0");
        assert_eq!(share(&of("[-10.0, -2.0]"), -5.0), -5.0, "top below 0");
        assert_eq!(release(&of("[-4.0, 4.0]")), Command::Set(-4.0));
    }

    /// The incident: in drive (acknowledged, reported), reverse went out and the
    /// gearbox fell silent before it answered; `drive` again, pending, was taken for
    /// drive reached — the old acknowledgement and the old report — so a brake release
    /// passed intake while the gearbox was on its way to reverse, and at the wire the
    /// shift back to drive was no shift (the stale report said drive) and went out
    /// with the brake released. What the gearbox reports counts only once it answered
    /// for the last gear it was sent.
    #[test]
    fn a_report_from_before_another_gear_went_out_is_not_the_gear() {
        let gate = crate::testkit::gate(Instant::now());
        let v = gate.vehicle();
        let trans = v.find("trans").unwrap();
        let state = |w: &str| Command::State(trans.config().state_index(w).unwrap());
        let (drive, reverse) = (state("drive"), state("reverse"));
        // In drive: acknowledged, then reported.
        trans.slot().fly(drive);
        trans.slot().finish(drive, true);
        reports(trans, 3.0);
        let f = gather(v, Plays::BRAKE);
        assert_eq!((f.gear, f.shifting), (Some(3), false), "in drive");
        // Reverse goes out and is not answered; drive again, pending.
        trans.slot().fly(reverse);
        trans.slot().finish(reverse, false);
        trans.slot().submit(drive, Instant::now());
        let f = gather(v, Plays::BRAKE);
        assert_eq!((f.gear, f.shifting), (None, true), "on its way somewhere");
        let f = gather_wire(v, Plays::GEAR);
        assert_eq!(f.gear, None, "at the wire too: drive again is a shift");
        // Drive goes out and is acknowledged: a report from before says nothing yet …
        trans.slot().fly(drive);
        trans.slot().finish(drive, true);
        assert!(
            gather(v, Plays::BRAKE).shifting,
            "acknowledged, not yet reported"
        );
        // … a report after it does.
        reports(trans, 3.0);
        let f = gather(v, Plays::BRAKE);
        assert_eq!((f.gear, f.in_gear, f.shifting), (Some(3), true, false));
        // A resend of drive changes nothing.
        trans.slot().fly(drive);
        assert!(!gather(v, Plays::BRAKE).shifting, "a resend in flight");
        trans.slot().finish(drive, true);
        assert!(!gather(v, Plays::BRAKE).shifting, "a resend acknowledged");
    }
}
