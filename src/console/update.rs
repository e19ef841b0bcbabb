//! The only place the console's state changes: [`update`] applies one [`Action`] and
//! [`tick`] advances time (a fresh snapshot, the teleop deadman). Engine effects go
//! through [`Controls`], so both are tested with a recording fake and no terminal.

use super::controls::{Controls, Thread};
use super::keymap::{Action, Mode, SimAction, Target, SIM_SLOW, SIM_VANISH};
use super::model::{Ask, Edit, Field, Model, BRAKE_STEP, GAS_STEP, HOME_WAIT, STEER_STEP};
use crate::exit::Exit;
use crate::value::{Command, Control, EstopState, Gear, Role};
use std::time::{Duration, Instant};

/// What the loop does after an update.
#[derive(Clone, Debug, PartialEq)]
pub enum Flow {
    Continue,
    /// Leave the console (the caller then brings the vehicle to the safe state).
    Exit(Exit),
}

/// Advance time: take a new snapshot, follow up a steering reset, show a new
/// recovery outcome, and run the deadman.
pub fn tick(m: &mut Model, c: &dyn Controls, now: Instant) {
    m.now = now;
    m.snap = c.snapshot(now, m.in_bench().then_some(m.bench));
    m.cursor = m.cursor.min(m.fields().len() - 1);
    follow_steer_reset(m, c, now);
    let outcome = m.snap.supervision.last_outcome.clone();
    if outcome.is_some() && outcome != m.outcome_seen {
        let text = outcome.clone().unwrap_or_default();
        m.say(format!("supervisor: {text}"), text.contains("gave up"));
        m.outcome_seen = outcome;
    }
    let t = &mut m.teleop;
    if let Some(last) = t.last_key {
        if !t.tripped && now.saturating_duration_since(last) >= t.deadman {
            t.tripped = true;
            t.accel = -1.0;
            c.safe_state();
            let secs = t.deadman.as_secs_f64();
            m.accel = Some(-1.0);
            m.say(
                format!("deadman: no teleop key for {secs:.1}s — gas 0, brake full"),
                true,
            );
            tracing::warn!("teleop deadman tripped: gas 0, brake full");
        }
    }
    // The accel shown is the one sent while engaged: once disengaged (STOP, `D`, the
    // gate, the watchdog, the supervisor) the vehicle has gas 0 and the brake full,
    // whatever the console sent before.
    if !m.snap.engaged {
        m.accel = None;
    }
}

/// Apply one action.
pub fn update(m: &mut Model, a: Action, c: &dyn Controls, now: Instant) -> Flow {
    m.now = now;
    match a {
        Action::Interrupt => return Flow::Exit(Exit::Signal(libc::SIGINT)),
        Action::Quit => return Flow::Exit(Exit::Quit),
        Action::Stop => {
            stop(m, c);
            return Flow::Continue;
        }
        Action::Help if !matches!(m.mode, Mode::Help | Mode::Edit | Mode::Confirm) => {
            m.back_to = m.mode;
            m.mode = Mode::Help;
            m.help_scroll = 0;
            return Flow::Continue;
        }
        _ => {}
    }
    match m.mode {
        Mode::Main => main(m, a, c),
        Mode::Edit => edit(m, a, c),
        Mode::Confirm => confirm(m, a, c),
        Mode::Teleop => teleop(m, a, c, now),
        Mode::Bench => bench(m, a, c),
        Mode::Help => match a {
            Action::Up => m.help_scroll = m.help_scroll.saturating_sub(1),
            Action::Down => m.help_scroll = m.help_scroll.saturating_add(1),
            Action::Back | Action::Cancel | Action::Help => m.mode = m.back_to,
            _ => {}
        },
    }
    Flow::Continue
}

fn ask(m: &mut Model, q: Ask) {
    m.ask = Some(q);
    m.back_to = m.mode;
    m.mode = Mode::Confirm;
}

fn wake(m: &mut Model, c: &dyn Controls, role: Role) {
    match m.snap.device(role) {
        Some(d) if d.actuator => {
            c.wake(role);
            m.say(format!("woke the {role} command thread"), false);
        }
        Some(_) => m.say(
            format!("{role} is a sensor: it has no command thread"),
            true,
        ),
        None => m.say(format!("this vehicle has no {role}"), true),
    }
}

fn main(m: &mut Model, a: Action, c: &dyn Controls) {
    match a {
        Action::Up => m.cursor = m.cursor.saturating_sub(1),
        Action::Down => m.cursor = (m.cursor + 1).min(m.fields().len() - 1),
        Action::Left => m.move_device(-1),
        Action::Right => m.move_device(1),
        Action::Edit => start_edit(m, m.field()),
        Action::EditOf(t) => {
            let f = match t {
                Target::Accel => Field::Accel,
                Target::Device(r) => Field::Command(r),
            };
            if m.select(f) {
                start_edit(m, f);
            } else {
                m.say(format!("this vehicle has no {}", f.name()), true);
            }
        }
        Action::Wake(Some(r)) => wake(m, c, r),
        Action::Wake(None) => match m.field().role() {
            Some(r) => wake(m, c, r),
            None => m.say("move the cursor to a device to wake it", true),
        },
        Action::WakeAll => {
            let roles: Vec<Role> = m
                .snap
                .devices
                .iter()
                .filter(|d| d.actuator)
                .map(|d| d.role)
                .collect();
            for r in &roles {
                c.wake(*r);
            }
            m.say(format!("woke {} command threads", roles.len()), false);
        }
        Action::ResetSteering => reset_steering(m, c),
        Action::Engage => ask(m, Ask::Engage),
        Action::Disengage => ask(m, Ask::Disengage),
        Action::Interlocks => ask(m, Ask::Interlocks(!m.snap.interlocks)),
        Action::Teleop => enter_teleop(m),
        Action::Bench => {
            if let Some(r) = m.field().role() {
                m.bench = r;
            }
            m.mode = Mode::Bench;
        }
        _ => {}
    }
}

/// The text a field starts from when editing.
fn current_text(m: &Model, f: Field) -> String {
    let d = f.role().and_then(|r| m.snap.device(r));
    match (f, d) {
        (Field::Command(_), Some(d)) => d.latest.map(|c| c.to_string()).unwrap_or_default(),
        (Field::StDelay(_), Some(d)) => fmt_ms(d.status_period),
        (Field::CmDelay(_), Some(d)) => fmt_ms(d.command_timeout),
        (Field::StatusOn(_), Some(d)) => (d.status_on as u8).to_string(),
        (Field::CommandOn(_), Some(d)) => (d.command_on as u8).to_string(),
        (Field::Accel, _) => m.accel.map(|a| format!("{a:.3}")).unwrap_or_default(),
        _ => String::new(),
    }
}

/// A duration as the console writes it: whole milliseconds.
pub fn fmt_ms(d: Duration) -> String {
    format!("{}ms", d.as_millis())
}

fn start_edit(m: &mut Model, f: Field) {
    let buffer = current_text(m, f);
    m.edit = Some(Edit {
        field: f,
        buffer,
        fresh: true,
        error: None,
    });
    if m.mode != Mode::Edit {
        m.back_to = m.mode;
    }
    m.mode = Mode::Edit;
}

/// What a committed edit does.
#[derive(Debug, PartialEq)]
enum Apply {
    Submit(Role, Command),
    Accel(f64),
    StDelay(Role, Duration),
    CmDelay(Role, Duration),
    Enable(Role, Thread, bool),
}

fn parse_number(text: &str, lo: f64, hi: f64) -> Result<f64, String> {
    let v: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number: expected a value from {lo} to {hi}"))?;
    if !v.is_finite() || v < lo || v > hi {
        return Err(format!("{v} is out of range: expected {lo} … {hi}"));
    }
    Ok(v)
}

/// `50ms`, `1s`, `1.5s` or a bare number of milliseconds. Its range is the vehicle
/// file's, checked where the value is applied ([`Controls::set_status_period`]).
fn parse_period(text: &str) -> Result<Duration, String> {
    let t = text.trim();
    match t.parse::<f64>() {
        Ok(ms) if ms.is_finite() && (0.0..1e12).contains(&ms) => {
            Ok(Duration::from_secs_f64(ms / 1000.0))
        }
        _ => humantime::parse_duration(t).map_err(|_| {
            format!("{t:?} is not a duration: expected milliseconds (250) or 250ms, 1s, 1.5s")
        }),
    }
}

fn parse_flag(text: &str) -> Result<bool, String> {
    match text.trim().to_ascii_lowercase().as_str() {
        "1" | "on" | "yes" | "y" | "true" => Ok(true),
        "0" | "off" | "no" | "n" | "false" => Ok(false),
        t => Err(format!("{t:?}: expected 1 (on) or 0 (off)")),
    }
}

fn parse_edit(m: &Model, f: Field, text: &str) -> Result<Apply, String> {
    match f {
        Field::Command(Role::Trans) => text
            .parse::<Gear>()
            .map(|g| Apply::Submit(Role::Trans, Command::Gear(g))),
        Field::Command(r) => {
            let [lo, hi] = m.snap.device(r).map(|d| d.range).unwrap_or([-1.0, 1.0]);
            parse_number(text, lo, hi).map(|v| Apply::Submit(r, Command::Set(v)))
        }
        Field::Accel => parse_number(text, -1.0, 1.0).map(Apply::Accel),
        Field::StDelay(r) => parse_period(text).map(|d| Apply::StDelay(r, d)),
        Field::CmDelay(r) => parse_period(text).map(|d| Apply::CmDelay(r, d)),
        Field::StatusOn(r) => parse_flag(text).map(|on| Apply::Enable(r, Thread::Status, on)),
        Field::CommandOn(r) => parse_flag(text).map(|on| Apply::Enable(r, Thread::Command, on)),
    }
}

fn edit(m: &mut Model, a: Action, c: &dyn Controls) {
    let Some(e) = m.edit.as_mut() else {
        m.mode = m.back_to;
        return;
    };
    match a {
        Action::Input(ch) => {
            if e.fresh {
                e.buffer.clear();
                e.fresh = false;
            }
            e.buffer.push(ch);
            e.error = None;
        }
        Action::Backspace => {
            e.fresh = false;
            e.buffer.pop();
            e.error = None;
        }
        Action::Clear => {
            e.buffer.clear();
            e.fresh = false;
            e.error = None;
        }
        Action::Cancel | Action::Back => {
            m.edit = None;
            m.mode = m.back_to;
        }
        Action::Commit => {
            let (field, text) = (e.field, e.buffer.clone());
            match parse_edit(m, field, &text) {
                Err(why) => {
                    if let Some(e) = m.edit.as_mut() {
                        e.error = Some(why);
                    }
                }
                Ok(apply) => {
                    let pending = m.edit.take();
                    m.mode = m.back_to;
                    // A setting the vehicle file would refuse: stay in the field.
                    if let Err(why) = run_apply(m, c, field, apply) {
                        m.edit = pending.map(|e| Edit {
                            error: Some(why),
                            ..e
                        });
                        m.mode = Mode::Edit;
                    }
                }
            }
        }
        _ => {}
    }
}

/// Apply a committed edit; `Err` when a setting is refused (the edit stays open).
fn run_apply(m: &mut Model, c: &dyn Controls, field: Field, apply: Apply) -> Result<(), String> {
    match apply {
        Apply::Submit(r, cmd) => match c.submit(r, cmd) {
            Ok(()) => m.say(format!("{r} ← {cmd}"), false),
            Err(why) => m.say(format!("{r} {cmd} refused: {why}"), true),
        },
        Apply::Accel(a) => match c.submit_accel(a) {
            Ok(()) => {
                m.accel = Some(a);
                m.say(format!("accel ← {a:.3}"), false)
            }
            Err(why) => m.say(format!("accel {a:.3} refused: {why}"), true),
        },
        Apply::StDelay(r, d) => {
            c.set_status_period(r, d)?;
            m.say(format!("{} = {}", field.name(), fmt_ms(d)), false);
        }
        Apply::CmDelay(r, d) => {
            c.set_command_timeout(r, d)?;
            m.say(format!("{} = {}", field.name(), fmt_ms(d)), false);
        }
        Apply::Enable(r, t, on) => {
            c.set_enabled(r, t, on);
            m.say(
                format!("{} {}", field.name(), if on { "on" } else { "off" }),
                false,
            );
        }
    }
    Ok(())
}

fn confirm(m: &mut Model, a: Action, c: &dyn Controls) {
    match a {
        Action::Confirm => {
            let q = m.ask.take();
            m.mode = m.back_to;
            match q {
                Some(Ask::Engage) => match c.engage() {
                    Ok(()) => m.say("engaged", false),
                    Err(why) => m.say(format!("engage refused: {}", why.join("; ")), true),
                },
                Some(Ask::Disengage) => {
                    c.disengage("operator, from the console");
                    m.say("disengaged: gas 0, brake full", false);
                }
                Some(Ask::Interlocks(on)) => {
                    c.set_interlocks(on);
                    m.say(format!("interlocks {}", if on { "ON" } else { "OFF" }), !on);
                }
                None => {}
            }
        }
        Action::Cancel | Action::Back => {
            m.ask = None;
            m.mode = m.back_to;
            m.say("cancelled", false);
        }
        _ => {}
    }
}

fn enter_teleop(m: &mut Model) {
    let steer = m.snap.device(Role::Steer);
    let at = steer
        .and_then(|d| d.reading.position)
        .or(steer.and_then(|d| d.latest.map(|c| c.as_f64())))
        .unwrap_or(0.0);
    let deadman = m.teleop.deadman;
    m.teleop = super::model::Teleop::new(deadman);
    m.teleop.steer = at;
    m.mode = Mode::Teleop;
    m.say(
        format!(
            "teleop: steer and accel with the keys, full brake on its key; deadman {:.1}s",
            deadman.as_secs_f64()
        ),
        false,
    );
}

fn teleop(m: &mut Model, a: Action, c: &dyn Controls, now: Instant) {
    let t = &mut m.teleop;
    let (steer0, accel0) = (t.steer, t.accel);
    match a {
        Action::SteerLeft => t.steer = (t.steer - STEER_STEP).max(-1.0),
        Action::SteerRight => t.steer = (t.steer + STEER_STEP).min(1.0),
        Action::Center => t.steer = 0.0,
        Action::AccelUp if t.accel < 0.0 => t.accel = 0.0,
        Action::AccelUp => t.accel = (t.accel + GAS_STEP).min(1.0),
        Action::AccelDown if t.accel > 0.0 => t.accel = 0.0,
        Action::AccelDown => t.accel = (t.accel - BRAKE_STEP).max(-1.0),
        Action::FullBrake => t.accel = -1.0,
        Action::Engage => return ask(m, Ask::Engage),
        Action::Back | Action::Cancel => {
            c.safe_state();
            m.teleop.last_key = None;
            m.teleop.tripped = false;
            m.accel = Some(-1.0);
            m.mode = Mode::Main;
            m.say("left teleop: gas 0, brake full", false);
            return;
        }
        _ => return,
    }
    // Any teleop key re-arms the deadman.
    t.last_key = Some(now);
    t.tripped = false;
    t.steer = (t.steer * 1000.0).round() / 1000.0;
    t.accel = (t.accel * 1000.0).round() / 1000.0;
    let (steer, accel) = (t.steer, t.accel);
    let mut refused = Vec::new();
    if steer != steer0 || a == Action::Center {
        if let Err(why) = c.submit(Role::Steer, Command::Set(steer)) {
            refused.push(format!("steer {steer:.2}: {why}"));
        }
    }
    if accel != accel0 || matches!(a, Action::AccelUp | Action::AccelDown | Action::FullBrake) {
        match c.submit_accel(accel) {
            Ok(()) => m.accel = Some(accel),
            Err(why) => refused.push(format!("accel {accel:.2}: {why}")),
        }
    }
    if refused.is_empty() {
        m.say(
            format!("teleop: steer {steer:+.2} accel {accel:+.2}"),
            false,
        );
    } else {
        m.say(format!("refused: {}", refused.join("; ")), true);
    }
}

/// The operator's stop, the same from every mode: no question asked, and whatever was
/// half done (an edit, a question) is dropped. Teleop stays, its brake full and its
/// deadman idle until the next key.
fn stop(m: &mut Model, c: &dyn Controls) {
    c.disengage("operator stop from the console");
    if matches!(m.mode, Mode::Edit | Mode::Confirm) {
        m.edit = None;
        m.ask = None;
        m.mode = m.back_to;
    }
    if m.mode == Mode::Teleop {
        m.teleop.accel = -1.0;
        m.teleop.last_key = None;
        m.teleop.tripped = false;
    }
    m.say("STOP: disengaged, gas 0, brake full", true);
}

fn bench(m: &mut Model, a: Action, c: &dyn Controls) {
    let roles: Vec<Role> = m.snap.devices.iter().map(|d| d.role).collect();
    let i = roles.iter().position(|r| *r == m.bench).unwrap_or(0);
    match a {
        Action::NextDevice | Action::Right | Action::Down if !roles.is_empty() => {
            m.bench = roles[(i + 1) % roles.len()]
        }
        Action::PrevDevice | Action::Left | Action::Up if !roles.is_empty() => {
            m.bench = roles[(i + roles.len() - 1) % roles.len()]
        }
        Action::Edit => match m.bench_device() {
            Some(d) if d.actuator => {
                let f = Field::Command(d.role);
                m.select(f);
                start_edit(m, f);
            }
            _ => m.say(
                format!("{} is a sensor: it takes no commands", m.bench),
                true,
            ),
        },
        Action::Wake(_) => wake(m, c, m.bench),
        Action::Sim(what) => sim(m, c, what),
        Action::Back | Action::Cancel => m.mode = Mode::Main,
        _ => {}
    }
}

/// The paper's `e`, after the operator disabled and re-enabled the steering drive:
/// home it now; [`tick`] then commands it to hold where it stopped, once the drive
/// acknowledged the home command. (A latched drive fault needs the disable → enable
/// cycle first; the supervisor's `steering` procedure runs that whole sequence when the
/// drive reports a fault, once the vehicle is engaged.)
fn reset_steering(m: &mut Model, c: &dyn Controls) {
    if m.snap.device(Role::Steer).is_none() {
        return m.say("steering reset refused: this vehicle has no steering", true);
    }
    match c.submit(Role::Steer, Command::Control(Control::Home)) {
        Ok(()) => {
            m.steer_reset = Some(m.now);
            m.say(
                "steering reset: home sent; it will hold where it stops",
                false,
            );
        }
        Err(why) => m.say(format!("steering reset refused: {why}"), true),
    }
}

/// The second half of `e`: hold once home is acknowledged, or give up after
/// [`HOME_WAIT`].
fn follow_steer_reset(m: &mut Model, c: &dyn Controls, now: Instant) {
    let Some(since) = m.steer_reset else { return };
    let steer = m.snap.device(Role::Steer);
    let homed = steer.is_some_and(|d| d.executed == Some(Command::Control(Control::Home)));
    let at = steer.and_then(|d| d.reading.position);
    match at {
        Some(at) if homed => {
            m.steer_reset = None;
            let at = (at * 1000.0).round() / 1000.0;
            match c.submit(Role::Steer, Command::Set(at)) {
                Ok(()) => m.say(format!("steering reset: homed, holding {at:.3}"), false),
                Err(why) => m.say(
                    format!("steering reset: homed, but hold {at:.3} refused: {why}"),
                    true,
                ),
            }
        }
        _ if now.saturating_duration_since(since) > HOME_WAIT => {
            m.steer_reset = None;
            m.say(
                format!(
                    "steering reset: home not acknowledged within {}s (a latched drive fault \
                     needs disable → enable first)",
                    HOME_WAIT.as_secs()
                ),
                true,
            );
        }
        _ => {}
    }
}

/// The simulator line a bench key means for `role`, from the faults it has now.
pub fn sim_line(m: &Model, what: SimAction, role: Role) -> String {
    let f = m
        .snap
        .device(role)
        .and_then(|d| d.sim.clone())
        .unwrap_or_default();
    let on = |b: bool| if b { "off" } else { "on" };
    match what {
        SimAction::Silent => format!("silent {role} {}", on(f.silent)),
        SimAction::Garbage => format!("garbage {role} {}", on(f.garbage)),
        SimAction::Corrupt => format!("corrupt {role} {}", on(f.corrupt)),
        SimAction::Slow if f.slow_ms > 0 => format!("slow {role} 0"),
        SimAction::Slow => format!("slow {role} {}", SIM_SLOW.as_millis()),
        SimAction::Vanish => format!("vanish {role} {}", SIM_VANISH.as_millis()),
        SimAction::Clear => format!("clear {role}"),
        SimAction::Stall => "stall".into(),
        SimAction::Jam => "jam steer".into(),
        SimAction::Estop(s) => format!("estop {s}"),
    }
}

/// A bench fault key: tell the simulator, say what happened, show it at once.
fn sim(m: &mut Model, c: &dyn Controls, what: SimAction) {
    let line = sim_line(m, what, m.bench);
    match c.sim(&line) {
        None => m.say(
            "fault injection needs --sim (devices simulated in this process)",
            true,
        ),
        Some(Err(e)) => m.say(format!("sim: {e}"), true),
        Some(Ok(done)) => {
            let harmless = matches!(what, SimAction::Clear | SimAction::Estop(EstopState::Run))
                || done.ends_with(" off")
                || done.ends_with(" 0");
            m.say(format!("sim: {done}"), !harmless);
            m.snap = c.snapshot(m.now, Some(m.bench));
        }
    }
}

#[cfg(test)]
mod tests;
