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
    use crate::value::Reading;
    use crate::vehicle::Cached;
    use std::time::Instant;

    /// The gearbox reports `state` in a status taken now.
    fn reports(d: &Device, state: f64) {
        let mut r = Reading::default();
        r.set(0, state);
        d.store(Cached {
            reading: r,
            at: Some(Instant::now()),
        });
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
