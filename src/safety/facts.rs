//! What the rules need to know, gathered from the bound devices' slots and caches —
//! and only what the command at hand needs: a command to a device no rule looks at
//! gathers nothing, and each fact locks one slot or one cache once.

use super::rules::{Facts, Plays};
use crate::config::Bindings;
use crate::engine::slot::WireState;
use crate::value::Command;
use crate::vehicle::{Device, Vehicle};

/// A set point as a fraction of its device's range top.
fn fraction(d: &Device, v: f64) -> f64 {
    let hi = d.config().range[1];
    if hi > 0.0 {
        v / hi
    } else {
        v
    }
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

/// `c` is a set point of `d` at or below released.
fn releases(d: &Device, c: Option<Command>) -> bool {
    c.and_then(Command::set_point)
        .is_some_and(|x| fraction(d, x) <= super::rules::RELEASED)
}

/// What the gearbox is doing, as its slot and its cache say.
struct Gearbox {
    /// The gear reported.
    reported: Option<u8>,
    /// The reported gear drives the wheels.
    drives: bool,
    /// A shift is under way ([`Facts::shifting`]).
    shifting: bool,
    /// Where a command sent or in flight takes it ([`Facts::bound_for`]).
    bound_for: [Option<u8>; 2],
}

/// The gear reported, whether it drives, whether a shift is under way, and where the
/// commands already on their way take the gearbox. A gear command is *through* once the
/// gearbox acknowledged it and then reported that gear in a status taken after that (a
/// gearbox passing through neutral reports neutral mid-shift: a status from before the
/// command says nothing about it). A shift is under way while the newest gear command,
/// or one in flight behind it, is not through: a command to the gear reported, pending
/// behind a shift still on the wire, hides nothing.
fn gear(v: &Vehicle, b: &Bindings) -> Gearbox {
    let Some(g) = &b.gear else {
        return Gearbox {
            reported: None,
            drives: false,
            shifting: false,
            bound_for: [None; 2],
        };
    };
    let d = v.device(g.device);
    let reported = d
        .config()
        .state()
        .and_then(|i| d.reading(i))
        .map(|x| x as u8);
    let w = d.slot().wire();
    let status_after_ack = match (w.acked_at, d.cached().at) {
        (Some(acked), Some(status)) => status > acked,
        _ => false,
    };
    let through =
        |s: u8| w.acked == Some(Command::State(s)) && status_after_ack && reported == Some(s);
    let not_through = |c: Option<Command>| match c {
        Some(Command::State(s)) if !through(s) => Some(s),
        _ => None,
    };
    let shifting = not_through(w.latest()).is_some() || not_through(w.flight).is_some();
    let sent = not_through(w.sent);
    let flight = not_through(w.flight).filter(|&s| Some(s) != sent);
    Gearbox {
        reported,
        drives: reported.is_some_and(|s| g.drives(s)),
        shifting,
        bound_for: [sent, flight],
    }
}

/// A gear command is pending or in flight for the gearbox that is not the last one
/// sent: a shift on its way, which keeps the brake on until it is out.
pub(crate) fn shift_on_its_way(w: &WireState) -> bool {
    [w.pending, w.flight]
        .into_iter()
        .flatten()
        .any(|c| matches!(c, Command::State(_)) && w.sent != Some(c))
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
        let g = gear(v, b);
        (f.gear, f.in_gear, f.shifting, f.bound_for) =
            (g.reported, g.drives, g.shifting, g.bound_for);
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
            // A gear command not on the wire yet (whatever the gearbox reports: it may be
            // passing through that gear).
            f.shift_on_its_way = shift_on_its_way(&w);
        }
    }
    if plays.throttle || plays.brake {
        f.estop = v.estop();
    }
    if plays.gear {
        let g = gear(v, b);
        (f.gear, f.bound_for) = (g.reported, g.bound_for);
        f.speed = b.speed.and_then(|r| v.reading(r));
    }
    f
}

/// A pedal (throttle or brake) has nothing above released pending, in flight or last
/// sent.
pub(crate) fn released_on_wire(d: &Device, w: &WireState) -> bool {
    [w.pending, w.flight, w.sent]
        .into_iter()
        .flatten()
        .filter_map(Command::set_point)
        .all(|x| fraction(d, x) <= super::rules::RELEASED)
}

/// A set point of `d` as a fraction of its range top (the rules' scale).
pub fn share(d: &Device, v: f64) -> f64 {
    fraction(d, v)
}

/// The brake's newest command (pending, else in flight) applies it.
pub(crate) fn brake_applied_again(d: &Device, w: &WireState) -> bool {
    w.pending
        .or(w.flight)
        .and_then(Command::set_point)
        .is_some_and(|x| fraction(d, x) > super::rules::RELEASED)
}
