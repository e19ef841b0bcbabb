//! Hold-to-drive teleop end to end: the real binary on the simulated Alice in drive, its
//! console — embedded, or `adrive attach` on a running adrive — in a pseudo-terminal that
//! plays the operator's terminal (tests/common/terminal_player.rs): one that speaks the
//! kitty keyboard protocol (press, repeat and release events), or a legacy one whose held
//! key is its key repeat. The devices are `adrive sim` in a process of its own, so what
//! reached each pedal is read from the simulator's own lines, in its own clock.
//!
//! Every wait has a generous deadline and polls. Where a test shows that something did
//! not happen first, a later event is its barrier: the deadman's full brake comes a
//! second after the last key, so a hold that ended on its own shows as the hold brake
//! before it.

mod common;

use common::simproc::{vehicle_file, SimProcess};
use common::terminal_player::{Key, Kind, Play, Player};
use common::{Reaped, DEADLINE};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_adrive");
const COLS: u16 = 100;
const ROWS: u16 = 30;
/// The terminal's key repeat as played here: the first repeat after this, then one
/// every [`INTERVAL`].
const DELAY: Duration = Duration::from_millis(300);
const INTERVAL: Duration = Duration::from_millis(30);

/// A command a device received, as `adrive sim` printed it.
#[derive(Clone, Debug, PartialEq)]
struct Received {
    /// The simulator's clock, seconds.
    at: f64,
    device: String,
    value: String,
}

impl Received {
    fn number(&self) -> f64 {
        self.value.parse().unwrap_or(f64::NAN)
    }
}

/// The simulated Alice, adrive on it and a console on a played terminal.
struct Rig {
    sim: SimProcess,
    /// The console: `adrive` itself, or `adrive attach`.
    console: Reaped,
    /// adrive headless, when the console is attached to it.
    _service: Option<Reaped>,
    term: Player,
    socket: PathBuf,
    _dir: tempfile::TempDir,
}

impl Rig {
    /// adrive with its console embedded, on a terminal that plays `play`, with `env`.
    fn embedded(name: &str, play: Play, env: &[(&str, &str)]) -> Rig {
        let dir = common::tempdir(name);
        let sim = SimProcess::start();
        let socket = dir.path().join("adrive.sock");
        let mut cmd = Command::new(BIN);
        cmd.arg("--config")
            .arg(common::tolerant(vehicle_file(dir.path(), &sim, "")))
            .args(["--listen", "127.0.0.1:0", "--log-dir"])
            .arg(dir.path().join("log"))
            .arg("--socket")
            .arg(&socket);
        Rig::on_terminal(cmd, play, env, sim, None, socket, dir)
    }

    /// adrive headless, and `adrive attach` on a terminal that plays `play`.
    fn attached(name: &str, play: Play) -> Rig {
        let dir = common::tempdir(name);
        let sim = SimProcess::start();
        let socket = dir.path().join("adrive.sock");
        let service = Command::new(BIN)
            .arg("--config")
            .arg(common::tolerant(vehicle_file(dir.path(), &sim, "")))
            .args(["--headless", "--listen", "127.0.0.1:0", "--log-dir"])
            .arg(dir.path().join("log"))
            .arg("--socket")
            .arg(&socket)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let service = Reaped(service);
        common::wait_for("adrive's control socket", || socket.exists());
        let mut cmd = Command::new(BIN);
        cmd.arg("attach").arg("--socket").arg(&socket);
        Rig::on_terminal(cmd, play, &[], sim, Some(service), socket, dir)
    }

    fn on_terminal(
        mut cmd: Command,
        play: Play,
        env: &[(&str, &str)],
        sim: SimProcess,
        service: Option<Reaped>,
        socket: PathBuf,
        dir: tempfile::TempDir,
    ) -> Rig {
        cmd.env("TERM", "xterm-256color")
            .env("XDG_RUNTIME_DIR", dir.path())
            .env_remove("TMUX")
            .env_remove("STY")
            .env_remove("NO_COLOR")
            .envs(env.iter().copied());
        let (child, term) = Player::spawn_playing(&mut cmd, COLS, ROWS, true, play);
        Rig {
            sim,
            console: Reaped(child),
            _service: service,
            term,
            socket,
            _dir: dir,
        }
    }

    /// The screen as the terminal shows it now.
    fn screen(&self) -> String {
        screen(&self.term)
    }

    fn wait_for(&self, what: &str, ok: impl Fn(&str) -> bool) -> String {
        wait_screen(&self.term, what, ok)
    }

    fn keys(&mut self, k: &str) {
        self.term.write(k.as_bytes());
    }

    /// Engage (`E` `y`, again while devices have not all reported), put the gear in
    /// drive (`t`, Ctrl-U, `d`, Enter) and enter teleop (`d`).
    fn teleop_in_drive(&mut self) {
        self.wait_for("every device", |s| {
            ["STEER", "GAS", "BRAKE", "TRANS", "ESTOP", "OBD"]
                .iter()
                .all(|d| s.contains(d))
        });
        let end = Instant::now() + DEADLINE;
        loop {
            self.keys("E");
            self.wait_for("the confirmation", |s| s.contains("Engage?"));
            self.keys("y");
            // The outcome of this `y`: the frame that closed the question says it (a
            // refusal from an earlier try may still be in the log pane).
            let s = self.wait_for("the engage outcome", common::engage_answered);
            if common::engaged_said(&s) {
                break;
            }
            assert!(Instant::now() < end, "could not engage:\n{s}");
            std::thread::sleep(Duration::from_millis(200));
        }
        self.keys("t");
        self.wait_for("the gear edit", |s| s.contains("edit trans command"));
        self.keys("\x15d\r");
        self.wait_for("drive", |s| s.contains("state drive"));
        self.keys("d");
        self.wait_for("teleop", |s| s.contains("TELEOP") && s.contains("DEADMAN"));
    }

    /// One key event: a kitty event where `kitty`, else the legacy bytes (a repeat is a
    /// press again; a release sends nothing).
    fn event(&mut self, key: Key, kind: Kind, kitty: bool) {
        match (kitty, kind) {
            (true, _) => self.term.kitty(key, kind),
            (false, Kind::Release) => {}
            (false, _) => self.term.key(key),
        }
    }

    /// Hold `key` as the terminal's key repeat does: the press, then after [`DELAY`] a
    /// repeat every [`INTERVAL`], `repeats` of them. Returns when the last was sent.
    fn hold(&mut self, key: Key, repeats: u32, kitty: bool) -> Instant {
        let start = Instant::now();
        self.event(key, Kind::Press, kitty);
        let mut last = start;
        for i in 0..repeats {
            sleep_until(start + DELAY + INTERVAL * i);
            self.event(key, Kind::Repeat, kitty);
            last = Instant::now();
        }
        last
    }

    /// Keep repeating `key` every [`INTERVAL`] until `done` holds (a pedal's command
    /// arrived) — the terminal still sending while the test waits.
    fn repeat_until(&mut self, key: Key, kitty: bool, what: &str, done: impl Fn(&Rig) -> bool) {
        let end = Instant::now() + DEADLINE;
        while !done(self) {
            assert!(Instant::now() < end, "waited for {what}");
            self.event(key, Kind::Repeat, kitty);
            std::thread::sleep(INTERVAL);
        }
    }

    /// With `↑` held (its gas level seen at the throttle, `gas`): `←` pressed under it
    /// and repeating, `↑` let go, then `+` (the gas level up) while `←` repeats on, until
    /// the bar shows the new level and the throttle has had 0. Every throttle command
    /// since `gas` was the level or 0: the release, not the level key, ended the gas.
    /// Returns the throttle's 0.
    fn release_up_under_left(&mut self, from: usize, gas: &Received) -> Received {
        self.hold(Key::Left, 3, true);
        self.event(Key::Up, Kind::Release, true);
        self.event(Key::Char('+'), Kind::Press, true);
        self.repeat_until(Key::Left, true, "throttle 0 and the new level", |r| {
            screen(&r.term).contains("gas 0.25 ·")
                && r.received(from)
                    .iter()
                    .any(|x| x.at > gas.at && is("gas", 0.0)(x))
        });
        let got = self.received(from);
        let after: Vec<&Received> = got
            .iter()
            .filter(|x| x.device == "gas" && x.at >= gas.at)
            .collect();
        assert!(
            after.iter().all(|x| is("gas", 0.2)(x) || is("gas", 0.0)(x)),
            "the gas outlived the release: {after:?}"
        );
        self.wait_received(from, "throttle 0", |x| x.at > gas.at && is("gas", 0.0)(x))
    }

    /// Every command the devices received after the simulator's line `from`, in the
    /// devices' order (the simulator's clock).
    fn received(&self, from: usize) -> Vec<Received> {
        let mut out: Vec<Received> = self.sim.lines()[from.min(self.sim.mark())..]
            .iter()
            .filter_map(|l| {
                let w: Vec<&str> = l.split_whitespace().collect();
                if w.get(2) != Some(&"<-") {
                    return None;
                }
                Some(Received {
                    at: w[0].trim_end_matches('s').parse().ok()?,
                    device: w[1].to_string(),
                    value: w[3].to_string(),
                })
            })
            .collect();
        out.sort_by(|a, b| a.at.total_cmp(&b.at));
        out
    }

    /// The first command `device` received after `from` (the simulator's line) that
    /// `ok` takes, waiting for it.
    fn wait_received(&self, from: usize, what: &str, ok: impl Fn(&Received) -> bool) -> Received {
        let end = Instant::now() + DEADLINE;
        loop {
            if let Some(r) = self.received(from).into_iter().find(&ok) {
                return r;
            }
            assert!(
                Instant::now() < end,
                "the devices never received {what}; they received:\n{:?}",
                self.received(from)
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// `adrive ctl status --json`'s gate.
    fn gate(&self) -> serde_json::Value {
        let out = Command::new(BIN)
            .args(["ctl", "status", "--json", "--socket"])
            .arg(&self.socket)
            .output()
            .unwrap();
        assert!(out.status.success(), "{out:?}");
        serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()["gate"].clone()
    }

    /// `q`, and the console ends well.
    fn quit(mut self) {
        self.keys("q");
        let code = common::wait_exit(&mut self.console);
        assert_eq!(code, Some(0), "{}", self.screen());
    }
}

/// The screen a played terminal shows now.
fn screen(term: &Player) -> String {
    common::screen_of(&term.bytes(), COLS, ROWS)
}

fn wait_screen(term: &Player, what: &str, ok: impl Fn(&str) -> bool) -> String {
    common::wait_screen(what, Duration::from_millis(20), || screen(term), ok)
}

fn sleep_until(t: Instant) {
    std::thread::sleep(t.saturating_duration_since(Instant::now()));
}

fn is(device: &'static str, value: f64) -> impl Fn(&Received) -> bool {
    move |r| r.device == device && (r.number() - value).abs() < 1e-6
}

/// The throttle and the brake were never applied at once at the devices: each
/// command's time against the other pedal's last.
fn never_together(got: &[Received]) {
    let (mut gas, mut brake) = (0.0, 0.0);
    for r in got {
        match r.device.as_str() {
            "gas" => gas = r.number(),
            "brake" => brake = r.number(),
            _ => continue,
        }
        assert!(
            !(gas > 0.0 && brake > 0.0),
            "gas {gas} and brake {brake} together at {}s: {got:?}",
            r.at
        );
    }
}

/// In a terminal that reports releases, on Alice in drive: the bar says `hold`; `↑`
/// held gives the gas level and holds it without climbing; `←` pressed under it (the
/// terminal now repeats `←`) keeps `↑` held, and letting `↑` go commands throttle 0 and
/// the hold brake while `←` is still repeating — the release itself, not a repeat that
/// stopped nor the deadman: the gas level raised right after it (`+`) never reaches the
/// throttle.
#[test]
fn releasing_up_commands_throttle_zero_at_once_and_holding_it_never_climbs() {
    let mut r = Rig::embedded("teleop-release", Play::kitty(), &[]);
    r.teleop_in_drive();
    r.wait_for("hold mode", |s| s.contains("TELEOP hold"));
    let from = r.sim.mark();
    r.hold(Key::Up, 40, true);
    let gas = r.wait_received(from, "the gas level", is("gas", 0.2));
    let zero = r.release_up_under_left(from, &gas);
    let hold = r.wait_received(from, "the hold brake", |x| {
        x.at >= zero.at && is("brake", 0.3)(x)
    });
    r.event(Key::Left, Kind::Release, true);
    let got = r.received(from);
    let held: Vec<&Received> = got
        .iter()
        .filter(|x| x.device == "gas" && x.at >= gas.at && x.at < zero.at)
        .collect();
    assert!(
        held.iter().all(|x| is("gas", 0.2)(x)),
        "the gas climbed or dropped while ↑ was held: {held:?}"
    );
    // From the gas on: the brake that stood at 1.0 before `↑` (its refresh may reach
    // the device after the mark) is not the deadman's.
    assert!(
        !got.iter()
            .any(|x| x.at >= gas.at && x.at <= hold.at && is("brake", 1.0)(x)),
        "the full brake between the gas and the hold brake: {got:?}"
    );
    never_together(&got);
    assert_eq!(r.gate()["engaged"], true);
    let s = r.screen();
    assert!(!s.contains("TRIPPED"), "{s}");
    r.quit();
}

/// Press, repeats, then nothing — the release lost with a stalled link: the hold ends
/// by itself (throttle 0, the hold brake) before the deadman's full brake, which still
/// comes a second after the last key and disengages.
#[test]
fn a_release_that_never_arrives_ends_the_gas_before_the_deadman() {
    let mut r = Rig::embedded("teleop-lost", Play::kitty(), &[]);
    r.teleop_in_drive();
    let from = r.sim.mark();
    r.hold(Key::Up, 8, true);
    let gas = r.wait_received(from, "the gas level", is("gas", 0.2));
    let full = r.wait_received(from, "the deadman's full brake", |x| {
        x.at > gas.at && is("brake", 1.0)(x)
    });
    let got = r.received(from);
    let zero = got
        .iter()
        .find(|x| x.at > gas.at && is("gas", 0.0)(x))
        .unwrap_or_else(|| panic!("no throttle 0: {got:?}"));
    assert!(
        zero.at < full.at,
        "throttle 0 only with the deadman: {got:?}"
    );
    assert!(
        got.iter()
            .any(|x| x.at >= zero.at && x.at < full.at && is("brake", 0.3)(x)),
        "no hold brake before the deadman: {got:?}"
    );
    never_together(&got);
    r.wait_for("the deadman tripped", |s| s.contains("DEADMAN TRIPPED"));
    assert_eq!(r.gate()["engaged"], false);
    r.quit();
}

/// The number N in "stops ≤ N ms" on the screen.
fn stops_ms(s: &str) -> Option<u64> {
    let at = s.find("stops ≤ ")? + "stops ≤ ".len();
    s[at..].split_whitespace().next()?.parse().ok()
}

/// Inside tmux (presses only): the bar says `repeat` and the bound it keeps, learnt
/// from a first hold's key repeat; a hold ends when its repeats stop — throttle 0 and
/// the hold brake well before the deadman — and so does a single tap.
#[test]
fn inside_tmux_a_hold_follows_the_learnt_key_repeat_and_a_tap_holds_briefly() {
    let mut r = Rig::embedded(
        "teleop-tmux",
        Play::default(),
        &[("TMUX", "/tmp/tmux-0/default,1234,0")],
    );
    r.teleop_in_drive();
    let s = r.wait_for("repeat mode", |s| s.contains("TELEOP repeat: stops ≤"));
    assert_eq!(stops_ms(&s), Some(150), "nothing learnt yet:\n{s}");
    for (what, repeats) in [("a hold", 30), ("a tap", 0)] {
        let from = r.sim.mark();
        r.hold(Key::Up, repeats, false);
        let gas = r.wait_received(from, "the gas level", is("gas", 0.2));
        let full = r.wait_received(from, "the deadman's full brake", |x| {
            x.at > gas.at && is("brake", 1.0)(x)
        });
        let got = r.received(from);
        let zero = got
            .iter()
            .find(|x| x.at > gas.at && is("gas", 0.0)(x))
            .unwrap_or_else(|| panic!("{what}: no throttle 0: {got:?}"));
        assert!(zero.at < full.at, "{what}: gas until the deadman: {got:?}");
        assert!(
            got.iter()
                .any(|x| x.at >= zero.at && x.at < full.at && is("brake", 0.3)(x)),
            "{what}: no hold brake before the deadman: {got:?}"
        );
        never_together(&got);
        if repeats > 0 {
            // The first hold taught the key repeat: three of its intervals.
            let s = r.wait_for("the learnt bound", |s| stops_ms(s).is_some_and(|n| n < 150));
            let n = stops_ms(&s).unwrap();
            assert!((60..=120).contains(&n), "learnt {n} ms from 30 ms:\n{s}");
        }
        r.wait_for("the deadman tripped", |s| s.contains("DEADMAN TRIPPED"));
        r.keys("E");
        r.wait_for("the confirmation", |s| s.contains("Engage?"));
        r.keys("y");
        let s = r.wait_for("engaged again", common::engage_answered);
        assert!(common::engaged_said(&s), "{s}");
        // The trip is over with the engage: the bar idles until the next key (it
        // said `DEADMAN TRIPPED` until then, and the next hold's trip was not seen).
        r.wait_for("the deadman idle again", |s| {
            s.contains("DEADMAN idle") && !s.contains("DEADMAN TRIPPED")
        });
    }
    r.quit();
}

/// Gas and brake never together, and never gas without its key: `↓` pressed while `↑`
/// is held takes the gas away and brakes at the brake level, `↑` held under it gives no
/// gas, letting `↓` go is the hold brake; then `←` held alone moves the steering and
/// gives no gas.
#[test]
fn the_brake_key_wins_and_no_pedal_key_held_is_never_gas() {
    let mut r = Rig::embedded("teleop-pedals", Play::kitty(), &[]);
    r.teleop_in_drive();
    let from = r.sim.mark();
    r.hold(Key::Up, 10, true);
    let gas = r.wait_received(from, "the gas level", is("gas", 0.2));
    r.hold(Key::Down, 10, true);
    let brake = r.wait_received(from, "the brake level", |x| {
        x.at > gas.at && is("brake", 0.6)(x)
    });
    r.event(Key::Down, Kind::Release, true);
    let hold = r.wait_received(from, "the hold brake", |x| {
        x.at > brake.at && is("brake", 0.3)(x)
    });
    r.event(Key::Up, Kind::Release, true);
    r.hold(Key::Left, 20, true);
    r.event(Key::Left, Kind::Release, true);
    let steered = r.wait_received(from, "the steering moved left", |x| {
        x.at > hold.at && x.device == "steer" && x.number() < -0.05
    });
    let got = r.received(from);
    never_together(&got);
    let late_gas: Vec<&Received> = got
        .iter()
        .filter(|x| x.device == "gas" && x.at > brake.at && x.number() > 0.0)
        .collect();
    assert!(
        late_gas.is_empty(),
        "gas without ↑ alone held: {late_gas:?}"
    );
    assert!(steered.at > hold.at);
    assert_eq!(r.gate()["engaged"], true);
    r.quit();
}

/// The bar names the mode, `m` forces step mode (the bar says `step`, `↑` steps as it
/// always did) and back; help's key-event viewer (`?` `e`) lists the last key events
/// with their kinds.
#[test]
fn the_bar_names_the_mode_step_is_forced_and_help_shows_key_events() {
    let mut r = Rig::embedded("teleop-modes", Play::kitty(), &[]);
    r.teleop_in_drive();
    r.wait_for("hold mode", |s| s.contains("TELEOP hold"));
    r.keys("m");
    r.wait_for("step mode", |s| s.contains("TELEOP step"));
    r.keys("m");
    r.wait_for("hold mode again", |s| s.contains("TELEOP hold"));
    r.keys("?");
    r.wait_for("help", |s| s.contains("help — keys"));
    r.keys("e");
    r.wait_for("the key-event viewer", |s| {
        s.contains("KEY EVENTS") && s.contains("reports presses, repeats and releases")
    });
    r.hold(Key::Left, 2, true);
    r.event(Key::Left, Kind::Release, true);
    let s = r.wait_for("the release among the events", |s| {
        s.lines().any(|l| l.contains('←') && l.contains("release"))
    });
    for kind in ["press", "repeat", "release"] {
        assert!(
            s.lines().any(|l| l.contains('←') && l.contains(kind)),
            "{kind}:\n{s}"
        );
    }
    r.keys("\x1b[27u");
    r.wait_for("teleop again", |s| s.contains("TELEOP hold"));
    r.quit();
}

/// `adrive attach` holds to drive from its own terminal: its header names how that
/// terminal's keys drive (`keys hold`), and a release commands throttle 0 on the
/// vehicle; an attached legacy terminal says `keys repeat`.
#[test]
fn an_attached_console_holds_to_drive_and_names_its_own_terminal_s_keys() {
    let mut r = Rig::attached("teleop-attach", Play::kitty());
    r.wait_for("its keys", |s| s.contains("│ keys hold │"));
    r.teleop_in_drive();
    let from = r.sim.mark();
    r.hold(Key::Up, 20, true);
    let gas = r.wait_received(from, "the gas level", is("gas", 0.2));
    r.release_up_under_left(from, &gas);
    r.event(Key::Left, Kind::Release, true);
    never_together(&r.received(from));
    // A second console, on a legacy terminal, names its own keys.
    let mut cmd = Command::new(BIN);
    cmd.arg("attach")
        .arg("--socket")
        .arg(&r.socket)
        .env("TERM", "xterm-256color")
        .env_remove("TMUX")
        .env_remove("STY");
    let (child, term) = Player::spawn_playing(&mut cmd, COLS, ROWS, true, Play::default());
    let _watcher = Reaped(child);
    wait_screen(&term, "a legacy terminal's keys", |s| {
        s.contains("│ WATCHING │ keys repeat ≤150ms │")
    });
    r.quit();
}
