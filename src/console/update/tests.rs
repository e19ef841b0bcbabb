//! `update` and `tick` with a recording fake engine: keys → actions → state.

use super::*;
use crate::config::VehicleConfig;
use crate::console::keymap::Keymap;
use crate::console::model::ANSWER_HOLDS;
use crate::console::theme::Theme;
use crate::controls::live::change_settings;
use crate::controls::{capture, Scene, Sources, Tune};
use crate::safety::{self, Done, Refused, Reject};
use crate::testkit;
use crossterm::event::{KeyEvent, KeyModifiers};
use std::cell::RefCell;

mod hold;

/// Records every call; refuses submits while `refuse` is set. Settings go through the
/// sample vehicle's real checks.
struct Fake {
    /// The sample vehicle (not started): its configuration, and the real checks of
    /// a console setting edit.
    gate: std::sync::Arc<crate::engine::Gate>,
    snap: Scene,
    calls: RefCell<Vec<String>>,
    refuse: Option<Reject>,
    /// An attached console's adrive that no longer answers: even STOP is not taken.
    gone: bool,
    engage: Result<(), Refused>,
    /// The devices are simulated: `sim` lines are taken.
    simulated: bool,
    /// The teleop deadman as the console last armed it (`None`: disarmed).
    deadman: std::cell::Cell<Option<Duration>>,
    /// The engine ended the held gas's lease: a renewal finds nothing to renew.
    lease_ended: std::cell::Cell<bool>,
    /// The console's characterization, as the engine would report it.
    characterizing: RefCell<Option<crate::controls::Characterizing>>,
}

impl Fake {
    fn new() -> Fake {
        Fake::of(VehicleConfig::alice())
    }
    /// The tractor: 32 devices with free names (`vehicles/tractor.toml`).
    fn tractor() -> Fake {
        let text = include_str!("../../../vehicles/tractor.toml");
        Fake::of(crate::config::parse(text, "vehicles/tractor.toml").unwrap())
    }
    fn of(config: VehicleConfig) -> Fake {
        let now = Instant::now();
        let g = testkit::gate_of(config, now);
        Fake {
            snap: capture(&g, &Sources::default(), now, None),
            gate: g,
            calls: RefCell::default(),
            refuse: None,
            gone: false,
            engage: Ok(()),
            simulated: false,
            deadman: std::cell::Cell::default(),
            lease_ended: std::cell::Cell::default(),
            characterizing: RefCell::default(),
        }
    }
    fn log(&self, s: String) {
        self.calls.borrow_mut().push(s);
    }
    fn calls(&self) -> Vec<String> {
        self.calls.borrow().clone()
    }
    fn name(&self, id: DeviceId) -> &str {
        &self.gate.vehicle().config().devices[id.index()].name
    }
    /// A device of the sample in the frame, by name, to change what the console sees.
    fn device(&mut self, name: &str) -> &mut DeviceView {
        self.snap
            .snap
            .devices
            .iter_mut()
            .find(|d| d.name == name)
            .unwrap()
    }
}

/// Alice's device by name.
fn id(name: &str) -> DeviceId {
    let a = VehicleConfig::alice();
    DeviceId(a.devices.iter().position(|d| d.name == name).unwrap() as u16)
}

impl Controls for Fake {
    fn scene(&self, _now: Instant, _bench: Option<DeviceId>) -> Scene {
        self.snap.clone()
    }
    fn parse(&self, id: DeviceId, text: &str) -> Result<Command, String> {
        self.gate.vehicle().config().devices[id.index()].parse_command(text)
    }
    fn ask(&self, ask: safety::Ask) -> Result<Done, Refused> {
        let refused = |done: Done| self.refuse.map_or(Ok(done), |r| Err(Refused::Rule(r)));
        match ask {
            safety::Ask::Set(id, command) => {
                let d = &self.gate.vehicle().config().devices[id.index()];
                self.log(format!("submit {} {}", d.name, d.command_text(command)));
                refused(Done::Commanded)
            }
            safety::Ask::Accel(accel) => {
                self.log(format!("accel {accel}"));
                refused(Done::Commanded)
            }
            safety::Ask::Held(h) => {
                self.log(format!(
                    "held {} for {}ms then {}",
                    h.accel,
                    h.lease.as_millis(),
                    h.release
                ));
                refused(Done::Commanded)
            }
            safety::Ask::Renew(lease) => {
                self.log(format!("renew {}ms", lease.as_millis()));
                refused(if self.lease_ended.get() {
                    Done::Same
                } else {
                    Done::Commanded
                })
            }
            safety::Ask::Engage => {
                self.log("engage".into());
                self.engage.clone().map(|()| Done::Engaged)
            }
            safety::Ask::Disengage => {
                self.log("disengage".into());
                self.reached().map(|()| Done::Disengaged(true))
            }
            safety::Ask::Stop => {
                self.log("stop".into());
                self.reached().map(|()| Done::Disengaged(true))
            }
            safety::Ask::Take => {
                self.log("take".into());
                Ok(Done::Commanding)
            }
            safety::Ask::Release => {
                self.log("release".into());
                Ok(Done::Released)
            }
            safety::Ask::Hold => {
                self.log("hold".into());
                refused(Done::Commanded)
            }
            safety::Ask::Clear => {
                self.log("clear overrides".into());
                self.gate
                    .clear_overrides()
                    .map(Done::Cleared)
                    .map_err(Refused::Clear)
            }
        }
    }
    fn tune(&self, tune: Tune) -> Result<(), String> {
        match tune {
            Tune::StatusPeriod(id, d) => {
                change_settings(self.gate.vehicle(), id, |c| c.status_period = d)?;
                self.log(format!("st delay {} {d:?}", self.name(id)));
                Ok(())
            }
            Tune::CommandTimeout(id, d) => {
                change_settings(self.gate.vehicle(), id, |c| c.command_timeout = d)?;
                self.log(format!("cm delay {} {d:?}", self.name(id)));
                Ok(())
            }
            Tune::Enabled(id, thread, on) => {
                self.log(format!("enable {} {thread:?} {on}", self.name(id)));
                self.refuse.map_or(Ok(()), |r| Err(r.to_string()))
            }
            Tune::Wake(id) => {
                self.log(format!("wake {}", self.name(id)));
                self.refuse.map_or(Ok(()), |r| Err(r.to_string()))
            }
        }
    }
    fn deadman(&self, armed: Option<Duration>) {
        self.deadman.set(armed);
    }
    fn set_interlocks(&self, on: bool) -> Result<(), Refused> {
        self.log(format!("interlocks {on}"));
        Ok(())
    }
    fn sim(&self, line: &str) -> Option<Result<String, String>> {
        if !self.simulated {
            return None;
        }
        self.log(format!("sim {line}"));
        Some(Ok(line.to_string()))
    }
    fn answered(&self, _at: Instant) {
        self.log("answered".into());
    }
    fn characterize_check(&self, id: DeviceId) -> Result<String, String> {
        self.log(format!("characterize check {}", self.name(id)));
        crate::characterize::check_device(&self.gate, self.name(id))?;
        match self.refuse {
            Some(r) => Err(format!("not ready: {r}")),
            None => Ok("stopped, in park, the brake held".into()),
        }
    }
    fn characterize(
        &self,
        id: DeviceId,
        procedures: &[crate::characterize::Procedure],
        out: &std::path::Path,
    ) -> Result<(), String> {
        self.log(format!(
            "characterize {} {} into {}",
            self.name(id),
            procedures.len(),
            out.display()
        ));
        Ok(())
    }
    fn characterizing(&self) -> Option<crate::controls::Characterizing> {
        self.characterizing.borrow().clone()
    }
    fn characterize_end(&self, why: &str) {
        self.log(format!("characterize end: {why}"));
        if let Some(c) = self.characterizing.borrow_mut().as_mut() {
            c.end.get_or_insert(Err(format!("stopped: {why}")));
        }
    }
}

/// Draw `m` at its screen size, keeping what the frame showed (as the console's loop).
fn draw(m: &mut Model) -> ratatui::buffer::Buffer {
    let mut buf = ratatui::buffer::Buffer::empty(m.screen);
    m.drawn = crate::console::view::draw(m, m.screen, &mut buf);
    buf
}

impl Fake {
    /// Whether an ask reached the engine at all.
    fn reached(&self) -> Result<(), Refused> {
        match self.gone {
            true => Err(Refused::Unanswered(
                "adrive went away: its connection closed".into(),
            )),
            false => Ok(()),
        }
    }
}

fn model(f: &Fake) -> Model {
    Model::new(
        Keymap::default_map(),
        Theme::default(),
        f.snap.clone(),
        Duration::from_millis(500),
    )
}

/// Press keys (written as in a keymap) through the default keymap.
fn press(m: &mut Model, f: &Fake, keys: &[&str], now: Instant) -> Flow {
    let mut flow = Flow::Continue;
    for k in keys {
        let key: crate::console::keymap::Key = k.parse().unwrap();
        let mods = if key.ctrl {
            KeyModifiers::CONTROL
        } else {
            KeyModifiers::NONE
        };
        let ev = KeyEvent::new(key.code, mods);
        // As the console's loop: the key acts on what the frame before it showed.
        draw(m);
        flow = super::key(m, &ev, now, f, now);
    }
    flow
}

fn typing(s: &str) -> Vec<String> {
    s.chars().map(|c| c.to_string()).collect()
}

#[test]
fn s_then_a_value_then_enter_submits_a_steering_command() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["s"], now);
    assert_eq!(m.mode, Mode::Edit);
    assert_eq!(m.edit.as_ref().unwrap().field, Field::Command(id("steer")));
    let keys = typing("0.5");
    let keys: Vec<&str> = keys.iter().map(String::as_str).collect();
    press(&mut m, &f, &keys, now);
    assert_eq!(m.edit.as_ref().unwrap().buffer, "0.5");
    press(&mut m, &f, &["<Enter>"], now);
    assert_eq!(m.mode, Mode::Main);
    assert_eq!(f.calls(), ["submit steer 0.500"]);
    assert!(!m.message.unwrap().bad);
}

#[test]
fn esc_cancels_an_edit_and_changes_nothing() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["g", "1", "<Esc>"], now);
    assert_eq!(m.mode, Mode::Main);
    assert!(m.edit.is_none());
    assert!(f.calls().is_empty());
}

#[test]
fn a_bad_value_shows_an_inline_error_and_changes_nothing() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    // Out of the gas range 0…1.
    press(&mut m, &f, &["g", "2", "<Enter>"], now);
    assert_eq!(m.mode, Mode::Edit, "stays in the field");
    let err = m.edit.as_ref().unwrap().error.clone().unwrap();
    assert!(err.contains("out of range"), "{err}");
    // Not a number.
    press(&mut m, &f, &["<C-u>", "x", "<Enter>"], now);
    assert!(m
        .edit
        .as_ref()
        .unwrap()
        .error
        .as_ref()
        .unwrap()
        .contains("not a number"));
    // A bad gear, a bad period, a bad flag.
    press(&mut m, &f, &["<Esc>", "t", "z", "<Enter>"], now);
    assert!(m
        .edit
        .as_ref()
        .unwrap()
        .error
        .as_ref()
        .unwrap()
        .contains("trans takes one of park, reverse, neutral, drive"));
    assert!(f.calls().is_empty(), "{:?}", f.calls());
    // Typing clears the error; a good value then goes through.
    press(&mut m, &f, &["<Backspace>", "d", "<Enter>"], now);
    assert_eq!(f.calls(), ["submit trans drive"]);
}

#[test]
fn delays_and_thread_flags_are_edited_in_place() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    // Cursor starts on steer's command; down to st delay.
    press(&mut m, &f, &["j", "<Enter>"], now);
    assert_eq!(m.edit.as_ref().unwrap().field, Field::StDelay(id("steer")));
    assert_eq!(m.edit.as_ref().unwrap().buffer, "50ms", "prefilled");
    press(&mut m, &f, &["2", "0", "<Enter>"], now);
    press(&mut m, &f, &["j", "<Enter>", "1", "s", "<Enter>"], now);
    press(&mut m, &f, &["j", "<Enter>", "0", "<Enter>"], now);
    press(&mut m, &f, &["j", "<Enter>", "o", "n", "<Enter>"], now);
    assert_eq!(
        f.calls(),
        [
            "st delay steer 20ms",
            "cm delay steer 1s",
            "enable steer Status false",
            "enable steer Command true",
        ]
    );
    press(&mut m, &f, &["k", "<Enter>", "0", "m", "s", "<Enter>"], now);
    assert!(m.edit.as_ref().unwrap().error.is_some(), "0ms is refused");
}

/// The console took `st delay 1.5s` on a device whose `status_max_age` is 250 ms, which
/// the vehicle file refuses; the device then flipped between faulty and clear.
#[test]
fn a_status_period_the_vehicle_file_would_refuse_is_refused_in_place() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    // Steer's st delay; Alice's steer has status_max_age 250ms.
    press(
        &mut m,
        &f,
        &["j", "<Enter>", "1", ".", "5", "s", "<Enter>"],
        now,
    );
    assert_eq!(m.mode, Mode::Edit, "stays in the field");
    let e = m.edit.as_ref().unwrap();
    assert_eq!(e.buffer, "1.5s", "what was typed is kept");
    let err = e.error.clone().unwrap();
    assert!(
        err.contains("status_max_age 250ms, status_period 1500ms")
            && err.contains("expected `status_max_age` at least `status_period`"),
        "{err}"
    );
    // Out of the vehicle file's range, too.
    press(&mut m, &f, &["<C-u>", "0", "<Enter>"], now);
    let err = m.edit.as_ref().unwrap().error.clone().unwrap();
    assert!(err.contains("status_period: expected a duration"), "{err}");
    assert!(f.calls().is_empty(), "nothing changed: {:?}", f.calls());
    let steer = f.gate.vehicle().find("steer").unwrap();
    assert_eq!(steer.settings().status_period(), Duration::from_millis(50));
    // A value the file takes goes through.
    press(&mut m, &f, &["<C-u>", "2", "0", "0", "<Enter>"], now);
    assert_eq!(m.mode, Mode::Main);
    assert_eq!(f.calls(), ["st delay steer 200ms"]);
    assert_eq!(steer.settings().status_period(), Duration::from_millis(200));
    // cm delay: the simulated gas's own watchdog (1s) must outlast the resend.
    press(&mut m, &f, &["j", "l", "<Enter>", "2", "s", "<Enter>"], now);
    let err = m.edit.as_ref().unwrap().error.clone().unwrap();
    assert!(err.contains("sim.watchdog 1s, command_timeout 2s"), "{err}");
}

#[test]
fn left_and_right_move_between_devices_keeping_the_field() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["j", "l"], now);
    assert_eq!(m.field(), Field::StDelay(id("gas")));
    press(&mut m, &f, &["l", "l", "l"], now);
    assert_eq!(m.field(), Field::StDelay(id("estop")));
    press(&mut m, &f, &["h"], now);
    assert_eq!(m.field(), Field::StDelay(id("trans")));
}

#[test]
fn a_refused_command_is_reported_not_hidden() {
    let mut f = Fake::new();
    f.refuse = Some(Reject::Disengaged);
    let mut m = model(&f);
    press(&mut m, &f, &["b", "0", "<Enter>"], Instant::now());
    let msg = m.message.unwrap();
    assert!(msg.bad && msg.text.contains("refused"), "{}", msg.text);
}

#[test]
fn engage_disengage_and_interlocks_ask_first() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["E"], now);
    assert_eq!((m.mode, m.ask), (Mode::Confirm, Some(Question::Engage)));
    press(&mut m, &f, &["n"], now);
    assert_eq!(m.mode, Mode::Main);
    assert!(f.calls().is_empty());
    press(&mut m, &f, &["E", "y"], now);
    assert_eq!(f.calls(), ["engage"]);
    press(&mut m, &f, &["I", "<Esc>", "I", "y", "D", "y"], now);
    assert_eq!(f.calls(), ["engage", "interlocks false", "disengage"]);
    // Keys other than yes/no do nothing while asking.
    press(&mut m, &f, &["E", "g", "s"], now);
    assert_eq!(m.mode, Mode::Confirm);
    assert_eq!(f.calls().len(), 3);
}

#[test]
fn space_stops_at_once_without_asking() {
    let f = Fake::new();
    let mut m = model(&f);
    press(&mut m, &f, &["<Space>"], Instant::now());
    assert_eq!(m.mode, Mode::Main);
    assert_eq!(f.calls(), ["stop"]);
    assert!(m.message.unwrap().text.contains("STOP"));
}

/// The emergency stop once existed only in main, teleop (as a full brake that stayed
/// engaged) and bench: Space in the middle of an edit or a question typed a space or
/// did nothing. It stops from every mode now, dropping what was half done.
#[test]
fn space_is_stop_in_every_mode() {
    let now = Instant::now();
    for (keys, back_in) in [
        (&["g", "0", "."][..], Mode::Main),
        (&["E"][..], Mode::Main),
        (&["?"][..], Mode::Help),
        (&["d", "w"][..], Mode::Teleop),
        (&["d", "E"][..], Mode::Teleop),
        (&["x"][..], Mode::Bench),
        (&["x", "<Enter>"][..], Mode::Bench),
        (&["/", "b", "r"][..], Mode::Main),
        (&["x", "/", "o"][..], Mode::Bench),
    ] {
        let f = Fake::new();
        let mut m = model(&f);
        press(&mut m, &f, keys, now);
        let before = f.calls().len();
        press(&mut m, &f, &["<Space>"], now);
        assert_eq!(f.calls()[before..], ["stop"], "{keys:?}");
        assert_eq!(m.mode, back_in, "{keys:?}");
        assert!(
            m.edit.is_none() && m.ask.is_none() && m.find.is_none(),
            "{keys:?}"
        );
        assert!(
            m.message.as_ref().unwrap().text.contains("STOP"),
            "{keys:?}"
        );
        if back_in == Mode::Teleop {
            // The next up releases the brake first; the deadman waits for a key.
            assert_eq!(m.teleop.accel, -1.0);
            assert_eq!(m.teleop.last_key, None);
        }
    }
}

#[test]
fn a_refused_engage_says_why() {
    let mut f = Fake::new();
    f.engage = Err(Refused::Blocked(vec![crate::snapshot::Blocker::Faulty {
        device: "steer".into(),
        fault: "timeout".into(),
    }]));
    let mut m = model(&f);
    press(&mut m, &f, &["E", "y"], Instant::now());
    let msg = m.message.unwrap();
    assert!(
        msg.bad && msg.text.contains("steer is faulty"),
        "{}",
        msg.text
    );
}

#[test]
fn wake_keys_wake_command_threads() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["S", "G", "w", "W"], now);
    assert_eq!(
        f.calls(),
        [
            "wake steer",
            "wake gas",
            "wake steer",
            "wake steer",
            "wake gas",
            "wake brake",
            "wake trans"
        ]
    );
    press(&mut m, &f, &["e"], now);
    assert_eq!(f.calls().last().unwrap(), "submit steer home");
}

#[test]
fn q_quits_and_ctrl_c_is_sigint_from_any_mode() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    assert_eq!(press(&mut m, &f, &["q"], now), Flow::Exit(Exit::Quit));
    press(&mut m, &f, &["g"], now);
    assert_eq!(
        press(&mut m, &f, &["<C-c>"], now),
        Flow::Exit(Exit::Signal(libc::SIGINT))
    );
    // While editing, q is a character.
    assert_eq!(press(&mut m, &f, &["q"], now), Flow::Continue);
}

#[test]
fn help_opens_over_any_mode_and_closes_back() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["d", "?"], now);
    assert_eq!((m.mode, m.back_to), (Mode::Help, Mode::Teleop));
    press(&mut m, &f, &["j", "j"], now);
    assert_eq!(m.help_scroll, 2);
    press(&mut m, &f, &["<Esc>"], now);
    assert_eq!(m.mode, Mode::Teleop);
}

#[test]
fn teleop_steps_steering_and_accel_and_b_brakes() {
    let f = Fake::new();
    let mut m = model(&f);
    m.teleop.forced_step = true;
    let now = Instant::now();
    press(&mut m, &f, &["d"], now);
    assert_eq!(m.mode, Mode::Teleop);
    assert_eq!(m.teleop.steer, 0.231, "starts where the steering is");
    press(&mut m, &f, &["<Right>", "a", "a", "<Up>", "w", "b"], now);
    assert_eq!(
        f.calls(),
        [
            "submit steer 0.281",
            "submit steer 0.231",
            "submit steer 0.181",
            "accel 0.1",
            "accel 0.2",
            "accel -1",
        ]
    );
    // From braking, up releases first.
    press(&mut m, &f, &["<Up>"], now);
    assert_eq!(m.teleop.accel, 0.0);
    press(&mut m, &f, &["<Esc>"], now);
    assert_eq!(m.mode, Mode::Main);
    assert_eq!(
        f.calls().last().unwrap(),
        "hold",
        "leaving teleop holds: brake full"
    );
    assert_eq!(f.deadman.get(), None, "and disarms the deadman");
}

/// The deadman is the console's watchdog in the intake (tested there, over time);
/// the console arms and feeds it with every teleop key, disarms it on leaving teleop
/// and on STOP, and shows what it did when the snapshot says it tripped.
#[test]
fn teleop_keys_arm_the_deadman_and_the_console_shows_its_trip() {
    let mut f = Fake::new();
    let mut m = model(&f);
    m.teleop.forced_step = true;
    let t0 = Instant::now();
    press(&mut m, &f, &["d"], t0);
    assert_eq!(f.deadman.get(), None, "no key yet: idle");
    assert_eq!(m.teleop.state(m.now), super::super::model::Deadman::Idle);
    press(&mut m, &f, &["w"], t0);
    assert_eq!(f.deadman.get(), Some(m.teleop.deadman));
    f.snap.snap.gate.engaged = false;
    f.snap.snap.gate.watchdog = Some(crate::snapshot::WatchdogView {
        state: crate::snapshot::WatchdogState::Tripped,
        timeout_ms: 500.0,
        last_command_age_ms: None,
        // The console reads the cause's type, never its words.
        last_trip: Some("no teleop key for 0.5s".into()),
        trip: Some(crate::snapshot::TripKind::Deadman),
    });
    tick(&mut m, &f, t0 + Duration::from_millis(600));
    assert_eq!(m.teleop.state(m.now), super::super::model::Deadman::Tripped);
    assert_eq!(m.teleop.accel, -1.0);
    let msg = m.message.clone().unwrap();
    assert!(msg.bad && msg.text.contains("deadman"), "{}", msg.text);
    // The next key re-arms it; the watchdog standing tripped (until the next engage)
    // is no new trip.
    press(&mut m, &f, &["<Left>"], t0 + Duration::from_secs(3));
    tick(&mut m, &f, t0 + Duration::from_secs(3));
    assert!(matches!(
        m.teleop.state(m.now),
        super::super::model::Deadman::Armed { .. }
    ));
    press(&mut m, &f, &["<Space>"], t0 + Duration::from_secs(3));
    assert_eq!(f.deadman.get(), None, "STOP disarms it");
    press(&mut m, &f, &["<Left>"], t0 + Duration::from_secs(4));
    tick(&mut m, &f, t0 + Duration::from_secs(4));
    let msg = m.message.clone().unwrap();
    assert!(
        !msg.text.contains("deadman"),
        "a trip said twice: {}",
        msg.text
    );
    // Tripped again, then engaged again: the bar leaves the trip and idles, as the
    // intake's deadman does until the next teleop key.
    tick(&mut m, &f, t0 + Duration::from_secs(5));
    f.snap.snap.gate.watchdog = None;
    tick(&mut m, &f, t0 + Duration::from_secs(6));
    f.snap.snap.gate.watchdog = Some(crate::snapshot::WatchdogView {
        state: crate::snapshot::WatchdogState::Tripped,
        timeout_ms: 500.0,
        last_command_age_ms: None,
        last_trip: None,
        trip: Some(crate::snapshot::TripKind::Deadman),
    });
    tick(&mut m, &f, t0 + Duration::from_secs(7));
    assert_eq!(m.teleop.state(m.now), super::super::model::Deadman::Tripped);
    f.snap.snap.gate.engaged = true;
    f.snap.snap.gate.watchdog = None;
    tick(&mut m, &f, t0 + Duration::from_secs(8));
    assert_eq!(m.teleop.state(m.now), super::super::model::Deadman::Idle);
}

/// Another source's command refused because the console commands shows in the
/// message line.
#[test]
fn a_refused_attempt_of_another_source_shows_in_the_message_line() {
    let mut f = Fake::new();
    let mut m = model(&f);
    f.snap.snap.gate.refused = 1;
    f.snap.snap.gate.last_refused =
        Some("refused steer 0.500 from network 127.0.0.1:5555: commanded by console".into());
    tick(&mut m, &f, Instant::now());
    let msg = m.message.clone().unwrap();
    assert!(
        msg.bad && msg.text.contains("127.0.0.1:5555"),
        "{}",
        msg.text
    );
    m.message = None;
    tick(&mut m, &f, Instant::now());
    assert!(m.message.is_none(), "said once");
}

/// News that comes with a frame after the operator's key — another source's refusal
/// from before it, the supervisor's outcome — never replaces the key's answer before
/// it was read: it waits [`ANSWER_HOLDS`], then shows for its own full time.
#[test]
fn news_after_a_key_waits_for_its_answer_to_be_read() {
    let mut f = Fake::new();
    let mut m = model(&f);
    let t0 = Instant::now();
    press(&mut m, &f, &["E", "y"], t0);
    assert_eq!(m.message.as_ref().unwrap().text, "engaged");
    f.snap.snap.gate.refused = 1;
    f.snap.snap.gate.last_refused =
        Some("refused steer -0.500 from console #1: commanded by console #2".into());
    let before = t0 + ANSWER_HOLDS - Duration::from_millis(1);
    tick(&mut m, &f, t0 + Duration::from_millis(100));
    tick(&mut m, &f, before);
    assert_eq!(
        m.message.as_ref().unwrap().text,
        "engaged",
        "the answer holds"
    );
    let shown = t0 + ANSWER_HOLDS;
    tick(&mut m, &f, shown);
    let msg = m.message.clone().unwrap();
    assert_eq!(
        msg.text,
        "refused steer -0.500 from console #1: commanded by console #2"
    );
    assert_eq!(msg.at, shown, "the news shows for its own time");
    tick(&mut m, &f, shown + Duration::from_millis(100));
    assert_eq!(m.message, Some(msg), "said once");
    // With no answer of the operator's on the line, news shows at once.
    f.snap.snap.gate.refused = 2;
    let later = shown + Duration::from_secs(1);
    tick(&mut m, &f, later);
    assert_eq!(m.message.as_ref().unwrap().at, later);
}

#[test]
fn bench_cycles_devices_sends_to_one_device_and_asks_for_sim_faults() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["l", "x"], now);
    assert_eq!((m.mode, m.bench), (Mode::Bench, id("gas")));
    press(&mut m, &f, &["<Tab>", "<Enter>"], now);
    assert_eq!(m.edit.as_ref().unwrap().field, Field::Command(id("brake")));
    press(&mut m, &f, &["0", ".", "5", "<Enter>"], now);
    assert_eq!(m.mode, Mode::Bench);
    assert_eq!(f.calls(), ["submit brake 0.500"]);
    press(&mut m, &f, &["s"], now);
    assert!(m.message.as_ref().unwrap().text.contains("needs --sim"));
    assert_eq!(f.calls(), ["submit brake 0.500"], "nothing was injected");
    press(&mut m, &f, &["<BackTab>", "<BackTab>", "<BackTab>"], now);
    assert_eq!(m.bench, id("obd"));
    press(&mut m, &f, &["<Enter>"], now);
    assert_eq!(m.mode, Mode::Bench, "a sensor takes no commands");
    press(&mut m, &f, &["<Esc>"], now);
    assert_eq!(m.mode, Mode::Main);
}

#[test]
fn c_edits_the_virtual_accel() {
    let f = Fake::new();
    let mut m = model(&f);
    press(
        &mut m,
        &f,
        &["c", "-", "0", ".", "3", "<Enter>"],
        Instant::now(),
    );
    assert_eq!(f.calls(), ["accel -0.3"]);
    assert_eq!(m.accel, Some(-0.3));
}

/// `accel 0.300` stayed on screen after STOP, although STOP brakes fully.
#[test]
fn stop_clears_the_accel_shown() {
    let mut f = Fake::new();
    f.snap.snap.gate.engaged = true;
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["c", "0", ".", "3", "<Enter>"], now);
    tick(&mut m, &f, now);
    assert_eq!(m.accel, Some(0.3), "shown while engaged");
    press(&mut m, &f, &["<Space>"], now);
    assert_eq!(f.calls(), ["accel 0.3", "stop"]);
    f.snap.snap.gate.engaged = false;
    tick(&mut m, &f, now);
    assert_eq!(m.accel, None);
}

#[test]
fn e_homes_the_steering_then_holds_where_it_stopped() {
    let mut f = Fake::new();
    let mut m = model(&f);
    let t0 = Instant::now();
    press(&mut m, &f, &["e"], t0);
    assert_eq!(f.calls(), ["submit steer home"]);
    assert_eq!(m.steer_reset, Some(t0));
    // Not acknowledged yet: nothing more.
    tick(&mut m, &f, t0 + Duration::from_millis(100));
    assert_eq!(f.calls().len(), 1);
    // The drive acknowledged home: hold where it is.
    f.device("steer").executed = Some(Value::Text("home".into()));
    tick(&mut m, &f, t0 + Duration::from_millis(200));
    assert_eq!(f.calls(), ["submit steer home", "submit steer 0.231"]);
    assert_eq!(m.steer_reset, None);
    let msg = m.message.clone().unwrap();
    assert!(
        !msg.bad && msg.text.contains("holding 0.231"),
        "{}",
        msg.text
    );
}

#[test]
fn e_says_so_when_home_is_not_acknowledged_or_refused() {
    let mut f = Fake::new();
    let mut m = model(&f);
    let t0 = Instant::now();
    press(&mut m, &f, &["e"], t0);
    tick(&mut m, &f, t0 + HOME_WAIT + Duration::from_millis(100));
    let msg = m.message.clone().unwrap();
    assert!(
        msg.bad && msg.text.contains("not acknowledged"),
        "{}",
        msg.text
    );
    assert_eq!(m.steer_reset, None);
    assert_eq!(f.calls(), ["submit steer home"], "no hold without home");
    // Refused at intake (a recovery procedure has the steering).
    f.refuse = Some(Reject::Recovering);
    press(&mut m, &f, &["e"], t0);
    let msg = m.message.clone().unwrap();
    assert!(msg.bad && msg.text.contains("refused"), "{}", msg.text);
    assert_eq!(m.steer_reset, None);
}

#[test]
fn bench_fault_keys_drive_the_simulator_and_toggle_from_its_state() {
    use crate::controls::SimFaults;
    let mut f = Fake::new();
    f.simulated = true;
    let mut m = model(&f);
    let now = Instant::now();
    // Steering on the bench.
    press(&mut m, &f, &["x"], now);
    assert_eq!((m.mode, m.bench), (Mode::Bench, id("steer")));
    press(
        &mut m,
        &f,
        &["s", "g", "c", "l", "v", "x", "K", "J", "p", "r"],
        now,
    );
    assert_eq!(
        f.calls(),
        [
            "sim silent steer on",
            "sim garbage steer on",
            "sim corrupt steer on",
            "sim slow steer 150",
            "sim vanish steer 2000",
            "sim clear steer",
            "sim stall",
            "sim jam steer",
            "sim estop pause",
            "sim estop run",
        ]
    );
    assert!(
        !m.message.as_ref().unwrap().bad,
        "e-stop run is not a fault"
    );
    // The same keys switch off what is on, on the device now on the bench.
    f.snap.sim_faults = vec![None; f.snap.devices.len()];
    f.snap.sim_faults[id("gas").index()] = Some(SimFaults {
        silent: true,
        slow_ms: 150,
        ..SimFaults::default()
    });
    let mut m = model(&f);
    press(&mut m, &f, &["l", "x", "s", "l", "g"], now);
    assert_eq!(m.bench, id("gas"));
    assert_eq!(
        &f.calls()[10..],
        ["sim silent gas off", "sim slow gas 0", "sim garbage gas on"]
    );
    assert!(m.message.as_ref().unwrap().bad, "garbage on is a fault");
}

#[test]
fn a_recovery_outcome_is_said_once() {
    use crate::snapshot::OutcomeKind;
    let mut f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    f.snap.snap.supervisor.last_outcome = Some("recovery engine_stall done in 6.1 s".into());
    f.snap.snap.supervisor.outcome = Some(OutcomeKind::Done);
    f.snap.snap.supervisor.outcomes = 1;
    tick(&mut m, &f, now);
    let msg = m.message.take().unwrap();
    assert_eq!(msg.text, "supervisor: recovery engine_stall done in 6.1 s");
    assert!(!msg.bad);
    tick(&mut m, &f, now);
    assert!(m.message.is_none(), "said once");
    // The same words again are a new outcome: told again.
    f.snap.snap.supervisor.outcomes = 2;
    tick(&mut m, &f, now);
    assert_eq!(
        m.message.take().unwrap().text,
        "supervisor: recovery engine_stall done in 6.1 s"
    );
    // Bad by the outcome's type, whatever its words.
    f.snap.snap.supervisor.last_outcome =
        Some("recovery engine_stall: step park did not complete".into());
    f.snap.snap.supervisor.outcome = Some(OutcomeKind::GaveUp);
    f.snap.snap.supervisor.outcomes = 3;
    tick(&mut m, &f, now);
    assert!(m.message.take().unwrap().bad);
}

/// The device under the cursor, by name.
fn under_cursor(m: &Model) -> &str {
    &m.snap.devices[m.cursor_device()].name
}

#[test]
fn a_device_found_by_name_is_edited_and_woken_from_the_cursor() {
    let f = Fake::tractor();
    let mut m = model(&f);
    let now = Instant::now();
    let keys = ["/", "w", "i", "p", "<Enter>"];
    press(&mut m, &f, &keys, now);
    assert_eq!((m.mode, under_cursor(&m)), (Mode::Main, "wiper"));
    press(&mut m, &f, &["<Enter>", "0", ".", "5", "<Enter>", "w"], now);
    assert_eq!(f.calls(), ["submit wiper 0.500", "wake wiper"]);
    // A state device, by a part of its name, with its state typed.
    let mut keys = vec!["/", "s", "i", "g", "n", "<Enter>", "<Enter>", "<C-u>"];
    keys.extend(["h", "a", "z", "a", "r", "d", "<Enter>"]);
    press(&mut m, &f, &keys, now);
    assert_eq!(f.calls()[2..], ["submit turn_signal hazard"]);
    // Any field of it: the cursor moves on from the command.
    press(
        &mut m,
        &f,
        &["j", "<Enter>", "<C-u>", "5", "0", "<Enter>"],
        now,
    );
    assert_eq!(f.calls()[3..], ["st delay turn_signal 50ms"]);
    // A sensor has no command thread to wake.
    press(&mut m, &f, &["/", "b", "a", "t", "<Enter>", "w"], now);
    assert_eq!(under_cursor(&m), "battery");
    assert!(m
        .message
        .as_ref()
        .unwrap()
        .text
        .contains("battery is a sensor"));
    assert_eq!(f.calls().len(), 4);
}

#[test]
fn escape_leaves_the_cursor_where_the_prompt_was_opened() {
    let f = Fake::tractor();
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["l", "l", "j"], now);
    let (cursor, field) = (m.cursor, m.field());
    press(&mut m, &f, &["/", "h", "o", "r"], now);
    assert_eq!(under_cursor(&m), "horn");
    press(&mut m, &f, &["<Esc>"], now);
    assert_eq!((m.mode, m.cursor, m.field()), (Mode::Main, cursor, field));
    // A name that matches nothing: Enter says so and changes nothing.
    press(&mut m, &f, &["/", "z", "z", "<Enter>"], now);
    assert_eq!((m.mode, m.cursor), (Mode::Main, cursor));
    let msg = m.message.clone().unwrap();
    assert!(
        msg.bad && msg.text.contains("no device matches \"zz\""),
        "{}",
        msg.text
    );
    // n before any name was looked for says how to look for one.
    let mut m = model(&f);
    press(&mut m, &f, &["n"], now);
    assert!(m.message.unwrap().text.contains("/ finds a device"));
    assert!(f.calls().is_empty());
}

#[test]
fn n_and_capital_n_look_for_the_same_name_again() {
    let f = Fake::tractor();
    let mut m = model(&f);
    let now = Instant::now();
    // "light" matches headlights and work_lights only.
    let keys = ["/", "l", "i", "g", "h", "t", "<Enter>"];
    press(&mut m, &f, &keys, now);
    assert_eq!(under_cursor(&m), "headlights");
    press(&mut m, &f, &["n"], now);
    assert_eq!(under_cursor(&m), "work_lights");
    press(&mut m, &f, &["n"], now);
    assert_eq!(under_cursor(&m), "headlights", "wraps around");
    press(&mut m, &f, &["N"], now);
    assert_eq!(under_cursor(&m), "work_lights");
    // The bench looks for it too, and moves the bench device.
    press(&mut m, &f, &["x", "n"], now);
    assert_eq!(m.mode, Mode::Bench);
    assert_eq!(m.snap.devices[m.bench.index()].name, "headlights");
}

#[test]
fn page_keys_move_the_cursor_by_the_page_the_screen_shows() {
    let f = Fake::tractor();
    let mut m = model(&f);
    let now = Instant::now();
    // 80×24: one packed panel a page, so a page is a device.
    m.screen = ratatui::layout::Rect::new(0, 0, 80, 24);
    press(&mut m, &f, &["<PageDown>"], now);
    assert_eq!(under_cursor(&m), "throttle");
    // 100×40: three rows of two panels.
    m.screen = ratatui::layout::Rect::new(0, 0, 100, 40);
    press(&mut m, &f, &["<PageDown>"], now);
    assert_eq!(under_cursor(&m), "hitch");
    press(&mut m, &f, &["<PageUp>", "<PageUp>"], now);
    assert_eq!(under_cursor(&m), "steer");
    // Alice's devices all have their panels: a page is all of them.
    let f = Fake::new();
    let mut m = model(&f);
    press(&mut m, &f, &["<PageDown>"], now);
    assert_eq!(m.field(), Field::Accel);
    press(&mut m, &f, &["<PageUp>"], now);
    assert_eq!(m.field(), Field::Command(id("steer")));
}

#[test]
fn the_override_key_pushes_the_bench_device_toward_its_far_end_and_again_lets_go() {
    use crate::controls::SimFaults;
    let mut f = Fake::new();
    f.simulated = true;
    // The brake held full, the gas at rest: each pushed toward the other end.
    for d in &mut f.snap.snap.devices {
        if d.name == "brake" || d.name == "gas" {
            let at = if d.name == "brake" { 1.0 } else { 0.0 };
            for (n, v) in &mut d.readings.0 {
                if n == crate::config::device::POSITION {
                    *v = Some(Value::Number(at));
                }
            }
        }
    }
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["l", "x", "o", "<Tab>", "o"], now);
    assert_eq!(m.bench, id("brake"));
    assert_eq!(f.calls(), ["sim override gas 1", "sim override brake 0"]);
    assert!(
        m.message.as_ref().unwrap().bad,
        "a hand on it is an override"
    );
    // With the hand on, the same key lets go.
    f.snap.sim_faults = vec![None; f.snap.devices.len()];
    f.snap.sim_faults[id("brake").index()] = Some(SimFaults {
        hand: Some(0.0),
        ..SimFaults::default()
    });
    m.snap = f.snap.clone();
    press(&mut m, &f, &["o"], now);
    assert_eq!(&f.calls()[2..], ["sim override brake off"]);
    assert!(!m.message.as_ref().unwrap().bad, "letting go is no fault");
}

#[test]
fn the_clear_key_clears_a_latched_override_through_the_gate_from_main_teleop_and_bench() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["C"], now);
    assert_eq!(m.message.as_ref().unwrap().text, "no override to clear");
    // Latched, the driver's hand off: cleared, from each mode that has the key.
    for keys in [&["C"][..], &["d", "C"], &["<Esc>", "x", "C"]] {
        f.gate.take_over("steer", "test");
        assert_eq!(f.gate.overridden(), ["steer"]);
        press(&mut m, &f, keys, now);
        let msg = m.message.as_ref().unwrap();
        assert_eq!(msg.text, "override cleared on steer: engage when ready");
        assert!(!msg.bad);
        assert!(f.gate.overridden().is_empty(), "{keys:?}");
    }
    assert_eq!(
        f.calls().iter().filter(|c| *c == "clear overrides").count(),
        4
    );
}

/// The defect: in teleop in park, `Up` showed `accel +0.10 gas` in the bar while the
/// message line said it was refused. The bar shows what the intake accepted: a refused
/// key leaves it where it was, and teleop starts from what the vehicle was told (the
/// brake full after engaging), not from an invented coast.
#[test]
fn the_teleop_bar_shows_what_was_applied_never_what_was_refused() {
    let mut f = Fake::new();
    f.device("brake").commanded = Some(Value::Number(1.0));
    f.device("gas").commanded = Some(Value::Number(0.0));
    f.snap.snap.gate.engaged = true;
    let mut m = model(&f);
    m.teleop.forced_step = true;
    let now = Instant::now();
    press(&mut m, &f, &["d"], now);
    assert_eq!((m.teleop.steer, m.teleop.accel), (0.231, -1.0));
    // Up from braking releases first (accepted); up again asks for gas: refused.
    press(&mut m, &f, &["<Up>"], now);
    assert_eq!(m.teleop.accel, 0.0);
    f.refuse = Some(Reject::Disengaged);
    press(&mut m, &f, &["<Up>", "<Right>"], now);
    assert_eq!(f.calls()[1..], ["accel 0.1", "submit steer 0.281"]);
    assert_eq!(
        (m.teleop.steer, m.teleop.accel),
        (0.231, 0.0),
        "nothing applied"
    );
    let msg = m.message.clone().unwrap();
    assert!(
        msg.bad && msg.text.contains("refused: steer 0.28"),
        "{}",
        msg.text
    );
    assert!(
        msg.text.ends_with("still steer +0.23 accel +0.00"),
        "{}",
        msg.text
    );
    let screen = draw(&mut m);
    let bar: String = (0..screen.area.height)
        .map(|y| {
            (0..screen.area.width)
                .map(|x| screen[(x, y)].symbol())
                .collect::<String>()
        })
        .find(|l| l.starts_with("TELEOP"))
        .unwrap();
    assert!(
        bar.contains("steer +0.23") && bar.contains("accel +0.00 coast"),
        "{bar}"
    );
    // Whoever commands it, the bar follows what the vehicle was told.
    f.device("brake").commanded = Some(Value::Number(0.0));
    f.device("gas").commanded = Some(Value::Number(0.2));
    f.device("steer").commanded = Some(Value::Number(-0.1));
    tick(&mut m, &f, now);
    assert_eq!((m.teleop.steer, m.teleop.accel), (-0.1, 0.2));
    assert_eq!(m.accel, Some(0.2), "the supervisory panel's accel too");
}

/// Waking a command thread, switching a thread and leaving teleop said they were done
/// when the intake refused them (a console that does not command): each says what
/// happened.
#[test]
fn a_refused_wake_switch_or_hold_says_so() {
    let mut f = Fake::new();
    f.refuse = Some(Reject::Disengaged);
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["w"], now);
    let msg = m.message.clone().unwrap();
    assert!(
        msg.bad && msg.text.starts_with("wake steer refused"),
        "{}",
        msg.text
    );
    press(&mut m, &f, &["W"], now);
    let msg = m.message.clone().unwrap();
    assert!(
        msg.bad && msg.text.starts_with("wake all refused"),
        "{}",
        msg.text
    );
    press(&mut m, &f, &["j", "j", "j", "<Enter>", "0", "<Enter>"], now);
    let msg = m.message.clone().unwrap();
    assert!(
        msg.bad && msg.text.starts_with("steer status thread off refused"),
        "{}",
        msg.text
    );
    press(&mut m, &f, &["d", "<Esc>"], now);
    let msg = m.message.clone().unwrap();
    assert!(
        msg.bad && msg.text.starts_with("left teleop; the brake not applied"),
        "{}",
        msg.text
    );
    assert_eq!(m.accel, None, "no brake shown that was not applied");
}

/// An attached console whose adrive stopped answering: STOP is not said to be done.
#[test]
fn a_stop_that_did_not_reach_the_engine_is_not_said_to_be_done() {
    let mut f = Fake::new();
    f.gone = true;
    let mut m = model(&f);
    press(&mut m, &f, &["<Space>"], Instant::now());
    let msg = m.message.clone().unwrap();
    assert!(
        msg.bad && msg.text.starts_with("STOP NOT CONFIRMED: adrive went away"),
        "{}",
        msg.text
    );
    press(&mut m, &f, &["D", "y"], Instant::now());
    let msg = m.message.clone().unwrap();
    assert!(msg.text.starts_with("disengage not done"), "{}", msg.text);
}

/// A STOP not confirmed outlives a message's time on the line, under the operator's
/// own answers only (not news), until a frame from adrive shows the vehicle
/// disengaged; a frame still engaged, or none, leaves it said.
#[test]
fn a_stop_not_confirmed_stays_on_the_line_until_adrive_shows_the_vehicle_disengaged() {
    use crate::console::model::MESSAGE_FOR;
    let mut f = Fake::new();
    f.gone = true;
    f.snap.snap.gate.engaged = true;
    f.snap.quiet = Some(Duration::from_secs(2));
    let mut m = model(&f);
    let t0 = Instant::now();
    press(&mut m, &f, &["<Space>"], t0);
    let line = |m: &Model| m.message_line().map(|(t, bad)| (t.into_owned(), bad));
    let later = t0 + MESSAGE_FOR + Duration::from_secs(2);
    tick(&mut m, &f, later);
    let (text, bad) = line(&m).expect("said");
    assert!(
        bad && text.starts_with("STOP NOT CONFIRMED (10 s ago): adrive went away"),
        "{text}"
    );
    // News does not cover it; the operator's own answer does, for its time.
    m.tell("supervisor: something", false);
    assert!(line(&m).unwrap().0.starts_with("STOP NOT CONFIRMED"));
    m.say("an answer", false);
    assert_eq!(line(&m).unwrap().0, "an answer");
    tick(&mut m, &f, later + MESSAGE_FOR);
    assert!(line(&m).unwrap().0.starts_with("STOP NOT CONFIRMED"));
    // adrive speaks again, still engaged: still not confirmed; then disengaged.
    f.snap.quiet = None;
    tick(&mut m, &f, later + MESSAGE_FOR);
    assert!(line(&m).unwrap().0.starts_with("STOP NOT CONFIRMED"));
    f.snap.snap.gate.engaged = false;
    tick(&mut m, &f, later + MESSAGE_FOR);
    assert_eq!(
        line(&m),
        Some((
            "adrive answers again: the vehicle is disengaged".into(),
            false
        ))
    );
}

/// `M` on the bench: refused at once with the reason where the check refuses, and
/// nothing asked; else the question names the device, the procedures, the directory
/// and what was checked, and `y` starts it. While it runs the bench stays on its
/// device; `Esc` ends it, and how it ended is said at the next tick.
#[test]
fn m_on_the_bench_asks_then_characterizes_and_esc_ends_it() {
    let mut f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["x", "<Tab>", "<Tab>", "<Tab>"], now);
    assert_eq!(m.bench, id("trans"));
    press(&mut m, &f, &["M"], now);
    let said = m.message.clone().unwrap();
    assert!(
        said.bad
            && said
                .text
                .starts_with("characterize trans refused: trans is a state")
    );
    assert_eq!(m.mode, Mode::Bench, "nothing asked");
    press(&mut m, &f, &["<Tab>", "<Tab>", "<Tab>"], now);
    assert_eq!(m.bench, id("steer"));
    f.refuse = Some(Reject::ShiftWhileMoving);
    press(&mut m, &f, &["M"], now);
    assert!(m
        .message
        .as_ref()
        .unwrap()
        .text
        .contains("characterize steer refused: not ready"));
    assert_eq!(m.mode, Mode::Bench);
    f.refuse = None;
    press(&mut m, &f, &["M"], now);
    assert_eq!(m.mode, Mode::Confirm);
    let text = m.question_text(m.ask.unwrap());
    assert!(
        text.starts_with("Characterize steer (step, sweep, deadband, backlash, rate, delay) into "),
        "{text}"
    );
    assert!(text.contains("/characterize-steer-"), "{text}");
    assert!(text.contains("It moves steer over 90 % of its range for about 30 s; the vehicle must be stopped, in park, with the brake held."), "{text}");
    assert!(
        text.ends_with("Checked now: stopped, in park, the brake held."),
        "{text}"
    );
    // The question is drawn whole at 80×24: it may be answered.
    press(&mut m, &f, &["y"], now);
    assert_eq!(m.mode, Mode::Bench);
    let calls = f.calls();
    assert!(
        calls
            .last()
            .unwrap()
            .starts_with("characterize steer 6 into "),
        "{calls:?}"
    );
    // Running, as the engine says.
    *f.characterizing.borrow_mut() = Some(crate::controls::Characterizing {
        device: id("steer"),
        name: "steer".into(),
        procedures: crate::characterize::Procedure::ALL.to_vec(),
        out: "/x/characterize-steer-1".into(),
        progress: crate::controls::Progress {
            stage: crate::controls::Stage::Sweep,
            done: 30,
            total: 50,
            elapsed: Duration::from_secs(15),
        },
        end: None,
    });
    tick(&mut m, &f, now);
    let screen = draw(&mut m);
    let text: String = (0..24)
        .map(|y| (0..80).map(|x| screen[(x, y)].symbol()).collect::<String>() + "\n")
        .collect();
    assert!(text.contains("characterize steer: running"), "{text}");
    assert!(
        text.contains("sweep · step 31 of 50 · 15.0 s · about 10.0 s left"),
        "{text}"
    );
    assert!(
        text.contains("steer over the last 10 s"),
        "the chart beside it:\n{text}"
    );
    press(&mut m, &f, &["<Tab>"], now);
    assert_eq!(m.bench, id("steer"), "the bench stays on its device");
    assert!(m
        .message
        .as_ref()
        .unwrap()
        .text
        .contains("STOP or Esc ends it"));
    press(&mut m, &f, &["<Esc>"], now);
    assert_eq!(m.mode, Mode::Main);
    assert_eq!(
        f.calls().last().unwrap(),
        "characterize end: the operator left the bench view"
    );
    let said = m.message.clone().unwrap();
    assert!(said.bad, "{said:?}");
    assert_eq!(
        said.text,
        "characterize steer ended early: stopped: the operator left the bench view; safe state, nothing written"
    );
}

/// The bench with a characterization under way is never drawn blind: at 80×24 and at
/// the smallest console, 80×22, the run's box says what it does and how to end it;
/// below that, the small screen names STOP and quit, which still act.
#[test]
fn a_characterization_on_the_bench_is_drawn_at_80x24_and_smaller() {
    let f = Fake::new();
    let mut m = model(&f);
    let now = Instant::now();
    press(&mut m, &f, &["x"], now);
    m.characterize_shown = true;
    m.characterizing = Some(crate::controls::Characterizing {
        device: id("steer"),
        name: "steer".into(),
        procedures: crate::characterize::Procedure::ALL.to_vec(),
        out: "/a/rather/long/directory/of/the/operator/characterize-steer-20261127-140812".into(),
        progress: crate::controls::Progress {
            stage: crate::controls::Stage::Steps,
            done: 3,
            total: 50,
            elapsed: Duration::from_secs(2),
        },
        end: None,
    });
    for (w, h) in [(80, 24), (80, 22), (100, 30), (79, 22), (60, 20)] {
        m.screen = ratatui::layout::Rect::new(0, 0, w, h);
        let b = draw(&mut m);
        let text: String = (0..h)
            .map(|y| (0..w).map(|x| b[(x, y)].symbol()).collect::<String>() + "\n")
            .collect();
        if w >= 80 && h >= 22 {
            assert!(
                text.contains("characterize steer: running"),
                "{w}×{h}:\n{text}"
            );
            assert!(
                text.contains("large steps · step 4 of 50"),
                "{w}×{h}:\n{text}"
            );
            assert!(
                text.contains("Space STOP or Esc ends it"),
                "{w}×{h}:\n{text}"
            );
            assert!(m.drawn.devices.contains(&id("steer")), "{w}×{h}");
        } else {
            assert!(
                text.contains("needs a terminal of at least 80×22"),
                "{w}×{h}:\n{text}"
            );
            assert!(text.contains("Space"), "{w}×{h}:\n{text}");
        }
    }
    // Where there is room, the traffic stays under the box.
    m.screen = ratatui::layout::Rect::new(0, 0, 100, 40);
    let b = draw(&mut m);
    let text: String = (0..40)
        .map(|y| (0..100).map(|x| b[(x, y)].symbol()).collect::<String>() + "\n")
        .collect();
    assert!(text.contains("raw traffic"), "{text}");
    assert!(
        text.contains("writing to /a/rather/long/directory"),
        "{text}"
    );
}
