//! The console's state (the "model" of the Elm architecture): the mode, the cursor,
//! an edit in progress, a pending question, the name prompt, teleop and bench state,
//! the screen's size and the latest [`Scene`] of the vehicle. Only
//! [`update`](super::update) changes it; the view only reads it.

use super::hold::{Drive, Holds, KeyRepeat};
use super::keymap::{Keymap, Mode};
use super::layout::{self, Devices};
use super::sight::Drawn;
use super::theme::Theme;
use super::trail::Trail;
use crate::config::TeleopConfig;
use crate::controls::Scene;
use crate::snapshot::DeviceView;
use crate::value::DeviceId;
use crossterm::event::{KeyCode, KeyEventKind, KeyModifiers};
use ratatui::layout::Rect;
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// How long `e` waits for the steering drive to acknowledge its home command.
pub(crate) const HOME_WAIT: Duration = Duration::from_secs(3);
/// Teleop steps per key, in step mode.
pub(crate) const STEER_STEP: f64 = 0.05;
pub(crate) const GAS_STEP: f64 = 0.1;
pub(crate) const BRAKE_STEP: f64 = 0.25;

/// A field the cursor can stand on (the Sparrow screen's editable entries).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Field {
    /// The device's command.
    Command(DeviceId),
    /// `st delay`: the status period.
    StDelay(DeviceId),
    /// `cm delay`: the command timeout (resend period).
    CmDelay(DeviceId),
    /// Status thread enabled.
    StatusOn(DeviceId),
    /// Command thread enabled.
    CommandOn(DeviceId),
    /// The vehicle's virtual accel command.
    Accel,
}

impl Field {
    pub fn device(self) -> Option<DeviceId> {
        match self {
            Field::Command(r)
            | Field::StDelay(r)
            | Field::CmDelay(r)
            | Field::StatusOn(r)
            | Field::CommandOn(r) => Some(r),
            Field::Accel => None,
        }
    }

    /// The field in words, `steer cm delay`, with the device's name from `frame`.
    pub fn name(self, frame: &Scene) -> String {
        let n = |id: DeviceId| frame.at(id).map_or("?", |d| d.name.as_str()).to_string();
        match self {
            Field::Command(r) => format!("{} command", n(r)),
            Field::StDelay(r) => format!("{} st delay", n(r)),
            Field::CmDelay(r) => format!("{} cm delay", n(r)),
            Field::StatusOn(r) => format!("{} status thread", n(r)),
            Field::CommandOn(r) => format!("{} command thread", n(r)),
            Field::Accel => "accel".into(),
        }
    }

    /// The fields of one device, in screen order.
    pub fn of(r: DeviceId, d: &DeviceView) -> Vec<Field> {
        if d.is_actuator() {
            vec![
                Field::Command(r),
                Field::StDelay(r),
                Field::CmDelay(r),
                Field::StatusOn(r),
                Field::CommandOn(r),
            ]
        } else {
            vec![Field::StDelay(r), Field::StatusOn(r)]
        }
    }

    fn same_kind(self, role: DeviceId) -> Field {
        match self {
            Field::Command(_) => Field::Command(role),
            Field::StDelay(_) => Field::StDelay(role),
            Field::CmDelay(_) => Field::CmDelay(role),
            Field::StatusOn(_) => Field::StatusOn(role),
            Field::CommandOn(_) => Field::CommandOn(role),
            Field::Accel => Field::Accel,
        }
    }
}

/// A field being edited in place.
#[derive(Clone, Debug, PartialEq)]
pub struct Edit {
    pub field: Field,
    pub buffer: String,
    /// The buffer still holds the prefilled value: the first character replaces it.
    pub fresh: bool,
    /// Why the last commit was refused (shown inline; nothing was changed).
    pub error: Option<String>,
}

/// The name prompt (`/`): the device whose name matches what is typed is under the
/// cursor (on the bench: on the bench) at once.
#[derive(Clone, Debug, PartialEq)]
pub struct Find {
    pub query: String,
    /// Where the cursor was when the prompt opened: cancelling goes back there.
    pub(crate) from_cursor: usize,
    /// The device on the bench when the prompt opened.
    pub(crate) from_bench: DeviceId,
}

/// A question waiting for yes or no.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Question {
    Engage,
    Disengage,
    /// Take command from whoever has it.
    Take,
    /// Switch the interlocks to this.
    Interlocks(bool),
    /// Characterize the device on the bench ([`Model::characterize_ask`] says what it
    /// will do).
    Characterize(DeviceId),
}

impl Question {
    pub fn text(self) -> &'static str {
        match self {
            Question::Engage => "Engage? Commands will move the vehicle.",
            Question::Disengage => "Disengage? Gas 0, brake full, commands refused.",
            Question::Take => "Take command? The source commanding now is refused from then on.",
            Question::Interlocks(true) => "Turn the interlocks ON?",
            Question::Interlocks(false) => {
                "Turn the interlocks OFF? Nothing will stop gas against the brake."
            }
            Question::Characterize(_) => "Characterize the device on the bench?",
        }
    }
}

/// What a characterization from the bench will do, asked before it starts.
#[derive(Clone, Debug, PartialEq)]
pub struct CharacterizeAsk {
    pub device: DeviceId,
    pub name: String,
    pub procedures: Vec<crate::characterize::Procedure>,
    /// Where it will write.
    pub out: std::path::PathBuf,
    /// What proved the vehicle still when it was asked (`stopped, in park, the brake
    /// held`).
    pub proof: String,
}

impl CharacterizeAsk {
    /// The question in words: the device, the procedures, the directory, what it does
    /// to the device and what was checked.
    pub fn text(&self) -> String {
        let procedures: Vec<String> = self
            .procedures
            .iter()
            .map(|p| format!("{p:?}").to_lowercase())
            .collect();
        format!(
            "Characterize {name} ({procedures}) into {out}? It {what}. Checked now: {proof}.",
            name = self.name,
            procedures = procedures.join(", "),
            out = self.out.display(),
            what = crate::characterize::background::what_it_does(&self.name),
            proof = self.proof,
        )
    }
}

/// The outcome line under the screen.
#[derive(Clone, Debug, PartialEq)]
pub struct Message {
    pub text: String,
    pub bad: bool,
    pub at: Instant,
    /// The answer to the operator's own key (not news from elsewhere).
    pub own: bool,
}

/// How long the answer to the operator's own key holds the message line against news
/// from elsewhere (another source refused, the supervisor's outcome): the news came
/// with a frame that may be older than the key, and an answer replaced before it was
/// read is an answer lost. The news waits, then shows; the log pane has it at once.
pub const ANSWER_HOLDS: std::time::Duration = std::time::Duration::from_millis(1500);

/// How long an outcome message stays on the message line.
pub(crate) const MESSAGE_FOR: Duration = Duration::from_secs(8);

/// Teleop: set points driven by keys, with a deadman. `steer` and `accel` are what
/// the intake accepted (the bar shows them). In step mode a key asks for the next step
/// from them; in hold and repeat modes the keys held ([`Holds`]) say what to ask.
#[derive(Clone, Debug, PartialEq)]
pub struct Teleop {
    pub steer: f64,
    /// −1 full brake … 1 full gas.
    pub accel: f64,
    pub deadman: Duration,
    /// The last teleop key; `None` until the first one (the deadman is idle).
    pub(crate) last_key: Option<Instant>,
    pub tripped: bool,
    /// What a held key commands: the vehicle file's `[teleop]`, then the operator's keys.
    pub levels: TeleopConfig,
    /// The operator chose step mode.
    pub forced_step: bool,
    /// The keys held.
    pub holds: Holds,
    /// A pedal key was pressed since teleop began: from then on the pedals follow the
    /// keys held (until then nothing is asked for them).
    pub(crate) pedal_keys: bool,
    /// The accel the holds last had the intake accept.
    pub(crate) asked: Option<f64>,
    /// Until when the engine holds the gas: the lease last granted or renewed.
    pub(crate) lease: Option<Instant>,
    /// Full brake (its key) stands until the next pedal key.
    pub(crate) full_brake: bool,
    /// Where a held steering key moves the steering from, and when it was there.
    pub(crate) steer_from: Option<(f64, Instant)>,
}

/// What the deadman is doing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Deadman {
    /// No teleop key yet.
    Idle,
    /// Keys arriving; trips after `left` without one.
    Armed { left: Duration },
    /// Tripped: gas 0 and brake full were commanded.
    Tripped,
}

impl Teleop {
    pub fn new(deadman: Duration) -> Teleop {
        Teleop {
            steer: 0.0,
            accel: 0.0,
            deadman,
            last_key: None,
            tripped: false,
            levels: TeleopConfig::default(),
            forced_step: false,
            holds: Holds::default(),
            pedal_keys: false,
            asked: None,
            lease: None,
            full_brake: false,
            steer_from: None,
        }
    }

    /// Let every key go and forget what the holds asked: nothing more is commanded
    /// until the next pedal key (a stop, the deadman, leaving teleop).
    pub(crate) fn let_go(&mut self) {
        self.holds.clear();
        self.pedal_keys = false;
        self.asked = None;
        self.lease = None;
        self.full_brake = false;
        self.steer_from = None;
    }

    pub fn state(&self, now: Instant) -> Deadman {
        match self.last_key {
            _ if self.tripped => Deadman::Tripped,
            None => Deadman::Idle,
            Some(t) => Deadman::Armed {
                left: self
                    .deadman
                    .saturating_sub(now.saturating_duration_since(t)),
            },
        }
    }
}

/// A key event as the terminal sent it, for the key-event viewer (help).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SeenKey {
    pub code: KeyCode,
    pub modifiers: KeyModifiers,
    pub kind: KeyEventKind,
    /// When its bytes were read.
    pub at: Instant,
}

/// How many key events the viewer keeps.
pub(crate) const SEEN_KEYS: usize = 12;

/// The whole console state.
pub struct Model {
    pub keymap: Keymap,
    pub theme: Theme,
    pub mode: Mode,
    /// Where `back`/`cancel` returns to from edit, confirm and help.
    pub(crate) back_to: Mode,
    pub snap: Scene,
    /// Index into [`Model::fields`].
    pub cursor: usize,
    pub edit: Option<Edit>,
    pub ask: Option<Question>,
    pub message: Option<Message>,
    /// News from elsewhere waiting for the operator's answer to be read ([`ANSWER_HOLDS`]).
    pub(crate) news: Option<Message>,
    /// A STOP adrive did not confirm (an attached console's adrive silent): when, and
    /// why. It stays on the message line until a frame from adrive shows the vehicle
    /// disengaged or a later STOP is confirmed; a message of its own time fades, this
    /// does not.
    pub(crate) stop_unconfirmed: Option<(Instant, String)>,
    /// The intake's deadman trip the console already knows of: the watchdog stands
    /// tripped until the next engage, and a trip is said once, when it happens.
    pub(crate) deadman_trip_seen: bool,
    pub teleop: Teleop,
    /// The device the bench view shows.
    pub bench: DeviceId,
    /// Its last seconds, for the bench chart (fed by each tick on the bench).
    pub trail: Trail,
    pub(crate) help_scroll: u16,
    /// The accel applied while engaged: the throttle and brake the intake accepted, as
    /// one value (the console's last accepted accel until the next snapshot shows it).
    pub accel: Option<f64>,
    /// The time of the last tick or key (the view's "now").
    pub now: Instant,
    /// `e` sent steering a home command at this time; once the drive acknowledges
    /// it, the console commands it to hold where it stopped.
    pub(crate) steer_reset: Option<Instant>,
    /// The supervisor's last recovery outcome already shown as a message.
    /// The supervisor's outcomes already told (its count of them).
    pub(crate) outcomes_seen: u64,
    /// How many asks of other sources the intake had refused at the last tick (a new
    /// one is shown as a message).
    pub(crate) refused_seen: u64,
    /// The terminal's size at the last draw: what a page of devices is worked out from.
    pub screen: Rect,
    /// The name prompt, while it is open.
    pub find: Option<Find>,
    /// The last name looked for, which the next and previous match keys look for again.
    pub(crate) last_find: Option<String>,
    /// What the last frame showed: what keys may act on ([`check`](super::sight::check)).
    pub drawn: Drawn,
    /// The terminal's key repeat, learnt from what arrives.
    pub repeat: KeyRepeat,
    /// The last key events, oldest first (help's key-event viewer).
    pub keys: VecDeque<SeenKey>,
    /// Help shows the key-event viewer.
    pub(crate) key_viewer: bool,
    /// The console's own terminal: what it reports of the keys, and whether the
    /// liveness check can see the operator's link.
    pub terminal: TerminalView,
    /// The characterization asked about, while the question is open.
    pub characterize_ask: Option<CharacterizeAsk>,
    /// The console's characterization as the engine reported it at the last tick,
    /// shown on the bench while it runs and, once it ended, until the bench is left.
    pub characterizing: Option<crate::controls::Characterizing>,
    /// The bench shows the characterization (started from it, not yet left).
    pub(crate) characterize_shown: bool,
}

/// What the console knows of its own terminal (set by the console's loop).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TerminalView {
    /// What its keys report, once the probe ended (`None` before).
    pub keyboard: Option<super::input::Keyboard>,
    /// A terminal multiplexer on this machine answers for the operator's terminal
    /// (`tmux`, `screen`): the round trip reaches it, not the operator — the header
    /// says "link unchecked".
    pub multiplexer: Option<&'static str>,
}

impl Model {
    pub fn new(keymap: Keymap, theme: Theme, snap: Scene, deadman: Duration) -> Model {
        let bench = DeviceId(0);
        Model {
            keymap,
            theme,
            mode: Mode::Main,
            back_to: Mode::Main,
            cursor: 0,
            edit: None,
            ask: None,
            message: None,
            news: None,
            stop_unconfirmed: None,
            deadman_trip_seen: snap.gate.deadman_tripped(),
            teleop: Teleop {
                levels: snap.teleop,
                ..Teleop::new(deadman)
            },
            bench,
            trail: Trail::default(),
            help_scroll: 0,
            accel: None,
            now: Instant::now(),
            outcomes_seen: snap.supervisor.outcomes,
            refused_seen: snap.gate.refused,
            steer_reset: None,
            screen: Rect::new(0, 0, layout::MIN_WIDTH, 24),
            find: None,
            last_find: None,
            drawn: Drawn::default(),
            repeat: KeyRepeat::default(),
            keys: VecDeque::with_capacity(SEEN_KEYS),
            key_viewer: false,
            terminal: TerminalView::default(),
            characterize_ask: None,
            characterizing: None,
            characterize_shown: false,
            snap,
        }
    }

    /// The terminal reports key releases (the kitty keyboard protocol): teleop holds
    /// while a key is pressed. Else (presses only, or not known yet) holds follow the
    /// key repeat.
    pub fn releases(&self) -> bool {
        self.terminal.keyboard == Some(super::input::Keyboard::Releases)
    }

    /// How teleop reads its keys: step when the operator chose it, hold where the
    /// terminal reports releases, else repeat.
    pub fn drive(&self) -> Drive {
        match (self.teleop.forced_step, self.releases()) {
            (true, _) => Drive::Step,
            (false, true) => Drive::Hold,
            (false, false) => Drive::Repeat,
        }
    }

    /// Every field in cursor order: each device's, then accel.
    pub fn fields(&self) -> Vec<Field> {
        let mut f: Vec<Field> = self
            .snap
            .devices
            .iter()
            .enumerate()
            .flat_map(|(i, d)| Field::of(DeviceId(i as u16), d))
            .collect();
        if self.snap.gate.accel {
            f.push(Field::Accel);
        }
        f
    }

    pub fn field(&self) -> Field {
        let f = self.fields();
        f.get(self.cursor.min(f.len().saturating_sub(1)))
            .copied()
            .unwrap_or(Field::Accel)
    }

    pub(crate) fn select(&mut self, field: Field) -> bool {
        match self.fields().iter().position(|f| *f == field) {
            Some(i) => {
                self.cursor = i;
                true
            }
            None => false,
        }
    }

    /// The index of the device under the cursor; the last device's while the cursor
    /// is on something else (accel).
    pub fn cursor_device(&self) -> usize {
        self.field()
            .device()
            .map_or(self.snap.devices.len().saturating_sub(1), DeviceId::index)
    }

    /// The device the name prompt and the match keys move: the bench's on the bench,
    /// else the one under the cursor.
    pub(crate) fn found_device(&self) -> usize {
        if self.in_bench() {
            self.bench.index()
        } else {
            self.cursor_device()
        }
    }

    /// How the main screen lays the devices out in `body`.
    pub(crate) fn layout_in(&self, body: Rect) -> Devices {
        layout::devices(
            self.snap.devices.len(),
            body,
            self.snap.strip_len(),
            self.cursor_device(),
        )
    }

    /// How the main screen lays the devices out on the screen drawn last.
    pub fn layout(&self) -> Devices {
        self.layout_in(layout::split(self.screen)[1])
    }

    /// How many devices a page holds: the full panels on screen at once (every
    /// device while each has its own panel).
    pub fn page(&self) -> usize {
        match self.layout() {
            Devices::Panels { .. } => self.snap.devices.len(),
            Devices::Many(l) => l.per_page,
        }
    }

    /// Put the cursor on device `id`'s first field (its command, a sensor's
    /// `st delay`).
    pub(crate) fn select_device(&mut self, id: DeviceId) -> bool {
        match self.snap.at(id).map(|d| Field::of(id, d)[0]) {
            Some(f) => self.select(f),
            None => false,
        }
    }

    /// Move the cursor to the neighbouring device (`step` ±1), same kind of field.
    pub(crate) fn move_device(&mut self, step: isize) {
        let here = self.field();
        let mut stops: Vec<Option<DeviceId>> = (0..self.snap.devices.len())
            .map(|i| Some(DeviceId(i as u16)))
            .collect();
        if self.snap.gate.accel {
            stops.push(None);
        }
        let i = stops.iter().position(|r| *r == here.device()).unwrap_or(0) as isize;
        let j = (i + step).clamp(0, stops.len() as isize - 1) as usize;
        let target = match stops[j] {
            None => Field::Accel,
            Some(r) => {
                let d = self.snap.at(r).expect("listed");
                let want = here.same_kind(r);
                let of = Field::of(r, d);
                if of.contains(&want) {
                    want
                } else {
                    of[0]
                }
            }
        };
        self.select(target);
    }

    /// The answer to the operator's own key, on the message line at once.
    pub fn say(&mut self, text: impl Into<String>, bad: bool) {
        self.message = Some(Message {
            text: text.into(),
            bad,
            at: self.now,
            own: true,
        });
    }

    /// News from elsewhere (another source refused, the supervisor's outcome): on the
    /// message line at once, unless the operator's own answer is still fresh there —
    /// then after it ([`ANSWER_HOLDS`]; the newest news wins).
    pub fn tell(&mut self, text: impl Into<String>, bad: bool) {
        self.news = Some(Message {
            text: text.into(),
            bad,
            at: self.now,
            own: false,
        });
        self.show_news();
    }

    /// What the message line shows now, and whether it is bad news: the last message for
    /// [`MESSAGE_FOR`]; a STOP not confirmed for as long as it is not, beneath only the
    /// operator's own answers since.
    pub(crate) fn message_line(&self) -> Option<(std::borrow::Cow<'_, str>, bool)> {
        let fresh = self
            .message
            .as_ref()
            .filter(|x| self.now.saturating_duration_since(x.at) < MESSAGE_FOR);
        match (&self.stop_unconfirmed, fresh) {
            (Some((at, _)), Some(x)) if x.own && x.at > *at => {
                Some((x.text.as_str().into(), x.bad))
            }
            (Some((at, why)), _) => {
                let ago = self.now.saturating_duration_since(*at).as_secs();
                Some((
                    format!("STOP NOT CONFIRMED ({ago} s ago): {why}").into(),
                    true,
                ))
            }
            (None, Some(x)) => Some((x.text.as_str().into(), x.bad)),
            (None, None) => None,
        }
    }

    /// The news waiting, once the operator's answer has held the line long enough.
    pub(crate) fn show_news(&mut self) {
        let holds = self
            .message
            .as_ref()
            .is_some_and(|m| m.own && self.now.saturating_duration_since(m.at) < ANSWER_HOLDS);
        if !holds {
            if let Some(mut news) = self.news.take() {
                news.at = self.now;
                self.message = Some(news);
            }
        }
    }

    /// The device the bench shows, if it is in the vehicle.
    pub(crate) fn bench_device(&self) -> Option<&DeviceView> {
        self.snap.at(self.bench)
    }

    /// Whether the bench view is on screen (possibly under a dialog).
    pub(crate) fn in_bench(&self) -> bool {
        self.mode == Mode::Bench
            || (matches!(
                self.mode,
                Mode::Edit | Mode::Help | Mode::Confirm | Mode::Find
            ) && self.back_to == Mode::Bench)
    }

    /// The question's words: a characterization's from what it will do.
    pub fn question_text(&self, q: Question) -> String {
        match (q, &self.characterize_ask) {
            (Question::Characterize(id), Some(a)) if a.device == id => a.text(),
            _ => q.text().to_string(),
        }
    }

    /// The characterization the bench shows, if any: the bench device's, from the
    /// bench.
    pub(crate) fn bench_run(&self) -> Option<&crate::controls::Characterizing> {
        self.characterizing
            .as_ref()
            .filter(|c| self.characterize_shown && c.device == self.bench)
    }

    /// A characterization is under way.
    pub(crate) fn characterize_running(&self) -> bool {
        self.characterizing.as_ref().is_some_and(|c| c.running())
    }

    /// Whether the teleop view is on screen (possibly under a dialog).
    pub(crate) fn in_teleop(&self) -> bool {
        self.mode == Mode::Teleop
            || (matches!(self.mode, Mode::Help | Mode::Confirm) && self.back_to == Mode::Teleop)
    }
}
