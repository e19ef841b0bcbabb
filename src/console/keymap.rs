//! Key bindings: which key runs which [`Action`] in which [`Mode`].
//!
//! Bindings are TOML, one section per mode, records `{ on, run, desc }` (the layout of
//! yazi's keymaps). `keymaps/default.toml` is compiled in; a user file (`--keymap FILE`,
//! or `keymap.toml` in the user's config directory) is merged over it: a record whose
//! key is already bound in that mode replaces the binding, `run = "none"` removes it,
//! any other record is added. Help and hint bar are generated from the loaded map.
//!
//! A file with an unknown key, an unknown action, an unknown field or section, the
//! same key bound twice in one section, or a binding of Ctrl-C (always "stop adrive,
//! safe state first") is refused with `file:line: message` naming the expected form.
//! A user file that leaves a mode without a key bound to `stop` (the emergency stop,
//! `<Space>` in every mode of the default) is loaded with a warning naming the record
//! that took it away. Nothing here panics on bad input.

use crate::config::Role;
use crate::value::EstopState;
use crossterm::event::{KeyCode, KeyEvent, KeyEventKind, KeyModifiers};
use serde::Deserialize;
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// The compiled-in keymap.
pub(crate) const DEFAULT_TOML: &str = include_str!("../../keymaps/default.toml");
/// The name errors in the compiled-in keymap are reported under.
pub(crate) const DEFAULT_PATH: &str = "keymaps/default.toml";

/// One key: a code plus modifiers. Written `g`, `G`, `?`, `<C-c>`, `<Up>`, `<Space>`,
/// `<Enter>`, `<Esc>`, `<A-x>`, `<S-Tab>`, `<F1>`, `<lt>` (a literal `<`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Key {
    pub code: KeyCode,
    pub ctrl: bool,
    pub(crate) alt: bool,
    pub shift: bool,
}

const NAMED: &[(&str, KeyCode)] = &[
    ("Enter", KeyCode::Enter),
    ("Esc", KeyCode::Esc),
    ("Tab", KeyCode::Tab),
    ("BackTab", KeyCode::BackTab),
    ("Backspace", KeyCode::Backspace),
    ("Delete", KeyCode::Delete),
    ("Insert", KeyCode::Insert),
    ("Home", KeyCode::Home),
    ("End", KeyCode::End),
    ("PageUp", KeyCode::PageUp),
    ("PageDown", KeyCode::PageDown),
    ("Up", KeyCode::Up),
    ("Down", KeyCode::Down),
    ("Left", KeyCode::Left),
    ("Right", KeyCode::Right),
    ("Space", KeyCode::Char(' ')),
    ("lt", KeyCode::Char('<')),
];

/// The expected form of a key, for error messages.
pub(crate) const KEY_FORM: &str = "a single character (g, G, ?) or <Name> with Name one of \
Enter, Esc, Tab, BackTab, Backspace, Delete, Insert, Home, End, PageUp, PageDown, Up, \
Down, Left, Right, Space, lt, F1…F12 or a character, optionally after C- (Ctrl), A- (Alt), \
S- (Shift), e.g. <C-c>";

impl Key {
    pub const fn plain(code: KeyCode) -> Key {
        Key {
            code,
            ctrl: false,
            alt: false,
            shift: false,
        }
    }

    pub const fn ctrl(c: char) -> Key {
        Key {
            code: KeyCode::Char(c),
            ctrl: true,
            alt: false,
            shift: false,
        }
    }

    /// The key of a terminal event. A shifted character arrives as its capital (or
    /// its symbol), so Shift is dropped for characters; `<S-Tab>` is `BackTab`.
    pub(crate) fn from_event(e: &KeyEvent) -> Key {
        let m = e.modifiers;
        let is_char = matches!(e.code, KeyCode::Char(_) | KeyCode::BackTab);
        Key {
            code: e.code,
            ctrl: m.contains(KeyModifiers::CONTROL),
            alt: m.contains(KeyModifiers::ALT),
            shift: m.contains(KeyModifiers::SHIFT) && !is_char,
        }
    }

    fn name(self) -> String {
        match self.code {
            KeyCode::F(n) => format!("F{n}"),
            KeyCode::Char(c) => NAMED
                .iter()
                .find(|(_, k)| *k == KeyCode::Char(c))
                .map(|(n, _)| n.to_string())
                .unwrap_or_else(|| c.to_string()),
            code => NAMED
                .iter()
                .find(|(_, k)| *k == code)
                .map(|(n, _)| n.to_string())
                .unwrap_or_else(|| format!("{code:?}")),
        }
    }
}

impl fmt::Display for Key {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let plain = !(self.ctrl || self.alt || self.shift);
        if let (true, KeyCode::Char(c)) = (plain, self.code) {
            if c != ' ' && c != '<' {
                return write!(f, "{c}");
            }
        }
        f.write_str("<")?;
        if self.ctrl {
            f.write_str("C-")?;
        }
        if self.alt {
            f.write_str("A-")?;
        }
        if self.shift {
            f.write_str("S-")?;
        }
        write!(f, "{}>", self.name())
    }
}

impl FromStr for Key {
    type Err = String;
    fn from_str(s: &str) -> Result<Key, String> {
        let bad = || format!("unknown key {s:?}: expected {KEY_FORM}");
        let mut chars = s.chars();
        if let (Some(c), None) = (chars.next(), chars.next()) {
            if c.is_control() {
                return Err(bad());
            }
            return Ok(Key::plain(KeyCode::Char(c)));
        }
        let inner = s
            .strip_prefix('<')
            .and_then(|r| r.strip_suffix('>'))
            .filter(|r| !r.is_empty())
            .ok_or_else(bad)?;
        let mut key = Key::plain(KeyCode::Null);
        let mut rest = inner;
        loop {
            let (m, tail) = match rest.split_once('-') {
                Some((m, tail)) if !tail.is_empty() && m.len() == 1 => (m, tail),
                _ => break,
            };
            match m {
                "C" | "c" => key.ctrl = true,
                "A" | "a" | "M" | "m" => key.alt = true,
                "S" | "s" => key.shift = true,
                _ => return Err(bad()),
            }
            rest = tail;
        }
        let mut chars = rest.chars();
        key.code = if let (Some(c), None) = (chars.next(), chars.next()) {
            KeyCode::Char(c)
        } else if let Some(n) = rest
            .strip_prefix('F')
            .and_then(|n| n.parse::<u8>().ok())
            .filter(|n| (1..=12).contains(n))
        {
            KeyCode::F(n)
        } else {
            NAMED
                .iter()
                .find(|(n, _)| n.eq_ignore_ascii_case(rest))
                .map(|(_, k)| *k)
                .ok_or_else(bad)?
        };
        // `<S-Tab>` is what terminals send as BackTab; a shifted character is its capital.
        if key.shift {
            match key.code {
                KeyCode::Tab => (key.code, key.shift) = (KeyCode::BackTab, false),
                KeyCode::Char(c) if c.is_alphabetic() => {
                    (key.code, key.shift) = (KeyCode::Char(c.to_ascii_uppercase()), false)
                }
                KeyCode::Char(_) => key.shift = false,
                _ => {}
            }
        }
        Ok(key)
    }
}

/// The console's modes; each has its own section in a keymap.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Mode {
    /// The main screen: cursor over fields, shortcuts.
    Main,
    /// Editing a field in place.
    Edit,
    /// Driving from the keyboard, with a deadman.
    Teleop,
    /// One device up close.
    Bench,
    /// A yes/no question before a consequential action.
    Confirm,
    /// The help overlay.
    Help,
    /// The name prompt: jump to a device by typing its name.
    Find,
}

impl Mode {
    pub const ALL: [Mode; 7] = [
        Mode::Main,
        Mode::Edit,
        Mode::Teleop,
        Mode::Bench,
        Mode::Confirm,
        Mode::Help,
        Mode::Find,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Mode::Main => "main",
            Mode::Edit => "edit",
            Mode::Teleop => "teleop",
            Mode::Bench => "bench",
            Mode::Confirm => "confirm",
            Mode::Help => "help",
            Mode::Find => "find",
        }
    }

    fn index(self) -> usize {
        Mode::ALL.iter().position(|m| *m == self).expect("listed")
    }
}

impl fmt::Display for Mode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The roles that bind an actuator, which keys may name.
pub(crate) const ACTUATOR_ROLES: [Role; 4] =
    [Role::Steering, Role::Throttle, Role::Brake, Role::Gear];

/// What a field edit (or a shortcut that starts one) is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// The command of the device bound to a role (the vehicle file's
    /// `[vehicle.roles]`).
    Device(Role),
    /// The vehicle's virtual `accel` command (−1…1: brake below 0, gas above).
    Accel,
}

/// Everything a key can do.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Action {
    /// Leave (safe state first).
    Quit,
    Help,
    /// Leave the current mode (back to where it was entered from).
    Back,
    Up,
    Down,
    Left,
    Right,
    /// Edit the field under the cursor.
    Edit,
    /// Jump to a command field and edit it (the paper's g, s, b, c, t).
    EditOf(Target),
    Commit,
    Cancel,
    Backspace,
    Clear,
    /// Wake a command thread (broadcast its condition variable): the device under the
    /// cursor (`None`) or a named one.
    Wake(Option<Role>),
    WakeAll,
    /// Reset steering after a disable and re-enable (the paper's `e`): home the drive,
    /// then hold where it stops.
    ResetSteering,
    Engage,
    /// Disengage (asks first).
    Disengage,
    /// Stop now: disengage and command the safe state, without asking.
    Stop,
    /// Interlocks on/off (asks first).
    Interlocks,
    Confirm,
    Teleop,
    SteerLeft,
    SteerRight,
    AccelUp,
    AccelDown,
    FullBrake,
    Center,
    /// A teleop setting one step up (`true`) or down.
    Level(Knob, bool),
    /// Teleop: step mode on or off (back to what the terminal gives).
    StepMode,
    /// Help: show or hide the last key events, with their kinds.
    KeyEvents,
    Bench,
    NextDevice,
    PrevDevice,
    /// The full panels of the next / previous page of devices.
    PageDown,
    PageUp,
    /// Open the name prompt: jump to a device by typing its name.
    Find,
    /// The next / previous device matching the name looked for.
    FindNext,
    FindPrev,
    /// Complete the name typed to the longest prefix its matches share.
    Complete,
    /// Clear a latched driver override, as the network's `clear` does (refused while
    /// the driver's hand is still on).
    ClearOverride,
    /// Take command of the engaged vehicle from whoever has it (asks first).
    TakeCommand,
    /// Give command up: the vehicle stays engaged for the handover to another source.
    ReleaseCommand,
    /// Bench, under `--sim`: inject or clear a simulator fault.
    Sim(SimAction),
    /// Bench: characterize the device on the bench (asks first), as `adrive
    /// characterize` does.
    Characterize,
    /// Unbinds a key in a user keymap.
    None,
    /// A character typed while editing (not bindable).
    Input(char),
    /// Ctrl-C (always bound, not bindable).
    Interrupt,
}

/// A teleop setting that keys change (the vehicle file's `[teleop]`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Knob {
    /// The throttle while its key is held.
    Gas,
    /// The brake while its key is held.
    Brake,
    /// The brake while no pedal key is held.
    Hold,
    /// How fast a held steering key moves the steering.
    SteerRate,
}

/// What a bench key does to the simulator (`--sim` only). The first five act on the
/// device on the bench and toggle; the rest act on the simulated vehicle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimAction {
    /// Stop answering (on/off).
    Silent,
    /// Answer noise instead of replies (on/off).
    Garbage,
    /// Flip a bit of every reply: a bad CRC or checksum (on/off).
    Corrupt,
    /// Reply [`SIM_SLOW`] late (on/off).
    Slow,
    /// Close the port and come back after [`SIM_VANISH`], as a USB unplug.
    Vanish,
    /// Clear every fault of the device.
    Clear,
    /// The engine dies.
    Stall,
    /// The steering drive latches a fault (disable → enable clears it).
    Jam,
    /// Put the simulated e-stop in this state.
    Estop(EstopState),
    /// A driver's hand pushes the device on the bench toward the end of its range
    /// farther from where it is; again, the hand lets go (on/off).
    Override,
}

impl SimAction {
    /// Every action a bench key may do.
    pub const ALL: [SimAction; 12] = [
        SimAction::Silent,
        SimAction::Garbage,
        SimAction::Corrupt,
        SimAction::Slow,
        SimAction::Vanish,
        SimAction::Clear,
        SimAction::Stall,
        SimAction::Jam,
        SimAction::Estop(EstopState::Pause),
        SimAction::Estop(EstopState::Run),
        SimAction::Estop(EstopState::Disable),
        SimAction::Override,
    ];
}

/// How late a "slow" simulated device replies.
pub(crate) const SIM_SLOW: std::time::Duration = std::time::Duration::from_millis(150);
/// How long a "vanished" simulated device stays away.
pub(crate) const SIM_VANISH: std::time::Duration = std::time::Duration::from_millis(2000);

/// The valid `run` values, for error messages.
pub(crate) const ACTION_FORM: &str = "quit, help, back, up, down, left, right, edit, \
edit steering|throttle|brake|gear|accel (also steer, gas, trans), commit, cancel, \
backspace, clear, wake, wake steering|throttle|brake|gear, \
wake all, reset_steering, engage, disengage, stop, interlocks, confirm, teleop, steer_left, \
steer_right, accel_up, accel_down, full_brake, center, gas_more, gas_less, brake_more, \
brake_less, hold_more, hold_less, steer_faster, steer_slower, step_mode, key_events, bench, \
next_device, prev_device, \
page_down, page_up, find, find_next, find_prev, complete, clear_override, take_command, \
release_command, characterize, \
sim silent|garbage|corrupt|slow|vanish|clear|stall|jam|override, \
sim estop pause|run|disable, none";

const SIMPLE: &[(&str, Action)] = &[
    ("quit", Action::Quit),
    ("help", Action::Help),
    ("back", Action::Back),
    ("up", Action::Up),
    ("down", Action::Down),
    ("left", Action::Left),
    ("right", Action::Right),
    ("edit", Action::Edit),
    ("commit", Action::Commit),
    ("cancel", Action::Cancel),
    ("backspace", Action::Backspace),
    ("clear", Action::Clear),
    ("wake", Action::Wake(None)),
    ("wake all", Action::WakeAll),
    ("reset_steering", Action::ResetSteering),
    ("engage", Action::Engage),
    ("disengage", Action::Disengage),
    ("stop", Action::Stop),
    ("interlocks", Action::Interlocks),
    ("confirm", Action::Confirm),
    ("teleop", Action::Teleop),
    ("steer_left", Action::SteerLeft),
    ("steer_right", Action::SteerRight),
    ("accel_up", Action::AccelUp),
    ("accel_down", Action::AccelDown),
    ("full_brake", Action::FullBrake),
    ("center", Action::Center),
    ("gas_more", Action::Level(Knob::Gas, true)),
    ("gas_less", Action::Level(Knob::Gas, false)),
    ("brake_more", Action::Level(Knob::Brake, true)),
    ("brake_less", Action::Level(Knob::Brake, false)),
    ("hold_more", Action::Level(Knob::Hold, true)),
    ("hold_less", Action::Level(Knob::Hold, false)),
    ("steer_faster", Action::Level(Knob::SteerRate, true)),
    ("steer_slower", Action::Level(Knob::SteerRate, false)),
    ("step_mode", Action::StepMode),
    ("key_events", Action::KeyEvents),
    ("bench", Action::Bench),
    ("next_device", Action::NextDevice),
    ("prev_device", Action::PrevDevice),
    ("page_down", Action::PageDown),
    ("page_up", Action::PageUp),
    ("find", Action::Find),
    ("find_next", Action::FindNext),
    ("find_prev", Action::FindPrev),
    ("complete", Action::Complete),
    ("clear_override", Action::ClearOverride),
    ("take_command", Action::TakeCommand),
    ("release_command", Action::ReleaseCommand),
    ("characterize", Action::Characterize),
    ("sim silent", Action::Sim(SimAction::Silent)),
    ("sim garbage", Action::Sim(SimAction::Garbage)),
    ("sim corrupt", Action::Sim(SimAction::Corrupt)),
    ("sim slow", Action::Sim(SimAction::Slow)),
    ("sim vanish", Action::Sim(SimAction::Vanish)),
    ("sim clear", Action::Sim(SimAction::Clear)),
    ("sim stall", Action::Sim(SimAction::Stall)),
    ("sim jam", Action::Sim(SimAction::Jam)),
    ("sim override", Action::Sim(SimAction::Override)),
    (
        "sim estop pause",
        Action::Sim(SimAction::Estop(EstopState::Pause)),
    ),
    (
        "sim estop run",
        Action::Sim(SimAction::Estop(EstopState::Run)),
    ),
    (
        "sim estop disable",
        Action::Sim(SimAction::Estop(EstopState::Disable)),
    ),
    ("none", Action::None),
];

impl FromStr for Action {
    type Err = String;
    fn from_str(s: &str) -> Result<Action, String> {
        let words: Vec<&str> = s.split_whitespace().collect();
        let norm = words.join(" ");
        if let Some((_, a)) = SIMPLE.iter().find(|(n, _)| *n == norm) {
            return Ok(*a);
        }
        let bad = || format!("unknown action {s:?}: expected one of {ACTION_FORM}");
        match words.as_slice() {
            ["edit", "accel"] => Ok(Action::EditOf(Target::Accel)),
            ["edit", dev] => match Role::from_word(dev) {
                Some(r) if ACTUATOR_ROLES.contains(&r) => Ok(Action::EditOf(Target::Device(r))),
                _ => Err(bad()),
            },
            ["wake", dev] => match Role::from_word(dev) {
                Some(r) if ACTUATOR_ROLES.contains(&r) => Ok(Action::Wake(Some(r))),
                _ => Err(bad()),
            },
            _ => Err(bad()),
        }
    }
}

impl fmt::Display for Action {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some((n, _)) = SIMPLE.iter().find(|(_, a)| a == self) {
            return f.write_str(n);
        }
        match self {
            Action::EditOf(Target::Accel) => f.write_str("edit accel"),
            Action::EditOf(Target::Device(r)) => write!(f, "edit {r}"),
            Action::Wake(Some(r)) => write!(f, "wake {r}"),
            Action::Input(c) => write!(f, "input {c:?}"),
            Action::Interrupt => f.write_str("interrupt"),
            other => write!(f, "{other:?}"),
        }
    }
}

/// One binding.
#[derive(Clone, Debug, PartialEq)]
pub struct Binding {
    pub on: Key,
    pub run: Action,
    pub desc: String,
    /// Where it was written (the line in its file).
    pub line: usize,
}

/// A keymap error: `file:line: message`, or `file: message` for the file as a whole
/// (one that cannot be read).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{path}{}: {message}", at_line(*.line))]
pub struct KeymapError {
    pub path: String,
    /// The 1-based line; 0 for the file as a whole.
    pub line: usize,
    pub message: String,
}

/// Bindings per mode, in file order (help lists them in that order).
#[derive(Clone, Debug, PartialEq)]
pub struct Keymap {
    modes: [Vec<Binding>; 7],
    /// The file it was read from, for messages.
    path: String,
    /// Problems that did not stop it loading (see [`Keymap::warnings`]).
    warnings: Vec<KeymapError>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    main: Option<RawSection>,
    edit: Option<RawSection>,
    teleop: Option<RawSection>,
    bench: Option<RawSection>,
    confirm: Option<RawSection>,
    help: Option<RawSection>,
    find: Option<RawSection>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSection {
    #[serde(default)]
    keymap: Vec<toml::Spanned<RawBinding>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBinding {
    on: toml::Spanned<String>,
    run: toml::Spanned<String>,
    #[serde(default)]
    desc: String,
}

/// `:12` for line 12; nothing for line 0 (the file as a whole).
fn at_line(line: usize) -> String {
    match line {
        0 => String::new(),
        n => format!(":{n}"),
    }
}

fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

impl Keymap {
    /// The compiled-in default keymap.
    pub fn default_map() -> Keymap {
        Keymap::parse(DEFAULT_TOML, DEFAULT_PATH).expect("the compiled-in keymap parses")
    }

    /// Parse one keymap file on its own; `path` names it in errors.
    pub fn parse(text: &str, path: &str) -> Result<Keymap, KeymapError> {
        let err = |offset: usize, message: String| KeymapError {
            path: path.to_string(),
            line: line_of(text, offset),
            message,
        };
        let raw: RawFile = toml::from_str(text).map_err(|e| {
            let offset = e.span().map(|s| s.start).unwrap_or(0);
            let mut message = e.message().trim().to_string();
            if message.contains("unknown field") && !message.contains("`keymap`") {
                message.push_str(" (sections are [main], [edit], [teleop], [bench], [confirm], [help], [find], each with keymap = [{ on = \"g\", run = \"edit throttle\", desc = \"…\" }, …])");
            }
            err(offset, message)
        })?;
        let sections = [
            raw.main,
            raw.edit,
            raw.teleop,
            raw.bench,
            raw.confirm,
            raw.help,
            raw.find,
        ];
        let mut modes: [Vec<Binding>; 7] = Default::default();
        for (i, section) in sections.into_iter().enumerate() {
            let Some(section) = section else { continue };
            for rec in section.keymap {
                let rec = rec.into_inner();
                let on: Key = rec
                    .on
                    .get_ref()
                    .parse()
                    .map_err(|m| err(rec.on.span().start, m))?;
                if on == Key::ctrl('c') {
                    return Err(err(
                        rec.on.span().start,
                        "<C-c> cannot be bound or unbound: it always stops adrive, safe \
                         state first; expected another key"
                            .into(),
                    ));
                }
                let run: Action = rec
                    .run
                    .get_ref()
                    .parse()
                    .map_err(|m| err(rec.run.span().start, m))?;
                // A description is drawn on the terminal: printable text on one line.
                crate::config::device::check_text("desc", &rec.desc, true)
                    .map_err(|m| err(rec.on.span().start, m))?;
                if modes[i].iter().any(|b| b.on == on) {
                    return Err(err(
                        rec.on.span().start,
                        format!(
                            "{on} is bound twice in [{}]: expected each key once per section",
                            Mode::ALL[i]
                        ),
                    ));
                }
                modes[i].push(Binding {
                    on,
                    run,
                    desc: rec.desc,
                    line: line_of(text, rec.on.span().start),
                });
            }
        }
        Ok(Keymap {
            modes,
            path: path.to_string(),
            warnings: Vec::new(),
        })
    }

    /// Merge `over` (a user file) over this map. A mode it leaves without a `stop` key
    /// gets a warning at the record that took the last one away.
    pub fn merge(&mut self, over: Keymap) {
        for (i, (mine, theirs)) in self.modes.iter_mut().zip(over.modes).enumerate() {
            let had_stop = mine.iter().any(|b| b.run == Action::Stop);
            let mut took_stop = None;
            for b in theirs {
                let at = mine.iter().position(|m| m.on == b.on);
                if at.is_some_and(|i| mine[i].run == Action::Stop) {
                    took_stop = Some((b.on, b.line));
                }
                match at {
                    Some(i) if b.run == Action::None => {
                        mine.remove(i);
                    }
                    Some(i) => mine[i] = b,
                    None if b.run == Action::None => {}
                    None => mine.push(b),
                }
            }
            let has_stop = mine.iter().any(|b| b.run == Action::Stop);
            if let (true, false, Some((key, line))) = (had_stop, has_stop, took_stop) {
                self.warnings.push(KeymapError {
                    path: over.path.clone(),
                    line,
                    message: format!(
                        "[{}] has no STOP key left: this record takes {key} away from \
                         stop; expected run = \"stop\" on some key in every mode",
                        Mode::ALL[i]
                    ),
                });
            }
        }
    }

    /// The default map with the file at `path` merged over it.
    pub fn load(path: &Path) -> Result<Keymap, KeymapError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| KeymapError {
            path: name.clone(),
            line: 0,
            message: crate::paths::cannot_read(path, &e),
        })?;
        let mut map = Keymap::default_map();
        map.merge(Keymap::parse(&text, &name)?);
        Ok(map)
    }

    /// What loading found wrong without refusing the file (a mode left without a
    /// STOP key), as `file:line: message`: adrive logs them and the console shows them.
    pub fn warnings(&self) -> &[KeymapError] {
        &self.warnings
    }

    /// What `adrive` runs with: `--keymap FILE` if given, else the user's
    /// `$XDG_CONFIG_HOME/adrive/keymap.toml` (or `~/.config/adrive/keymap.toml`) if it
    /// exists, merged over the default.
    pub(crate) fn for_run(flag: Option<&Path>) -> Result<Keymap, KeymapError> {
        match flag.map(Path::to_path_buf).or_else(user_keymap_path) {
            Some(p) if flag.is_some() || p.exists() => Keymap::load(&p),
            _ => Ok(Keymap::default_map()),
        }
    }

    pub fn bindings(&self, mode: Mode) -> &[Binding] {
        &self.modes[mode.index()]
    }

    pub fn lookup(&self, mode: Mode, key: Key) -> Option<Action> {
        self.bindings(mode)
            .iter()
            .find(|b| b.on == key)
            .map(|b| b.run)
    }

    /// The first key bound to `action` in `mode`, for hints such as "y to confirm".
    pub fn key_for(&self, mode: Mode, action: Action) -> Option<Key> {
        self.bindings(mode)
            .iter()
            .find(|b| b.run == action)
            .map(|b| b.on)
    }
}

/// The user's keymap file location.
pub(crate) fn user_keymap_path() -> Option<PathBuf> {
    std::env::var_os("XDG_CONFIG_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".config")))
        .map(|d| d.join("adrive").join("keymap.toml"))
}

/// The pure key handler: what a terminal key event means in `mode`. Ctrl-C always
/// means [`Action::Interrupt`]; releases are ignored; an unbound character typed
/// while editing or in the name prompt is [`Action::Input`].
/// A key's description for this vehicle: `{throttle}` (any role's name in braces)
/// becomes the name of the device bound to it (`gas` on Alice, `throttle` on the cart),
/// so the default keymap's `g gas` reads `g throttle` on a vehicle that calls it so.
/// `None` when a role it names is not bound: the key does nothing there.
pub fn describe(desc: &str, roles: &crate::snapshot::Pairs<String>) -> Option<String> {
    let mut out = String::with_capacity(desc.len());
    let mut rest = desc;
    while let Some(open) = rest.find('{') {
        let Some(close) = rest[open..].find('}') else {
            break;
        };
        let role = &rest[open + 1..open + close];
        out.push_str(&rest[..open]);
        match Role::from_word(role) {
            Some(r) => {
                let bound = roles.get(r.as_str())?;
                out.push_str(bound.split('.').next().unwrap_or(bound));
            }
            None => out.push_str(&rest[open..=open + close]),
        }
        rest = &rest[open + close + 1..];
    }
    out.push_str(rest);
    Some(out)
}

pub fn key_to_action(map: &Keymap, mode: Mode, e: &KeyEvent) -> Option<Action> {
    if e.kind == KeyEventKind::Release {
        return None;
    }
    let key = Key::from_event(e);
    if key == Key::ctrl('c') {
        return Some(Action::Interrupt);
    }
    match map.lookup(mode, key) {
        Some(Action::None) => None,
        Some(a) => Some(a),
        None => match (mode, key) {
            (
                Mode::Edit | Mode::Find,
                Key {
                    code: KeyCode::Char(c),
                    ctrl: false,
                    alt: false,
                    ..
                },
            ) => Some(Action::Input(c)),
            _ => None,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_round_trip_through_text() {
        for s in [
            "g",
            "G",
            "?",
            "<C-c>",
            "<Up>",
            "<Space>",
            "<Enter>",
            "<Esc>",
            "<Tab>",
            "<BackTab>",
            "<F1>",
            "<F12>",
            "<lt>",
            "<A-x>",
            "<C-A-Left>",
            "<S-Up>",
            "<Backspace>",
            "<PageDown>",
            "-",
            ">",
        ] {
            let k: Key = s.parse().unwrap_or_else(|e| panic!("{s}: {e}"));
            assert_eq!(k.to_string(), s, "{s}");
        }
        assert_eq!("<S-Tab>".parse::<Key>().unwrap().to_string(), "<BackTab>");
        assert_eq!("<S-g>".parse::<Key>().unwrap().to_string(), "G");
        assert_eq!("<enter>".parse::<Key>().unwrap().to_string(), "<Enter>");
        assert_eq!(" ".parse::<Key>().unwrap().to_string(), "<Space>");
    }

    #[test]
    fn bad_keys_say_what_is_expected() {
        for s in ["", "gg", "<Foo>", "<X-a>", "<>", "<C->", "<F13>"] {
            let e = s.parse::<Key>().unwrap_err();
            assert!(e.contains("expected"), "{s}: {e}");
        }
    }

    #[test]
    fn key_events_map_to_keys() {
        let ev = |code, m| KeyEvent::new(code, m);
        assert_eq!(
            Key::from_event(&ev(KeyCode::Char('G'), KeyModifiers::SHIFT)),
            "G".parse().unwrap()
        );
        assert_eq!(
            Key::from_event(&ev(KeyCode::Char('c'), KeyModifiers::CONTROL)),
            Key::ctrl('c')
        );
        assert_eq!(
            Key::from_event(&ev(KeyCode::BackTab, KeyModifiers::SHIFT)),
            "<BackTab>".parse().unwrap()
        );
    }

    #[test]
    fn actions_round_trip_and_list_valid_names() {
        for (n, a) in SIMPLE {
            assert_eq!(n.parse::<Action>(), Ok(*a));
            assert_eq!(a.to_string(), *n);
        }
        for s in [
            "edit throttle",
            "edit accel",
            "edit gear",
            "wake steering",
            "wake all",
        ] {
            assert_eq!(s.parse::<Action>().unwrap().to_string(), s);
        }
        // Alice's device names, as keymaps written for her say them.
        for (old, new) in [
            ("edit gas", "edit throttle"),
            ("wake trans", "wake gear"),
            ("edit steer", "edit steering"),
        ] {
            assert_eq!(old.parse::<Action>().unwrap().to_string(), new);
        }
        let e = "edit obd".parse::<Action>().unwrap_err();
        assert!(e.contains("reset_steering"), "{e}");
        assert!("fly".parse::<Action>().is_err());
    }

    #[test]
    fn the_default_keymap_loads_and_binds_the_papers_keys() {
        let m = Keymap::default_map();
        for (k, a) in [
            ("g", "edit throttle"),
            ("s", "edit steering"),
            ("b", "edit brake"),
            ("c", "edit accel"),
            ("t", "edit gear"),
            ("e", "reset_steering"),
            ("?", "help"),
            ("q", "quit"),
        ] {
            assert_eq!(
                m.lookup(Mode::Main, k.parse().unwrap()),
                Some(a.parse().unwrap()),
                "{k}"
            );
        }
        for mode in Mode::ALL {
            assert!(!m.bindings(mode).is_empty(), "{mode} has no bindings");
        }
    }

    #[test]
    fn errors_name_file_line_and_form() {
        let text = "[main]\nkeymap = [\n  { on = \"g\", run = \"edit throttle\" },\n  { on = \"<Hyper-x>\", run = \"quit\" },\n]\n";
        let e = Keymap::parse(text, "my.toml").unwrap_err();
        assert_eq!((e.path.as_str(), e.line), ("my.toml", 4), "{e}");
        assert!(e.message.contains("expected"), "{e}");

        let text = "[main]\nkeymap = [\n  { on = \"g\", run = \"edit throttle\" },\n\n  { on = \"x\", run = \"launch\" },\n]\n";
        let e = Keymap::parse(text, "my.toml").unwrap_err();
        assert_eq!(e.line, 5, "{e}");
        assert!(e.message.contains("reset_steering"), "{e}");

        let text = "[main]\nkeymap = [\n  { on = \"g\", run = \"edit throttle\" },\n  { on = \"g\", run = \"quit\" },\n]\n";
        let e = Keymap::parse(text, "my.toml").unwrap_err();
        assert_eq!(e.line, 4, "{e}");
        assert!(e.message.contains("twice"), "{e}");

        let text = "[mian]\nkeymap = []\n";
        let e = Keymap::parse(text, "my.toml").unwrap_err();
        assert_eq!(e.line, 1, "{e}");
        assert!(e.message.contains("[main]"), "{e}");

        let text = "[main]\nkeymap = [\n  { on = \"g\", rn = \"quit\" },\n]\n";
        let e = Keymap::parse(text, "my.toml").unwrap_err();
        assert_eq!(e.line, 3, "{e}");

        // A description reaches the terminal: an escape sequence or a newline in it
        // is refused at its record.
        for desc in ["\\u001b[2Jgone", "two\\nlines"] {
            let text = format!(
                "[main]\nkeymap = [\n  {{ on = \"g\", run = \"quit\", desc = \"{desc}\" }},\n]\n"
            );
            let e = Keymap::parse(&text, "my.toml").unwrap_err();
            assert_eq!(e.line, 3, "{e}");
            assert!(
                e.message.contains("desc")
                    && e.message.contains("expected printable text on one line"),
                "{e}"
            );
            assert!(!e.to_string().contains('\x1b'), "{e:?}");
        }
    }

    #[test]
    fn a_user_file_is_merged_over_the_default() {
        let mut m = Keymap::default_map();
        let user = Keymap::parse(
            "[main]\nkeymap = [\n { on = \"g\", run = \"none\" },\n { on = \"<F5>\", run = \"edit throttle\", desc = \"gas\" },\n { on = \"q\", run = \"help\" },\n]\n",
            "user.toml",
        )
        .unwrap();
        m.merge(user);
        assert_eq!(m.lookup(Mode::Main, "g".parse().unwrap()), None);
        assert_eq!(
            m.lookup(Mode::Main, "<F5>".parse().unwrap()),
            Some(Action::EditOf(Target::Device(Role::Throttle)))
        );
        assert_eq!(
            m.lookup(Mode::Main, "q".parse().unwrap()),
            Some(Action::Help)
        );
    }

    /// A keymap once bound `<C-c>`, and the hint bar showed it, although Ctrl-C always
    /// `adrive --keymap nonexist.toml` said `nonexist.toml:0: cannot read: …`: a file
    /// that cannot be read has no line to name.
    #[test]
    fn a_keymap_file_that_cannot_be_read_is_named_without_a_line() {
        let path = Path::new("target/no-such-directory/nonexist.toml");
        let e = Keymap::load(path).unwrap_err();
        let text = e.to_string();
        assert!(
            text.starts_with("target/no-such-directory/nonexist.toml: cannot read: "),
            "{text}"
        );
        assert!(!text.contains(":0:"), "{text}");
    }

    /// stops adrive. Binding or unbinding it is refused at its line.
    #[test]
    fn binding_ctrl_c_is_refused_at_its_line() {
        for run in ["help", "none", "stop"] {
            let text = format!(
                "[teleop]\nkeymap = [\n  {{ on = \"i\", run = \"accel_up\" }},\n  {{ on = \"<C-c>\", run = \"{run}\" }},\n]\n"
            );
            let e = Keymap::parse(&text, "my.toml").unwrap_err();
            assert_eq!((e.path.as_str(), e.line), ("my.toml", 4), "{e}");
            assert!(
                e.message.contains("<C-c>") && e.message.contains("expected another key"),
                "{e}"
            );
        }
    }

    #[test]
    fn every_mode_of_the_default_has_an_emergency_stop_on_space() {
        let m = Keymap::default_map();
        for mode in Mode::ALL {
            assert_eq!(
                m.lookup(mode, Key::plain(KeyCode::Char(' '))),
                Some(Action::Stop),
                "{mode}"
            );
        }
        assert!(m.warnings().is_empty());
    }

    /// The shipped teleop keymap once took `<Space>` (STOP) on the main screen for
    /// teleop, silently. A user file that leaves a mode without a stop key loads, with
    /// a warning at the record that took it.
    #[test]
    fn a_user_keymap_that_takes_stop_away_is_warned_about_at_its_line() {
        let mut m = Keymap::default_map();
        let user = "[main]\nkeymap = [\n  { on = \"<Space>\", run = \"teleop\" },\n]\n\
                    [bench]\nkeymap = [\n  { on = \"<Space>\", run = \"none\" },\n]\n\
                    [help]\nkeymap = [\n  { on = \"<Space>\", run = \"back\" },\n  { on = \"s\", run = \"stop\" },\n]\n";
        m.merge(Keymap::parse(user, "user.toml").unwrap());
        let shown: Vec<String> = m.warnings().iter().map(|w| w.to_string()).collect();
        assert_eq!(shown.len(), 2, "{shown:?}");
        assert!(
            shown[0].starts_with("user.toml:3: [main] has no STOP key"),
            "{shown:?}"
        );
        assert!(shown[0].contains("<Space>"), "{shown:?}");
        assert!(shown[1].starts_with("user.toml:7: [bench]"), "{shown:?}");
        // [help] still has a stop key (s): no warning for it.
        assert_eq!(
            m.key_for(Mode::Help, Action::Stop),
            Some("s".parse().unwrap())
        );
    }

    #[test]
    fn ctrl_c_is_always_an_interrupt_and_editing_takes_characters() {
        let m = Keymap::default_map();
        let ev = KeyEvent::new(KeyCode::Char('c'), KeyModifiers::CONTROL);
        for mode in Mode::ALL {
            assert_eq!(key_to_action(&m, mode, &ev), Some(Action::Interrupt));
        }
        let ev = KeyEvent::new(KeyCode::Char('7'), KeyModifiers::NONE);
        assert_eq!(key_to_action(&m, Mode::Edit, &ev), Some(Action::Input('7')));
        let mut rel = KeyEvent::new(KeyCode::Char('q'), KeyModifiers::NONE);
        rel.kind = KeyEventKind::Release;
        assert_eq!(key_to_action(&m, Mode::Main, &rel), None);
    }

    /// The default keymap's `g gas` is `g throttle` on a vehicle that calls it so, and
    /// absent where nothing is bound.
    #[test]
    fn a_description_names_the_device_bound_to_its_role() {
        use crate::snapshot::Pairs;
        let alice: Pairs<String> = [("throttle", "gas"), ("estop", "estop.estop")]
            .into_iter()
            .map(|(r, d)| (r.to_string(), d.to_string()))
            .collect();
        assert_eq!(describe("{throttle}", &alice).as_deref(), Some("gas"));
        assert_eq!(
            describe("wake {throttle}", &alice).as_deref(),
            Some("wake gas")
        );
        assert_eq!(
            describe("{estop} pause", &alice).as_deref(),
            Some("estop pause")
        );
        assert_eq!(describe("{gear}", &alice), None, "no gear bound");
        assert_eq!(
            describe("a {brace} {", &alice).as_deref(),
            Some("a {brace} {")
        );
    }
}
