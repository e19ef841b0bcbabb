//! Hold-to-drive through `key` and `tick`: key events with their kinds and the instants
//! their bytes were read, in hold mode (releases reported) and repeat mode (presses
//! only), and what the console asks of the engine.

use super::*;
use crate::console::hold::Drive;
use crate::console::input::Keyboard;
use crossterm::event::KeyEventKind::{self, Press, Release, Repeat};

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// One key event (written as in a keymap) of `kind`, read at `at` and handled then, as
/// the console's loop does.
fn ev(m: &mut Model, f: &Fake, key: &str, kind: KeyEventKind, at: Instant) -> Flow {
    let k: crate::console::keymap::Key = key.parse().unwrap();
    let mut e = KeyEvent::new(k.code, KeyModifiers::NONE);
    e.kind = kind;
    draw(m);
    super::super::key(m, &e, at, f, at)
}

/// The console in teleop, its terminal reporting releases or not, the key repeat
/// learnt as `delay` then every `interval` ms (from a key held on the main screen).
fn teleop(f: &Fake, releases: bool, learnt: Option<(u64, u64)>, t: Instant) -> Model {
    let mut m = model(f);
    m.screen = ratatui::layout::Rect::new(0, 0, 100, 30);
    m.terminal.keyboard = Some(match releases {
        true => Keyboard::Releases,
        false => Keyboard::PressesOnly,
    });
    if let Some((delay, interval)) = learnt {
        let code = crossterm::event::KeyCode::Char('x');
        m.repeat.see(code, Press, t);
        for i in 0..8 {
            let kind = if releases { Repeat } else { Press };
            m.repeat.see(code, kind, t + ms(delay + i * interval));
        }
        let f = m.repeat.figures();
        assert_eq!((f.delay, f.interval), (ms(delay), ms(interval)));
    }
    press(&mut m, f, &["d"], t);
    assert_eq!(m.mode, Mode::Teleop);
    f.calls.borrow_mut().clear();
    m
}

/// Calls made since the last look.
fn new_calls(f: &Fake) -> Vec<String> {
    std::mem::take(&mut *f.calls.borrow_mut())
}

/// Entering teleop commands nothing: the pedals are asked for from the first pedal key.
#[test]
fn entering_teleop_commands_nothing_until_a_pedal_key() {
    let f = Fake::new();
    let t = Instant::now();
    let mut m = teleop(&f, true, None, t);
    tick(&mut m, &f, t + ms(500));
    assert_eq!(new_calls(&f), Vec::<String>::new());
    assert_eq!(m.drive(), Drive::Hold);
}

/// Hold mode: `↑` pressed gives the gas level on a lease, each repeat renews it
/// without climbing, and the release brings the hold brake at once.
#[test]
fn hold_press_repeats_release_gas_at_its_level_then_the_hold_brake_at_once() {
    let f = Fake::new();
    let t = Instant::now();
    let mut m = teleop(&f, true, None, t);
    ev(&mut m, &f, "<Up>", Press, t);
    assert_eq!(new_calls(&f), ["held 0.2 for 550ms then -0.3"]);
    assert_eq!(
        f.deadman.get(),
        Some(m.teleop.deadman),
        "the key feeds the deadman"
    );
    for i in 0..20 {
        ev(&mut m, &f, "<Up>", Repeat, t + ms(500 + 50 * i));
    }
    let calls = new_calls(&f);
    assert_eq!(calls.len(), 20);
    assert!(calls.iter().all(|c| c == "renew 100ms"), "{calls:?}");
    assert_eq!(m.teleop.accel, 0.2, "holding ↑ holds the gas level");
    let bar = screen_text(&mut m);
    assert!(
        bar.contains("TELEOP hold") && bar.contains("held ↑"),
        "{bar}"
    );
    ev(&mut m, &f, "<Up>", Release, t + ms(1460));
    assert_eq!(new_calls(&f), ["accel -0.3"]);
    assert!(m.teleop.holds.is_empty());
}

/// Hold mode, the release lost (press, repeats, then nothing): the console lets go two
/// intervals after the last repeat, which is what the last lease asked of the engine.
#[test]
fn hold_with_the_release_lost_ends_two_intervals_after_the_last_repeat() {
    let f = Fake::new();
    let t = Instant::now();
    let mut m = teleop(&f, true, Some((500, 30)), t);
    ev(&mut m, &f, "<Up>", Press, t);
    let mut last = t;
    for i in 0..5 {
        last = t + ms(500 + 30 * i);
        ev(&mut m, &f, "<Up>", Repeat, last);
    }
    let calls = new_calls(&f);
    assert_eq!(calls[0], "held 0.2 for 530ms then -0.3");
    assert_eq!(
        calls.last().unwrap(),
        "renew 60ms",
        "the engine ends it 60 ms on"
    );
    tick(&mut m, &f, last + ms(59));
    assert_eq!(new_calls(&f), Vec::<String>::new());
    tick(&mut m, &f, last + ms(60));
    assert_eq!(new_calls(&f), ["accel -0.3"]);
    // A repeat after that is no press: nothing.
    ev(&mut m, &f, "<Up>", Repeat, last + ms(200));
    assert_eq!(new_calls(&f), Vec::<String>::new());
}

/// Repeat mode (tmux): the key repeat at 25 and 33 Hz is learnt from a first hold, the
/// bar says `repeat` with its bound, presses hold without a drop while they come, and
/// the gas ends two intervals after the last (the device has it within three).
#[test]
fn repeat_mode_learns_25_and_33_hz_and_ends_within_three_intervals() {
    for (delay, interval) in [(500u64, 40u64), (250, 30)] {
        let f = Fake::new();
        let t = Instant::now();
        let mut m = teleop(&f, false, None, t);
        assert_eq!(m.drive(), Drive::Repeat);
        // The first hold teaches the key repeat.
        ev(&mut m, &f, "<Up>", Press, t);
        for i in 0..10 {
            ev(&mut m, &f, "<Up>", Press, t + ms(delay + interval * i));
        }
        tick(&mut m, &f, t + ms(3000));
        let learnt = m.repeat.figures();
        assert!(learnt.learnt);
        assert_eq!((learnt.delay, learnt.interval), (ms(delay), ms(interval)));
        let bar = screen_text(&mut m);
        let bound = format!(
            "TELEOP repeat: stops ≤ {} ms after the repeats end",
            3 * interval
        );
        assert!(bar.contains(&bound), "{bar}");
        new_calls(&f);
        // The second hold: 100 repeats, then the key comes up.
        let t2 = t + ms(5000);
        ev(&mut m, &f, "<Up>", Press, t2);
        let mut last = t2;
        for i in 0..100 {
            last = t2 + ms(delay + interval * i);
            tick(&mut m, &f, last - ms(1));
            ev(&mut m, &f, "<Up>", Press, last);
        }
        let calls = new_calls(&f);
        assert_eq!(
            calls[0],
            format!("held 0.2 for {}ms then -0.3", delay + interval)
        );
        assert!(
            calls[1..]
                .iter()
                .all(|c| *c == format!("renew {}ms", 2 * interval)),
            "no drop, no climb mid-hold: {calls:?}"
        );
        tick(&mut m, &f, last + ms(2 * interval - 1));
        assert_eq!(new_calls(&f), Vec::<String>::new());
        tick(&mut m, &f, last + ms(2 * interval));
        assert_eq!(new_calls(&f), ["accel -0.3"]);
    }
}

/// A single tap holds at most the learnt delay and one interval, in both modes.
#[test]
fn a_tap_holds_at_most_the_learnt_delay_and_an_interval() {
    for releases in [false, true] {
        let f = Fake::new();
        let t = Instant::now();
        let mut m = teleop(&f, releases, Some((500, 30)), t);
        ev(&mut m, &f, "<Up>", Press, t);
        assert_eq!(new_calls(&f), ["held 0.2 for 530ms then -0.3"]);
        tick(&mut m, &f, t + ms(529));
        assert_eq!(new_calls(&f), Vec::<String>::new());
        tick(&mut m, &f, t + ms(530));
        assert_eq!(new_calls(&f), ["accel -0.3"]);
    }
}

/// Gas and brake never together: `↓` takes the gas away at once, `↑` does nothing while
/// `↓` is held, and letting `↓` go is the hold level, not gas.
#[test]
fn the_brake_key_ends_the_gas_and_keeps_it_away() {
    let f = Fake::new();
    let t = Instant::now();
    let mut m = teleop(&f, true, Some((500, 30)), t);
    ev(&mut m, &f, "<Up>", Press, t);
    ev(&mut m, &f, "<Down>", Press, t + ms(100));
    ev(&mut m, &f, "<Up>", Press, t + ms(200));
    assert!(m
        .message
        .as_ref()
        .unwrap()
        .text
        .contains("no gas while the brake key"));
    ev(&mut m, &f, "<Down>", Release, t + ms(300));
    assert_eq!(
        new_calls(&f),
        ["held 0.2 for 530ms then -0.3", "accel -0.6", "accel -0.3"]
    );
}

/// `←` held moves the steering at the set rate from where it was, and leaves it where
/// it is on release.
#[test]
fn a_held_steering_key_moves_at_the_rate_and_holds_on_release() {
    let f = Fake::new();
    let t = Instant::now();
    let mut m = teleop(&f, true, Some((500, 50)), t);
    assert_eq!(m.teleop.steer, 0.231);
    ev(&mut m, &f, "<Left>", Press, t);
    for i in 0..10 {
        ev(&mut m, &f, "<Left>", Repeat, t + ms(500 + 50 * i));
    }
    ev(&mut m, &f, "<Left>", Release, t + ms(1000));
    let calls = new_calls(&f);
    assert_eq!(calls.last().unwrap(), "submit steer -0.269", "{calls:?}");
    assert_eq!(m.teleop.steer, -0.269);
    tick(&mut m, &f, t + ms(2000));
    assert_eq!(new_calls(&f), Vec::<String>::new(), "it holds where it is");
}

/// The levels change with their keys within their limits; the hold never above the
/// brake; a held key asks the new level at once.
#[test]
fn level_keys_change_what_a_held_key_asks_within_the_limits() {
    let f = Fake::new();
    let t = Instant::now();
    let mut m = teleop(&f, true, Some((500, 30)), t);
    ev(&mut m, &f, "<Up>", Press, t);
    ev(&mut m, &f, "+", Press, t + ms(100));
    assert_eq!(m.teleop.levels.gas, 0.25);
    assert_eq!(
        new_calls(&f),
        [
            "held 0.2 for 530ms then -0.3",
            "renew 530ms",
            "held 0.25 for 530ms then -0.3"
        ]
    );
    for i in 0..6 {
        press(&mut m, &f, &["+"], t + ms(200 + i));
    }
    assert_eq!(m.teleop.levels.gas, 0.5, "the most a keyboard holds");
    let msg = m.message.clone().unwrap();
    assert!(msg.bad && msg.text.contains("is the most"), "{}", msg.text);
    for _ in 0..7 {
        press(&mut m, &f, &["}"], t + ms(300));
    }
    assert_eq!(m.teleop.levels.hold, 0.6, "up to the brake's 0.60");
    let msg = m.message.clone().unwrap();
    assert!(
        msg.bad && msg.text.contains("`hold` at most `brake`"),
        "{}",
        msg.text
    );
    let bar = screen_text(&mut m);
    assert!(
        bar.contains("gas 0.50 · brake 0.60 · hold 0.60 · steer 0.50/s"),
        "{bar}"
    );
}

/// `m` forces step mode (every key a step, as before holds) and back; keys held are
/// let go first.
#[test]
fn step_mode_is_forced_and_undone_by_its_key() {
    let f = Fake::new();
    let t = Instant::now();
    let mut m = teleop(&f, true, Some((500, 30)), t);
    ev(&mut m, &f, "<Up>", Press, t);
    press(&mut m, &f, &["m"], t + ms(10));
    assert_eq!(m.drive(), Drive::Step);
    ev(&mut m, &f, "<Up>", Press, t + ms(20));
    ev(&mut m, &f, "<Up>", Release, t + ms(30));
    assert_eq!(
        new_calls(&f),
        [
            "held 0.2 for 530ms then -0.3",
            "renew 530ms",
            "accel -0.3",
            "accel 0"
        ]
    );
    assert!(screen_text(&mut m).contains("TELEOP step"));
    press(&mut m, &f, &["m"], t + ms(40));
    assert_eq!(m.drive(), Drive::Hold);
}

/// Keys hold only on teleop's screen: help over the bar lets every key go at once (the
/// release that follows finds nothing held), and a key the operator cannot see holds
/// nothing.
#[test]
fn help_over_the_bar_lets_go_and_an_unseen_key_holds_nothing() {
    let f = Fake::new();
    let t = Instant::now();
    let mut m = teleop(&f, true, Some((500, 30)), t);
    ev(&mut m, &f, "<Up>", Press, t);
    assert_eq!(new_calls(&f), ["held 0.2 for 530ms then -0.3"]);
    ev(&mut m, &f, "?", Press, t + ms(50));
    assert_eq!(m.mode, Mode::Help);
    let calls = new_calls(&f);
    assert_eq!(calls.last().unwrap(), "accel -0.3", "{calls:?}");
    assert!(m.teleop.holds.is_empty());
    ev(&mut m, &f, "<Up>", Release, t + ms(100));
    assert_eq!(new_calls(&f), Vec::<String>::new());
    press(&mut m, &f, &["<Esc>"], t + ms(150));
    m.screen = ratatui::layout::Rect::new(0, 0, 30, 30);
    ev(&mut m, &f, "<Up>", Press, t + ms(200));
    assert_eq!(new_calls(&f), Vec::<String>::new());
    let msg = m.message.clone().unwrap();
    assert!(
        msg.bad && msg.text.starts_with("accel up refused"),
        "{}",
        msg.text
    );
}

/// Hold mode: another key's events (any key: the terminal repeats only the last key
/// pressed) keep a key held whose release has not come, and renew the engine's lease at
/// once — not at the next tick, after the lease ran out.
#[test]
fn another_key_s_events_keep_a_hold_and_its_lease() {
    let f = Fake::new();
    let t = Instant::now();
    let mut m = teleop(&f, true, Some((500, 30)), t);
    ev(&mut m, &f, "<Up>", Press, t);
    ev(&mut m, &f, "x", Press, t + ms(300));
    for i in 0..10 {
        ev(&mut m, &f, "x", Repeat, t + ms(800 + 30 * i));
    }
    assert_eq!(
        new_calls(&f)[..3],
        ["held 0.2 for 530ms then -0.3", "renew 530ms", "renew 60ms"]
    );
    tick(&mut m, &f, t + ms(1100));
    assert_eq!(new_calls(&f), Vec::<String>::new(), "no drop, no new ask");
    ev(&mut m, &f, "<Up>", Release, t + ms(1110));
    assert_eq!(new_calls(&f), ["accel -0.3"]);
}

/// Refused gas holds nothing (only a new press asks again); a lease the engine ended
/// (this console late) is asked afresh while the key is still held.
#[test]
fn refused_gas_holds_nothing_and_a_lease_ended_early_is_asked_again() {
    let mut f = Fake::new();
    let t = Instant::now();
    let mut m = teleop(&f, true, Some((500, 30)), t);
    f.refuse = Some(Reject::Disengaged);
    ev(&mut m, &f, "<Up>", Press, t);
    ev(&mut m, &f, "<Up>", Repeat, t + ms(500));
    let calls = new_calls(&f);
    assert_eq!(
        calls.iter().filter(|c| c.starts_with("held")).count(),
        1,
        "{calls:?}"
    );
    assert!(!calls.iter().any(|c| c.starts_with("renew")), "{calls:?}");
    ev(&mut m, &f, "<Up>", Release, t + ms(510));
    f.refuse = None;
    new_calls(&f);
    ev(&mut m, &f, "<Up>", Press, t + ms(1000));
    f.lease_ended.set(true);
    ev(&mut m, &f, "<Up>", Repeat, t + ms(1500));
    assert_eq!(
        new_calls(&f),
        [
            "held 0.2 for 530ms then -0.3",
            "renew 60ms",
            "held 0.2 for 60ms then -0.3"
        ]
    );
}

/// The deadman trips: nothing stays held, nothing is asked until the next key.
#[test]
fn the_deadman_lets_every_key_go() {
    let mut f = Fake::new();
    let t = Instant::now();
    let mut m = teleop(&f, true, Some((500, 30)), t);
    ev(&mut m, &f, "<Up>", Press, t);
    ev(&mut m, &f, "<Left>", Press, t);
    f.snap.snap.gate.engaged = false;
    f.snap.snap.gate.watchdog = Some(crate::snapshot::WatchdogView {
        state: crate::snapshot::WatchdogState::Tripped,
        timeout_ms: 500.0,
        last_command_age_ms: None,
        last_trip: Some("deadman: no teleop key for 0.5s".into()),
        trip: Some(crate::snapshot::TripKind::Deadman),
    });
    tick(&mut m, &f, t + ms(100));
    assert!(m.teleop.holds.is_empty() && m.teleop.asked.is_none());
    new_calls(&f);
    tick(&mut m, &f, t + ms(2000));
    assert_eq!(new_calls(&f), Vec::<String>::new());
}

/// Help's key-event viewer lists the last key events with their kinds and the time
/// between them, and says what the terminal reports.
#[test]
fn the_help_key_event_viewer_shows_kinds() {
    let f = Fake::new();
    let t = Instant::now();
    let mut m = teleop(&f, true, None, t);
    press(&mut m, &f, &["?", "e"], t);
    assert!(m.key_viewer);
    ev(&mut m, &f, "<Left>", Press, t + ms(10));
    ev(&mut m, &f, "<Left>", Repeat, t + ms(510));
    ev(&mut m, &f, "<Left>", Release, t + ms(530));
    let s = screen_text(&mut m);
    assert!(s.contains("KEY EVENTS"), "{s}");
    assert!(
        s.contains("this terminal reports presses, repeats and releases"),
        "{s}"
    );
    assert!(s.contains("teleop drives in hold"), "{s}");
    for l in [
        "←          press   +10 ms",
        "←          repeat  +500 ms",
        "←          release +20 ms",
    ] {
        assert!(s.contains(l), "{l:?} in\n{s}");
    }
}

/// The screen as text, drawn as the console's loop draws it.
fn screen_text(m: &mut Model) -> String {
    let b = draw(m);
    let a = b.area;
    (0..a.height)
        .map(|y| (0..a.width).map(|x| b[(x, y)].symbol()).collect::<String>() + "\n")
        .collect()
}

/// A key script: each key pressed, held for some repeats or tapped, let go (or its
/// release lost where releases are reported: the link stalled, and nothing after it
/// arrives), with pauses between.
#[derive(Clone, Copy, Debug)]
struct Hold {
    key: u8,
    repeats: u8,
    /// The release is lost with the link, which stays stalled (hold mode) — or never
    /// sent (repeat mode). A link loses no single event: in hold mode a release that
    /// did not come while later keys' events do means the key is still down.
    lost: bool,
    /// A pause after it, ms.
    pause: u16,
}

fn hold_strategy() -> impl proptest::strategy::Strategy<Value = Hold> {
    use proptest::prelude::*;
    (0u8..3, 0u8..30, any::<bool>(), 0u16..800).prop_map(|(key, repeats, lost, pause)| Hold {
        key,
        repeats,
        lost,
        pause,
    })
}

/// The engine as the fake's calls tell it: the accel asked and until when its gas lasts.
#[derive(Default)]
struct Engine {
    accel: f64,
    gas_until: Option<Instant>,
}

impl Engine {
    fn follow(&mut self, calls: Vec<String>, now: Instant) {
        for c in calls {
            let w: Vec<&str> = c.split(' ').collect();
            match w[..] {
                ["held", a, "for", l, "then", _] => {
                    self.accel = a.parse().unwrap();
                    let l: u64 = l.trim_end_matches("ms").parse().unwrap();
                    self.gas_until = Some(now + ms(l));
                }
                ["renew", l] => {
                    let l: u64 = l.trim_end_matches("ms").parse().unwrap();
                    if self.gas_until.is_some_and(|u| now < u) {
                        self.gas_until = Some(now + ms(l));
                    }
                }
                ["accel", a] => {
                    self.accel = a.parse().unwrap();
                    self.gas_until = None;
                }
                _ => {}
            }
        }
    }

    /// Gas at `now`.
    fn gas(&self, now: Instant) -> bool {
        self.accel > 0.0 && self.gas_until.is_none_or(|u| now < u)
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
    /// Whatever the keys do, in hold and repeat modes: no gas while `↓` is held, and no
    /// gas after `↑` came up (or its repeats stopped) for longer than a press holds —
    /// the learnt delay and one interval. Looked at every 10 ms, as the engine's monitor.
    #[test]
    fn no_gas_without_its_key_held_and_never_under_the_brake_key(
        releases in proptest::prelude::any::<bool>(),
        script in proptest::collection::vec(hold_strategy(), 1..12),
    ) {
        let (delay, interval) = (500u64, 30u64);
        let f = Fake::new();
        let t0 = Instant::now();
        let mut m = teleop(&f, releases, Some((delay, interval)), t0);
        let bound = ms(delay + interval);
        let mut engine = Engine::default();
        // (instant, key, kind), in order; what is held physically between.
        let mut events = Vec::new();
        let mut at = t0;
        for h in &script {
            let key = ["<Up>", "<Down>", "<Left>"][h.key as usize];
            events.push((at, key, Press));
            let mut last = at;
            for i in 0..u64::from(h.repeats) {
                last = at + ms(delay + interval * i);
                events.push((last, key, if releases { Repeat } else { Press }));
            }
            let up = last + ms(10);
            if releases && !h.lost {
                events.push((up, key, Release));
            }
            events.push((up, "", Release)); // the key is up from here
            at = up + ms(u64::from(h.pause) + 1);
            if releases && h.lost {
                // The link stalled: nothing more arrives.
                break;
            }
        }
        let end = at + ms(1000);
        let (mut i, mut now) = (0, t0);
        let mut held: Option<&str> = None;
        let mut last_up: Option<Instant> = None;
        while now <= end {
            while i < events.len() && events[i].0 <= now {
                let (t, key, kind) = events[i];
                if key.is_empty() {
                    if held == Some("<Up>") {
                        last_up = Some(t);
                    }
                    held = None;
                } else {
                    if kind == Press && held.is_none() {
                        held = Some(key);
                    }
                    ev(&mut m, &f, key, kind, t);
                    engine.follow(new_calls(&f), t);
                }
                i += 1;
            }
            tick(&mut m, &f, now);
            engine.follow(new_calls(&f), now);
            if engine.gas(now) {
                proptest::prop_assert!(held != Some("<Down>"), "gas under the brake key at {:?}", now - t0);
                if held != Some("<Up>") {
                    let since = now.saturating_duration_since(last_up.unwrap_or(t0));
                    proptest::prop_assert!(
                        since < bound,
                        "gas {since:?} after ↑ came up (at {:?})", now - t0
                    );
                }
            }
            now += ms(10);
        }
    }
}
