//! End to end: the real binary with `--sim` in a real pseudo-terminal, driven by keys.
//! The screen is rebuilt from the bytes the console writes with a terminal emulator
//! (`vt100`), so checks read what an operator would see. Every wait has a generous
//! deadline and polls; none is a fixed sleep.

mod common;

use common::pty::{attach, openpty};
use common::terminal_player::{Answer, Key, Kind, Play, Player};
use common::{engage_answered, DEADLINE};
use std::os::fd::AsRawFd;
use std::os::fd::OwnedFd;
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_adrive");
const COLS: u16 = 100;
const ROWS: u16 = 30;
/// In `extra`: the vehicle file [`common::tolerant_alice`] writes.
const TOLERANT: &str = "<tolerant alice>";

/// The console in a pseudo-terminal, with everything it wrote so far.
struct Console {
    child: Child,
    /// The terminal, played (it answers what adrive asks of it).
    term: Player,
    slave: OwnedFd,
    log_dir: PathBuf,
    /// The terminal's columns and rows.
    size: (u16, u16),
}

impl Console {
    fn start(name: &str, extra: &[&str]) -> Console {
        Console::start_sized(name, extra, (COLS, ROWS))
    }

    fn start_sized(name: &str, extra: &[&str], size: (u16, u16)) -> Console {
        Console::start_playing(name, extra, size, Play::default())
    }

    /// The console on a terminal that plays `play` (see tests/common/terminal_player.rs).
    fn start_playing(name: &str, extra: &[&str], size: (u16, u16), play: Play) -> Console {
        Console::start_in(name, extra, size, play, &[])
    }

    /// On [`common::tolerant_alice`] (`--config`), for tests that hold the vehicle
    /// engaged for seconds.
    fn start_tolerant(name: &str, play: Play) -> Console {
        Console::start_in(name, &["--config", TOLERANT], (COLS, ROWS), play, &[])
    }

    /// The same, with `env` in its environment.
    fn start_in(
        name: &str,
        extra: &[&str],
        size: (u16, u16),
        play: Play,
        env: &[(&str, &str)],
    ) -> Console {
        Console::spawn(name, extra, size, play, env, false)
    }

    /// On [`common::tolerant_alice`] at `size`, working in its log directory (where a
    /// characterization from the bench writes, and which the test removes).
    fn start_working(name: &str, size: (u16, u16)) -> Console {
        Console::spawn(
            name,
            &["--config", TOLERANT],
            size,
            Play::default(),
            &[],
            true,
        )
    }

    /// `in_log_dir`: adrive's working directory is its log directory.
    fn spawn(
        name: &str,
        extra: &[&str],
        size: (u16, u16),
        play: Play,
        env: &[(&str, &str)],
        in_log_dir: bool,
    ) -> Console {
        let log_dir =
            std::env::temp_dir().join(format!("adrive-e2e-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&log_dir);
        std::fs::create_dir_all(&log_dir).unwrap();
        // Where `extra` names the tolerant vehicle, it is written in the log directory.
        let tolerant = extra
            .contains(&TOLERANT)
            .then(|| common::tolerant_alice(&log_dir));
        let extra: Vec<&str> = extra
            .iter()
            .map(|a| match (*a, &tolerant) {
                (TOLERANT, Some(file)) => file.to_str().unwrap(),
                (a, _) => a,
            })
            .collect();
        let (master, slave) = openpty(size.0, size.1);
        let mut cmd = Command::new(BIN);
        cmd.arg("--sim")
            // Tests run in parallel: each takes its own ephemeral command port.
            .args(["--listen", "127.0.0.1:0"])
            .arg("--log-dir")
            .arg(&log_dir)
            .env("XDG_RUNTIME_DIR", &log_dir)
            .env("TMPDIR", &log_dir)
            .env_remove("RUNTIME_DIRECTORY")
            .env_remove("TMUX")
            .env_remove("STY")
            .args(extra)
            .env("TERM", "xterm-256color")
            .env_remove("NO_COLOR")
            .envs(env.iter().copied());
        if in_log_dir {
            cmd.current_dir(&log_dir);
        }
        attach(&mut cmd, &slave, true);
        let child = cmd.spawn().expect("start adrive");
        let term = Player::start(master, play);
        Console {
            child,
            term,
            slave,
            log_dir,
            size,
        }
    }

    fn bytes(&self) -> Vec<u8> {
        self.term.bytes()
    }

    /// The screen as the terminal shows it now.
    fn screen(&self) -> String {
        common::screen_of(&self.bytes(), self.size.0, self.size.1)
    }

    fn wait_for(&self, what: &str, ok: impl Fn(&str) -> bool) -> String {
        common::wait_screen(what, Duration::from_millis(20), || self.screen(), ok)
    }

    /// Resize the terminal as a terminal window does: the kernel signals SIGWINCH.
    fn resize(&self, cols: u16, rows: u16) {
        self.term.resize(cols, rows);
    }

    fn keys(&mut self, k: &str) {
        self.term.write(k.as_bytes());
    }

    /// Wait for adrive to exit; its status, once the terminal read all it wrote.
    fn wait_exit(&mut self) -> ExitStatus {
        let end = Instant::now() + DEADLINE;
        loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                self.term.read_to_end();
                return s;
            }
            if Instant::now() > end {
                let _ = self.child.kill();
                panic!("adrive did not exit; screen:\n{}", self.screen());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn log(&self) -> String {
        let mut all = String::new();
        for e in std::fs::read_dir(&self.log_dir).unwrap() {
            all.push_str(&std::fs::read_to_string(e.unwrap().path()).unwrap_or_default());
        }
        all
    }

    /// Raw mode is off again: canonical input and echo, as a shell expects.
    #[allow(unsafe_code)]
    fn cooked(&self) -> bool {
        // SAFETY: a zeroed termios is a valid out-parameter.
        let mut t: libc::termios = unsafe { std::mem::zeroed() };
        // SAFETY: tcgetattr fills the struct from a valid terminal fd.
        let r = unsafe { libc::tcgetattr(self.slave.as_raw_fd(), &mut t) };
        assert_eq!(r, 0);
        t.c_lflag & libc::ICANON != 0 && t.c_lflag & libc::ECHO != 0
    }

    /// The steering position on screen (the first "position" is steering's).
    fn steer_position(screen: &str) -> Option<f64> {
        let at = screen.find("position ")? + "position ".len();
        screen[at..].split_whitespace().next()?.parse().ok()
    }

    /// The vehicle as `adrive ctl status --json` reports it over the control socket:
    /// what the engine did, whatever the screen shows.
    fn status(&self) -> serde_json::Value {
        let out = Command::new(BIN)
            .args(["ctl", "status", "--json", "--socket"])
            .arg(self.log_dir.join("adrive/adrive.sock"))
            .output()
            .expect("adrive ctl runs");
        assert!(out.status.success(), "{out:?}");
        serde_json::from_slice(&out.stdout).expect("a snapshot")
    }

    /// Device `name`'s command as the engine has it (`null` before any).
    fn commanded(&self, name: &str) -> serde_json::Value {
        let snap = self.status();
        let d = snap["devices"]
            .as_array()
            .unwrap()
            .iter()
            .find(|d| d["name"] == name)
            .unwrap_or_else(|| panic!("no {name} in {snap}"));
        d["commanded"].clone()
    }

    /// Engage, retrying while devices have not all reported yet.
    fn engage(&mut self) {
        self.wait_for("the main screen", |s| {
            s.contains("STEER") && s.contains("OBD")
        });
        self.engage_now();
    }

    /// Engage from the main screen, retrying while devices have not all reported yet.
    fn engage_now(&mut self) {
        let end = Instant::now() + DEADLINE;
        loop {
            self.keys("E");
            self.wait_for("the confirmation", |s| s.contains("Engage?"));
            self.keys("y");
            // The outcome of this `y`: the frame that closed the question says it (a
            // refusal still on the screen from the last try is not it).
            let s = self.wait_for("the engage outcome", engage_answered);
            if common::engaged_said(&s) {
                self.wait_for("the header", |s| s.contains("│ ENGAGED"));
                return;
            }
            assert!(Instant::now() < end, "could not engage:\n{s}");
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// Enter on the command under the cursor, `value`, Enter; then wait for device
    /// `name`'s row to show `shown` as command and measurement.
    fn command(&mut self, name: &str, value: &str, shown: &str) {
        self.keys("\r");
        self.wait_for("the command edit", |s| {
            s.contains(&format!("edit {name} command"))
        });
        self.keys(&format!("\x15{value}\r"));
        self.wait_for(&format!("{name} at {value}"), |s| {
            cmd_meas(s, name) == shown
        });
    }

    /// Engage, then `t`, Ctrl-U, `d`, Enter: drive.
    fn engage_in_drive(&mut self) {
        self.engage();
        self.keys("t");
        self.wait_for("the gear edit", |s| s.contains("edit trans command"));
        self.keys("\x15d\r");
        self.wait_for("drive", |s| s.contains("state drive"));
    }
}

impl Drop for Console {
    fn drop(&mut self) {
        // SIGTERM first: the simulator in the console removes its directory of links.
        common::stop(&mut self.child);
        let _ = std::fs::remove_dir_all(&self.log_dir);
    }
}

fn left_alternate_screen(bytes: &[u8]) -> bool {
    bytes.windows(8).any(|w| w == b"\x1b[?1049l")
}

/// What the terminal shows once the console's screen is gone: written after it left
/// the alternate screen.
fn after_the_screen(bytes: &[u8]) -> String {
    let text = String::from_utf8_lossy(bytes);
    text.rsplit("\x1b[?1049l")
        .next()
        .unwrap_or_default()
        .to_string()
}

#[test]
fn keys_engage_and_steer_and_q_leaves_the_terminal_and_vehicle_safe() {
    // Held engaged to prove the console, not device timing: on the tolerant Alice.
    let mut c = Console::start("steer", &["--config", TOLERANT]);
    c.engage();
    // Sparrow's `s`: edit the steering command in place.
    c.keys("s");
    c.wait_for("the steering edit", |s| s.contains("edit steer command"));
    c.keys("0.5\r");
    c.wait_for("the command on screen", |s| s.contains("cmd 0.500"));
    // The simulated steering moves toward it and reports it back.
    let s = c.wait_for("steering near 0.5", |s| {
        Console::steer_position(s).is_some_and(|p| p > 0.45)
    });
    assert!(s.contains("meas 0.5") || s.contains("meas 0.4"), "{s}");
    // Disengage, and again: the second is answered as the network and `adrive ctl`
    // answer it.
    c.keys("D");
    c.wait_for("the confirmation", |s| s.contains("Disengage?"));
    c.keys("y");
    c.wait_for("disengaged", |s| s.contains("DISENGAGED"));
    c.keys("D");
    c.wait_for("the confirmation", |s| s.contains("Disengage?"));
    c.keys("y");
    c.wait_for("the same answer as every front end's", |s| {
        s.contains("already disengaged")
    });
    c.keys("q");
    let status = c.wait_exit();
    assert!(status.success(), "{status:?}");
    assert!(left_alternate_screen(&c.bytes()), "no ESC[?1049l written");
    assert!(c.cooked(), "the terminal was left in raw mode");
    let log = c.log();
    assert!(log.contains("stopping: operator quit"), "{log}");
    assert!(log.contains("safe state acknowledged"), "{log}");
    // The terminal says so too (it said nothing: the safe state was in the log only).
    let said = after_the_screen(&c.bytes());
    assert!(
        said.contains(
            "adrive: stopped (operator quit); safe state acknowledged: gas 0.000, brake 1.000; log in "
        ),
        "{said:?}"
    );
}

#[test]
fn ctrl_c_stops_safely_and_restores_the_terminal() {
    let mut c = Console::start("ctrlc", &[]);
    c.wait_for("the main screen", |s| s.contains("STEER"));
    c.keys("\x03");
    let status = c.wait_exit();
    assert!(status.success(), "{status:?}");
    assert!(left_alternate_screen(&c.bytes()));
    assert!(c.cooked());
    let log = c.log();
    assert!(log.contains("stopping: SIGINT"), "{log}");
    assert!(log.contains("safe state acknowledged"), "{log}");
}

#[allow(unsafe_code)]
#[test]
fn sigterm_stops_safely_and_restores_the_terminal() {
    let mut c = Console::start("term", &[]);
    c.wait_for("the main screen", |s| s.contains("STEER"));
    // SAFETY: signalling our own child.
    unsafe { libc::kill(c.child.id() as i32, libc::SIGTERM) };
    let status = c.wait_exit();
    assert!(status.success(), "{status:?}");
    assert!(left_alternate_screen(&c.bytes()));
    assert!(c.cooked());
    assert!(c.log().contains("safe state acknowledged"));
}

/// An SSH session dropping: SIGHUP ends the run as a hang-up (status 129), the safe
/// state first, then the terminal as it was.
#[allow(unsafe_code)]
#[test]
fn sighup_stops_safely_and_restores_the_terminal() {
    let mut c = Console::start("hup", &[]);
    c.wait_for("the main screen", |s| s.contains("STEER"));
    // SAFETY: signalling our own child.
    unsafe { libc::kill(c.child.id() as i32, libc::SIGHUP) };
    let status = c.wait_exit();
    assert_eq!(status.code(), Some(129), "{status:?}");
    assert!(left_alternate_screen(&c.bytes()), "no ESC[?1049l written");
    assert!(c.cooked(), "the terminal was left in raw mode");
    let log = c.log();
    assert!(log.contains("stopping: SIGHUP"), "{log}");
    assert!(log.contains("safe state acknowledged"), "{log}");
}

/// A panic in another thread (the supervisor's, on its first turn) ends the run like
/// any other exit: safe state, terminal restored, status 101.
#[test]
fn a_panic_in_the_supervisor_thread_stops_safely_and_restores_the_terminal() {
    let mut c = Console::start("panic-sup", &["--inject-panic", "supervisor"]);
    let status = c.wait_exit();
    assert_eq!(status.code(), Some(101), "{status:?}");
    assert!(left_alternate_screen(&c.bytes()), "no ESC[?1049l written");
    assert!(c.cooked(), "the terminal was left in raw mode");
    let log = c.log();
    assert!(
        log.contains("injected panic (--inject-panic supervisor)"),
        "{log}"
    );
    assert!(log.contains("stopping: panic: thread supervisor"), "{log}");
    assert!(log.contains("safe state acknowledged"), "{log}");
}

/// A panic in the console's own (main) thread while it holds the terminal: the panic
/// hook restores the terminal before anything is printed, and unwinding drops the
/// engine, which commands the safe state.
#[test]
fn a_panic_in_the_main_thread_restores_the_terminal_and_the_engine_stops_safely() {
    let mut c = Console::start("panic-main", &["--inject-panic", "main"]);
    c.wait_for("the main screen", |s| s.contains("STEER"));
    let status = c.wait_exit();
    assert_eq!(status.code(), Some(101), "{status:?}");
    let bytes = c.bytes();
    assert!(left_alternate_screen(&bytes), "no ESC[?1049l written");
    // The panic message comes after the restore, on the normal screen.
    let restored = bytes.windows(8).position(|w| w == b"\x1b[?1049l").unwrap();
    let text = String::from_utf8_lossy(&bytes[restored..]);
    assert!(text.contains("injected panic"), "{text}");
    assert!(c.cooked(), "the terminal was left in raw mode");
    let log = c.log();
    assert!(log.contains("engine dropped without shutdown"), "{log}");
    assert!(log.contains("safe state acknowledged"), "{log}");
}

/// The bench's simulator keys: the e-stop to pause (the supervisor's fault, the
/// vehicle disengaged) and back to run; steering silenced (its fault, in red) and
/// cleared.
#[test]
fn bench_keys_inject_faults_that_the_console_shows_and_clear() {
    let mut c = Console::start("bench-faults", &[]);
    c.engage();
    c.keys("x");
    c.wait_for("the bench", |s| s.contains("steer raw traffic"));
    c.keys("p");
    let s = c.wait_for("the e-stop pause fault", |s| {
        s.contains("FAULT estop_pause") && s.contains("DISENGAGED")
    });
    assert!(
        s.contains("e-stop pause ·"),
        "the simulator box says so:\n{s}"
    );
    c.keys("r");
    c.wait_for("the fault gone", |s| {
        !s.contains("estop_pause") && s.contains("e-stop run ·")
    });
    c.keys("s");
    c.wait_for("steering silent", |s| {
        s.contains("faults silent") && s.contains("FAULT steer silent")
    });
    c.keys("x");
    c.wait_for("steering answering again", |s| {
        s.contains("faults none") && !s.contains("FAULT steer")
    });
    // Back on the main screen, nothing is left faulty.
    c.keys("\x1b");
    // Wait for the mode itself: sent too soon after Esc, `q` would arrive with it as
    // one `ESC q` sequence, which a terminal reads as Alt-q.
    c.wait_for("the main screen", |s| {
        s.contains("│ MAIN │") && s.contains("faults none") && !s.contains("FAULTY")
    });
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// A driver's hand from the bench (`o`) on the steering of an engaged vehicle: the
/// supervisor names the override and the vehicle is handed over; `C` is refused in
/// the message line while the hand is on, `o` lets go, `C` clears it, and engaging
/// works again.
#[test]
fn the_override_key_hands_over_and_the_clear_key_clears_once_let_go() {
    let mut c = Console::start("override", &[]);
    c.engage();
    c.keys("x");
    c.wait_for("the bench", |s| s.contains("steer raw traffic"));
    c.keys("o");
    c.wait_for("the override", |s| {
        s.contains("a hand pushes it toward 1")
            && s.contains("driver's hand on it")
            && s.contains("DISENGAGED")
    });
    c.keys("C");
    c.wait_for("the refusal", |s| {
        s.contains("override not cleared: the driver is still moving steer")
    });
    c.keys("o");
    c.wait_for("the hand off", |s| {
        s.contains("the hand lets go") && s.contains("let go: clear to engage again")
    });
    c.keys("C");
    c.wait_for("the override cleared", |s| {
        s.contains("override cleared on steer: engage when ready")
    });
    c.keys("\x1b");
    c.wait_for("the main screen", |s| s.contains("│ MAIN │"));
    c.engage_now();
    c.keys("q");
    assert!(c.wait_exit().success());
    let log = c.log();
    assert!(log.contains("override cleared: steer"), "{log}");
}

/// An engine stall injected from the bench while in drive: the supervisor's
/// engine_stall procedure runs step by step on screen and reports its outcome.
#[test]
fn an_engine_stall_from_the_bench_is_recovered_step_by_step_on_screen() {
    let mut c = Console::start("stall", &[]);
    c.engage_in_drive();
    c.keys("x");
    c.wait_for("the bench", |s| s.contains("raw traffic"));
    c.keys("K");
    c.wait_for("the stall recovery", |s| {
        s.contains("RECOVERY engine_stall") && s.contains("(try 1/3)")
    });
    c.keys("\x1b");
    c.wait_for("the outcome", |s| {
        s.contains("supervisor: recovery engine_stall done")
    });
    c.wait_for("the engine running in drive", |s| {
        s.contains("│ MAIN │")
            && s.contains("state drive")
            && (s.contains("run 1") || s.contains("running 1"))
    });
    c.keys("q");
    assert!(c.wait_exit().success());
    let log = c.log();
    for step in ["gas off", "brake", "park", "starter", "back in drive"] {
        assert!(log.contains(step), "{step} not logged:\n{log}");
    }
}

#[test]
fn a_resize_redraws_and_a_small_window_gets_a_message() {
    let mut c = Console::start("resize", &[]);
    c.wait_for("the main screen", |s| s.contains("STEER"));
    c.resize(60, 20);
    c.wait_for("the too-small message", |s| s.contains("at least 80×22"));
    c.resize(COLS, ROWS);
    c.wait_for("the screen again", |s| {
        s.contains("STEER") && !s.contains("at least")
    });
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// The defect: in a window smaller than 80×22 the console drew only "needs 80×22",
/// yet every key still acted — `E` `y` engaged and `s 0.7 Enter` moved the steering
/// with nothing on the screen. Below the minimum size only STOP and quit act; every
/// other key is refused in words on the small screen, and nothing reaches the vehicle
/// (read back over the control socket). Grown again, the keys act again.
#[test]
fn a_window_below_the_minimum_size_drives_nothing_but_stop_and_quit() {
    // Held engaged to prove the console, not device timing: on the tolerant Alice.
    let mut c = Console::start("small", &["--config", TOLERANT]);
    c.engage();
    c.resize(60, 20);
    c.wait_for("the too-small message", |s| s.contains("at least 80×22"));
    // Engaged: a steering command would be taken. Refused, with the reason on screen.
    c.keys("s0.7\r");
    c.wait_for("the edit refused", |s| {
        s.contains("edit refused: the window is 60×20")
    });
    assert_ne!(
        c.commanded("steer"),
        serde_json::json!(0.7),
        "the steering moved"
    );
    // STOP acts, on the small screen too.
    c.keys(" ");
    c.wait_for("the stop", |s| s.contains("STOP: disengaged"));
    let gate = c.status()["gate"].clone();
    assert_eq!(gate["engaged"], false, "{gate}");
    assert!(
        gate["reason"]
            .as_str()
            .unwrap()
            .contains("stop from console"),
        "{gate}"
    );
    // `E` `y` engages nothing; `x` after them is the sentinel that both were read.
    c.keys("E");
    c.wait_for("engage refused", |s| s.contains("engage refused"));
    c.keys("yx");
    c.wait_for("the bench refused", |s| s.contains("bench refused"));
    assert_eq!(c.status()["gate"]["engaged"], false);
    // Grown again, the same keys act.
    c.resize(COLS, ROWS);
    c.wait_for("the screen again", |s| {
        s.contains("STEER") && !s.contains("at least")
    });
    c.engage_now();
    assert_eq!(c.status()["gate"]["engaged"], true);
    // `q` quits from the small screen, the safe state first.
    c.resize(60, 20);
    c.wait_for("the too-small message", |s| s.contains("at least 80×22"));
    c.keys("q");
    assert!(c.wait_exit().success());
    let log = c.log();
    assert!(log.contains("stopping: operator quit"), "{log}");
    assert!(log.contains("safe state acknowledged"), "{log}");
}

/// A question asked at full size cannot be answered once the window shrinks below
/// the minimum: the dialog is no longer on the screen. Grown again, it is, and `y`
/// answers it.
#[test]
fn a_question_cannot_be_answered_once_the_window_hides_it() {
    let mut c = Console::start("small-dialog", &[]);
    c.wait_for("the main screen", |s| s.contains("│ MAIN │"));
    // Every device has reported: nothing but the screen stands in the way of engaging.
    common::wait_for("every device to report", || {
        c.status()["gate"]["blockers"] == serde_json::json!([])
    });
    c.keys("E");
    c.wait_for("the confirmation", |s| s.contains("Engage?"));
    c.resize(60, 20);
    c.wait_for("the too-small message", |s| s.contains("at least 80×22"));
    c.keys("y");
    c.wait_for("the answer refused", |s| {
        s.contains("yes refused: the window is 60×20")
    });
    assert_eq!(c.status()["gate"]["engaged"], false, "answered unseen");
    c.resize(COLS, ROWS);
    c.wait_for("the question again", |s| s.contains("Engage?"));
    c.keys("y");
    c.wait_for("engaged", |s| s.contains("│ ENGAGED"));
    assert_eq!(c.status()["gate"]["engaged"], true);
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// Every row of `screen` that reaches the right edge ends in a border or the mark of a
/// cut (`…`, or the `)` that closes it): nothing is cut off silently.
fn assert_cuts_marked(screen: &str) {
    for (y, row) in screen.lines().enumerate() {
        let chars: Vec<char> = row.trim_end().chars().collect();
        if chars.len() < usize::from(COLS) {
            continue;
        }
        let last = chars[usize::from(COLS) - 1];
        assert!(
            "…)│┐┘┤─".contains(last),
            "row {y} is cut without a mark:\n{row}\n\n{screen}"
        );
    }
}

/// The defect: on the bench at 100×30 with simulator faults on, the panel's title and
/// the fault strip were cut mid-word at the edge, and a keymap's warning was cut at
/// 100 columns in the log pane. Cut at a word, marked with `…`.
#[test]
fn at_100x30_text_cut_to_fit_is_marked_on_the_main_screen_and_the_bench() {
    let dir = common::tempdir("e2e-cut");
    let keymap = dir.path().join("my.toml");
    std::fs::write(
        &keymap,
        "[main]\nkeymap = [\n    { on = \"<Space>\", run = \"none\" },\n]\n",
    )
    .unwrap();
    let mut c = Console::start("cut", &["--keymap", keymap.to_str().unwrap()]);
    // The warning starts with the keymap's path, in the temporary directory: how much
    // of the rest fits depends on that.
    let s = c.wait_for("the keymap's warning", |s| {
        s.contains("WARN  keymap:") && s.contains("OBD")
    });
    let warning = s.lines().find(|l| l.contains("WARN  keymap:")).unwrap();
    let warning = warning.trim_end();
    assert!(warning.ends_with('…'), "{warning}");
    assert_cuts_marked(&s);
    c.keys("x");
    c.wait_for("the bench", |s| s.contains("steer raw traffic"));
    c.keys("l");
    c.wait_for("slow", |s| s.contains("faults slow 150ms"));
    c.keys("c");
    c.wait_for("corrupt", |s| s.contains("faults corrupt, slow 150ms"));
    c.keys("s");
    let s = c.wait_for("the faults and the strip", |s| {
        s.contains("faults silent, corrupt, slow 150ms") && s.contains("FAULT steer")
    });
    let title = s.lines().find(|l| l.starts_with("┌STEER")).unwrap();
    assert!(title.contains(" FAULT sim…─"), "{title}");
    assert_cuts_marked(&s);
    c.keys("x");
    c.wait_for("the faults cleared", |s| s.contains("faults none"));
    c.keys("\x1b");
    c.wait_for("the main screen", |s| s.contains("│ MAIN │"));
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// Incident: after the window was resized, quitting left the console's top lines in
/// the terminal's scrollback: tmux, leaving an alternate screen that has grown, shrinks
/// it back to the old size first and pushes its top lines into the history, unless
/// they are blank. The console leaves the alternate screen blank.
#[test]
fn quitting_after_a_resize_leaves_the_alternate_screen_blank() {
    let mut c = Console::start("resize-quit", &[]);
    c.wait_for("the main screen", |s| s.contains("STEER"));
    let clears = |b: &[u8]| b.windows(4).filter(|w| w == b"\x1b[2J").count();
    let before = clears(&c.bytes());
    c.resize(120, 40);
    // The console clears the screen and draws it again at the new size.
    let end = Instant::now() + DEADLINE;
    while clears(&c.bytes()) == before {
        assert!(Instant::now() < end, "no redraw after the resize");
        std::thread::sleep(Duration::from_millis(20));
    }
    c.keys("q");
    assert!(c.wait_exit().success());
    let bytes = c.bytes();
    let leave = bytes
        .windows(8)
        .rposition(|w| w == b"\x1b[?1049l")
        .expect("ESC[?1049l written");
    let nz = |n: u16| std::num::NonZeroU16::new(n).unwrap();
    let mut screen = vt100::Parser::new(nz(40), nz(120), 0);
    screen.process(&bytes[..leave]);
    let left = screen.screen().contents();
    assert!(
        left.trim().is_empty(),
        "left on the alternate screen:\n{left}"
    );
}

/// Incident: after the terminal was resized, the next key stayed unread until another
/// key came (crossterm's edge-triggered source returned the resize and dropped the
/// keyboard's readiness), so a STOP pressed once did nothing. Keys have been read
/// before the resize, as at any console in use.
#[test]
fn a_stop_pressed_after_a_resize_stops_at_once() {
    // Held engaged to prove the console, not device timing: on the tolerant Alice.
    let mut c = Console::start("stop-after-resize", &["--config", TOLERANT]);
    c.engage();
    c.resize(60, 20);
    c.wait_for("the too-small message", |s| s.contains("at least 80×22"));
    c.resize(COLS, ROWS);
    c.wait_for("the screen again", |s| {
        s.contains("STEER") && !s.contains("at least")
    });
    c.keys(" ");
    c.wait_for("the stop, from one key", |s| {
        s.contains("STOP: disengaged") && s.contains("│ DISENGAGED")
    });
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// The number on screen right after `label`.
fn number_after(screen: &str, label: &str) -> Option<f64> {
    let at = screen.find(label)? + label.len();
    screen[at..].split_whitespace().next()?.parse().ok()
}

/// In `adrive --sim`: `E` `y`, then `t` Ctrl-U `d` Enter, then `c` Ctrl-U `0.3` Enter
/// left gas and brake both at 0 and the vehicle standing: the gas waited for a second
/// `accel`. And `accel 0.300` stayed on screen after STOP. One `accel` gives gas now,
/// and STOP clears it.
#[test]
fn one_accel_from_braking_gives_gas_and_stop_clears_it() {
    // Held engaged to prove the console, not device timing: on the tolerant Alice.
    let mut c = Console::start("accel", &["--config", TOLERANT]);
    c.engage_in_drive();
    c.keys("c");
    c.wait_for("the accel edit", |s| s.contains("edit accel"));
    c.keys("\x150.3\r");
    c.wait_for("the brake released and the gas given", |s| {
        s.contains("BRAKE 0…1 cmd 0.000")
            && number_after(s, "GAS 0…1 cmd 0.300 meas ").is_some_and(|g| g > 0.1)
            && s.contains("accel 0.300")
    });
    c.keys(" ");
    c.wait_for("STOP: full brake, no gas, no accel shown", |s| {
        s.contains("BRAKE 0…1 cmd 1.000")
            && s.contains("GAS 0…1 cmd 0.000")
            && s.contains("accel -")
    });
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// A device's row in the list of many devices: its name and the values after it
/// (command, measurement, age, delay p50 where it has room, error code).
fn row(screen: &str, name: &str) -> Vec<String> {
    let key = format!("{name} ");
    screen
        .lines()
        .find_map(|l| l.find(&key).map(|at| l[at..].to_string()))
        .map(|r| r.split_whitespace().map(String::from).collect())
        .unwrap_or_default()
}

/// The command and the measurement in a device's row: `0.500 0.500`.
fn cmd_meas(screen: &str, name: &str) -> String {
    row(screen, name)
        .get(1..3)
        .map(|v| v.join(" "))
        .unwrap_or_default()
}

/// The tractor's 32 devices at 80×24, as an operator runs it: a row each, then `/`
/// jumps to a device by name, Enter edits its command from there, and the simulated
/// device reports it back; the name prompt takes Space as STOP.
#[test]
fn thirty_two_devices_at_80x24_jump_by_name_and_command_one() {
    let mut c = Console::start_sized("tractor", &["--config", "vehicles/tractor.toml"], (80, 24));
    let s = c.wait_for("a row for every device", |s| {
        s.contains("device             cmd     meas   age e") && s.contains("tyre_pressure ")
    });
    // Names and states whole (it read `parking_br… appli…`).
    c.wait_for("the parking brake's state whole", |s| {
        row(s, "parking_brake")
            .get(2)
            .is_some_and(|m| ["applied", "released"].contains(&m.as_str()))
    });
    for name in [
        "steer",
        "engine",
        "hitch_load",
        "wiper",
        "turn_signal",
        "gnss",
    ] {
        assert_eq!(row(&s, name).first().map(String::as_str), Some(name), "{s}");
    }
    c.engage_now();
    // Each key of the name moves the cursor; the prompt says what it found.
    c.keys("/wip");
    c.wait_for("the wiper found", |s| {
        s.contains("/wip▏  wiper 1 of 1") && s.contains("WIPER 0…1 cmd")
    });
    c.keys("\r");
    c.wait_for("the prompt closed", |s| !s.contains("/wip▏"));
    // From there, Enter edits the command; the simulated wiper reports it back.
    c.command("wiper", "0.5", "0.500 0.500");
    // A state device, found by a part of its name.
    c.keys("/sig\r");
    c.wait_for("the turn signal found", |s| {
        s.contains("TURN_SIGNAL O/L/R/H")
    });
    c.command("turn_signal", "left", "left left");
    // Space in the name prompt is STOP.
    c.keys("/h");
    c.wait_for("the prompt", |s| s.contains("/h▏"));
    c.keys(" ");
    c.wait_for("the stop", |s| {
        s.contains("STOP: disengaged") && s.contains("│ DISENGAGED") && !s.contains("/h▏")
    });
    c.keys("q");
    assert!(c.wait_exit().success());
    assert!(c.log().contains("safe state acknowledged"));
}

/// The listener's address, from the NETWORK panel (`--listen 127.0.0.1:0` picks a
/// free port).
fn listen_addr(screen: &str) -> String {
    let at = screen
        .find("NETWORK 127.0.0.1:")
        .expect("the network panel")
        + "NETWORK ".len();
    screen[at..].split_whitespace().next().unwrap().to_string()
}

/// `adrive send --to ADDR WORDS…`, as a planner in another terminal: its reply.
fn send(to: &str, words: &[&str]) -> String {
    let out = Command::new(BIN)
        .args(["send", "--to", to])
        .args(words)
        .output()
        .expect("adrive send runs");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The walk's first incident: engaged at the console and teleoperating, one `adrive
/// send steer 0.5` from another terminal took the wheel (and the network watchdog then
/// disengaged in the middle of teleop). Now the sender is refused with a reply naming
/// the console, the console shows the attempt, and the steering stays; once the
/// operator releases command (`R`), the sender engages and steers.
#[test]
fn a_network_sender_does_not_steer_the_consoles_vehicle_until_the_operator_releases() {
    // It holds the vehicle engaged for seconds to prove who commands, not device timing.
    let mut c = Console::start("owner", &["--config", TOLERANT]);
    c.engage();
    let s = c.wait_for("the header naming the console", |s| {
        s.contains("ENGAGED (by console)")
    });
    let to = listen_addr(&s);
    c.keys("d");
    c.wait_for("teleop", |s| s.contains("DEADMAN"));
    c.keys("a");
    c.wait_for("the teleop steer", |s| s.contains("teleop: steer"));
    let reply = send(&to, &["steer", "0.5"]);
    assert!(
        reply.contains("refused steer 0.5") && reply.contains("commanded by console"),
        "{reply}"
    );
    let s = c.wait_for("the attempt in the message line", |s| {
        s.contains("refused steer 0.500 from network")
    });
    assert!(!s.contains("cmd 0.500"), "the steering was moved:\n{s}");
    assert!(s.contains("ENGAGED (by console)"), "{s}");
    // Hand over: leave teleop (the brake holds), release command.
    c.keys("\x1b");
    c.wait_for("main", |s| s.contains("left teleop"));
    c.keys("R");
    c.wait_for("released", |s| s.contains("command released"));
    let reply = send(&to, &["engage", "steer", "0.5"]);
    assert!(reply.contains("ok engaged"), "{reply}");
    c.wait_for("the sender steering", |s| s.contains("cmd 0.500"));
    c.keys("q");
    assert!(c.wait_exit().success());
    let log = c.log();
    assert!(
        log.contains("WARN") && log.contains("refused steer 0.500 from network"),
        "the refusal is not in the log at WARN:\n{log}"
    );
}

/// The walk's second incident, from teleop: in park with the brake on, the up key
/// (`accel 0.10`) was refused and yet released the brake; then the bar showed
/// `accel +0.10 gas` while the message line said it was refused. Teleop starts from
/// what the vehicle was told (the brake full: up releases it first), a refused accel
/// changes nothing, and the bar shows what was applied. The same held (the gas
/// refused as a whole, the brake left full), in step mode (the incident's keys), and
/// from the main screen's accel: refused, the brake stays full.
#[test]
fn a_refused_teleop_accel_in_park_leaves_the_bar_and_the_brake_as_applied() {
    // Held engaged to prove the console, not device timing: on the tolerant Alice.
    let mut c = Console::start("park", &["--config", TOLERANT]);
    c.engage();
    c.wait_for("the brake full", |s| s.contains("BRAKE 0…1 cmd 1.000"));
    c.keys("d");
    c.wait_for("teleop from the brake applied", |s| {
        s.contains("DEADMAN") && s.contains("accel -1.00 brake")
    });
    c.keys("w");
    let s = c.wait_for("the held gas refused", |s| s.contains("refused: gas 0.20"));
    assert!(s.contains("accel -1.00 brake"), "the bar shows gas:\n{s}");
    assert!(
        s.contains("GAS 0…1 cmd 0.000") && s.contains("BRAKE 0…1 cmd 1.000"),
        "the refused gas changed the pedals:\n{s}"
    );
    c.keys("m");
    c.wait_for("step mode", |s| s.contains("TELEOP step"));
    c.keys("w");
    c.wait_for("the brake released", |s| {
        s.contains("teleop: steer") && s.contains("accel +0.00 coast")
    });
    c.keys("w");
    let s = c.wait_for("the refusal", |s| s.contains("refused: accel 0.10"));
    assert!(s.contains("accel +0.00 coast"), "the bar shows gas:\n{s}");
    assert!(!s.contains("+0.10 gas"), "the bar shows gas:\n{s}");
    assert!(s.contains("GAS 0…1 cmd 0.000"), "gas was given:\n{s}");
    // Leave teleop (the brake full again), then ask gas from the main screen.
    c.keys("\x1b");
    c.wait_for("the brake full again", |s| {
        s.contains("left teleop") && s.contains("BRAKE 0…1 cmd 1.000")
    });
    c.keys("c\x150.1\r");
    let s = c.wait_for("the refusal", |s| s.contains("accel 0.100 refused"));
    assert!(
        s.contains("BRAKE 0…1 cmd 1.000") && s.contains("accel -1.000"),
        "the brake was released:\n{s}"
    );
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// The OSCC kit under `--sim`: the main screen shows its CAN modules like any other
/// device (the steering's flags, no position), and the steering's bench shows its bus up,
/// the kit's frames decoded by the DBC.
#[test]
fn the_bench_of_a_can_kit_module_shows_its_bus() {
    let mut c = Console::start("can-bench", &["--config", "vehicles/oscc.toml"]);
    let s = c.wait_for("the kit's modules", |s| {
        s.contains("STEER") && s.contains("CAR") && s.contains("enabled")
    });
    let title = s.lines().find(|l| l.contains("STEER")).unwrap();
    assert!(!title.contains("meas"), "no position to show:\n{s}");
    c.keys("x");
    // The simulator presents the bus's adapter: the reader brings it up (until then
    // the bench says the adapter is not opened yet) and the kit's reports come in.
    let s = c.wait_for("the bus up on the bench, the kit's reports decoded", |s| {
        s.contains("bus kit: last frame of each id") && s.contains("STEERING_REPORT  enabled: ")
    });
    assert!(s.contains("<- 0x083 STEERING_REPORT"), "{s}");
    assert!(s.contains("│up  500 kbit/s"), "{s}");
    c.keys("\x1b");
    c.wait_for("the main screen", |s| s.contains("│ MAIN │"));
    c.keys("q");
    let status = c.wait_exit();
    assert!(status.success(), "{status:?}\n{}", c.log());
}

/// The incident: on the OSCC kit, which has no e-stop and reports no engine, the bench
/// offered `p` (e-stop pause), `K` (engine stall) and `J` (jam), each answered success,
/// and the simulator box then showed `e-stop pause · ENGINE STOPPED`, states that do not
/// exist. The box offers only the keys the simulator takes on this vehicle, shows only
/// what the vehicle has (the module's state), and each such key is refused with what
/// is missing.
#[test]
fn the_bench_of_a_can_kit_offers_only_the_faults_the_vehicle_has() {
    let mut c = Console::start("can-sim-keys", &["--config", "vehicles/oscc.toml"]);
    c.wait_for("the kit's modules", |s| {
        s.contains("STEER") && s.contains("CAR")
    });
    c.keys("x");
    let s = c.wait_for("the steering's bench with its simulator box", |s| {
        s.contains("steering module disabled") && s.contains("driver's hand")
    });
    for absent in ["e-stop", "engine", "jam steering"] {
        assert!(!s.contains(absent), "{absent} shown:\n{s}");
    }
    c.keys("p");
    c.wait_for("the e-stop key refused", |s| {
        s.contains("sim: estop: no e-stop is bound on this vehicle")
    });
    c.keys("K");
    c.wait_for("the stall key refused", |s| {
        s.contains("sim: stall: no device of this vehicle reports the engine")
    });
    c.keys("J");
    c.wait_for("the jam key refused", |s| {
        s.contains("sim: jam: steer is driven by a kit's module")
    });
    c.keys("\x1b");
    c.wait_for("the main screen", |s| s.contains("│ MAIN │"));
    c.keys("q");
    let status = c.wait_exit();
    assert!(status.success(), "{status:?}\n{}", c.log());
}

/// The incident: on the OSCC kit, `e` (the paper's steering reset: home the drive) was
/// answered `home sent`; the steering module has no home message, so its driver
/// dropped the command at the wire, the module heard nothing for its watchdog's 250 ms,
/// disabled itself, and the supervisor disengaged the vehicle. A control the device's
/// protocol does not carry is refused at intake, with what it lacks, and the vehicle
/// stays engaged.
#[test]
fn a_steering_reset_a_kit_cannot_take_is_refused_and_the_vehicle_stays_engaged() {
    let mut c = Console::start("can-reset", &["--config", "vehicles/oscc.toml"]);
    c.wait_for("the kit's modules", |s| {
        s.contains("STEER") && s.contains("CAR")
    });
    c.engage_now();
    c.keys("e");
    let s = c.wait_for("the reset refused", |s| {
        s.contains("steering reset refused")
    });
    assert!(common::said(&s).contains("no such control"), "{s}");
    // Still engaged, by the console, after the refusal: the gate's own account.
    let status = ctl(&c, &["status"]);
    assert!(status.contains("ENGAGED by console"), "{status}");
    c.keys("q");
    let status = c.wait_exit();
    assert!(status.success(), "{status:?}\n{}", c.log());
    let log = c.log();
    assert!(!log.contains("unsupported command"), "{log}");
    assert!(!log.contains("disabled while engaged"), "{log}");
}

/// The incident: on the cart (its steering -30 … 30 degrees), teleop's steering went
/// from -1 to 1 in the device's units — a degree either way, the gauge at full lock —
/// and entering teleop with the wheel at 15 degrees would have sent it to 1. Teleop
/// steers from the range's left end (-1) to its right (1), 0 straight ahead.
#[test]
fn teleop_steers_a_cart_over_its_whole_range_in_its_own_units() {
    let mut c = Console::start("cart-teleop", &["--config", "vehicles/cart.toml"]);
    c.wait_for("the cart's main screen", |s| {
        s.contains("STEER") && s.contains("│ MAIN │")
    });
    c.engage_now();
    c.keys("s");
    c.wait_for("the steering edit", |s| s.contains("edit steer command"));
    c.keys("15\r");
    c.wait_for("the command on screen", |s| s.contains("cmd 15.0"));
    c.keys("d");
    c.wait_for("teleop", |s| s.contains("TELEOP"));
    c.keys("m");
    let s = c.wait_for("step mode", |s| s.contains("TELEOP step"));
    // Entered where the wheel was told to be: 15 of 30 degrees right is +0.50.
    assert!(s.contains("steer +0.50"), "{s}");
    // A step right from there (0.05 of the half range: 1.5 degrees).
    c.keys("\x1b[C");
    common::wait_for("the steering at 16.5 degrees", || {
        c.commanded("steer").as_f64() == Some(16.5)
    });
    // Ten steps more: the right end of its range, not 1.
    for _ in 0..10 {
        c.keys("\x1b[C");
    }
    common::wait_for("the steering at full lock", || {
        c.commanded("steer").as_f64() == Some(30.0)
    });
    c.wait_for("the bar at +1.00", |s| s.contains("steer +1.00"));
    c.keys("z");
    common::wait_for("the steering centred", || {
        c.commanded("steer").as_f64() == Some(0.0)
    });
    c.keys(" ");
    c.wait_for("stopped", |s| s.contains("DISENGAGED"));
    c.keys("q");
    let status = c.wait_exit();
    assert!(status.success(), "{status:?}\n{}", c.log());
}

/// `adrive ctl` on the console's control socket; its standard output.
fn ctl(c: &Console, args: &[&str]) -> String {
    let out = ctl_output(c, args);
    assert!(out.status.success(), "ctl {args:?}: {out:?}");
    String::from_utf8(out.stdout).unwrap()
}

/// `adrive ctl ARGS` on the console's adrive succeeded.
fn ctl_ok(c: &Console, args: &[&str]) -> bool {
    ctl_output(c, args).status.success()
}

fn ctl_output(c: &Console, args: &[&str]) -> std::process::Output {
    Command::new(BIN)
        .arg("ctl")
        .args(args)
        .arg("--socket")
        .arg(c.log_dir.join("adrive").join("adrive.sock"))
        .output()
        .unwrap()
}

/// The snapshot as `adrive ctl status --json` reports it.
fn status(c: &Console) -> serde_json::Value {
    serde_json::from_str(&ctl(c, &["status", "--json"])).unwrap()
}

/// A device's number in a JSON snapshot: `commanded`, `executed`, or a reading.
fn number(snap: &serde_json::Value, device: &str, what: &str) -> Option<f64> {
    let d = snap["devices"]
        .as_array()?
        .iter()
        .find(|d| d["name"] == device)?;
    d[what].as_f64().or_else(|| d["readings"][what].as_f64())
}

/// The override faults in a JSON snapshot.
fn overrides(snap: &serde_json::Value) -> Vec<String> {
    snap["supervisor"]["faults"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["kind"] == "override")
        .map(|f| f.to_string())
        .collect()
}

/// The incident, on the real binary: a driver's hand on the steering, let go, the
/// override cleared (the brake then in the manual state, commanded 0); then the
/// e-stop paused. The brake went full by the actuator's own watchdog (the wire refused
/// the release the e-stop forbids, so nothing reached it), and the supervisor named it
/// "driver override on brake", latched it, and the gate's reason said so. Now the
/// e-stop's rule commands the brake full, the e-stop is the reason, and no override is
/// named or latched. Before that, after the clear, the console, `adrive ctl status`
/// (its table and its JSON) and the broadcast say the same reason: the override
/// cleared.
#[test]
fn an_e_stop_pause_after_a_cleared_override_is_named_as_the_e_stop() {
    use common::headless::{with_network, Watch};
    let port = common::free_port();
    let dir = common::tempdir("estop-cause");
    let file = dir.path().join("alice.toml");
    let vehicle = with_network(
        adrive::config::ALICE_TOML,
        "127.0.0.1:0",
        &format!("127.0.0.1:{port}"),
        "",
    );
    std::fs::write(&file, vehicle).unwrap();
    let watch = Watch::start(&format!("127.0.0.1:{port}"));
    let mut c = Console::start("estop-cause", &["--config", file.to_str().unwrap()]);
    c.engage();
    c.keys("x");
    c.wait_for("the bench", |s| s.contains("steer raw traffic"));
    c.keys("o");
    c.wait_for("the override", |s| {
        s.contains("DISENGAGED (driver override on steer)") && s.contains("driver's hand on it")
    });
    c.keys("o");
    c.wait_for("the hand off", |s| {
        s.contains("let go: clear to engage again")
    });
    c.keys("C");
    c.wait_for("the override cleared", |s| {
        s.contains("override cleared on steer")
            && s.contains("DISENGAGED (driver override on steer, cleared)")
    });
    // One reason for every reader.
    let said = "disengaged: driver override on steer, cleared";
    assert_eq!(status(&c)["gate"]["reason"], said);
    let table = ctl(&c, &["status"]);
    assert!(
        table.contains("DISENGAGED (driver override on steer, cleared)"),
        "{table}"
    );
    watch.until(said, |s| s.gate.reason == said);

    c.keys("p");
    c.wait_for("the e-stop", |s| {
        s.contains("FAULT estop_pause") && s.contains("DISENGAGED (e-stop is in pause)")
    });
    // The brake goes full by adrive's command, the e-stop's rule.
    let start = Instant::now();
    let applied = loop {
        let snap = status(&c);
        assert!(overrides(&snap).is_empty(), "{snap:#}");
        if number(&snap, "brake", "position").is_some_and(|p| p > 0.95) {
            break snap;
        }
        assert!(
            start.elapsed() < DEADLINE,
            "the brake never applied: {snap:#}"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(
        number(&applied, "brake", "commanded"),
        Some(1.0),
        "{applied:#}"
    );
    // The old judgement named it within the actuator's own watchdog (1 s) and the
    // override time (300 ms) of the pause; watch the vehicle's own clock pass 2 s more
    // with the brake held full, and no override named or latched at any turn.
    let from = applied["uptime_s"].as_f64().unwrap();
    loop {
        let snap = status(&c);
        assert!(overrides(&snap).is_empty(), "{snap:#}");
        assert!(snap["gate"]["overridden"].is_null(), "{snap:#}");
        assert_eq!(snap["gate"]["reason"], "disengaged: e-stop is in pause");
        assert_eq!(number(&snap, "brake", "executed"), Some(1.0), "{snap:#}");
        if snap["uptime_s"].as_f64().unwrap() > from + 2.0 {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let s = c.screen();
    assert!(!s.contains("OVERRIDE"), "{s}");
    let table = ctl(&c, &["status"]);
    assert!(table.contains("DISENGAGED (e-stop is in pause)"), "{table}");
    assert!(!table.contains("override"), "{table}");
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// The gate as `adrive ctl status --json` has it: engaged, and why not.
fn gate(c: &Console) -> (bool, String) {
    let g = status(c)["gate"].clone();
    (
        g["engaged"] == true,
        g["reason"].as_str().unwrap_or("").to_string(),
    )
}

/// Wait until the gate disengages; how long after `from` it was seen, and why.
fn wait_disengaged(c: &Console, from: Instant) -> (Duration, String) {
    let end = Instant::now() + DEADLINE;
    loop {
        let (engaged, why) = gate(c);
        if !engaged {
            return (from.elapsed(), why);
        }
        assert!(Instant::now() < end, "still engaged after {DEADLINE:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The bound a commanding console's terminal must answer within (the vehicle file's
/// `[console] terminal_timeout`, by default).
const TERMINAL_TIMEOUT: Duration = Duration::from_secs(1);

/// The incident, embedded: the operator engaged over SSH, then the session froze — the
/// terminal stopped reading (and so answering). While it answered, the vehicle stayed
/// engaged well past the bound; once it stopped, the safe state came within the bound
/// (from the last answer), with words that say why; the operator who comes back reads
/// why; and the console, whose terminal no longer takes what it writes (window resizes
/// filled the pseudo-terminal), still ends on SIGTERM, safely.
#[test]
fn a_terminal_that_stops_reading_stops_the_vehicle_within_the_bound() {
    let mut c = commander_stalls("stall", Player::stop_reading);
    // Frozen again, its pseudo-terminal full: the loop is not stuck on it.
    c.term.stop_reading();
    for i in 0..12u16 {
        c.resize(100 + i % 2 * 20, 30 + i % 2 * 10);
        std::thread::sleep(Duration::from_millis(30));
    }
    assert!(common::signal(&c.child, libc::SIGTERM));
    let status = c.wait_exit();
    assert!(status.success(), "{status:?}");
    assert!(c.log().contains("safe state acknowledged"));
}

/// The same with a terminal that still reads what the console draws but answers no
/// round trip any more (the way back is what stalled).
#[test]
fn a_terminal_that_stops_answering_stops_the_vehicle_within_the_bound() {
    let mut c = commander_stalls("mute", Player::stop_answering);
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// Engage, hold command for three bounds while the terminal answers, stall it as
/// `stall` says: the safe state within the bound, said in the gate's reason and the
/// log; then the terminal comes back and the screen says why.
fn commander_stalls(name: &str, stall: fn(&Player)) -> Console {
    let mut c = Console::start_tolerant(name, Play::default());
    c.engage();
    let asked = c.term.cursor_requests();
    // Answered, command is held for three bounds.
    let held = Instant::now() + TERMINAL_TIMEOUT * 3;
    while Instant::now() < held {
        assert!(gate(&c).0, "disengaged while the terminal answered");
        std::thread::sleep(Duration::from_millis(100));
    }
    assert!(
        c.term.cursor_requests() > asked + 4,
        "the console asked every few hundred ms"
    );
    let answered = c.term.cursor_answers();
    let stalled = Instant::now();
    stall(&c.term);
    let (after, why) = wait_disengaged(&c, stalled);
    // The engine's own measure of the silence when it acted: the bound, and its tick.
    assert!(
        why.contains("watchdog: console: its terminal stopped answering for 1."),
        "{why}"
    );
    assert!(
        after < TERMINAL_TIMEOUT + Duration::from_millis(1500),
        "the safe state came {after:?} after the stall"
    );
    assert_eq!(
        c.term.cursor_answers(),
        answered,
        "it answered nothing since"
    );
    let log = c.log();
    assert!(
        log.contains("watchdog: console: its terminal stopped answering for 1."),
        "{log}"
    );
    // The operator comes back: the screen says why, and nobody moved the vehicle.
    c.term.set(|p| {
        p.reading = true;
        p.cursor = Answer::Now;
    });
    c.wait_for("why", |s| s.contains("stopped answering"));
    assert!(!gate(&c).0, "engaged again by itself");
    c
}

/// The terminal's answer to the liveness check arriving just after the operator's Esc
/// (in one read: `ESC ESC [ 21 ; 76 R`), or cut by a pause longer than a lone Esc's
/// wait (a slow SSH link): it is an answer, never keys. Read as keys, its `R` released
/// command — in a real run, while the screenshots were taken — and the vehicle stopped.
#[test]
fn a_terminal_answer_beside_the_operators_esc_is_never_keys() {
    // Held engaged to prove the console, not device timing: on the tolerant Alice.
    let mut c = Console::start("esc-answer", &["--config", TOLERANT]);
    c.engage();
    c.term.write(b"\x1b\x1b[21;76R");
    c.term.write(b"\x1b[21;7");
    std::thread::sleep(Duration::from_millis(200));
    c.term.write(b"6R");
    // A barrier: help opens once every byte before it was taken.
    c.keys("?");
    c.wait_for("help", |s| s.contains("keys from the loaded keymap"));
    let (engaged, why) = gate(&c);
    assert!(engaged, "the answer's bytes were keys: {why}");
    let log = c.log();
    assert!(!log.contains("released command"), "{log}");
    c.keys(" ");
    c.wait_for("the stop", |s| s.contains("DISENGAGED"));
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// A console that watches (the operator commands through `adrive ctl`) asks its
/// terminal nothing, and its terminal stalling stops nothing.
#[test]
fn a_watching_console_whose_terminal_stalls_never_stops_the_vehicle() {
    let mut c = Console::start_tolerant("watch-stall", Play::default());
    c.wait_for("the main screen", |s| {
        s.contains("STEER") && s.contains("OBD")
    });
    let end = Instant::now() + DEADLINE;
    while !ctl_ok(&c, &["engage"]) {
        assert!(Instant::now() < end, "could not engage: {}", gate(&c).1);
        std::thread::sleep(Duration::from_millis(200));
    }
    c.wait_for("the operator commanding", |s| {
        s.contains("ENGAGED (by operator")
    });
    c.term.stop_reading();
    let held = Instant::now() + TERMINAL_TIMEOUT * 3;
    while Instant::now() < held {
        let (engaged, why) = gate(&c);
        assert!(engaged, "a watcher's terminal stopped the vehicle: {why}");
        std::thread::sleep(Duration::from_millis(100));
    }
    assert_eq!(c.term.cursor_requests(), 0, "a watcher asked its terminal");
    ctl(&c, &["stop"]);
    c.term.set(|p| p.reading = true);
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// A slow but live link: every answer comes 300 ms after its request. The bound is
/// measured from the last answer, not from a schedule, so command is held — here for
/// a minute — and the console keeps drawing.
#[test]
fn a_slow_but_live_terminal_keeps_command_for_a_minute() {
    let play = Play {
        cursor: Answer::After(Duration::from_millis(300)),
        ..Play::default()
    };
    let mut c = Console::start_tolerant("slow", play);
    c.engage();
    let until = Instant::now() + Duration::from_secs(60);
    while Instant::now() < until {
        let (engaged, why) = gate(&c);
        assert!(engaged, "disengaged on a slow but live link: {why}");
        std::thread::sleep(Duration::from_millis(250));
    }
    assert!(c.term.cursor_answers() > 150, "{}", c.term.cursor_answers());
    c.keys(" ");
    c.wait_for("the stop", |s| s.contains("DISENGAGED"));
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// A console that does not command asks nothing: the check costs nothing until the
/// console commands, and then it asks at once.
#[test]
fn a_console_asks_only_while_it_commands() {
    let mut c = Console::start("quiet", &[]);
    c.wait_for("the main screen", |s| {
        s.contains("STEER") && s.contains("OBD")
    });
    common::wait_for("every device to report", || {
        status(&c)["gate"]["blockers"]
            .as_array()
            .is_some_and(Vec::is_empty)
    });
    c.keys("E");
    c.wait_for("the confirmation", |s| s.contains("Engage?"));
    assert_eq!(c.term.cursor_requests(), 0, "asked before commanding");
    c.keys("y");
    c.wait_for("engaged", |s| s.contains("│ ENGAGED"));
    c.wait_for("a request", |_| c.term.cursor_requests() > 0);
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// The kitty keyboard protocol's push, in the bytes: `CSI > 3 u`.
fn pushed(bytes: &[u8]) -> bool {
    bytes.windows(5).any(|w| w == b"\x1b[>3u")
}

/// The pop comes before the alternate screen is left (each screen has its own stack).
fn popped_before_leaving(bytes: &[u8]) -> bool {
    let pop = bytes.windows(4).rposition(|w| w == b"\x1b[<u");
    let leave = bytes.windows(8).rposition(|w| w == b"\x1b[?1049l");
    matches!((pop, leave), (Some(p), Some(l)) if p < l)
}

/// A terminal that speaks the kitty keyboard protocol is asked for releases (flags 3
/// pushed) and left in the legacy encoding on every way out: quit, SIGTERM, SIGHUP, a
/// panic.
#[allow(unsafe_code)]
#[test]
fn the_kitty_flags_are_pushed_where_supported_and_popped_on_every_way_out() {
    for (how, extra) in [
        ("quit", &[][..]),
        ("term", &[][..]),
        ("hup", &[][..]),
        ("panic", &["--inject-panic", "main"][..]),
    ] {
        let mut c =
            Console::start_playing(&format!("kitty-{how}"), extra, (COLS, ROWS), Play::kitty());
        c.wait_for("the main screen", |s| s.contains("STEER"));
        c.wait_for("the flags pushed", |_| c.term.kitty_flags() == 3);
        let status = match how {
            "quit" => {
                // A press reported in the protocol's own encoding is a key as before.
                c.term.kitty(Key::Char('q'), Kind::Press);
                c.wait_exit()
            }
            "term" => {
                assert!(common::signal(&c.child, libc::SIGTERM));
                c.wait_exit()
            }
            "hup" => {
                // SAFETY: signalling our own child.
                unsafe { libc::kill(c.child.id() as i32, libc::SIGHUP) };
                c.wait_exit()
            }
            _ => c.wait_exit(),
        };
        let bytes = c.bytes();
        assert!(pushed(&bytes), "{how}");
        assert_eq!(
            c.term.kitty_flags(),
            0,
            "{how}: the terminal was left in the protocol"
        );
        assert!(popped_before_leaving(&bytes), "{how}");
        assert!(c.cooked(), "{how}");
        assert_eq!(
            status.success(),
            how == "quit" || how == "term",
            "{how}: {status:?}"
        );
        assert!(c.log().contains("safe state acknowledged"), "{how}");
    }
}

/// A legacy terminal (no flags answer) is never pushed into the protocol, and one that
/// answers nothing at all does not hold the console up: it starts, presses only.
#[test]
fn a_terminal_without_the_protocol_or_without_answers_gets_presses_only() {
    for (name, play) in [("legacy", Play::default()), ("silent", Play::silent())] {
        let mut c = Console::start_playing(name, &[], (COLS, ROWS), play);
        c.wait_for("the main screen", |s| s.contains("STEER"));
        let end = Instant::now() + DEADLINE;
        while !c
            .log()
            .contains("console: the terminal reports presses only")
        {
            assert!(Instant::now() < end, "{name}: {}", c.log());
            std::thread::sleep(Duration::from_millis(20));
        }
        c.keys("q");
        assert!(c.wait_exit().success());
        assert!(!pushed(&c.bytes()), "{name}");
    }
}

/// A commanding console's terminal closed (the SSH session dropped): no terminal is
/// left to pop flags on or answer; the way out is the hang-up's, safe and prompt.
#[test]
fn a_closed_terminal_in_the_protocol_stops_safely() {
    let mut c = Console::start_playing("kitty-closed", &[], (COLS, ROWS), Play::kitty());
    c.engage();
    c.wait_for("the flags pushed", |_| c.term.kitty_flags() == 3);
    c.term.hang_up();
    let status = c.wait_exit();
    assert_eq!(status.code(), Some(129), "{status:?}");
    let log = c.log();
    assert!(log.contains("safe state acknowledged"), "{log}");
    assert!(!log.contains("panicked"), "{log}");
}

/// Interlocks off and engaged (the brake full, as the engage found it), the gas at 0.3:
/// the one accel value read `0.300` — gas alone, while the brake was full against it.
/// Both pedals applied are said as both, in the fault's colour, until one lets go.
#[test]
fn with_interlocks_off_gas_and_brake_both_applied_are_shown_as_both() {
    let mut c = Console::start_tolerant("both-pedals", Play::default());
    c.engage_now();
    c.keys("I");
    c.wait_for("the question", |s| s.contains("Turn the interlocks OFF?"));
    c.keys("y");
    c.wait_for("interlocks off", |s| s.contains("INTERLOCKS OFF"));
    c.keys("g");
    c.wait_for("the gas edit", |s| s.contains("edit gas command"));
    c.keys("\x150.3\r");
    c.wait_for("both pedals", |s| {
        s.contains("accel gas 0.300 + brake 1.000") && s.contains("BRAKE 0…1 cmd 1.000")
    });
    c.keys("b");
    c.wait_for("the brake edit", |s| s.contains("edit brake command"));
    c.keys("\x150\r");
    c.wait_for("the gas alone", |s| s.contains("accel 0.300 "));
    c.keys("q");
    assert!(c.wait_exit().success());
}

/// Inside tmux on the vehicle, tmux answers for the operator's terminal: the console
/// does not probe for the kitty protocol (tmux drops releases), says `link unchecked`
/// in its header, and still asks its round trips (tmux itself may stop). At 80×24 the
/// gate's reason is whole beside it (it read `DISENGAGED (stop from…)` while
/// `interlocks on` kept its room).
#[test]
fn inside_tmux_the_header_says_the_link_is_unchecked() {
    let mut c = Console::start_in(
        "tmux",
        &[],
        (80, 24),
        Play::kitty(),
        &[("TMUX", "/tmp/tmux-0/default,1234,0")],
    );
    c.wait_for("link unchecked", |s| s.contains("link unchecked"));
    assert!(
        !c.term
            .asked()
            .iter()
            .any(|(_, a)| *a == common::terminal_player::Asked::Flags),
        "probed for the kitty protocol inside tmux"
    );
    c.engage();
    c.wait_for("a request", |_| c.term.cursor_requests() > 0);
    c.keys(" ");
    c.wait_for("the stop's reason whole beside the link", |s| {
        s.lines()
            .next()
            .is_some_and(|top| top.contains("│ link unchecked │ DISENGAGED (stop from console)"))
    });
    c.keys("q");
    assert!(c.wait_exit().success());
    assert!(!pushed(&c.bytes()));
}

/// A real tmux server of the test's own (its socket in `dir`, where the console's
/// control socket and log go too), killed when dropped.
struct Tmux {
    dir: tempfile::TempDir,
}

impl Tmux {
    /// `cmd` in a new detached session, its log in `dir`/log.
    fn start(dir: tempfile::TempDir, cmd: &[&str]) -> Tmux {
        let t = Tmux { dir };
        let out = t
            .tmux()
            .args(["new-session", "-d", "-x", "100", "-y", "30", "-s", "adrive"])
            .args(cmd)
            .env("XDG_RUNTIME_DIR", t.dir.path())
            .env_remove("TMUX")
            .env_remove("RUNTIME_DIRECTORY")
            .output()
            .expect("tmux is needed for this test (apt-get install tmux)");
        assert!(out.status.success(), "tmux new-session: {out:?}");
        t
    }

    fn tmux(&self) -> Command {
        let mut c = Command::new("tmux");
        c.arg("-S")
            .arg(self.dir.path().join("tmux.sock"))
            .args(["-f", "/dev/null"]);
        c
    }

    /// The pane as tmux shows it.
    fn screen(&self) -> String {
        let out = self
            .tmux()
            .args(["capture-pane", "-p", "-t", "adrive"])
            .output()
            .unwrap();
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    fn wait_for(&self, what: &str, ok: impl Fn(&str) -> bool) -> String {
        common::wait_screen(what, Duration::from_millis(50), || self.screen(), ok)
    }

    fn keys(&self, k: &str) {
        let out = self
            .tmux()
            .args(["send-keys", "-t", "adrive", k])
            .output()
            .unwrap();
        assert!(out.status.success(), "{out:?}");
    }

    fn ctl(&self, args: &[&str]) -> std::process::Output {
        Command::new(BIN)
            .arg("ctl")
            .args(args)
            .arg("--socket")
            .arg(self.dir.path().join("adrive").join("adrive.sock"))
            .output()
            .unwrap()
    }

    fn engaged(&self) -> bool {
        let out = self.ctl(&["status", "--json"]);
        let snap: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_default();
        snap["gate"]["engaged"] == true
    }
}

impl Drop for Tmux {
    fn drop(&mut self) {
        let _ = self.tmux().arg("kill-server").output();
        // The console, its terminal gone, stops safely; its log says so.
        let log = self.dir.path().join("log");
        let end = Instant::now() + DEADLINE;
        while Instant::now() < end {
            let done = std::fs::read_dir(&log).into_iter().flatten().any(|e| {
                std::fs::read_to_string(e.unwrap().path())
                    .is_ok_and(|l| l.contains("safe state acknowledged"))
            });
            if done {
                break;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

/// Inside a real tmux on the vehicle, with no client attached at all — nobody sees the
/// console — tmux answers the round trips itself: the check cannot see the operator's
/// link there, and the header says so (`link unchecked`), found from tmux's own
/// environment.
#[test]
fn inside_a_real_tmux_the_round_trip_is_answered_by_tmux_and_the_header_says_link_unchecked() {
    let dir = common::tempdir("tmux");
    let vehicle = common::tolerant_alice(dir.path());
    let log = dir.path().join("log");
    let t = Tmux::start(
        dir,
        &[
            BIN,
            "--sim",
            "--config",
            vehicle.to_str().unwrap(),
            "--listen",
            "127.0.0.1:0",
            "--log-dir",
            log.to_str().unwrap(),
        ],
    );
    t.wait_for("the console", |s| s.contains("STEER") && s.contains("OBD"));
    assert!(t.screen().contains("link unchecked"), "{}", t.screen());
    let end = Instant::now() + DEADLINE;
    loop {
        t.keys("E");
        t.wait_for("the question", |s| s.contains("Engage?"));
        t.keys("y");
        let s = t.wait_for("the answer", engage_answered);
        if common::engaged_said(&s) {
            break;
        }
        assert!(Instant::now() < end, "could not engage:\n{s}");
        std::thread::sleep(Duration::from_millis(200));
    }
    // Detached, nobody at any terminal: tmux answers, command is held.
    let held = Instant::now() + TERMINAL_TIMEOUT * 3;
    while Instant::now() < held {
        assert!(t.engaged(), "disengaged:\n{}", t.screen());
        std::thread::sleep(Duration::from_millis(100));
    }
    let s = t.screen();
    assert!(s.contains("link unchecked") && s.contains("ENGAGED"), "{s}");
    assert!(
        std::fs::read_dir(&log)
            .unwrap()
            .any(|e| std::fs::read_to_string(e.unwrap().path())
                .is_ok_and(|l| l.contains("inside tmux, which answers for the terminal"))),
        "the log says why the link is not checked"
    );
}

/// What the confirmation dialog on `screen` says, its lines joined without spaces
/// (its lines break between words, and within a path).
fn dialog_text(screen: &str) -> String {
    let rows: Vec<Vec<char>> = screen.lines().map(|l| l.chars().collect()).collect();
    let Some(top) = rows
        .iter()
        .position(|r| r.iter().collect::<String>().contains("┌ confirm"))
    else {
        return String::new();
    };
    let left = rows[top].iter().position(|&c| c == '┌').unwrap();
    let right = rows[top].iter().rposition(|&c| c == '┐').unwrap();
    rows[top + 1..]
        .iter()
        .take_while(|r| r.get(left) != Some(&'└'))
        .map(|r| r[left + 1..right.min(r.len())].iter().collect::<String>())
        .collect::<String>()
        .replace(' ', "")
}

/// The directories a characterization from the bench wrote in `dir`.
fn characterized(dir: &std::path::Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with("characterize-steer-"))
        })
        .collect()
}

impl Console {
    /// On the bench of the steering (the first device), `M`: the question, read
    /// whole; `y`: under way, its progress on the bench.
    fn characterize_steer(&mut self) -> String {
        self.wait_for("the main screen", |s| {
            s.contains("STEER") && s.contains("OBD")
        });
        self.keys("x");
        self.wait_for("the bench", |s| s.contains("BENCH") && s.contains("STEER"));
        // The devices' first reports prove the vehicle still: until then it is refused.
        let end = Instant::now() + DEADLINE;
        loop {
            self.keys("M");
            let s = self.wait_for("the question or a refusal", |s| {
                s.contains("Characterize steer") || s.contains("characterize steer refused")
            });
            if s.contains("Characterize steer") {
                break;
            }
            assert!(Instant::now() < end, "refused:\n{s}");
            std::thread::sleep(Duration::from_millis(200));
        }
        let q = self.wait_for("the whole question", |s| s.contains("y yes"));
        let asked = dialog_text(&q);
        for words in [
            "Characterize steer (step, sweep, deadband, backlash, rate, delay) into",
            &format!("{}/characterize-steer-", self.log_dir.display()),
            "It moves steer over 90 % of its range for about 30 s; the vehicle must be \
             stopped, in park, with the brake held.",
            "Checked now: stopped, in park, the brake held.",
        ] {
            assert!(asked.contains(&words.replace(' ', "")), "{words}:\n{q}");
        }
        self.keys("y");
        let s = self.wait_for("under way", |s| {
            s.contains("characterize steer: running") && s.contains("large steps · step")
        });
        assert!(s.contains("STOP or Esc ends it"), "{s}");
        s
    }

    /// Who commands the vehicle now, as the engine says (`None`: nobody).
    fn commander(&self) -> Option<String> {
        let g = &self.status()["gate"];
        (g["engaged"] == true).then(|| g["commander"].as_str().unwrap_or("?").to_string())
    }

    /// The steering's measured position, as the engine has it.
    fn steer_at(&self) -> f64 {
        let snap = self.status();
        snap["devices"]
            .as_array()
            .unwrap()
            .iter()
            .find(|d| d["name"] == "steer")
            .and_then(|d| d["readings"]["position"].as_f64())
            .expect("steer reports its position")
    }

    /// Wait until the steering stands still: two readings 200 ms apart the same.
    fn steer_still(&self) -> f64 {
        let end = Instant::now() + DEADLINE;
        let mut last = self.steer_at();
        loop {
            std::thread::sleep(Duration::from_millis(200));
            let now = self.steer_at();
            if (now - last).abs() < 1e-4 {
                return now;
            }
            assert!(Instant::now() < end, "steer still moving: {last} → {now}");
            last = now;
        }
    }
}

/// At 80×24, the operator's smallest full console: the bench's key asks first, naming
/// the device, the procedures, the directory, what it does and what was checked; the
/// run commands as `characterize` beside a console that keeps drawing, shows its
/// stage, step and time left beside the chart, and ends with its figures on the bench,
/// its files in the directory it named and its end in the log.
#[test]
fn the_bench_characterizes_its_device_and_says_what_it_measured() {
    let mut c = Console::start_working("char-bench", (80, 24));
    c.characterize_steer();
    assert_eq!(c.commander().as_deref(), Some("characterize"));
    let s = c.wait_for("the chart beside the run", |s| {
        s.contains("steer over the last")
    });
    assert!(s.contains("command") || s.contains("measured"), "{s}");
    // The console keeps drawing while it runs: the step counts up.
    let step = |s: &str| -> Option<u32> {
        let at = s.find("· step ")? + "· step ".len();
        s[at..].split_whitespace().next()?.parse().ok()
    };
    let first = step(&c.screen()).unwrap_or(0);
    c.wait_for("a later step", |s| step(s).is_some_and(|n| n > first + 2));
    // A whole characterization takes tens of seconds: its own deadline.
    let end = Instant::now() + DEADLINE * 8;
    let s = loop {
        let s = c.screen();
        assert!(!s.contains("ended early"), "ended early:\n{s}");
        if s.contains("characterize steer: done") {
            break c.wait_for("the figures", |s| s.contains("settle"));
        }
        assert!(
            Instant::now() < end,
            "not done after {:?}:\n{s}",
            DEADLINE * 8
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    for f in [
        "rate up",
        "delay",
        "deadband",
        "backlash",
        "rise",
        "overshoot",
        "settle",
    ] {
        assert!(s.contains(f), "{f}:\n{s}");
    }
    assert!(
        s.contains("written to …") || s.contains("written to /"),
        "{s}"
    );
    assert_eq!(c.commander(), None, "let go when done");
    let dirs = characterized(&c.log_dir);
    assert_eq!(dirs.len(), 1, "{dirs:?}");
    for f in ["summary.json", "samples.csv", "sim.toml", "report.md"] {
        assert!(dirs[0].join(f).is_file(), "{f} in {}", dirs[0].display());
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dirs[0].join("summary.json")).unwrap())
            .unwrap();
    assert!(
        summary["rate_up"].as_f64().is_some_and(|r| r > 0.5),
        "{summary}"
    );
    let log = c.log();
    assert!(log.contains("characterize steer: done in"), "{log}");
    c.keys("q");
    assert!(c.wait_exit().success());
    assert!(c.log().contains("safe state acknowledged"));
}

/// STOP mid-run ends it at once: the vehicle disengaged into its safe state, the
/// bench saying why, nothing written, the steering still; Esc then leaves the bench.
#[test]
fn stop_mid_characterization_ends_it_safe_and_writes_nothing() {
    let mut c = Console::start_working("char-stop", (80, 24));
    c.characterize_steer();
    c.wait_for("the steering moving", |_| c.steer_at().abs() > 0.1);
    c.keys(" ");
    let s = c.wait_for("ended early", |s| {
        s.contains("characterize steer: ended early")
    });
    assert!(s.contains("stop from console"), "{s}");
    assert_eq!(c.commander(), None);
    let reason = c.status()["gate"]["reason"]
        .as_str()
        .unwrap_or("")
        .to_string();
    assert!(reason.contains("characterize ended"), "{reason}");
    c.steer_still();
    assert!(characterized(&c.log_dir).is_empty(), "nothing written");
    c.keys("\x1b");
    c.wait_for("the main screen", |s| {
        s.contains("GAS") && !s.contains("BENCH")
    });
    c.keys("q");
    assert!(c.wait_exit().success());
    let log = c.log();
    assert!(
        log.contains("characterize steer: ended early, nothing written"),
        "{log}"
    );
    assert!(log.contains("safe state acknowledged"), "{log}");
}

/// Leaving the bench mid-run (Esc) ends it at once, as STOP does, saying why.
#[test]
fn leaving_the_bench_mid_characterization_ends_it() {
    let mut c = Console::start_working("char-esc", (80, 24));
    c.characterize_steer();
    // The bench stays on the device while it runs.
    c.keys("\t");
    c.wait_for("the bench held", |s| {
        s.contains("the bench stays on the device")
    });
    c.keys("\x1b");
    let s = c.wait_for("said how it ended", |s| {
        s.contains("characterize steer ended early")
    });
    assert!(s.contains("the operator left the bench view"), "{s}");
    assert_eq!(c.commander(), None);
    c.steer_still();
    assert!(characterized(&c.log_dir).is_empty());
}

/// The console's terminal closed mid-run (an SSH session dropping): the run ends at
/// once, safe state first, and adrive stops as on a hang-up.
#[test]
fn a_terminal_closed_mid_characterization_ends_it_safe() {
    let mut c = Console::start_working("char-hup", (80, 24));
    c.characterize_steer();
    c.term.hang_up();
    let status = c.wait_exit();
    assert_eq!(status.code(), Some(129), "{status:?}");
    let log = c.log();
    assert!(log.contains("characterize steer: ended early"), "{log}");
    assert!(log.contains("the console is stopping"), "{log}");
    assert!(log.contains("safe state acknowledged"), "{log}");
    assert!(characterized(&c.log_dir).is_empty());
}

/// The console's terminal frozen mid-run without closing (it still reads, it answers
/// no round trip: a link gone quiet): the operator no longer sees the run, so it ends
/// within the terminal's bound, the vehicle let go in its safe state, and the bench
/// says why when the terminal comes back. The console asks while the run is under way
/// though it does not command.
#[test]
fn a_terminal_frozen_mid_characterization_ends_it_within_the_bound() {
    let mut c = Console::start_working("char-mute", (80, 24));
    let asked = c.term.cursor_requests();
    c.characterize_steer();
    c.wait_for("asked while it runs", |_| {
        c.term.cursor_requests() > asked + 2
    });
    let frozen = Instant::now();
    c.term.stop_answering();
    let end = frozen + TERMINAL_TIMEOUT + DEADLINE;
    while c.commander().is_some() {
        assert!(Instant::now() < end, "still characterizing, unanswered");
        std::thread::sleep(Duration::from_millis(20));
    }
    // The bound runs from the terminal's last answer, up to one asking period (250 ms)
    // before it was frozen here.
    let after = frozen.elapsed();
    assert!(
        after >= TERMINAL_TIMEOUT - Duration::from_millis(250)
            && after < TERMINAL_TIMEOUT + Duration::from_millis(1500),
        "the run ended {after:?} after the terminal froze"
    );
    c.steer_still();
    assert!(characterized(&c.log_dir).is_empty(), "nothing written");
    c.term.set(|p| p.cursor = Answer::Now);
    let s = c.wait_for("why", |s| s.contains("characterize steer ended early"));
    assert!(s.contains("stopped answering"), "{s}");
    c.keys("q");
    assert!(c.wait_exit().success());
    let log = c.log();
    assert!(
        log.contains("nothing written: stopped: the console's terminal stopped answering"),
        "{log}"
    );
    assert!(log.contains("safe state acknowledged"), "{log}");
}

/// Refused at once, with the reason, where it cannot run: a device that is not a
/// setpoint actuator, and a vehicle out of park.
#[test]
fn characterize_is_refused_for_a_state_device_and_out_of_park() {
    let mut c = Console::start_working("char-refused", (80, 24));
    c.engage_in_drive();
    c.keys("D");
    c.wait_for("the confirmation", |s| s.contains("Disengage?"));
    c.keys("y");
    c.wait_for("disengaged", |s| s.contains("DISENGAGED"));
    // The cursor is on the gearbox.
    c.keys("x");
    c.wait_for("the bench", |s| s.contains("BENCH") && s.contains("TRANS"));
    c.keys("M");
    let s = c.wait_for("refused", |s| s.contains("characterize trans refused"));
    assert!(s.contains("trans is a state device"), "{s}");
    c.keys("/steer\r");
    c.wait_for("the steering on the bench", |s| s.contains("┌STEER"));
    c.keys("M");
    let s = c.wait_for("refused", |s| s.contains("characterize steer refused"));
    assert!(s.contains("not ready: the gearbox is not in park"), "{s}");
    assert!(!s.contains("Characterize steer ("), "{s}");
    assert_eq!(c.commander(), None);
}
