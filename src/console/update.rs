//! The only place the console's state changes: [`update`] applies one [`Action`] and
//! [`tick`] advances time (a fresh snapshot, the teleop deadman). Engine effects go
//! through [`Controls`], so both are tested with a recording fake and no terminal.

use super::keymap::{Action, Mode, SimAction, Target, SIM_SLOW, SIM_VANISH};
use super::model::{Edit, Field, Model, Question, SeenKey, HOME_WAIT, SEEN_KEYS};
use super::sight;
use crate::config::Role;
use crate::controls::{Controls, Thread};
use crate::exit::Exit;
use crate::snapshot::DeviceView;
use crate::value::{Command, Control, DeviceId, EstopState, Value};
use crossterm::event::KeyEvent;
use std::time::{Duration, Instant};

mod characterize;
mod find;
mod teleop;

/// What the loop does after an update.
#[derive(Clone, Debug, PartialEq)]
pub enum Flow {
    Continue,
    /// Leave the console (the caller then brings the vehicle to the safe state).
    Exit(Exit),
}

/// Advance time: take a new snapshot (on the bench, its device's sample for the
/// chart), follow up a steering reset, show a new
/// recovery outcome, end teleop's holds whose key events stopped, and show what the
/// deadman did.
pub fn tick(m: &mut Model, c: &dyn Controls, now: Instant) {
    m.now = now;
    m.show_news();
    m.snap = c.scene(now, m.in_bench().then_some(m.bench));
    if m.in_bench() {
        if let Some(d) = m.snap.at(m.bench) {
            m.trail.push(m.bench, d, now);
        }
    }
    m.cursor = m.cursor.min(m.fields().len().saturating_sub(1));
    // A STOP not confirmed is, once adrive speaks again and says disengaged.
    if m.stop_unconfirmed.is_some() && m.snap.quiet.is_none() && !m.snap.gate.engaged {
        m.stop_unconfirmed = None;
        m.tell("adrive answers again: the vehicle is disengaged", false);
    }
    characterize::tick(m, c);
    follow_steer_reset(m, c, now);
    let sup = &m.snap.supervisor;
    if sup.outcomes > m.outcomes_seen {
        if let Some(text) = sup.last_outcome.clone() {
            let bad = sup.outcome == Some(crate::snapshot::OutcomeKind::GaveUp);
            m.tell(format!("supervisor: {text}"), bad);
        }
    }
    m.outcomes_seen = m.snap.supervisor.outcomes;
    // Someone else's command refused because of who commands: say it where the
    // operator looks (the log pane has it at WARN too).
    if m.snap.gate.refused > m.refused_seen {
        if let Some(text) = m.snap.gate.last_refused.clone() {
            m.tell(text, true);
        }
    }
    m.refused_seen = m.snap.gate.refused;
    // The deadman is the console's watchdog in the intake; here only what it did.
    // Said once, when it happens: the watchdog stands tripped until the next engage,
    // and a key after a STOP is no new trip.
    let t = &mut m.teleop;
    let deadman_tripped = m.snap.gate.deadman_tripped();
    let new_trip = deadman_tripped && !m.deadman_trip_seen;
    m.deadman_trip_seen = deadman_tripped;
    // Engaged again (or the trip otherwise over): the deadman idles until the next
    // teleop key, as the intake's does.
    if t.tripped && !deadman_tripped {
        t.tripped = false;
        t.last_key = None;
    }
    if t.last_key.is_some() && !t.tripped && new_trip {
        t.let_go();
        t.tripped = true;
        t.accel = -1.0;
        m.accel = Some(-1.0);
        let secs = t.deadman.as_secs_f64();
        m.say(
            format!(
                "deadman: no teleop key for {secs:.1}s — gas 0, brake full, disengaged (E engages)"
            ),
            true,
        );
    }
    // What the vehicle was told, not what the console asked: the accel shown (while
    // engaged: once disengaged — STOP, `D`, the gate, the watchdog, the supervisor —
    // the vehicle has gas 0 and the brake full, whatever the console sent before) and
    // the teleop bar follow the commands the intake accepted, whoever sent them.
    let applied = m.snap.accel();
    m.accel = if m.snap.gate.engaged {
        applied.or(m.accel)
    } else {
        None
    };
    if m.in_teleop() {
        if let Some(a) = applied {
            m.teleop.accel = a;
        }
        if let Some(s) = m.snap.steering() {
            m.teleop.steer = m.snap.steering_share(s);
        }
    }
    teleop::tick(m, c, now);
}

/// A key event from the terminal, its bytes read at `at`: kept for the key-event
/// viewer and taught to the key-repeat learner; a teleop hold key's press, repeat or
/// release drives teleop's holds; anything else goes through the keymap to [`update`]
/// (a release nowhere: a repeat acts as a press).
pub fn key(m: &mut Model, e: &KeyEvent, at: Instant, c: &dyn Controls, now: Instant) -> Flow {
    m.now = now;
    if m.keys.len() == SEEN_KEYS {
        m.keys.pop_front();
    }
    m.keys.push_back(SeenKey {
        code: e.code,
        modifiers: e.modifiers,
        kind: e.kind,
        at,
    });
    m.repeat.see(e.code, e.kind, at);
    let flow = match teleop::key(m, e, at, c, now) {
        true => Flow::Continue,
        false => match sight::key(m, e) {
            Some(a) => update(m, a, c, now),
            None => Flow::Continue,
        },
    };
    teleop::held_only_in_teleop(m, c, now);
    flow
}

/// The console found what its terminal reports of the keys (at start, or upgraded by
/// a late answer); teleop read them `before`: if the mode changed, keys held the old
/// way are let go, and teleop reads them the new way from here.
pub fn keyboard(m: &mut Model, before: super::hold::Drive, c: &dyn Controls, now: Instant) {
    if m.drive() != before {
        teleop::switched(m, c, now);
    }
}

/// Apply one action — unless its target was not on the last frame drawn
/// ([`sight::check`]): then it is refused, and the operator told.
pub fn update(m: &mut Model, a: Action, c: &dyn Controls, now: Instant) -> Flow {
    m.now = now;
    if let Err(why) = sight::check(m, a) {
        let text = sight::refusal(a, &why);
        tracing::info!("console: {text}");
        m.say(text, true);
        return Flow::Continue;
    }
    match a {
        Action::Interrupt => return Flow::Exit(Exit::Signal(libc::SIGINT)),
        Action::Quit => return Flow::Exit(Exit::Quit),
        Action::Stop => {
            stop(m, c);
            return Flow::Continue;
        }
        Action::Help if !matches!(m.mode, Mode::Help | Mode::Edit | Mode::Confirm | Mode::Find) => {
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
        Mode::Teleop => teleop::action(m, a, c, now),
        Mode::Bench => bench(m, a, c),
        Mode::Find => find::prompt(m, a),
        Mode::Help => match a {
            Action::Up => m.help_scroll = m.help_scroll.saturating_sub(1),
            Action::Down => m.help_scroll = m.help_scroll.saturating_add(1),
            Action::Back | Action::Cancel | Action::Help => m.mode = m.back_to,
            Action::KeyEvents => m.key_viewer = !m.key_viewer,
            _ => {}
        },
    }
    Flow::Continue
}

pub(super) fn ask(m: &mut Model, q: Question) {
    m.ask = Some(q);
    m.back_to = m.mode;
    m.mode = Mode::Confirm;
}

fn wake(m: &mut Model, c: &dyn Controls, id: DeviceId) {
    match m.snap.at(id) {
        Some(d) if d.is_actuator() => {
            let name = d.name.clone();
            match c.wake(id) {
                Ok(()) => m.say(format!("woke the {name} command thread"), false),
                Err(why) => m.say(format!("wake {name} refused: {why}"), true),
            }
        }
        Some(d) => {
            let name = d.name.clone();
            m.say(
                format!("{name} is a sensor: it has no command thread"),
                true,
            )
        }
        None => m.say("no such device", true),
    }
}

/// The device bound to `role`, or say there is none.
fn bound(m: &mut Model, role: Role) -> Option<DeviceId> {
    let id = m.snap.bound_id(role);
    if id.is_none() {
        m.say(
            format!("this vehicle has no {role} bound (vehicle.roles)"),
            true,
        );
    }
    id
}

fn main(m: &mut Model, a: Action, c: &dyn Controls) {
    match a {
        Action::Up => m.cursor = m.cursor.saturating_sub(1),
        Action::Down => m.cursor = (m.cursor + 1).min(m.fields().len() - 1),
        Action::Left => m.move_device(-1),
        Action::Right => m.move_device(1),
        Action::PageDown => m.move_device(m.page() as isize),
        Action::PageUp => m.move_device(-(m.page() as isize)),
        Action::Find => find::open(m),
        Action::FindNext => find::again(m, 1),
        Action::FindPrev => find::again(m, -1),
        Action::Edit => start_edit(m, m.field()),
        Action::EditOf(t) => {
            let f = match t {
                Target::Accel if m.snap.gate.accel => Field::Accel,
                Target::Accel => {
                    return m.say(
                        "this vehicle has no accel (it needs throttle and brake bound)",
                        true,
                    )
                }
                Target::Device(r) => match bound(m, r) {
                    Some(id) => Field::Command(id),
                    None => return,
                },
            };
            if m.select(f) {
                start_edit(m, f);
            } else {
                let name = f.name(&m.snap);
                m.say(format!("this vehicle has no {name}"), true);
            }
        }
        Action::Wake(Some(r)) => {
            if let Some(id) = bound(m, r) {
                wake(m, c, id)
            }
        }
        Action::Wake(None) => match m.field().device() {
            Some(r) => wake(m, c, r),
            None => m.say("move the cursor to a device to wake it", true),
        },
        Action::WakeAll => {
            let ids: Vec<DeviceId> = m
                .snap
                .devices
                .iter()
                .enumerate()
                .filter(|(_, d)| d.is_actuator())
                .map(|(i, _)| DeviceId(i as u16))
                .collect();
            let refused: Vec<String> = ids.iter().filter_map(|id| c.wake(*id).err()).collect();
            match refused.first() {
                None => m.say(format!("woke {} command threads", ids.len()), false),
                Some(why) => m.say(format!("wake all refused: {why}"), true),
            }
        }
        Action::ResetSteering => reset_steering(m, c),
        Action::Engage => ask(m, Question::Engage),
        Action::Disengage => ask(m, Question::Disengage),
        Action::Interlocks => ask(m, Question::Interlocks(!m.snap.gate.interlocks)),
        Action::ClearOverride => clear_override(m, c),
        Action::TakeCommand => take(m),
        Action::ReleaseCommand => release(m, c),
        Action::Teleop => teleop::enter(m),
        Action::Bench => {
            if let Some(r) = m.field().device() {
                m.bench = r;
            }
            m.mode = Mode::Bench;
        }
        _ => {}
    }
}

/// The text a field starts from when editing.
fn current_text(m: &Model, f: Field) -> String {
    let d = f.device().and_then(|r| m.snap.at(r));
    let ms = |x: f64| fmt_ms(Duration::from_secs_f64(x / 1e3));
    match (f, d) {
        (Field::Command(_), Some(d)) => match &d.commanded {
            Some(Value::Number(v)) => format!("{v:.3}"),
            Some(v) => v.to_string(),
            None => String::new(),
        },
        (Field::StDelay(_), Some(d)) => ms(d.settings.status_period_ms),
        (Field::CmDelay(_), Some(d)) => ms(d.settings.command_timeout_ms),
        (Field::StatusOn(_), Some(d)) => (d.settings.status_on as u8).to_string(),
        (Field::CommandOn(_), Some(d)) => (d.settings.command_on as u8).to_string(),
        (Field::Accel, _) => m.accel.map(|a| format!("{a:.3}")).unwrap_or_default(),
        _ => String::new(),
    }
}

/// A duration as the console writes it: whole milliseconds.
pub(crate) fn fmt_ms(d: Duration) -> String {
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
    Submit(DeviceId, Command),
    Accel(f64),
    StDelay(DeviceId, Duration),
    CmDelay(DeviceId, Duration),
    Enable(DeviceId, Thread, bool),
}

pub(crate) fn parse_number(text: &str, lo: f64, hi: f64) -> Result<f64, String> {
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

fn parse_edit(c: &dyn Controls, f: Field, text: &str) -> Result<Apply, String> {
    match f {
        Field::Command(r) => c.parse(r, text).map(|cmd| Apply::Submit(r, cmd)),
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
            match parse_edit(c, field, &text) {
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

/// A command in words for device `id`: `0.250`, `drive`, `home`.
pub fn words(m: &Model, id: DeviceId, cmd: Command) -> String {
    match cmd {
        Command::Set(v) => format!("{v:.3}"),
        Command::State(s) => m
            .snap
            .at(id)
            .and_then(|d| d.states.get(s as usize).cloned())
            .unwrap_or_else(|| format!("#{s}")),
        Command::Control(k) => k.to_string(),
    }
}

fn name_of(m: &Model, id: DeviceId) -> String {
    m.snap
        .at(id)
        .map_or("?".into(), |d: &DeviceView| d.name.clone())
}

/// Apply a committed edit; `Err` when a setting is refused (the edit stays open).
fn run_apply(m: &mut Model, c: &dyn Controls, field: Field, apply: Apply) -> Result<(), String> {
    let fname = field.name(&m.snap);
    match apply {
        Apply::Submit(r, cmd) => {
            let (name, w) = (name_of(m, r), words(m, r, cmd));
            match c.submit(r, cmd) {
                Ok(()) => m.say(format!("{name} ← {w}"), false),
                Err(why) => m.say(format!("{name} {w} refused: {why}"), true),
            }
        }
        Apply::Accel(a) => match c.submit_accel(a) {
            Ok(()) => {
                m.accel = Some(a);
                m.say(format!("accel ← {a:.3}"), false)
            }
            Err(why) => m.say(format!("accel {a:.3} refused: {why}"), true),
        },
        Apply::StDelay(r, d) => {
            c.set_status_period(r, d)?;
            m.say(format!("{fname} = {}", fmt_ms(d)), false);
        }
        Apply::CmDelay(r, d) => {
            c.set_command_timeout(r, d)?;
            m.say(format!("{fname} = {}", fmt_ms(d)), false);
        }
        Apply::Enable(r, t, on) => {
            let word = if on { "on" } else { "off" };
            match c.set_enabled(r, t, on) {
                Ok(()) => m.say(format!("{fname} {word}"), false),
                Err(why) => m.say(format!("{fname} {word} refused: {why}"), true),
            }
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
                Some(Question::Engage) => match c.engage() {
                    Ok(done) => m.say(done.to_string(), false),
                    Err(why) => m.say(format!("engage refused: {why}"), true),
                },
                Some(Question::Disengage) => match c.disengage() {
                    Ok(done) => m.say(done.to_string(), false),
                    Err(why) => m.say(format!("disengage not done: {why}"), true),
                },
                Some(Question::Take) => match c.take() {
                    Ok(()) => m.say("the console commands the vehicle", false),
                    Err(why) => m.say(format!("take command refused: {why}"), true),
                },
                Some(Question::Interlocks(on)) => match c.set_interlocks(on) {
                    Ok(()) => m.say(format!("interlocks {}", if on { "ON" } else { "OFF" }), !on),
                    Err(why) => m.say(format!("interlocks refused: {why}"), true),
                },
                Some(Question::Characterize(id)) => characterize::confirmed(m, c, id),
                None => {}
            }
        }
        Action::Cancel | Action::Back => {
            m.ask = None;
            m.characterize_ask = None;
            m.mode = m.back_to;
            m.say("cancelled", false);
        }
        _ => {}
    }
}

/// The operator's stop, the same from every mode: no question asked, and whatever was
/// half done (an edit, a question, the name prompt) is dropped. Teleop stays, its brake full and its
/// deadman idle until the next key.
fn stop(m: &mut Model, c: &dyn Controls) {
    let done = c.stop();
    if matches!(m.mode, Mode::Edit | Mode::Confirm | Mode::Find) {
        m.edit = None;
        m.ask = None;
        m.characterize_ask = None;
        m.find = None;
        m.mode = m.back_to;
    }
    if m.mode == Mode::Teleop {
        c.deadman(None);
        m.teleop.last_key = None;
        m.teleop.tripped = false;
    }
    // Nothing held stays held past a STOP, in any mode.
    m.teleop.let_go();
    match done {
        Ok(()) => {
            if m.mode == Mode::Teleop {
                m.teleop.accel = -1.0;
            }
            m.stop_unconfirmed = None;
            m.say("STOP: disengaged, gas 0, brake full", true)
        }
        // Only an attached console's adrive can fail to take it: say so, loudly, and
        // keep saying so until adrive shows the vehicle disengaged.
        Err(why) => {
            m.stop_unconfirmed = Some((m.now, why.to_string()));
            m.say(format!("STOP NOT CONFIRMED: {why}"), true)
        }
    }
}

fn bench(m: &mut Model, a: Action, c: &dyn Controls) {
    let n = m.snap.devices.len() as u16;
    let i = m.bench.0;
    if characterize::holds_the_bench(m, a) {
        return;
    }
    match a {
        Action::NextDevice | Action::Right | Action::Down if n > 0 => {
            m.bench = DeviceId((i + 1) % n)
        }
        Action::PrevDevice | Action::Left | Action::Up if n > 0 => {
            m.bench = DeviceId((i + n - 1) % n)
        }
        Action::Edit => match m.bench_device() {
            Some(d) if d.is_actuator() => {
                let f = Field::Command(m.bench);
                m.select(f);
                start_edit(m, f);
            }
            _ => {
                let name = name_of(m, m.bench);
                m.say(format!("{name} is a sensor: it takes no commands"), true)
            }
        },
        Action::Wake(_) => wake(m, c, m.bench),
        Action::Find => find::open(m),
        Action::FindNext => find::again(m, 1),
        Action::FindPrev => find::again(m, -1),
        Action::Sim(what) => sim(m, c, what),
        Action::ClearOverride => clear_override(m, c),
        Action::Characterize => characterize::ask(m, c),
        Action::Back | Action::Cancel => {
            characterize::left(m, c, "the operator left the bench view");
            m.mode = Mode::Main;
        }
        _ => {}
    }
}

/// The paper's `e`, after the operator disabled and re-enabled the steering drive:
/// home it now; [`tick`] then commands it to hold where it stopped, once the drive
/// acknowledged the home command. (A latched drive fault needs the disable → enable
/// cycle first; the supervisor's `steering` procedure runs that whole sequence when the
/// drive reports a fault, once the vehicle is engaged.)
fn reset_steering(m: &mut Model, c: &dyn Controls) {
    let Some(id) = m.snap.bound_id(Role::Steering) else {
        return m.say(
            "steering reset refused: this vehicle has no steering bound",
            true,
        );
    };
    match c.submit(id, Command::Control(Control::Home)) {
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
    let Some(id) = m.snap.bound_id(Role::Steering) else {
        m.steer_reset = None;
        return;
    };
    let steer = m.snap.at(id);
    let homed = steer.is_some_and(|d| d.executed == Some(Value::Text("home".into())));
    let at = steer.and_then(|d| d.position());
    match at {
        Some(at) if homed => {
            m.steer_reset = None;
            let at = (at * 1000.0).round() / 1000.0;
            match c.submit(id, Command::Set(at)) {
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

/// The simulator line a bench key means for device `id`, from the faults it has now.
pub(crate) fn sim_line(m: &Model, what: SimAction, id: DeviceId) -> String {
    let f = m.snap.sim_of(id).cloned().unwrap_or_default();
    let name = name_of(m, id);
    let on = |b: bool| if b { "off" } else { "on" };
    match what {
        SimAction::Silent => format!("silent {name} {}", on(f.silent)),
        SimAction::Garbage => format!("garbage {name} {}", on(f.garbage)),
        SimAction::Corrupt => format!("corrupt {name} {}", on(f.corrupt)),
        SimAction::Slow if f.slow_ms > 0 => format!("slow {name} 0"),
        SimAction::Slow => format!("slow {name} {}", SIM_SLOW.as_millis()),
        SimAction::Vanish => format!("vanish {name} {}", SIM_VANISH.as_millis()),
        SimAction::Clear => format!("clear {name}"),
        SimAction::Stall => "stall".into(),
        // The bench device's drive when it has one, else the steering's.
        SimAction::Jam => match m.snap.at(id) {
            Some(d) if d.kind == crate::value::Kind::Setpoint => format!("jam {name}"),
            _ => format!(
                "jam {}",
                m.snap
                    .bound("steering")
                    .map_or("?".to_string(), |d| d.name.clone())
            ),
        },
        SimAction::Estop(s) => format!("estop {s}"),
        SimAction::Override if f.hand.is_some() => format!("override {name} off"),
        SimAction::Override => format!("override {name} {}", far_end(m, id)),
    }
}

/// The end of device `id`'s range farther from where it is (its reading, else its
/// command): where a driver's hand pushing it moves it the most.
fn far_end(m: &Model, id: DeviceId) -> f64 {
    let Some(d) = m.snap.at(id) else { return 0.0 };
    let Some([lo, hi]) = d.range else { return 0.0 };
    let at = d
        .position()
        .or_else(|| d.commanded.as_ref().and_then(|v| v.as_f64()))
        .unwrap_or(lo);
    if at - lo > hi - at {
        lo
    } else {
        hi
    }
}

/// The operator clears a latched driver override: the gate's own rule (the same as
/// the network's `clear`), refused while the driver's hand is still on.
fn clear_override(m: &mut Model, c: &dyn Controls) {
    match c.clear_overrides() {
        Ok(cleared) if cleared.is_empty() => m.say("no override to clear", false),
        Ok(cleared) => m.say(
            format!(
                "override cleared on {}: engage when ready",
                cleared.join(", ")
            ),
            false,
        ),
        Err(why) => m.say(why.to_string(), true),
    }
}

/// The operator asks to take command (confirmed first): only while engaged and
/// commanded by another source.
fn take(m: &mut Model) {
    match m.snap.gate.commander.as_deref() {
        _ if !m.snap.gate.engaged => m.say(
            "nothing to take: the vehicle is not engaged (E engages)",
            true,
        ),
        Some("console") => m.say("the console already commands the vehicle", false),
        _ => ask(m, Question::Take),
    }
}

/// The operator gives command up: another source may engage within the handover,
/// else the vehicle stops.
fn release(m: &mut Model, c: &dyn Controls) {
    match c.release() {
        Ok(()) => m.say(
            "command released: another source may engage now; nobody does, the vehicle stops",
            false,
        ),
        Err(why) => m.say(format!("release refused: {why}"), true),
    }
}

/// A bench fault key: tell the simulator, say what happened, show it at once.
fn sim(m: &mut Model, c: &dyn Controls, what: SimAction) {
    let line = sim_line(m, what, m.bench);
    let letting_go =
        what == SimAction::Override && m.snap.sim_of(m.bench).is_some_and(|f| f.hand.is_some());
    match c.sim(&line) {
        None => m.say(
            "fault injection needs --sim (devices simulated in this process)",
            true,
        ),
        Some(Err(e)) => m.say(format!("sim: {e}"), true),
        Some(Ok(done)) => {
            let harmless = match what {
                SimAction::Clear | SimAction::Estop(EstopState::Run) => true,
                // "…toward 0" is a push, not a switch turned off.
                SimAction::Override => letting_go,
                _ => done.ends_with(" off") || done.ends_with(" 0"),
            };
            m.say(format!("sim: {done}"), !harmless);
            m.snap = c.scene(m.now, Some(m.bench));
        }
    }
}

#[cfg(test)]
mod tests;
