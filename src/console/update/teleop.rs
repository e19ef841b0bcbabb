//! Teleop's part of [`update`](super::update): entering it, its keys, and what the held
//! keys command ([`crate::console::hold`] says which are held).
//!
//! In **hold** and **repeat** modes the pedals follow the keys held, never a step: `↑`
//! held asks the gas level with a lease the engine ends by itself
//! ([`crate::safety::lease`]), renewed by each event that keeps the hold; `↓` held the
//! brake level; no pedal key held, the hold level (once a pedal key was touched since
//! teleop began; before that nothing is asked). `←`/`→` held move the steering at the
//! set rate from where it was, up to the instant the hold ends, and leave it there. In
//! **step** mode every key is a step, as before holds existed. In every mode a teleop
//! key feeds the deadman, the console's watchdog in the intake.

use super::{ask, clear_override, take, Controls};
use crate::config::{limits, Role, TeleopConfig};
use crate::console::hold::{Did, Drive, HoldKey};
use crate::console::keymap::{Action, Knob, Mode};
use crate::console::model::{Model, Question, BRAKE_STEP, GAS_STEP, STEER_STEP};
use crate::console::sight;
use crate::value::Command;
use crossterm::event::{KeyEvent, KeyEventKind};
use std::time::Instant;

/// Teleop starts from what the vehicle was told: the steering's command (where it has
/// none, where it is) and the throttle and brake as one accel. The levels and a step
/// mode the operator chose stay.
pub(super) fn enter(m: &mut Model) {
    let steer = m.snap.bound("steering");
    let at = m
        .snap
        .steering()
        .or(steer.and_then(|d| d.position()))
        .map_or(0.0, |v| m.snap.steering_share(v));
    let t = &mut m.teleop;
    *t = crate::console::model::Teleop {
        levels: t.levels,
        forced_step: t.forced_step,
        ..crate::console::model::Teleop::new(t.deadman)
    };
    t.steer = at;
    t.accel = m.snap.accel().unwrap_or(0.0);
    m.mode = Mode::Teleop;
    let how = match m.drive() {
        Drive::Hold => "hold the keys to drive (releases reported)".to_string(),
        Drive::Repeat => format!(
            "hold the keys to drive (the key repeat: stops ≤ {} ms after it ends)",
            m.repeat.figures().stops_ms()
        ),
        Drive::Step => "each key a step".to_string(),
    };
    let deadman = m.teleop.deadman.as_secs_f64();
    m.say(
        format!("teleop: {how}; full brake on its key; deadman {deadman:.1}s"),
        false,
    );
}

/// The hold key an action holds.
fn hold_key(a: Action) -> Option<HoldKey> {
    Some(match a {
        Action::AccelUp => HoldKey::Gas,
        Action::AccelDown => HoldKey::Brake,
        Action::SteerLeft => HoldKey::Left,
        Action::SteerRight => HoldKey::Right,
        _ => return None,
    })
}

/// A teleop key was seen: the deadman is fed (armed by the first).
fn feed(m: &mut Model, c: &dyn Controls, at: Instant) {
    let t = &mut m.teleop;
    t.last_key = Some(at.max(t.last_key.unwrap_or(at)));
    t.tripped = false;
    c.deadman(Some(t.deadman));
}

/// A key event before the keymap, with when its bytes were read (`at`): a release of
/// a held key lets it go, whatever the mode (letting go is never refused); in teleop,
/// in hold and repeat modes, a press or repeat of a hold key holds it. Returns whether
/// the event was taken here.
pub(super) fn key(
    m: &mut Model,
    e: &KeyEvent,
    at: Instant,
    c: &dyn Controls,
    now: Instant,
) -> bool {
    let drive = m.drive();
    let f = m.repeat.figures();
    // Any key's event shows the terminal still sends, and no release came for the keys
    // held: they are kept, and the engine's lease with them at once.
    let kept =
        drive == Drive::Hold && e.kind != KeyEventKind::Release && !m.teleop.holds.is_empty();
    if kept {
        m.teleop.holds.alive(&f, e.kind, at);
    }
    let taken = hold_event(m, e, at, c, now, drive);
    if kept && !taken {
        pedals(m, c, now);
    }
    taken
}

/// [`key`]'s part for the hold keys: whether the event was one of theirs.
fn hold_event(
    m: &mut Model,
    e: &KeyEvent,
    at: Instant,
    c: &dyn Controls,
    now: Instant,
    drive: Drive,
) -> bool {
    let f = m.repeat.figures();
    if e.kind == KeyEventKind::Release {
        if !m.teleop.holds.all().any(|h| h.code == e.code) {
            return false;
        }
        steer_to(m, c, at);
        let_go(m, e.code);
        if m.mode == Mode::Teleop {
            feed(m, c, at);
        }
        pedals(m, c, now);
        return true;
    }
    if m.mode != Mode::Teleop || drive == Drive::Step {
        return false;
    }
    let press = KeyEvent {
        kind: KeyEventKind::Press,
        ..*e
    };
    let Some(a) = sight::key(m, &press) else {
        return false;
    };
    let Some(which) = hold_key(a) else {
        return false;
    };
    if let Err(why) = sight::check(m, a) {
        // Not on the screen: this key holds nothing.
        if let_go(m, e.code) {
            pedals(m, c, now);
        }
        let text = sight::refusal(a, &why);
        tracing::info!("console: {text}");
        m.say(text, true);
        return true;
    }
    feed(m, c, at);
    steer_to(m, c, at);
    let was_steering = m.teleop.holds.steer.is_some();
    match m.teleop.holds.key(drive, &f, which, e.code, e.kind, at) {
        Did::Pressed if matches!(which, HoldKey::Left | HoldKey::Right) => {
            if !was_steering {
                m.teleop.steer_from = Some((m.teleop.steer, at));
            } else if let Some((from, _)) = m.teleop.steer_from {
                m.teleop.steer_from = Some((from, at));
            }
        }
        Did::Pressed => m.teleop.full_brake = false,
        Did::Nothing
            if which == HoldKey::Gas
                && e.kind == KeyEventKind::Press
                && m.teleop
                    .holds
                    .pedal
                    .is_some_and(|h| h.key == HoldKey::Brake) =>
        {
            m.say("teleop: no gas while the brake key is held", true);
        }
        _ => {}
    }
    if matches!(which, HoldKey::Gas | HoldKey::Brake) {
        // From the first pedal key on, the pedals are always asked for.
        m.teleop.pedal_keys = true;
    }
    steer_to(m, c, now);
    pedals(m, c, now);
    true
}

/// The held key sent as `code` lets go; whether one did.
fn let_go(m: &mut Model, code: crossterm::event::KeyCode) -> bool {
    match m.teleop.holds.let_go(code) {
        Some(h) => {
            if matches!(h.key, HoldKey::Left | HoldKey::Right) {
                m.teleop.steer_from = None;
            }
            true
        }
        None => false,
    }
}

/// Time passes: the steering moves while its key is held, holds whose events stopped
/// end, and the pedals follow.
pub(super) fn tick(m: &mut Model, c: &dyn Controls, now: Instant) {
    if m.teleop.holds.is_empty() {
        return;
    }
    steer_to(m, c, now);
    let gone = m.teleop.holds.expire(now);
    for h in &gone {
        let what = match h.key {
            HoldKey::Gas => "gas",
            HoldKey::Brake => "brake",
            HoldKey::Left | HoldKey::Right => "steering",
        };
        if matches!(h.key, HoldKey::Left | HoldKey::Right) {
            m.teleop.steer_from = None;
        }
        m.say(
            format!("teleop: {what} let go: its key's events stopped"),
            false,
        );
    }
    pedals(m, c, now);
}

/// Move the steering while its key is held, up to `upto` (or the hold's end), from
/// where it was when the key was pressed; asked of the intake when it moved.
fn steer_to(m: &mut Model, c: &dyn Controls, upto: Instant) {
    let t = &mut m.teleop;
    let (Some(h), Some((from, since))) = (t.holds.steer, t.steer_from) else {
        return;
    };
    let end = upto.min(h.until);
    if end <= since {
        return;
    }
    let dir = if h.key == HoldKey::Left { -1.0 } else { 1.0 };
    let to = (from + dir * t.levels.steer_rate * end.duration_since(since).as_secs_f64())
        .clamp(-1.0, 1.0);
    t.steer_from = Some((to, end));
    let to = (to * 1000.0).round() / 1000.0;
    if to == t.steer {
        return;
    }
    match m.snap.bound_id(Role::Steering) {
        Some(id) => match c.submit(id, Command::Set(m.snap.steering_units(to))) {
            Ok(()) => m.teleop.steer = to,
            Err(why) => {
                m.teleop.holds.steer = None;
                m.teleop.steer_from = None;
                m.say(format!("refused: steer {to:+.2}: {why}"), true);
            }
        },
        None => {
            m.teleop.holds.steer = None;
            m.say("refused: steer: no steering bound", true);
        }
    }
}

/// Ask for what the pedal keys held say, if it is not what was asked last: the gas
/// level on a lease until its hold ends (renewed while it lasts), the brake level, or
/// — no pedal key held, once one was — the hold level. Never gas without a key held.
fn pedals(m: &mut Model, c: &dyn Controls, now: Instant) {
    let t = &m.teleop;
    let l = t.levels;
    let (accel, until) = match t.holds.pedal {
        Some(h) if h.key == HoldKey::Brake => (-l.brake, None),
        Some(h) => (l.gas, Some(h.until)),
        None if !t.pedal_keys || t.full_brake => return,
        None => (-l.hold, None),
    };
    let accel = (accel * 1000.0).round() / 1000.0;
    let Some(until) = until else {
        if t.asked == Some(accel) && t.lease.is_none() {
            return;
        }
        let what = match t.holds.pedal {
            Some(_) => "brake held",
            None => "no pedal key held: the hold brake",
        };
        match c.submit_accel(accel) {
            Ok(()) => {
                applied(m, accel, None);
                m.say(format!("teleop: {what} {:.2}", -accel), false);
            }
            Err(why) => m.say(format!("refused: accel {accel:+.2}: {why}"), true),
        }
        return;
    };
    let left = until.saturating_duration_since(now);
    if left.is_zero() {
        // The hold ran out before it could be asked (a late turn): no gas.
        m.teleop.holds.pedal = None;
        return pedals(m, c, now);
    }
    if t.asked == Some(accel) && t.lease.is_some() {
        if t.lease == Some(until) {
            return;
        }
        match c.renew(left) {
            Ok(true) => {
                m.teleop.lease = Some(until);
                return;
            }
            // The engine ended it (this console was late): asked afresh below, the
            // key being held still.
            Ok(false) => {}
            Err(why) => {
                m.teleop.holds.pedal = None;
                m.teleop.lease = None;
                m.say(format!("refused: gas held: {why}"), true);
                return;
            }
        }
    }
    match c.submit_held(accel, left, -l.hold) {
        Ok(()) => {
            applied(m, accel, Some(until));
            m.say(format!("teleop: gas held {accel:.2}"), false);
        }
        Err(why) => {
            // Refused: the key holds nothing (only a new press asks again).
            m.teleop.holds.pedal = None;
            m.say(format!("refused: gas {accel:.2}: {why}"), true);
        }
    }
}

/// The intake took `accel` (leased until `lease`).
fn applied(m: &mut Model, accel: f64, lease: Option<Instant>) {
    let t = &mut m.teleop;
    t.asked = Some(accel);
    t.lease = lease;
    t.accel = accel;
    m.accel = Some(accel);
}

/// One of a setting's steps.
fn level_step(k: Knob) -> f64 {
    match k {
        Knob::SteerRate => 0.1,
        _ => 0.05,
    }
}

/// A level key: the setting one step up or down, within its limit (and the hold no
/// harder than the brake); what a held key asks follows at once.
fn level(m: &mut Model, c: &dyn Controls, k: Knob, up: bool, now: Instant) {
    let l = m.teleop.levels;
    let (limit, v) = match k {
        Knob::Gas => (&limits::TELEOP_GAS, l.gas),
        Knob::Brake => (&limits::TELEOP_BRAKE, l.brake),
        Knob::Hold => (&limits::TELEOP_HOLD, l.hold),
        Knob::SteerRate => (&limits::TELEOP_STEER_RATE, l.steer_rate),
    };
    let step = if up { level_step(k) } else { -level_step(k) };
    let to = (((v + step) * 100.0).round() / 100.0).clamp(limit.min, limit.max);
    let mut new = l;
    match k {
        Knob::Gas => new.gas = to,
        Knob::Brake => new.brake = to,
        Knob::Hold => new.hold = to,
        Knob::SteerRate => new.steer_rate = to,
    }
    let name = limit.key.replace('_', " ");
    if to == v {
        let end = if up { "most" } else { "least" };
        return m.say(
            format!(
                "teleop: {name} {v} is the {end} (the vehicle file's [teleop] {}: {})",
                limit.key,
                limit.expected()
            ),
            true,
        );
    }
    if let Err(v) = TeleopConfig::check(&new) {
        return m.say(format!("teleop: {name} stays: {}", v.message), true);
    }
    m.teleop.levels = new;
    m.say(format!("teleop: {name} {to}"), false);
    pedals(m, c, now);
}

/// A teleop key by the keymap: in step mode the arrows step; in every mode the taps
/// (full brake, center), the levels, step mode, engage, take, leave. The next set point
/// is asked of the intake; the bar takes what the intake accepted, and a refusal leaves
/// it where it was.
pub(super) fn action(m: &mut Model, a: Action, c: &dyn Controls, now: Instant) {
    let drive = m.drive();
    let t = &m.teleop;
    let (mut steer, mut accel) = (t.steer, t.accel);
    match a {
        // Held, not stepped, outside step mode ([`key`] takes their events).
        _ if hold_key(a).is_some() && drive != Drive::Step => return,
        Action::SteerLeft => steer = (steer - STEER_STEP).max(-1.0),
        Action::SteerRight => steer = (steer + STEER_STEP).min(1.0),
        Action::Center => steer = 0.0,
        Action::AccelUp if accel < 0.0 => accel = 0.0,
        Action::AccelUp => accel = (accel + GAS_STEP).min(1.0),
        Action::AccelDown if accel > 0.0 => accel = 0.0,
        Action::AccelDown => accel = (accel - BRAKE_STEP).max(-1.0),
        Action::FullBrake => accel = -1.0,
        Action::Level(k, up) => return level(m, c, k, up, now),
        Action::StepMode => return step_mode(m, c, now),
        Action::Engage => return ask(m, Question::Engage),
        Action::TakeCommand => return take(m),
        Action::ClearOverride => return clear_override(m, c),
        Action::Back | Action::Cancel => return leave(m, c),
        _ => return,
    }
    // Any teleop key re-arms the deadman (and feeds it).
    feed(m, c, now);
    if a == Action::Center {
        m.teleop.holds.steer = None;
        m.teleop.steer_from = None;
    }
    if a == Action::FullBrake {
        m.teleop.holds.pedal = None;
        m.teleop.lease = None;
        m.teleop.full_brake = true;
    }
    let steer = (steer * 1000.0).round() / 1000.0;
    let accel = (accel * 1000.0).round() / 1000.0;
    let mut refused = Vec::new();
    if steer != m.teleop.steer || a == Action::Center {
        match m.snap.bound_id(Role::Steering) {
            Some(id) => match c.submit(id, Command::Set(m.snap.steering_units(steer))) {
                Ok(()) => m.teleop.steer = steer,
                Err(why) => refused.push(format!("steer {steer:.2}: {why}")),
            },
            None => refused.push("steer: no steering bound".into()),
        }
    }
    if accel != m.teleop.accel
        || matches!(a, Action::AccelUp | Action::AccelDown | Action::FullBrake)
    {
        match c.submit_accel(accel) {
            Ok(()) => applied(m, accel, None),
            Err(why) => refused.push(format!("accel {accel:.2}: {why}")),
        }
    }
    let (steer, accel) = (m.teleop.steer, m.teleop.accel);
    if refused.is_empty() {
        m.say(
            format!("teleop: steer {steer:+.2} accel {accel:+.2}"),
            false,
        );
    } else {
        m.say(
            format!(
                "refused: {}; still steer {steer:+.2} accel {accel:+.2}",
                refused.join("; ")
            ),
            true,
        );
    }
}

/// Step mode on (every key a step) or off (back to what the terminal gives).
fn step_mode(m: &mut Model, c: &dyn Controls, now: Instant) {
    m.teleop.forced_step = !m.teleop.forced_step;
    switched(m, c, now);
}

/// The mode changed (step forced or undone, the terminal found to report releases):
/// keys held are let go first, as they were read the old way, and the bar's message
/// says the new mode.
pub(super) fn switched(m: &mut Model, c: &dyn Controls, now: Instant) {
    let_go_all(m, c, now);
    if m.mode != Mode::Teleop {
        return;
    }
    let text = match m.drive() {
        Drive::Step => "teleop: step — each key a step, the deadman brakes".to_string(),
        d => format!("teleop: {} — hold the keys to drive", d.as_str()),
    };
    m.say(text, false);
}

/// Keys hold only on teleop's own screen: once another covers it (help, a question)
/// or it was left, every key held lets go, as at its release.
pub(super) fn held_only_in_teleop(m: &mut Model, c: &dyn Controls, now: Instant) {
    if m.mode != Mode::Teleop {
        let_go_all(m, c, now);
    }
}

/// Every key held lets go: the steering stays where it got to, the pedals go to the
/// hold level.
fn let_go_all(m: &mut Model, c: &dyn Controls, now: Instant) {
    if m.teleop.holds.is_empty() {
        return;
    }
    steer_to(m, c, now);
    m.teleop.holds.clear();
    m.teleop.steer_from = None;
    pedals(m, c, now);
}

/// Leave teleop: gas 0, brake full, staying engaged — if the console commands.
fn leave(m: &mut Model, c: &dyn Controls) {
    let held = c.hold();
    c.deadman(None);
    m.teleop.last_key = None;
    m.teleop.tripped = false;
    m.teleop.let_go();
    m.mode = Mode::Main;
    match held {
        Ok(()) => {
            m.accel = Some(-1.0);
            m.say("left teleop: gas 0, brake full", false);
        }
        Err(why) => m.say(format!("left teleop; the brake not applied: {why}"), true),
    }
}
