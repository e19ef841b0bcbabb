//! What the operator can see, and the rule every key obeys: **no key acts on what the
//! operator cannot see** (DESIGN.md, Safety).
//!
//! Each frame the view reports what it drew ([`Drawn`]): whether the console was
//! drawn at all (below its minimum size it only says how big it needs to be), the
//! confirmation dialog whole with its answers, the name prompt, the editable fields
//! whose values are on screen (an edit with its caret among them), the devices whose
//! names are, the teleop bar, the bench's simulator keys, the help overlay. [`check`]
//! is the one rule, over the model and that report: before
//! [`update`](super::update::update) applies an action, an action whose target the
//! last frame did not show is refused, and [`refusal`] says so in words the operator
//! reads where they look — on the small screen too. A STOP is never refused, nor is
//! quitting. A dialog or the name prompt not drawn takes nothing else, not even `Esc`
//! (and the prompt takes no character that would push what is typed off its line);
//! leaving anything else that is open (an edit, help, a view) is allowed whenever the
//! console is drawn: it changes nothing the operator cannot see. The embedded console and `adrive attach` run the same loop
//! ([`drive`](super::drive)), so both obey it.
//!
//! Below the minimum size the small screen names the main screen's STOP and quit keys,
//! so [`key`] reads those two keys as the main screen does in every mode (`q` quits
//! even where an edit would have typed it); every other key is refused.

use super::keymap::{key_to_action, Action, Mode, SimAction};
use super::layout::{MIN_HEIGHT, MIN_WIDTH};
use super::model::{Field, Model, Question};
use crate::config::Role;
use crate::value::DeviceId;
use crossterm::event::KeyEvent;
use std::fmt;
use unicode_width::{UnicodeWidthChar, UnicodeWidthStr};

/// What the last frame showed the operator.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Drawn {
    /// The terminal's columns and rows at that frame.
    pub size: (u16, u16),
    /// The console itself was drawn (the terminal was at least the minimum size).
    pub console: bool,
    /// The confirmation dialog: its question, drawn whole with its answers.
    pub dialog: Option<Question>,
    /// The name prompt, with what is typed.
    pub prompt: bool,
    /// The help overlay.
    pub help: bool,
    /// The teleop bar, both its lines whole.
    pub teleop: bool,
    /// The teleop levels (gas, brake, hold, steering rate), whole.
    pub teleop_levels: bool,
    /// Editable fields whose value (or edit, with its caret) was drawn whole.
    pub fields: Vec<Field>,
    /// Devices whose name was drawn (a panel's title, a row of the list, the bench).
    pub devices: Vec<DeviceId>,
    /// The bench's simulator box: the fault keys drawn in it. `None` where there is
    /// no box (the devices are not simulated here: the keys only say so).
    pub sim_keys: Option<Vec<SimAction>>,
    /// The fault keys the box leaves out because this vehicle lacks what they act on
    /// (an e-stop, an engine): nothing is hidden, and the simulator refuses each,
    /// saying what is missing.
    pub sim_absent: Vec<SimAction>,
}

impl Drawn {
    /// The console covered by an overlay (help, a dialog): what was under it is not
    /// seen any more.
    pub(crate) fn covered(&mut self) {
        self.fields.clear();
        self.devices.clear();
        self.teleop = false;
        self.teleop_levels = false;
        self.sim_keys = None;
        self.sim_absent.clear();
    }
}

/// Why an action was refused: its target was not on the screen.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Unseen {
    /// The terminal is smaller than the console: only its size is on the screen.
    Small {
        size: (u16, u16),
    },
    Dialog,
    Prompt,
    Help,
    Teleop,
    TeleopLevels,
    /// An editable field, by name (`steer command`).
    Field(String),
    /// A device, by name.
    Device(String),
    /// A simulator fault key not in the box on the screen.
    SimKey,
}

impl fmt::Display for Unseen {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let what = match self {
            Unseen::Small { size: (w, h) } => {
                return write!(
                    f,
                    "the window is {w}×{h}, smaller than the console's \
                     {MIN_WIDTH}×{MIN_HEIGHT}"
                )
            }
            Unseen::Dialog => "the question",
            Unseen::Prompt => "the name prompt",
            Unseen::Help => "help",
            Unseen::Teleop => "the teleop bar",
            Unseen::TeleopLevels => "the teleop levels",
            Unseen::Field(name) | Unseen::Device(name) => name,
            Unseen::SimKey => "its key in the simulator box",
        };
        write!(f, "{what} is not on the screen (enlarge the window)")
    }
}

/// What the operator is told: `engage refused: the window is 60×20, …`.
pub(crate) fn refusal(a: Action, why: &Unseen) -> String {
    let what = match a {
        Action::Input(_) => "typing".to_string(),
        Action::Confirm => "yes".to_string(),
        a => a.to_string().replace('_', " "),
    };
    format!("{what} refused: {why}")
}

/// What a key means now: as [`key_to_action`] says in the current mode; below the
/// minimum size, the main screen's STOP and quit keys are those in every mode (the
/// small screen names them).
pub(crate) fn key(m: &Model, e: &KeyEvent) -> Option<Action> {
    let a = key_to_action(&m.keymap, m.mode, e);
    if m.drawn.console {
        return a;
    }
    match key_to_action(&m.keymap, Mode::Main, e) {
        Some(b @ (Action::Stop | Action::Quit)) => Some(b),
        _ => a,
    }
}

/// The rule: `Ok` when action `a` may act on what the last frame ([`Model::drawn`])
/// showed, else what was not on the screen.
pub(crate) fn check(m: &Model, a: Action) -> Result<(), Unseen> {
    let d = &m.drawn;
    let field = |f: Field| match d.fields.contains(&f) {
        true => Ok(()),
        false => Err(Unseen::Field(f.name(&m.snap))),
    };
    let device = |id: Option<DeviceId>| match id {
        // What acts on nothing says so itself.
        None => Ok(()),
        Some(id) if d.devices.contains(&id) => Ok(()),
        Some(id) => Err(Unseen::Device(
            m.snap
                .at(id)
                .map_or("the device".into(), |x| x.name.clone()),
        )),
    };
    let seen = |yes: bool, no: Unseen| if yes { Ok(()) } else { Err(no) };
    match a {
        Action::Stop | Action::Quit | Action::Interrupt => return Ok(()),
        _ if !d.console => return Err(Unseen::Small { size: d.size }),
        _ => {}
    }
    match (m.mode, a) {
        // A question or the name prompt not drawn takes no answer at all, not even no.
        (Mode::Confirm, _) => seen(m.ask.is_some() && d.dialog == m.ask, Unseen::Dialog),
        // A character that would push what is typed off the prompt's line is not
        // taken either: the prompt stays on the screen.
        (Mode::Find, Action::Input(c)) => {
            let typed = m.find.as_ref().map_or(0, |f| f.query.width());
            seen(
                d.prompt && typed + 2 + c.width().unwrap_or(1) <= usize::from(d.size.0),
                Unseen::Prompt,
            )
        }
        (Mode::Find, _) => seen(d.prompt, Unseen::Prompt),
        // Leaving what is open changes nothing the operator cannot see.
        (_, Action::Back | Action::Cancel) => Ok(()),
        // Typing and applying need the field with what is typed; deleting only
        // shortens it.
        (Mode::Edit, Action::Input(_) | Action::Commit) => match &m.edit {
            Some(e) => field(e.field),
            None => Ok(()),
        },
        (Mode::Help, _) => seen(d.help, Unseen::Help),
        (
            Mode::Teleop,
            Action::SteerLeft
            | Action::SteerRight
            | Action::AccelUp
            | Action::AccelDown
            | Action::FullBrake
            | Action::Center
            | Action::StepMode,
        ) => seen(d.teleop, Unseen::Teleop),
        (Mode::Teleop, Action::Level(..)) => seen(d.teleop_levels, Unseen::TeleopLevels),
        (Mode::Main, Action::Edit) => field(m.field()),
        (Mode::Main, Action::Wake(None)) => device(m.field().device()),
        (Mode::Main, Action::Wake(Some(r))) => device(m.snap.bound_id(r)),
        (Mode::Main, Action::ResetSteering) => device(m.snap.bound_id(Role::Steering)),
        (Mode::Bench, Action::Edit | Action::Wake(_) | Action::Characterize) => {
            device(Some(m.bench))
        }
        (Mode::Bench, Action::Sim(s)) => match &d.sim_keys {
            // A key the vehicle has no use for is answered by the simulator's
            // refusal, which says what is missing.
            Some(keys) => seen(
                keys.contains(&s) || d.sim_absent.contains(&s),
                Unseen::SimKey,
            ),
            None => Ok(()),
        },
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::console::keymap::Keymap;
    use crate::console::theme::Theme;
    use crate::controls::{capture, Sources};
    use crossterm::event::{KeyCode, KeyModifiers};
    use ratatui::buffer::Buffer;
    use ratatui::layout::Rect;
    use std::time::{Duration, Instant};

    fn model() -> Model {
        let now = Instant::now();
        let frame = capture(&crate::testkit::gate(now), &Sources::default(), now, None);
        Model::new(
            Keymap::default_map(),
            Theme::default(),
            frame,
            Duration::from_secs(1),
        )
    }

    /// Draw `m` at `w`×`h` as the console does, keeping what the frame showed.
    fn draw(m: &mut Model, w: u16, h: u16) -> Buffer {
        let mut buf = Buffer::empty(Rect::new(0, 0, w, h));
        m.screen = buf.area;
        m.drawn = crate::console::view::draw(m, buf.area, &mut buf);
        buf
    }

    fn text(b: &Buffer) -> String {
        let a = b.area;
        (0..a.height)
            .map(|y| (0..a.width).map(|x| b[(x, y)].symbol()).collect::<String>() + "\n")
            .collect()
    }

    const EVERY_ACTION: &[Action] = &[
        Action::Help,
        Action::Up,
        Action::Down,
        Action::Left,
        Action::Right,
        Action::Edit,
        Action::EditOf(crate::console::keymap::Target::Device(Role::Steering)),
        Action::Commit,
        Action::Backspace,
        Action::Clear,
        Action::Wake(None),
        Action::WakeAll,
        Action::ResetSteering,
        Action::Engage,
        Action::Disengage,
        Action::Interlocks,
        Action::Confirm,
        Action::Teleop,
        Action::SteerLeft,
        Action::SteerRight,
        Action::AccelUp,
        Action::AccelDown,
        Action::FullBrake,
        Action::Center,
        Action::Level(crate::console::keymap::Knob::Gas, true),
        Action::StepMode,
        Action::KeyEvents,
        Action::Bench,
        Action::NextDevice,
        Action::PrevDevice,
        Action::PageDown,
        Action::PageUp,
        Action::Find,
        Action::FindNext,
        Action::FindPrev,
        Action::Complete,
        Action::ClearOverride,
        Action::TakeCommand,
        Action::ReleaseCommand,
        Action::Sim(SimAction::Silent),
        Action::Input('y'),
    ];

    /// Below the minimum size, in every mode, nothing but STOP and quit acts.
    #[test]
    fn below_the_minimum_size_only_stop_and_quit_act_in_every_mode() {
        let mut m = model();
        for mode in Mode::ALL {
            m.mode = mode;
            m.ask = Some(Question::Engage);
            draw(&mut m, 60, 20);
            assert!(!m.drawn.console);
            for &a in EVERY_ACTION.iter().chain(&[Action::Back, Action::Cancel]) {
                assert_eq!(
                    check(&m, a),
                    Err(Unseen::Small { size: (60, 20) }),
                    "{mode} {a}"
                );
            }
            for a in [Action::Stop, Action::Quit, Action::Interrupt] {
                assert_eq!(check(&m, a), Ok(()), "{mode} {a}");
            }
        }
    }

    /// At the console's own sizes, what the view draws is what the keys may act on.
    #[test]
    fn at_full_size_every_target_of_the_main_screen_is_drawn() {
        let mut m = model();
        for (w, h) in [(80, 22), (80, 24), (100, 30), (120, 40)] {
            draw(&mut m, w, h);
            assert!(m.drawn.console, "{w}×{h}");
            let n = m.snap.devices.len();
            assert_eq!(m.drawn.devices.len(), n, "{w}×{h}: {:?}", m.drawn);
            for f in m.fields() {
                assert!(m.drawn.fields.contains(&f), "{w}×{h}: {f:?} not drawn");
            }
            for &a in EVERY_ACTION {
                assert_eq!(check(&m, a), Ok(()), "{w}×{h} {a}");
            }
        }
    }

    #[test]
    fn a_dialog_is_answered_only_while_it_is_drawn_whole() {
        let mut m = model();
        m.back_to = Mode::Main;
        m.mode = Mode::Confirm;
        m.ask = Some(Question::Engage);
        draw(&mut m, 80, 24);
        assert_eq!(m.drawn.dialog, Some(Question::Engage));
        assert_eq!(check(&m, Action::Confirm), Ok(()));
        // The question changed since the frame: the one drawn is not the one asked.
        m.ask = Some(Question::Interlocks(false));
        assert_eq!(check(&m, Action::Confirm), Err(Unseen::Dialog));
        // A dialog the frame did not show whole takes no answer, not even no.
        m.ask = Some(Question::Engage);
        m.drawn.dialog = None;
        assert_eq!(check(&m, Action::Confirm), Err(Unseen::Dialog));
        assert_eq!(check(&m, Action::Cancel), Err(Unseen::Dialog));
        assert_eq!(check(&m, Action::Stop), Ok(()));
    }

    #[test]
    fn the_too_small_screen_names_the_keys_and_says_the_refusal_at_40x10() {
        let mut m = model();
        draw(&mut m, 40, 10);
        let why = check(&m, Action::Engage).unwrap_err();
        m.say(refusal(Action::Engage, &why), true);
        let screen = text(&draw(&mut m, 40, 10));
        let flat = screen.split_whitespace().collect::<Vec<_>>().join(" ");
        for want in [
            "engage refused: the window is 40×10, smaller than the console's 80×22",
            "at least 80×22; this one is 40×10",
            "Space (STOP)",
            "q (quit)",
            "DISENGAGED",
        ] {
            assert!(flat.contains(want), "{want:?} not in:\n{screen}");
        }
    }

    #[test]
    fn below_the_minimum_size_q_quits_and_space_stops_from_any_mode() {
        let mut m = model();
        let q = KeyEvent::new(KeyCode::Char('q'), KeyModifiers::NONE);
        m.mode = Mode::Edit;
        draw(&mut m, 80, 24);
        assert_eq!(key(&m, &q), Some(Action::Input('q')), "typed while drawn");
        draw(&mut m, 60, 20);
        assert_eq!(key(&m, &q), Some(Action::Quit));
        let space = KeyEvent::new(KeyCode::Char(' '), KeyModifiers::NONE);
        m.mode = Mode::Find;
        assert_eq!(key(&m, &space), Some(Action::Stop));
    }

    /// The bench's fault keys act only where the simulator box shows them: with
    /// descriptions long enough to push the last keys off its lines, those keys are
    /// refused and the others act.
    #[test]
    fn a_fault_key_not_in_the_simulator_box_is_refused() {
        let mut m = model();
        m.snap.can_inject = true;
        m.mode = Mode::Bench;
        draw(&mut m, 80, 22);
        let keys = m.drawn.sim_keys.clone().unwrap();
        assert_eq!(
            keys.len(),
            11,
            "every key of the default at 80×22: {keys:?}"
        );
        let long = r#"
[bench]
keymap = [
    { on = "s", run = "sim silent", desc = "sim: this device stops answering altogether" },
    { on = "g", run = "sim garbage", desc = "sim: this device answers nothing but noise" },
    { on = "c", run = "sim corrupt", desc = "sim: a bit of every reply of this device flips" },
]
"#;
        m.keymap.merge(Keymap::parse(long, "long.toml").unwrap());
        draw(&mut m, 80, 22);
        let run = Action::Sim(SimAction::Estop(crate::value::EstopState::Run));
        assert_eq!(check(&m, Action::Sim(SimAction::Silent)), Ok(()));
        assert_eq!(check(&m, run), Err(Unseen::SimKey));
        assert_eq!(
            refusal(run, &Unseen::SimKey),
            "sim estop run refused: its key in the simulator box is not on the screen \
             (enlarge the window)"
        );
        // Without a simulator there is no box: the keys only say what they need.
        m.snap.can_inject = false;
        draw(&mut m, 80, 22);
        assert_eq!(check(&m, run), Ok(()));
    }

    /// An edit whose caret has run off its panel takes no more characters and is not
    /// applied; deleting brings it back.
    #[test]
    fn typing_into_a_field_not_drawn_is_refused_and_deleting_is_not() {
        let mut m = model();
        let steer = m.snap.id_of("steer").unwrap();
        m.back_to = Mode::Main;
        m.mode = Mode::Edit;
        m.edit = Some(crate::console::model::Edit {
            field: Field::Command(steer),
            buffer: "0.1234567890123456789012345".into(),
            fresh: false,
            error: None,
        });
        draw(&mut m, 80, 24);
        let name = "steer command".to_string();
        assert_eq!(
            check(&m, Action::Input('5')),
            Err(Unseen::Field(name.clone()))
        );
        assert_eq!(check(&m, Action::Commit), Err(Unseen::Field(name)));
        assert_eq!(check(&m, Action::Backspace), Ok(()));
        assert_eq!(check(&m, Action::Clear), Ok(()));
        m.edit.as_mut().unwrap().buffer = "0.7".into();
        draw(&mut m, 80, 24);
        assert_eq!(check(&m, Action::Commit), Ok(()));
    }

    /// The teleop keys act on the bar the frame showed, and only then.
    #[test]
    fn teleop_keys_act_only_while_the_bar_is_drawn() {
        let mut m = model();
        m.mode = Mode::Teleop;
        draw(&mut m, 80, 22);
        assert!(m.drawn.teleop);
        assert_eq!(check(&m, Action::AccelUp), Ok(()));
        m.drawn.teleop = false;
        for a in [Action::AccelUp, Action::SteerLeft, Action::FullBrake] {
            assert_eq!(check(&m, a), Err(Unseen::Teleop), "{a}");
        }
        assert_eq!(check(&m, Action::Stop), Ok(()), "a STOP is never refused");
        assert_eq!(check(&m, Action::Back), Ok(()));
        // A dialog over teleop covers it.
        m.ask = Some(Question::Engage);
        m.back_to = Mode::Teleop;
        m.mode = Mode::Confirm;
        draw(&mut m, 80, 22);
        assert!(!m.drawn.teleop && m.drawn.dialog == Some(Question::Engage));
    }

    /// The tractor's 32 devices at 80×22: the device and the field under the cursor
    /// are drawn wherever the cursor goes, so its keys act.
    #[test]
    fn with_many_devices_the_cursor_is_always_on_the_screen() {
        let now = Instant::now();
        let text = include_str!("../../vehicles/tractor.toml");
        let config = crate::config::parse(text, "vehicles/tractor.toml").unwrap();
        let frame = capture(
            &crate::testkit::gate_of(config, now),
            &Sources::default(),
            now,
            None,
        );
        let mut m = Model::new(
            Keymap::default_map(),
            Theme::default(),
            frame,
            Duration::from_secs(1),
        );
        for i in 0..m.fields().len() {
            m.cursor = i;
            draw(&mut m, 80, 22);
            assert_eq!(check(&m, Action::Edit), Ok(()), "{:?}", m.field());
            assert_eq!(check(&m, Action::Wake(None)), Ok(()), "{:?}", m.field());
        }
    }

    /// The name prompt takes keys only while drawn, and no character that would
    /// push what is typed off its line.
    #[test]
    fn the_name_prompt_takes_keys_only_while_drawn() {
        let mut m = model();
        m.back_to = Mode::Main;
        m.mode = Mode::Find;
        let typed = |m: &mut Model, q: String| {
            m.find = Some(crate::console::model::Find {
                query: q,
                from_cursor: 0,
                from_bench: DeviceId(0),
            })
        };
        typed(&mut m, "st".into());
        draw(&mut m, 80, 24);
        assert_eq!(check(&m, Action::Input('e')), Ok(()));
        // `/` and the caret take two columns: 78 typed fill the line.
        typed(&mut m, "x".repeat(78));
        draw(&mut m, 80, 24);
        assert!(m.drawn.prompt);
        assert_eq!(check(&m, Action::Input('y')), Err(Unseen::Prompt));
        assert_eq!(check(&m, Action::Backspace), Ok(()));
        typed(&mut m, "x".repeat(77));
        draw(&mut m, 80, 24);
        assert_eq!(check(&m, Action::Input('y')), Ok(()));
        // Not drawn: nothing but STOP and quit, not even Esc.
        m.drawn.prompt = false;
        for a in [
            Action::Input('y'),
            Action::Backspace,
            Action::Cancel,
            Action::Commit,
        ] {
            assert_eq!(check(&m, a), Err(Unseen::Prompt), "{a}");
        }
        assert_eq!(check(&m, Action::Stop), Ok(()));
    }
}
