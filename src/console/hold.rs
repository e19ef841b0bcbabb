//! Hold-to-drive: which teleop keys are held and until when, and the terminal's key
//! repeat learned from what arrives. Pure: key events with the instant their bytes were
//! read in, holds and figures out; [`update`](super::update) turns them into commands.
//!
//! A held key is held only while the terminal keeps saying so. How it says so is the
//! [`Drive`] mode:
//! - **hold**: the terminal reports releases (the kitty keyboard protocol). A press
//!   holds, a release lets go at once. A release can be lost with the link (a stalled
//!   SSH session, a lid closed), so a hold also lasts only while key events keep
//!   arriving: after a press, the learned delay before the first repeat and one
//!   interval more; after a repeat, two intervals. Any key's press or repeat keeps every
//!   hold whose release has not come (the terminal repeats only the last key pressed:
//!   `↑` held under `←` held is still held), so the stream's liveness is what bounds them.
//! - **repeat**: the terminal reports presses only (tmux, Terminal.app, the Linux
//!   console, mosh): a held key shows as its key repeat, learned here — the delay
//!   before the first repeat and the interval — and a hold ends when its own repeats
//!   stop: the delay and one interval after the press (a single tap holds that long),
//!   two intervals after a repeat. A press of another key never keeps it.
//! - **step**: neither, or the operator's choice: every key a step, as before holds
//!   existed, with the deadman.
//!
//! A hold that ended — let go, or its repeats stopped — is never taken up again by a
//! repeat, nor by a press that arrives packed behind another of the same key (faster
//! than any key repeat: bytes that waited in a stalled link): only a fresh press holds
//! again. Packed events that keep a hold keep it only as long as a repeat does. Nothing learnt yet, [`DEFAULT_DELAY`] and [`DEFAULT_INTERVAL`] apply: shorter
//! than most terminals' delay, so a first hold may pause once before its repeats
//! start, never run on.

use crossterm::event::{KeyCode, KeyEventKind};
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// The key-repeat delay assumed before one is learnt.
pub(crate) const DEFAULT_DELAY: Duration = Duration::from_millis(500);
/// The key-repeat interval assumed before one is learnt (20 Hz; terminals repeat at
/// 25–33 Hz by default).
pub(crate) const DEFAULT_INTERVAL: Duration = Duration::from_millis(50);
/// The longest delay before a first repeat taken as one.
const MAX_DELAY: Duration = Duration::from_millis(1000);
/// The slowest and fastest intervals taken as a key repeat (10 … 200 Hz): slower is a
/// person tapping.
const MAX_INTERVAL: Duration = Duration::from_millis(100);
const MIN_INTERVAL: Duration = Duration::from_millis(5);
/// How many in-run intervals and first delays the figures are taken from.
const KEEP_GAPS: usize = 32;
const KEEP_FIRSTS: usize = 4;

/// How teleop reads its keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Drive {
    /// Releases reported: held while pressed (and its key events keep coming).
    Hold,
    /// Presses only: held while its learned key repeat keeps coming.
    Repeat,
    /// Every key a step, with the deadman.
    Step,
}

impl Drive {
    pub fn as_str(self) -> &'static str {
        match self {
            Drive::Hold => "hold",
            Drive::Repeat => "repeat",
            Drive::Step => "step",
        }
    }
}

/// The key repeat's figures: learnt, or the defaults.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Figures {
    /// Before the first repeat.
    pub delay: Duration,
    /// Between repeats.
    pub interval: Duration,
    pub learnt: bool,
}

impl Figures {
    /// How long a press holds before its first repeat: the delay and one interval.
    pub fn first(&self) -> Duration {
        self.delay + self.interval
    }

    /// How long a repeat holds: two intervals, so one late repeat does not let go.
    pub fn next(&self) -> Duration {
        self.interval * 2
    }

    /// The bound the mode shows: a hold ends (the engine ends its gas) within two
    /// intervals of the last repeat, and the device has it within three.
    pub fn stops_within(&self) -> Duration {
        self.interval * 3
    }

    /// The bound in whole tens of milliseconds, rounded up: `100`.
    pub fn stops_ms(&self) -> u128 {
        self.stops_within().as_millis().div_ceil(10) * 10
    }
}

/// The run of one key being repeated.
#[derive(Clone, Debug)]
struct Run {
    code: KeyCode,
    last: Instant,
    /// Press to the first repeat.
    first: Option<Duration>,
    /// Between repeats.
    gaps: Vec<Duration>,
    /// Accepted as a key repeat (its figures went into the learnt ones).
    taken: bool,
}

/// The terminal's key repeat, learnt from what arrives: from the kitty protocol's repeat
/// events, or from a legacy terminal's presses of one key that come at a steady
/// interval after a longer first delay.
#[derive(Clone, Debug, Default)]
pub struct KeyRepeat {
    run: Option<Run>,
    firsts: VecDeque<Duration>,
    gaps: VecDeque<Duration>,
}

/// A legacy press of the run's key `gap` after its last continues the run when it could
/// be the key repeat: within the longest delay after the press, then within three of
/// the run's intervals.
fn continues(r: &Run, gap: Duration) -> bool {
    match r.first {
        None => gap <= MAX_DELAY,
        Some(_) if r.gaps.is_empty() => gap <= MAX_INTERVAL,
        Some(_) => gap <= median(&r.gaps) * 3,
    }
}

fn median(v: &[Duration]) -> Duration {
    let mut v = v.to_vec();
    v.sort();
    v[v.len() / 2]
}

impl KeyRepeat {
    /// A key event: `kind` as the terminal reported it, read at `at`.
    pub fn see(&mut self, code: KeyCode, kind: KeyEventKind, at: Instant) {
        let gap = |r: &Run| at.saturating_duration_since(r.last);
        let continues = self
            .run
            .as_ref()
            .is_some_and(|r| r.code == code && continues(r, gap(r)));
        match (kind, &mut self.run) {
            (KeyEventKind::Release, _) => self.run = None,
            (KeyEventKind::Repeat, Some(r)) if r.code == code => {
                let g = gap(r);
                r.last = at;
                match r.first {
                    None => r.first = Some(g),
                    Some(_) => r.gaps.push(g),
                }
            }
            // A repeat of a key whose press was not seen: nothing to measure from.
            (KeyEventKind::Repeat, _) => self.run = None,
            (KeyEventKind::Press, Some(r)) if continues => {
                let g = gap(r);
                r.last = at;
                match r.first {
                    None => r.first = Some(g),
                    Some(_) => r.gaps.push(g),
                }
            }
            (KeyEventKind::Press, _) => {
                self.run = Some(Run {
                    code,
                    last: at,
                    first: None,
                    gaps: Vec::new(),
                    taken: false,
                })
            }
        }
        self.learn();
    }

    /// Take the run's figures once it looks like a key repeat: a first delay, then at
    /// least two intervals no longer than the delay, steady but for the odd one a busy
    /// machine or link delayed or packed (three in four within half and twice their
    /// median). Only the steady ones are learnt.
    fn learn(&mut self) {
        let Some(r) = self.run.as_mut() else { return };
        let Some(first) = r.first else { return };
        if r.gaps.len() < 2 {
            return;
        }
        let interval = median(&r.gaps);
        let in_band = |g: &Duration| *g >= interval / 2 && *g <= interval * 2;
        let steady = r.gaps.iter().filter(|g| in_band(g)).count() * 4 >= r.gaps.len() * 3;
        let plausible = (MIN_INTERVAL..=MAX_INTERVAL).contains(&interval)
            && first >= interval
            && first <= MAX_DELAY;
        if !(steady && plausible) {
            return;
        }
        let new = if r.taken {
            &r.gaps[r.gaps.len() - 1..]
        } else {
            r.taken = true;
            if self.firsts.len() == KEEP_FIRSTS {
                self.firsts.pop_front();
            }
            self.firsts.push_back(first);
            &*r.gaps
        };
        for g in new.iter().filter(|g| in_band(g)) {
            if self.gaps.len() == KEEP_GAPS {
                self.gaps.pop_front();
            }
            self.gaps.push_back(*g);
        }
    }

    /// The figures: learnt (the longest of the last few first delays, the median
    /// interval), else the defaults.
    pub fn figures(&self) -> Figures {
        match self.firsts.iter().max() {
            Some(delay) if !self.gaps.is_empty() => Figures {
                delay: *delay,
                interval: median(&self.gaps.iter().copied().collect::<Vec<_>>()),
                learnt: true,
            },
            _ => Figures {
                delay: DEFAULT_DELAY,
                interval: DEFAULT_INTERVAL,
                learnt: false,
            },
        }
    }
}

/// A teleop key that is held to drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HoldKey {
    Gas,
    Brake,
    Left,
    Right,
}

/// One held key.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Held {
    /// The key as the terminal sends it (its release names it).
    pub code: KeyCode,
    /// Which hold key it is.
    pub key: HoldKey,
    /// Held until then, unless its events keep it.
    pub until: Instant,
    /// When it was last seen (its press or a repeat): packed presses behind it are
    /// not fresh ones.
    pub seen: Instant,
}

/// What an event did to the holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Did {
    /// A new hold.
    Pressed,
    /// A hold kept longer.
    Kept,
    /// A hold let go (its release).
    LetGo,
    /// Nothing: a repeat of a hold that ended, a press packed behind another, a gas key
    /// while the brake key is held.
    Nothing,
}

/// The held keys: at most one pedal and one steering direction.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Holds {
    pub pedal: Option<Held>,
    pub steer: Option<Held>,
    /// The last event of each key, to tell a fresh press from one packed behind it.
    last: Vec<(KeyCode, Instant)>,
}

impl Holds {
    /// Every held key.
    pub fn all(&self) -> impl Iterator<Item = &Held> {
        self.pedal.iter().chain(self.steer.iter())
    }

    pub fn is_empty(&self) -> bool {
        self.pedal.is_none() && self.steer.is_none()
    }

    fn slot(&mut self, key: HoldKey) -> &mut Option<Held> {
        match key {
            HoldKey::Gas | HoldKey::Brake => &mut self.pedal,
            HoldKey::Left | HoldKey::Right => &mut self.steer,
        }
    }

    /// The key `key` (sent as `code`) was pressed or repeated (`kind`) at `at`, in
    /// `drive` mode (not step) with the key repeat's figures `f`.
    pub fn key(
        &mut self,
        drive: Drive,
        f: &Figures,
        key: HoldKey,
        code: KeyCode,
        kind: KeyEventKind,
        at: Instant,
    ) -> Did {
        let before = self.last.iter().find(|(c, _)| *c == code).map(|(_, t)| *t);
        self.last.retain(|(c, _)| *c != code);
        self.last.push((code, at));
        if kind == KeyEventKind::Release {
            return match self.let_go(code) {
                Some(_) => Did::LetGo,
                None => Did::Nothing,
            };
        }
        let slot = self.slot(key);
        let held = slot.filter(|h| h.key == key && h.code == code && at < h.until);
        // Legacy: a press of the held key is its repeat.
        let repeat = kind == KeyEventKind::Repeat || (drive == Drive::Repeat && held.is_some());
        if repeat {
            return match held {
                Some(h) => {
                    // Packed behind the last (bytes that waited in a stalled link):
                    // stale, so they hold only as long as any repeat from now — never
                    // the first delay of a press they arrived with.
                    let packed = at.saturating_duration_since(h.seen) < f.interval / 2;
                    let until = match packed {
                        true => at + f.next(),
                        false => h.until.max(at + f.next()),
                    };
                    *slot = Some(Held {
                        until,
                        seen: at,
                        ..h
                    });
                    Did::Kept
                }
                None => Did::Nothing,
            };
        }
        // A press right behind another of the same key, faster than any key repeat:
        // bytes that waited (a stalled link), not a finger.
        if before.is_some_and(|t| at.saturating_duration_since(t) < f.interval / 2) {
            return Did::Nothing;
        }
        // The brake key held: the gas key does nothing (gas and brake never together).
        if key == HoldKey::Gas && slot.is_some_and(|h| h.key == HoldKey::Brake && at < h.until) {
            return Did::Nothing;
        }
        *slot = Some(Held {
            code,
            key,
            until: at + f.first(),
            seen: at,
        });
        Did::Pressed
    }

    /// A release: the held key sent as `code` lets go, and is returned.
    pub fn let_go(&mut self, code: KeyCode) -> Option<Held> {
        for slot in [&mut self.pedal, &mut self.steer] {
            if let Some(h) = slot.filter(|h| h.code == code) {
                *slot = None;
                return Some(h);
            }
        }
        None
    }

    /// Hold mode: a key event (`kind`, any key) at `at` shows the terminal still
    /// sends and no release came for the keys held: each lasts at least as long as
    /// after a press or a repeat of its own.
    pub fn alive(&mut self, f: &Figures, kind: KeyEventKind, at: Instant) {
        let bound = match kind {
            KeyEventKind::Press => f.first(),
            KeyEventKind::Repeat => f.next(),
            KeyEventKind::Release => return,
        };
        for h in [&mut self.pedal, &mut self.steer].into_iter().flatten() {
            if at < h.until {
                h.until = h.until.max(at + bound);
            }
        }
    }

    /// The holds that ran out by `now`, removed.
    pub fn expire(&mut self, now: Instant) -> Vec<Held> {
        let mut out = Vec::new();
        for slot in [&mut self.pedal, &mut self.steer] {
            if let Some(h) = slot.filter(|h| now >= h.until) {
                out.push(h);
                *slot = None;
            }
        }
        out
    }

    /// Let every key go (leaving teleop, a stop, the deadman, step forced).
    pub fn clear(&mut self) {
        self.pedal = None;
        self.steer = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use KeyEventKind::{Press, Release, Repeat};

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    /// A legacy key repeat of `code` as it arrives: a press at `t`, then presses after
    /// `delay` and every `interval`, `n` in all.
    fn legacy(r: &mut KeyRepeat, code: KeyCode, t: Instant, delay: u64, interval: u64, n: u64) {
        r.see(code, Press, t);
        for i in 0..n.saturating_sub(1) {
            r.see(code, Press, t + ms(delay + i * interval));
        }
    }

    #[test]
    fn a_legacy_key_repeat_at_25_and_33_hz_is_learnt_from_its_presses() {
        for (delay, interval) in [(500, 40), (660, 30), (250, 33)] {
            let mut r = KeyRepeat::default();
            assert!(!r.figures().learnt);
            legacy(&mut r, KeyCode::Up, Instant::now(), delay, interval, 12);
            let f = r.figures();
            assert!(f.learnt, "{delay}/{interval}");
            assert_eq!((f.delay, f.interval), (ms(delay), ms(interval)));
        }
    }

    #[test]
    fn kitty_repeat_events_teach_the_same_and_a_release_ends_the_run() {
        let mut r = KeyRepeat::default();
        let t = Instant::now();
        r.see(KeyCode::Left, Press, t);
        for i in 0..6 {
            r.see(KeyCode::Left, Repeat, t + ms(400 + i * 40));
        }
        r.see(KeyCode::Left, Release, t + ms(700));
        assert_eq!(
            r.figures(),
            Figures {
                delay: ms(400),
                interval: ms(40),
                learnt: true
            }
        );
    }

    /// A busy machine or link delays a repeat now and then and packs the next behind
    /// it: the key repeat is still learnt, from the steady intervals alone.
    #[test]
    fn a_key_repeat_with_a_late_and_a_packed_repeat_is_learnt() {
        let (mut r, t, code) = (KeyRepeat::default(), Instant::now(), KeyCode::Up);
        r.see(code, Press, t);
        // The first repeat on time, the second 25 ms late and the third read 5 ms
        // after it, then steady.
        let mut at = 300;
        for gap in [0, 55, 5, 30, 30, 30, 30, 30] {
            at += gap;
            r.see(code, Press, t + ms(at));
        }
        let f = r.figures();
        assert!(f.learnt);
        assert_eq!((f.delay, f.interval), (ms(300), ms(30)));
    }

    /// Taps are not a key repeat: slower than one, or the same gap from the start.
    #[test]
    fn taps_and_typing_teach_nothing() {
        let t = Instant::now();
        let mut r = KeyRepeat::default();
        for i in 0..10 {
            r.see(KeyCode::Up, Press, t + ms(i * 150));
        }
        assert!(!r.figures().learnt, "taps every 150 ms");
        let mut r = KeyRepeat::default();
        for (i, c) in "0.35".chars().enumerate() {
            r.see(KeyCode::Char(c), Press, t + ms(i as u64 * 30));
        }
        assert!(!r.figures().learnt, "typing");
    }

    fn f33() -> Figures {
        Figures {
            delay: ms(500),
            interval: ms(30),
            learnt: true,
        }
    }

    #[test]
    fn the_figure_shown_is_three_intervals_in_tens_of_ms() {
        assert_eq!(f33().stops_ms(), 90);
        let f = Figures {
            interval: Duration::from_micros(33_333),
            ..f33()
        };
        assert_eq!(f.stops_ms(), 100);
    }

    /// Hold mode: press, repeats, release — held until the release, at once.
    #[test]
    fn a_press_holds_until_its_release() {
        let (f, t) = (f33(), Instant::now());
        let mut h = Holds::default();
        let k =
            |h: &mut Holds, kind, at| h.key(Drive::Hold, &f, HoldKey::Gas, KeyCode::Up, kind, at);
        assert_eq!(k(&mut h, Press, t), Did::Pressed);
        assert_eq!(h.pedal.unwrap().until, t + ms(530));
        assert_eq!(k(&mut h, Repeat, t + ms(500)), Did::Kept);
        assert_eq!(k(&mut h, Repeat, t + ms(530)), Did::Kept);
        assert_eq!(h.pedal.unwrap().until, t + ms(590));
        assert_eq!(k(&mut h, Release, t + ms(545)), Did::LetGo);
        assert!(h.is_empty());
    }

    /// Hold mode, the release lost: press, repeats, then nothing — it ends two
    /// intervals after the last repeat, and a repeat after that does not take it up.
    #[test]
    fn a_lost_release_ends_the_hold_two_intervals_after_the_last_repeat() {
        let (f, t) = (f33(), Instant::now());
        let mut h = Holds::default();
        h.key(Drive::Hold, &f, HoldKey::Gas, KeyCode::Up, Press, t);
        for i in 0..5 {
            h.key(
                Drive::Hold,
                &f,
                HoldKey::Gas,
                KeyCode::Up,
                Repeat,
                t + ms(500 + 30 * i),
            );
        }
        let last = t + ms(620);
        assert!(h.expire(last + ms(59)).is_empty());
        assert_eq!(h.expire(last + ms(60)).len(), 1);
        assert_eq!(
            h.key(
                Drive::Hold,
                &f,
                HoldKey::Gas,
                KeyCode::Up,
                Repeat,
                last + ms(200)
            ),
            Did::Nothing,
            "only a fresh press holds again"
        );
        assert!(h.is_empty());
    }

    /// A tap holds at most the delay and one interval.
    #[test]
    fn a_tap_holds_at_most_the_learnt_delay_and_an_interval() {
        let (f, t) = (f33(), Instant::now());
        for drive in [Drive::Hold, Drive::Repeat] {
            let mut h = Holds::default();
            h.key(drive, &f, HoldKey::Left, KeyCode::Left, Press, t);
            assert!(h.expire(t + ms(529)).is_empty());
            assert_eq!(h.expire(t + ms(530))[0].key, HoldKey::Left);
        }
    }

    /// Repeat mode at 25 and 33 Hz: presses keep it, silence ends it within two
    /// intervals of the last; no mid-hold drop while they come on time.
    #[test]
    fn a_legacy_repeat_holds_while_it_comes_and_ends_when_it_stops() {
        for interval in [40u64, 30] {
            let f = Figures {
                delay: ms(500),
                interval: ms(interval),
                learnt: true,
            };
            let t = Instant::now();
            let mut h = Holds::default();
            let mut at = t;
            assert_eq!(
                h.key(Drive::Repeat, &f, HoldKey::Gas, KeyCode::Up, Press, at),
                Did::Pressed
            );
            at += ms(500);
            for _ in 0..50 {
                assert!(h.expire(at - ms(1)).is_empty(), "a drop mid-hold");
                assert_eq!(
                    h.key(Drive::Repeat, &f, HoldKey::Gas, KeyCode::Up, Press, at),
                    Did::Kept
                );
                at += ms(interval);
            }
            let last = at - ms(interval);
            assert!(h.expire(last + ms(2 * interval - 1)).is_empty());
            assert_eq!(h.expire(last + ms(2 * interval)).len(), 1);
        }
    }

    /// In repeat mode another key's repeats never keep a hold (its key may be up); in
    /// hold mode they do, while no release came for it.
    #[test]
    fn another_key_keeps_a_hold_only_where_releases_are_reported() {
        let (f, t) = (f33(), Instant::now());
        for (drive, kept) in [(Drive::Hold, true), (Drive::Repeat, false)] {
            let mut h = Holds::default();
            h.key(drive, &f, HoldKey::Gas, KeyCode::Up, Press, t);
            h.key(drive, &f, HoldKey::Left, KeyCode::Left, Press, t + ms(300));
            if drive == Drive::Hold {
                h.alive(&f, Press, t + ms(300));
            }
            for i in 0..20 {
                let at = t + ms(800 + 30 * i);
                let kind = if drive == Drive::Hold { Repeat } else { Press };
                h.key(drive, &f, HoldKey::Left, KeyCode::Left, kind, at);
                if drive == Drive::Hold {
                    h.alive(&f, kind, at);
                }
            }
            let gone = h.expire(t + ms(1400));
            assert_eq!(h.pedal.is_some(), kept, "{drive:?}: {gone:?}");
        }
    }

    /// Bytes that waited in a stalled link arrive packed: a press behind another of the
    /// same key faster than any repeat does not hold again.
    #[test]
    fn presses_packed_behind_a_stall_do_not_hold_again() {
        let (f, t) = (f33(), Instant::now());
        let mut h = Holds::default();
        h.key(Drive::Repeat, &f, HoldKey::Gas, KeyCode::Up, Press, t);
        h.key(
            Drive::Repeat,
            &f,
            HoldKey::Gas,
            KeyCode::Up,
            Press,
            t + ms(500),
        );
        assert_eq!(h.expire(t + ms(2000)).len(), 1, "the link stalled");
        let burst = t + ms(2000);
        assert_eq!(
            h.key(Drive::Repeat, &f, HoldKey::Gas, KeyCode::Up, Press, burst),
            Did::Pressed,
            "the first of the burst is a press, as far as anyone can tell"
        );
        assert_eq!(h.pedal.unwrap().until, burst + f.first());
        h.key(Drive::Repeat, &f, HoldKey::Gas, KeyCode::Up, Press, burst);
        assert_eq!(
            h.pedal.unwrap().until,
            burst + f.next(),
            "the burst holds as a repeat does, not as a press"
        );
        h.clear();
        assert_eq!(
            h.key(
                Drive::Repeat,
                &f,
                HoldKey::Gas,
                KeyCode::Up,
                Press,
                burst + ms(1)
            ),
            Did::Nothing
        );
    }

    /// Gas and brake never together: the brake key ends the gas at once, and the gas
    /// key does nothing while the brake key is held.
    #[test]
    fn the_brake_key_wins() {
        let (f, t) = (f33(), Instant::now());
        let mut h = Holds::default();
        h.key(Drive::Hold, &f, HoldKey::Gas, KeyCode::Up, Press, t);
        h.key(
            Drive::Hold,
            &f,
            HoldKey::Brake,
            KeyCode::Down,
            Press,
            t + ms(10),
        );
        assert_eq!(h.pedal.unwrap().key, HoldKey::Brake);
        assert_eq!(
            h.key(
                Drive::Hold,
                &f,
                HoldKey::Gas,
                KeyCode::Up,
                Press,
                t + ms(100)
            ),
            Did::Nothing
        );
        assert_eq!(h.pedal.unwrap().key, HoldKey::Brake);
    }
}
