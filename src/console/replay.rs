//! `adrive replay FILE`: the console plays a recording. The [`Player`] holds the
//! recorded snapshots, warnings and raw traffic and a clock (pause, step, seek,
//! speed); [`Replay`] is a read-only [`Controls`] that hands the console the
//! [`Scene`] of the moment played, so every panel is drawn by the same code as live —
//! faults red, recovery steps, log lines. Only the keys that look around reach the
//! console's update; nothing can be sent. With `--broadcast`, each snapshot played
//! is also sent as the state broadcast was, so other tools can be tested against a
//! past drive.

use super::input::Input;
use super::keymap::{Action, Keymap, Mode};
use super::model::Model;
use super::theme::Theme;
use super::update::{self, Flow};
use crate::controls::{Controls, Scene, Tune};
use crate::exit::Exit;
use crate::logging::ring::LogLine;
use crate::net::BROADCAST_MAX;
use crate::port::trace::{Dir, TraceEntry, CAPACITY};
use crate::record::message::{LogMsg, RawMsg};
use crate::record::read::Recording;
use crate::safety::{Ask, Done, Refused};
use crate::value::{Command, DeviceId};
use crossbeam_channel::{select, Receiver};
use crossterm::event::{KeyCode, KeyEvent, KeyEventKind, KeyModifiers};
use ratatui::buffer::Buffer;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Paragraph, Widget};
use std::collections::HashMap;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant, UNIX_EPOCH};

/// Speeds the player steps through with `-` and `+`.
pub(crate) const SPEEDS: [f64; 9] = [0.125, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0];
/// `[` and `]` seek this far; `{` and `}` a minute.
pub(crate) const SEEK: Duration = Duration::from_secs(10);
/// Log lines the replayed log pane holds, as the live one does.
const LOG_KEEP: usize = crate::logging::ring::KEEP;

/// A recording loaded for playing, and where the play is.
pub struct Player {
    /// The file's name, for the header.
    pub name: String,
    /// Snapshots as recorded (JSON), with their times (wall-clock ns).
    frames: Vec<(u64, Vec<u8>)>,
    /// Warnings and errors, as the live log pane keeps them.
    logs: Vec<(u64, LogLine)>,
    /// Raw traffic by device name.
    raw: HashMap<String, Vec<(u64, Dir, Vec<u8>)>>,
    pos: usize,
    playing: bool,
    speed: usize,
    /// While playing: the play's time at this instant.
    anchor: (Instant, u64),
    /// Why the recording ends early (cut off), for the header.
    pub cut: Option<String>,
}

impl Player {
    /// Load what replaying needs from `rec`; a recording without snapshots cannot be
    /// replayed.
    pub fn load(rec: &Recording) -> Result<Player, String> {
        let mut frames = Vec::new();
        let mut logs = Vec::new();
        let mut raw: HashMap<String, Vec<(u64, Dir, Vec<u8>)>> = HashMap::new();
        let mut start = None;
        let why = rec.for_each(|m| {
            let t0 = *start.get_or_insert(m.log_time);
            match m.topic {
                "/snapshot" => frames.push((m.log_time, m.data.to_vec())),
                "/log" => {
                    if let Ok(l) = serde_json::from_slice::<LogMsg>(m.data) {
                        let level = match l.level {
                            3 => tracing::Level::WARN,
                            4 | 5 => tracing::Level::ERROR,
                            _ => return,
                        };
                        let line = LogLine {
                            secs: m.log_time.saturating_sub(t0) as f64 / 1e9,
                            level,
                            text: l.message,
                        };
                        logs.push((m.log_time, line));
                    }
                }
                t if t.ends_with("/raw") => {
                    if let Ok(r) = serde_json::from_slice::<RawMsg>(m.data) {
                        let dev = t.trim_start_matches('/').trim_end_matches("/raw");
                        let dir = if r.dir == "out" { Dir::Out } else { Dir::In };
                        raw.entry(dev.to_string())
                            .or_default()
                            .push((m.log_time, dir, r.bytes()));
                    }
                }
                _ => {}
            }
        });
        if frames.is_empty() {
            return Err(format!(
                "{}: no snapshots to replay (channel /snapshot)",
                rec.path.display()
            ));
        }
        frames.sort_by_key(|(t, _)| *t);
        Ok(Player {
            name: rec.path.file_name().map_or_else(
                || rec.path.display().to_string(),
                |n| n.to_string_lossy().to_string(),
            ),
            frames,
            logs,
            raw,
            pos: 0,
            playing: true,
            speed: 3,
            anchor: (Instant::now(), 0),
            cut: rec.cut.clone().or(why),
        }
        .anchored(Instant::now()))
    }

    fn anchored(mut self, now: Instant) -> Player {
        self.anchor = (now, self.time());
        self
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    pub fn pos(&self) -> usize {
        self.pos
    }

    pub(crate) fn is_playing(&self) -> bool {
        self.playing
    }

    pub fn speed(&self) -> f64 {
        SPEEDS[self.speed]
    }

    /// The time of the snapshot shown (wall-clock ns).
    pub fn time(&self) -> u64 {
        self.frames[self.pos].0
    }

    fn start(&self) -> u64 {
        self.frames[0].0
    }

    fn end(&self) -> u64 {
        self.frames[self.frames.len() - 1].0
    }

    /// Seconds from the first snapshot to the one shown, and to the last.
    pub fn seconds(&self) -> (f64, f64) {
        let s = |t: u64| t.saturating_sub(self.start()) as f64 / 1e9;
        (s(self.time()), s(self.end()))
    }

    /// The snapshot shown, as recorded.
    pub fn json(&self) -> &[u8] {
        &self.frames[self.pos].1
    }

    /// Move the play on to `now`; returns the snapshots passed (to broadcast), the
    /// one now shown last. At the end the play pauses.
    pub(crate) fn advance(&mut self, now: Instant) -> std::ops::Range<usize> {
        if !self.playing {
            return self.pos..self.pos;
        }
        let (at, t) = self.anchor;
        let played = now.saturating_duration_since(at).as_secs_f64() * self.speed();
        let target = t + (played * 1e9) as u64;
        let from = self.pos;
        while self.pos + 1 < self.frames.len() && self.frames[self.pos + 1].0 <= target {
            self.pos += 1;
        }
        if self.pos + 1 == self.frames.len() {
            self.playing = false;
        }
        from + 1..self.pos + 1
    }

    /// Pause, or play on from here (from the start when at the end).
    pub(crate) fn toggle(&mut self, now: Instant) {
        if !self.playing && self.pos + 1 == self.frames.len() {
            self.pos = 0;
        }
        self.playing = !self.playing;
        self.anchor = (now, self.time());
    }

    /// One snapshot on (or back, `n` < 0), paused.
    pub fn step(&mut self, n: isize, now: Instant) {
        self.playing = false;
        self.pos = (self.pos as isize + n).clamp(0, self.frames.len() as isize - 1) as usize;
        self.anchor = (now, self.time());
    }

    /// Go `by` seconds on (or back): to the last snapshot at or before that time.
    pub(crate) fn seek(&mut self, by: f64, now: Instant) {
        let target = (self.time() as f64 + by * 1e9).max(0.0) as u64;
        self.pos = match self.frames.partition_point(|(t, _)| *t <= target) {
            0 => 0,
            n => n - 1,
        };
        self.anchor = (now, self.time());
    }

    /// To the first (`false`) or the last snapshot.
    pub fn jump(&mut self, to_end: bool, now: Instant) {
        self.pos = if to_end { self.frames.len() - 1 } else { 0 };
        self.anchor = (now, self.time());
    }

    /// Faster (`up`) or slower, within [`SPEEDS`].
    pub fn faster(&mut self, up: bool, now: Instant) {
        self.anchor = (now, self.time_now(now));
        self.speed = if up {
            (self.speed + 1).min(SPEEDS.len() - 1)
        } else {
            self.speed.saturating_sub(1)
        };
    }

    /// Play at this speed (the nearest of [`SPEEDS`]).
    pub fn set_speed(&mut self, speed: f64, now: Instant) {
        self.anchor = (now, self.time_now(now));
        self.speed = (0..SPEEDS.len())
            .min_by(|&a, &b| {
                (SPEEDS[a] - speed)
                    .abs()
                    .total_cmp(&(SPEEDS[b] - speed).abs())
            })
            .unwrap_or(3);
    }

    fn time_now(&self, now: Instant) -> u64 {
        if !self.playing {
            return self.time();
        }
        let (at, t) = self.anchor;
        t + (now.saturating_duration_since(at).as_secs_f64() * self.speed() * 1e9) as u64
    }

    /// The frame the console draws: the snapshot shown, the warnings and errors up to
    /// it, and the bench device's raw traffic up to it (ages as of `now`).
    pub fn scene(&self, now: Instant, bench: Option<DeviceId>) -> Scene {
        let t = self.time();
        let snap = crate::record::message::recorded_snapshot(self.json()).unwrap_or_default();
        let upto = self.logs.partition_point(|(at, _)| *at <= t);
        let logs = self.logs[upto.saturating_sub(LOG_KEEP)..upto]
            .iter()
            .map(|(_, l)| l.clone())
            .collect();
        let trace = bench
            .and_then(|id| snap.devices.get(id.index()))
            .and_then(|d| self.raw.get(&d.name))
            .map(|entries| {
                let upto = entries.partition_point(|(at, _, _)| *at <= t);
                entries[upto.saturating_sub(CAPACITY)..upto]
                    .iter()
                    .map(|(at, dir, bytes)| {
                        let ago = Duration::from_nanos(t.saturating_sub(*at));
                        TraceEntry::new(now.checked_sub(ago).unwrap_or(now), *dir, bytes)
                    })
                    .collect()
            })
            .unwrap_or_default();
        let n = snap.devices.len();
        Scene {
            snap,
            logs,
            trace,
            buckets: Vec::new(),
            can_inject: false,
            read_only: true,
            sim_vehicle: None,
            sim_faults: vec![None; n],
            sim_names: None,
            you: None,
            teleop: crate::config::TeleopConfig::default(),
            quiet: None,
        }
    }

    /// The replay's top line: file, play or pause, speed, where, when.
    pub fn bar(&self) -> String {
        let (at, total) = self.seconds();
        let state = if self.playing { "▶" } else { "❚❚" };
        let wall =
            humantime::format_rfc3339_seconds(UNIX_EPOCH + Duration::from_nanos(self.time()));
        let cut = if self.cut.is_some() { " CUT OFF" } else { "" };
        format!(
            " REPLAY {} {state} ×{} {at:.1}/{total:.1} s {}/{} {wall}{cut} │ space pause , . step [ ] ±10s - + speed q quit",
            self.name,
            self.speed(),
            self.pos + 1,
            self.frames.len(),
        )
    }
}

/// The console's [`Controls`] over a recording: frames from the [`Player`], every
/// change refused.
pub(crate) struct Replay<'a> {
    pub player: &'a Player,
}

const READ_ONLY: &str = "replay: read-only, nothing can be sent";

impl Controls for Replay<'_> {
    fn scene(&self, now: Instant, bench: Option<DeviceId>) -> Scene {
        self.player.scene(now, bench)
    }
    fn parse(&self, _: DeviceId, _: &str) -> Result<Command, String> {
        Err(READ_ONLY.into())
    }
    fn ask(&self, _: Ask) -> Result<Done, Refused> {
        Err(read_only())
    }
    fn tune(&self, _: Tune) -> Result<(), String> {
        Err(READ_ONLY.into())
    }
    fn set_interlocks(&self, _: bool) -> Result<(), Refused> {
        Err(read_only())
    }
    fn deadman(&self, _: Option<Duration>) {}
    fn sim(&self, _: &str) -> Option<Result<String, String>> {
        Some(Err(READ_ONLY.into()))
    }
    /// A recording commands nothing: no link to prove.
    fn answered(&self, _at: Instant) {}
    fn characterize_check(&self, _: DeviceId) -> Result<String, String> {
        Err(READ_ONLY.into())
    }
    fn characterize(
        &self,
        _: DeviceId,
        _: &[crate::characterize::Procedure],
        _: &std::path::Path,
    ) -> Result<(), String> {
        Err(READ_ONLY.into())
    }
    fn characterizing(&self) -> Option<crate::controls::Characterizing> {
        None
    }
    fn characterize_end(&self, _: &str) {}
}

/// Every change is refused in a replay: nothing is sent.
fn read_only() -> Refused {
    Refused::Unanswered(READ_ONLY.into())
}

/// The replay's own keys, before the keymap sees them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Key {
    Toggle,
    Step(isize),
    Seek(f64),
    Jump(bool),
    Faster(bool),
}

/// The replay key `k` is, if any.
pub(crate) fn replay_key(k: &KeyEvent) -> Option<Key> {
    if k.kind == KeyEventKind::Release || k.modifiers.contains(KeyModifiers::CONTROL) {
        return None;
    }
    Some(match k.code {
        KeyCode::Char(' ') | KeyCode::Char('p') => Key::Toggle,
        KeyCode::Char('.') => Key::Step(1),
        KeyCode::Char(',') => Key::Step(-1),
        KeyCode::Char(']') => Key::Seek(SEEK.as_secs_f64()),
        KeyCode::Char('[') => Key::Seek(-SEEK.as_secs_f64()),
        KeyCode::Char('}') => Key::Seek(60.0),
        KeyCode::Char('{') => Key::Seek(-60.0),
        KeyCode::Home => Key::Jump(false),
        KeyCode::End => Key::Jump(true),
        KeyCode::Char('+') | KeyCode::Char('=') => Key::Faster(true),
        KeyCode::Char('-') => Key::Faster(false),
        _ => return None,
    })
}

/// Apply a replay key.
pub fn apply(p: &mut Player, key: Key, now: Instant) {
    match key {
        Key::Toggle => p.toggle(now),
        Key::Step(n) => p.step(n, now),
        Key::Seek(s) => p.seek(s, now),
        Key::Jump(end) => p.jump(end, now),
        Key::Faster(up) => p.faster(up, now),
    }
}

/// The keymap's actions a replay lets through: looking around, help, leaving.
fn looks(a: Action, mode: Mode) -> bool {
    matches!(
        a,
        Action::Quit
            | Action::Interrupt
            | Action::Help
            | Action::Back
            | Action::Cancel
            | Action::Up
            | Action::Down
            | Action::Left
            | Action::Right
            | Action::Bench
            | Action::NextDevice
            | Action::PrevDevice
    ) && mode != Mode::Edit
}

/// Sends each snapshot played as the state broadcast was.
pub struct Broadcast {
    socket: UdpSocket,
    to: Vec<SocketAddr>,
}

impl Broadcast {
    pub fn new(to: Vec<SocketAddr>) -> std::io::Result<Broadcast> {
        let config = crate::net::NetworkConfig {
            broadcast_to: to.clone(),
            ..Default::default()
        };
        Ok(Broadcast {
            socket: crate::net::broadcast_socket(&config)?,
            to,
        })
    }

    /// Send one recorded snapshot, in parts when it does not fit one datagram, as the
    /// live broadcast does.
    pub fn send(&self, json: &[u8]) {
        let parts = crate::record::message::recorded_snapshot(json)
            .and_then(|s| s.datagrams(BROADCAST_MAX));
        let parts = match parts {
            Ok(p) => p,
            Err(e) => return tracing::warn!("replay broadcast: a recorded snapshot: {e}"),
        };
        for to in &self.to {
            for part in &parts {
                if let Err(e) = self.socket.send_to(part, to) {
                    tracing::warn!(%to, "replay broadcast: {e}");
                }
            }
        }
    }
}

/// The screen: the replay's line on top, the console under it.
struct Screen<'a> {
    model: &'a Model,
    bar: String,
}

impl Screen<'_> {
    /// Draw the replay's line and the console under it; what the console showed.
    fn draw(&self, area: Rect, buf: &mut Buffer) -> super::sight::Drawn {
        let [top, rest] = Layout::vertical([Constraint::Length(1), Constraint::Min(0)]).areas(area);
        let style = self.model.theme.bar().patch(self.model.theme.warn());
        let bar = super::panels::fit::shorten(&self.bar, usize::from(top.width));
        Paragraph::new(Line::from(Span::styled(
            format!("{bar:<width$}", width = top.width as usize),
            style,
        )))
        .render(top, buf);
        super::view::draw(self.model, rest, buf)
    }
}

/// Play `player` in the console until the operator quits or an exit arrives; each
/// snapshot played also goes to `broadcast`. The terminal is restored before this
/// returns.
pub fn run(
    mut player: Player,
    keymap: Keymap,
    exits: &Receiver<Exit>,
    broadcast: Option<Broadcast>,
) -> std::io::Result<Exit> {
    let now = Instant::now();
    let first = player.scene(now, None);
    let mut model = Model::new(
        keymap,
        Theme::from_env(),
        first,
        crate::config::limits::DEADMAN_DEFAULT,
    );
    if let Some(b) = &broadcast {
        b.send(player.json());
    }
    let mut screen = super::terminal::enter()?;
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let (events, reader) = super::start_input(&mut screen, &mut model, stop.clone())?;
    let ticker = crossbeam_channel::tick(crate::controls::TICK);
    let why = loop {
        // Draw only once the terminal took the last frame (console/terminal.rs).
        match screen.ready() {
            Err(e) => break Exit::HangUp(format!("cannot draw: {e}")),
            Ok(false) => {}
            Ok(true) => {
                let view = Screen {
                    model: &model,
                    bar: player.bar(),
                };
                let mut drawn = None;
                if let Err(e) = screen
                    .terminal
                    .draw(|f| drawn = Some(view.draw(f.area(), f.buffer_mut())))
                {
                    break Exit::HangUp(format!("cannot draw: {e}"));
                }
                model.drawn = drawn.unwrap_or_default();
            }
        }
        let msg = select! {
            recv(exits) -> why => break why.unwrap_or(Exit::Quit),
            recv(ticker) -> _ => None,
            recv(events) -> input => match input {
                Ok(Input::Key(k, _)) => Some(k),
                // Nothing to push: a replay has no teleop (releases are ignored).
                Ok(Input::Keyboard(k)) => {
                    model.terminal.keyboard = Some(k);
                    None
                }
                Ok(Input::Resize(..) | Input::Answer(_)) => None,
                Ok(Input::Closed(why)) => break Exit::HangUp(format!("input: {why}")),
                Err(_) => break Exit::HangUp("input thread ended".into()),
            },
        };
        let now = Instant::now();
        if let Some(k) = msg {
            if let Some(key) = replay_key(&k).filter(|_| model.mode != Mode::Help) {
                apply(&mut player, key, now);
                if let Some(b) = &broadcast {
                    b.send(player.json());
                }
            } else if let Some(a) = super::sight::key(&model, &k) {
                if looks(a, model.mode) {
                    let replay = Replay { player: &player };
                    if let Flow::Exit(why) = update::update(&mut model, a, &replay, now) {
                        break why;
                    }
                } else {
                    model.now = now;
                    model.say(READ_ONLY, true);
                }
            }
        }
        let passed = player.advance(now);
        if let Some(b) = &broadcast {
            for i in passed {
                b.send(&player.frames[i].1);
            }
        }
        update::tick(&mut model, &Replay { player: &player }, now);
    };
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    drop(screen);
    let deadline = Instant::now() + 2 * crate::controls::TICK;
    while !reader.is_finished() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    Ok(why)
}

/// Play `player` without a console, broadcasting each snapshot at its recorded pace
/// (times `speed`), until the end or an exit: why it ended, and how many snapshots it
/// sent.
pub fn headless(
    mut player: Player,
    exits: &Receiver<Exit>,
    broadcast: &Broadcast,
) -> (Exit, usize) {
    broadcast.send(player.json());
    let mut sent = 1;
    let tick = crossbeam_channel::tick(Duration::from_millis(5));
    loop {
        select! {
            recv(exits) -> why => return (why.unwrap_or(Exit::Quit), sent),
            recv(tick) -> _ => {
                for i in player.advance(Instant::now()) {
                    broadcast.send(&player.frames[i].1);
                    sent += 1;
                }
                if !player.is_playing() {
                    return (Exit::Quit, sent);
                }
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::snapshot::Snapshot;

    fn player(times_ms: &[u64]) -> Player {
        let frames = times_ms
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let s = Snapshot {
                    seq: i as u64,
                    ..Default::default()
                };
                (t * 1_000_000, serde_json::to_vec(&s).unwrap())
            })
            .collect();
        Player {
            name: "t.mcap".into(),
            frames,
            logs: Vec::new(),
            raw: HashMap::new(),
            pos: 0,
            playing: false,
            speed: 3,
            anchor: (Instant::now(), 0),
            cut: None,
        }
    }

    #[test]
    fn playing_follows_the_recorded_pace_and_the_speed() {
        let mut p = player(&[0, 100, 200, 300, 400]);
        let t0 = Instant::now();
        p.toggle(t0);
        assert_eq!(p.advance(t0 + Duration::from_millis(150)), 1..2);
        p.faster(true, t0 + Duration::from_millis(150));
        assert_eq!(p.speed(), 2.0);
        // 100 ms more at ×2 is 200 ms of recording: 350 ms.
        assert_eq!(p.advance(t0 + Duration::from_millis(250)), 2..4);
        assert!(p.is_playing());
        p.advance(t0 + Duration::from_millis(400));
        assert_eq!(p.pos(), 4);
        assert!(!p.is_playing(), "pauses at the end");
    }

    #[test]
    fn step_seek_and_jump_stay_inside_the_recording() {
        let mut p = player(&[0, 100, 200, 300, 20_000]);
        let now = Instant::now();
        p.step(-1, now);
        assert_eq!(p.pos(), 0);
        p.step(2, now);
        assert_eq!(p.pos(), 2);
        p.seek(10.0, now);
        assert_eq!(p.pos(), 3, "the last snapshot at or before 10.2 s");
        p.seek(60.0, now);
        assert_eq!(p.pos(), 4);
        p.seek(-60.0, now);
        assert_eq!(p.pos(), 0);
        p.jump(true, now);
        assert_eq!(p.pos(), 4);
        assert_eq!(p.scene(now, None).seq, 4);
    }

    /// A simulator key on the bench of a replay said "fault injection needs --sim",
    /// as if `--sim` would help; a replay is read-only, and its bench says so.
    #[test]
    fn the_simulator_keys_of_a_replay_say_it_is_read_only() {
        let p = player(&[0, 100]);
        let r = Replay { player: &p };
        assert_eq!(r.sim("silent steer on"), Some(Err(READ_ONLY.to_string())));
        assert!(p.scene(Instant::now(), None).read_only);
    }

    #[test]
    fn only_looking_around_reaches_the_console() {
        assert!(looks(Action::Bench, Mode::Main));
        assert!(looks(Action::Quit, Mode::Main));
        assert!(!looks(Action::Engage, Mode::Main));
        assert!(!looks(Action::Stop, Mode::Main));
        assert!(!looks(Action::Edit, Mode::Main));
        let space = KeyEvent::new(KeyCode::Char(' '), KeyModifiers::NONE);
        assert_eq!(replay_key(&space), Some(Key::Toggle));
    }

    /// The replay's line at 80 columns ran off the screen mid-word: it is cut at a
    /// word with `…`, and the console under it is drawn (its keys act on it).
    #[test]
    fn the_replay_line_is_cut_with_a_mark_and_the_console_drawn_under_it() {
        let p = player(&[0, 100]);
        let model = Model::new(
            Keymap::default_map(),
            Theme::default(),
            p.scene(Instant::now(), None),
            crate::config::limits::DEADMAN_DEFAULT,
        );
        let view = Screen {
            model: &model,
            bar: p.bar(),
        };
        let mut buf = Buffer::empty(Rect::new(0, 0, 80, 24));
        let drawn = view.draw(buf.area, &mut buf);
        let top: String = (0..80).map(|x| buf[(x, 0)].symbol()).collect();
        assert!(
            top.starts_with(" REPLAY t.mcap ❚❚ ×1 0.0/0.1 s 1/2 "),
            "{top}"
        );
        assert!(top.trim_end().ends_with('…'), "{top}");
        assert!(drawn.console, "80×23 under the replay's line");
    }
}
