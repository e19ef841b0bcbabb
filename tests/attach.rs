//! adrive as a service with consoles that come and go, as people use it at the
//! vehicle: the real binary headless on `adrive sim`'s devices, consoles attached with
//! `adrive attach` on real pseudo-terminals (one drives, one watches), terminals closed
//! the way an SSH session drops (the master side goes away), and `adrive ctl` for one
//! operator command at a time. Screens are rebuilt with a terminal emulator; every
//! wait has a generous deadline.

mod common;

use common::attached::Attached;
use common::pty::Master;
use common::simproc::{vehicle_file, SimProcess};
use common::terminal_player::{Answer, Play, Player};
use common::{lines, tempdir, wait_exit, DEADLINE};
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_adrive");
/// `adrive attach`'s default teleop deadman.
const DEADMAN: Duration = adrive::config::limits::DEADMAN_DEFAULT;

/// adrive headless (the service) with its control socket in a directory of its own.
struct Service {
    child: common::Reaped,
    dir: tempfile::TempDir,
    socket: PathBuf,
    /// Its command listener.
    listen: String,
    /// Where its state broadcast goes.
    broadcast: std::net::UdpSocket,
    log: Receiver<String>,
}

impl Service {
    /// On `adrive sim`'s ports, or (`sim: None`) with `--sim`.
    fn start(name: &str, sim: Option<&SimProcess>) -> Service {
        Service::start_on(name, sim, false)
    }

    /// With `--sim` on [`common::tolerant_alice`], for tests that hold the vehicle
    /// engaged for seconds.
    fn start_tolerant(name: &str) -> Service {
        Service::start_on(name, None, true)
    }

    /// On `adrive sim`'s ports, Alice made tolerant as [`common::tolerant`], for tests
    /// that hold the vehicle engaged for seconds.
    fn start_tolerant_on(name: &str, sim: &SimProcess) -> Service {
        Service::start_on(name, Some(sim), true)
    }

    fn start_on(name: &str, sim: Option<&SimProcess>, tolerant: bool) -> Service {
        let dir = tempdir(name);
        let socket = dir.path().join("run/adrive.sock");
        let mut cmd = Command::new(BIN);
        match (sim, tolerant) {
            (Some(sim), false) => cmd.arg("--config").arg(vehicle_file(dir.path(), sim, "")),
            (Some(sim), true) => {
                cmd.arg("--config")
                    .arg(common::tolerant(vehicle_file(dir.path(), sim, "")))
            }
            (None, false) => cmd.arg("--sim"),
            (None, true) => cmd
                .arg("--sim")
                .arg("--config")
                .arg(common::tolerant_alice(dir.path())),
        };
        let listen = format!("127.0.0.1:{}", common::free_port());
        let broadcast = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        broadcast
            .set_read_timeout(Some(Duration::from_millis(200)))
            .unwrap();
        let to = broadcast.local_addr().unwrap().to_string();
        let mut child = cmd
            .args(["--headless", "--broadcast-to", &to])
            .args(["--listen", &listen, "--log-dir"])
            .arg(dir.path().join("log"))
            .arg("--socket")
            .arg(&socket)
            .env("XDG_RUNTIME_DIR", dir.path())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let log = lines(child.stderr.take().unwrap());
        let svc = Service {
            child: common::Reaped(child),
            dir,
            socket,
            listen,
            broadcast,
            log,
        };
        svc.until("running headless");
        svc
    }

    /// Wait for a log line containing `what`.
    fn until(&self, what: &str) -> String {
        let end = Instant::now() + DEADLINE;
        loop {
            let l = self
                .log
                .recv_timeout(end.saturating_duration_since(Instant::now()))
                .unwrap_or_else(|_| panic!("adrive never logged {what:?}"));
            if l.contains(what) {
                return l;
            }
        }
    }

    fn ctl(&self, args: &[&str]) -> Output {
        ctl(&self.socket, args)
    }

    /// `adrive send`, as a planner.
    fn send(&self, words: &[&str]) -> Output {
        Command::new(BIN)
            .args(["send", "--to", &self.listen])
            .args(words)
            .output()
            .unwrap()
    }

    /// The gate, as `adrive ctl status --json` reports it.
    fn gate(&self) -> serde_json::Value {
        let out = self.ctl(&["status", "--json"]);
        assert!(out.status.success(), "{out:?}");
        let snap: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        snap["gate"].clone()
    }
}

fn ctl(socket: &Path, args: &[&str]) -> Output {
    Command::new(BIN)
        .arg("ctl")
        .args(args)
        .arg("--socket")
        .arg(socket)
        .output()
        .unwrap()
}

/// `adrive attach` to the socket at `socket`.
fn attach(socket: &Path) -> Attached {
    attach_playing(socket, Play::default())
}

/// [`attach`] on a terminal that plays `play` (tests/common/terminal_player.rs).
fn attach_playing(socket: &Path, play: Play) -> Attached {
    Attached::spawn(
        Command::new(BIN).arg("attach").arg("--socket").arg(socket),
        play,
    )
}

#[test]
fn two_consoles_attach_one_drives_the_watcher_leaves_freely_and_the_commanders_drop_is_its_watchdog(
) {
    let sim = SimProcess::start();
    // Held engaged for seconds to prove who commands and the consoles' watchdog, not
    // device timing: on the tolerant Alice.
    let svc = Service::start_tolerant_on("attach-two", &sim);
    let mut watcher = attach(&svc.socket);
    let mut driver = attach(&svc.socket);
    for c in [&watcher, &driver] {
        c.wait_for("watching", |s| s.contains("WATCHING"));
    }
    // The bench view draws the device's raw traffic and histogram from the stream.
    watcher.keys("x");
    watcher.wait_for("steer's raw traffic", |s| {
        s.contains("steer raw traffic") && s.contains("->") && s.contains("<-")
    });
    watcher.keys("\x1b");

    // One engages, steers and STOPs; the simulated devices receive it, the other sees it.
    driver.engage();
    let me = svc.gate()["commander"].as_str().unwrap().to_string();
    assert!(me.starts_with("console #"), "{me}");
    let mark = sim.mark();
    driver.steer("0.5");
    sim.wait_after(mark, &["steer", "<-", "0.500"]);
    watcher.wait_for("the steering command", |s| {
        s.contains("cmd 0.500") && s.contains(&format!("ENGAGED (by {me})"))
    });
    // The watcher cannot command: its steer is refused, and changes nothing.
    watcher.steer("-0.5");
    watcher.wait_for("the refusal", |s| s.contains(&format!("commanded by {me}")));
    let mark = sim.mark();
    driver.keys(" ");
    sim.wait_after(mark, &["brake", "<-", "1.000"]);
    watcher.wait_for("the stop", |s| {
        s.contains("DISENGAGED (stop from console #")
    });
    assert_ne!(sim.last_command("steer").as_deref(), Some("-0.500"));

    // Closing the watcher's terminal changes nothing: the driver still commands (a
    // command after it is the sentinel).
    driver.engage();
    watcher.term.hang_up();
    let status = watcher.wait_exit();
    assert!(
        status.is_some(),
        "the watcher did not end with its terminal"
    );
    svc.until("detached");
    let mark = sim.mark();
    driver.steer("0.3");
    sim.wait_after(mark, &["steer", "<-", "0.300"]);
    let gate = svc.gate();
    assert_eq!(gate["engaged"], true, "{gate}");
    assert_eq!(gate["commander"], me.as_str(), "{gate}");

    // Closing the driver's terminal (the master goes away, as an SSH drop) brakes and
    // disengages within its deadman; the service keeps running. The brake is first set
    // apart from full, so that the full brake waited for is the drop's, not a resend.
    let mark = sim.mark();
    driver.keys("b");
    driver.wait_for("the brake edit", |s| s.contains("edit brake command"));
    driver.keys("\x150.2\r");
    sim.wait_after(mark, &["brake", "<-", "0.200"]);
    let mark = sim.mark();
    let dropped = Instant::now();
    driver.term.hang_up();
    sim.wait_after(mark, &["brake", "<-", "1.000"]);
    let took = dropped.elapsed();
    assert!(
        took < DEADMAN,
        "the brake came {took:?} after the commander's terminal closed"
    );
    assert_eq!(sim.last_command("gas").as_deref(), Some("0.000"));
    let gate = svc.gate();
    assert_eq!(gate["engaged"], false, "{gate}");
    let reason = gate["reason"].as_str().unwrap();
    assert!(
        reason.contains(&format!("{me} went away")),
        "disengaged for another reason: {reason}"
    );
    let why = &gate["cause"]["why"];
    assert_eq!(
        (why["kind"].as_str(), why["trip"].as_str()),
        (Some("watchdog"), Some("gone")),
        "{gate}"
    );
    let _ = driver.wait_exit();
    let mut svc = svc;
    assert!(
        svc.child.try_wait().unwrap().is_none(),
        "the service stopped with its console"
    );
    // A console attaches again to the service that kept running, and takes command from
    // an operator who engaged with `adrive ctl` (a console outranks it, with a
    // confirmation); the operator is refused from then on.
    let mut again = attach(&svc.socket);
    again.wait_for("the reason", |s| s.contains("went away"));
    assert!(svc.ctl(&["engage"]).status.success());
    again.wait_for("the operator commanding", |s| {
        s.contains("ENGAGED (by operator")
    });
    again.keys("A");
    again.wait_for("the confirmation", |s| s.contains("Take command?"));
    again.keys("y");
    again.wait_for("command taken", |s| s.contains(" COMMANDING "));
    let out = svc.ctl(&["release"]);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    assert!(svc.gate()["commander"]
        .as_str()
        .unwrap()
        .starts_with("console #"));
}

/// `adrive attach` runs the same console loop over the control socket, and obeys the
/// same rule: below 80×22 only STOP and quit act, every other key is refused on the
/// small screen and nothing reaches the vehicle (read back with `adrive ctl`); grown
/// again, the keys act again.
#[test]
fn an_attached_console_below_the_minimum_size_drives_nothing_but_stop_and_quit() {
    // Held engaged to prove the console's small-window rule, not device timing: on the tolerant Alice.
    let svc = Service::start_tolerant("attach-small");
    let mut c = attach(&svc.socket);
    c.engage();
    c.term.resize(60, 20);
    c.wait_for("the too-small message", |s| s.contains("at least 80×22"));
    c.keys("s0.7\r");
    c.wait_for("the edit refused", |s| {
        s.contains("edit refused: the window is 60×20")
    });
    let snap = svc.ctl(&["status", "--json"]);
    let snap: serde_json::Value = serde_json::from_slice(&snap.stdout).unwrap();
    let steer = snap["devices"]
        .as_array()
        .unwrap()
        .iter()
        .find(|d| d["name"] == "steer")
        .unwrap();
    assert_ne!(steer["commanded"], serde_json::json!(0.7), "{steer}");
    assert_eq!(
        snap["gate"]["engaged"], true,
        "still engaged by this console"
    );
    c.keys(" ");
    c.wait_for("the stop", |s| s.contains("STOP: disengaged"));
    assert_eq!(svc.gate()["engaged"], false);
    c.keys("E");
    c.wait_for("engage refused", |s| s.contains("engage refused"));
    c.keys("yx");
    c.wait_for("the bench refused", |s| s.contains("bench refused"));
    assert_eq!(svc.gate()["engaged"], false);
    c.term.resize(100, 30);
    c.wait_for("the screen again", |s| {
        s.contains("STEER") && !s.contains("at least")
    });
    c.engage();
    assert_eq!(svc.gate()["engaged"], true);
    c.term.resize(60, 20);
    c.wait_for("the too-small message", |s| s.contains("at least 80×22"));
    c.keys("q");
    assert_eq!(c.wait_exit(), Some(0));
    // A commanding console that quits is its watchdog: the safe state, disengaged.
    common::wait_for("the vehicle disengaged", || svc.gate()["engaged"] == false);
}

/// The defect: a commanding `adrive attach` frozen (SIGSTOP, as Ctrl-Z or a frozen
/// session does) and resumed: adrive dropped it after about 4 s saying it "went away
/// (its connection closed)", and the console said "adrive went away" though adrive
/// still ran. Both ends say what happened: adrive, that the console stopped reading,
/// for how long, and that it dropped it (the vehicle stopped first: its watchdog); the
/// console, once it runs again, that adrive dropped it and why.
#[test]
fn a_frozen_commanding_console_is_dropped_and_both_ends_say_so() {
    // Held engaged to prove the console's own watchdog, not device timing: on the tolerant Alice.
    let svc = Service::start_tolerant("attach-frozen");
    let mut c = attach(&svc.socket);
    c.engage();
    assert!(common::signal(&c.child, libc::SIGSTOP));
    let line = svc.until("stopped reading for");
    assert!(
        line.contains("console #") && line.contains(": dropped"),
        "{line}"
    );
    // The vehicle stopped first: a frozen console's terminal answers nothing, and its
    // link's watchdog is shorter than adrive's patience with a client not reading.
    let gate = svc.gate();
    assert_eq!(gate["engaged"], false, "{gate}");
    let reason = gate["reason"].as_str().unwrap();
    assert!(
        reason.contains("its terminal stopped answering for"),
        "{reason}"
    );
    let why = &gate["cause"]["why"];
    assert_eq!(
        (why["kind"].as_str(), why["trip"].as_str()),
        (Some("watchdog"), Some("terminal")),
        "{gate}"
    );
    assert!(!reason.contains("went away"), "{reason}");
    // Resumed, the console reads what was sent, then adrive's word.
    assert!(common::signal(&c.child, libc::SIGCONT));
    assert_eq!(c.wait_exit(), Some(1));
    let text = String::from_utf8_lossy(&c.term.bytes()).into_owned();
    assert!(
        text.contains("adrive dropped this console: it stopped reading for"),
        "{text}"
    );
    assert!(!text.contains("went away"), "{text}");
    assert!(svc.ctl(&["status"]).status.success(), "adrive still runs");
}

/// The incident: adrive frozen (SIGSTOP; a hung host, a stalled link to it) under a
/// commanding `adrive attach`: for as long as it lasted the console showed `COMMANDING
/// … ENGAGED`, every figure frozen and nothing dimmed, as if live. A console whose
/// adrive sends no frame for a second says so in the gate's place, in the fault's
/// colour, with what adrive said last; the first frame after takes it away.
#[test]
fn an_attached_console_says_when_its_adrive_sends_nothing() {
    // Held engaged through a freeze of adrive itself: on the tolerant Alice.
    let svc = Service::start_tolerant("attach-quiet");
    let mut c = attach(&svc.socket);
    c.engage();
    assert!(common::signal(&svc.child, libc::SIGSTOP));
    let s = c.wait_for("the header to say adrive is silent", |s| {
        s.contains("NO WORD FROM ADRIVE")
    });
    let top = s.lines().next().unwrap_or_default();
    assert!(top.contains("(last said engaged)"), "{top}");
    assert!(!top.contains("│ ENGAGED"), "{top}");
    assert!(common::signal(&svc.child, libc::SIGCONT));
    c.wait_for("the gate again", |s| {
        !s.contains("NO WORD FROM ADRIVE")
            && s.lines().next().is_some_and(|l| l.contains("ENGAGED"))
    });
    c.keys("q");
    assert_eq!(c.wait_exit(), Some(0));
}

/// A STOP an attached console's adrive did not confirm (adrive frozen: a hung host, a
/// stalled link) was said once, as any message, and faded after 8 s with nothing
/// confirmed. It stays, counting, until adrive speaks again and shows the vehicle
/// disengaged — here by doing the STOP that waited in its socket.
#[test]
fn a_stop_adrive_did_not_confirm_stays_said_until_adrive_shows_the_vehicle_disengaged() {
    let svc = Service::start_tolerant("attach-stop-unconfirmed");
    let mut c = attach(&svc.socket);
    c.engage();
    assert!(common::signal(&svc.child, libc::SIGSTOP));
    c.wait_for("the header to say adrive is silent", |s| {
        s.contains("NO WORD FROM ADRIVE")
    });
    c.keys(" ");
    // Past the 8 s any other message stays, the STOP is still said not confirmed.
    let ago = |s: &str| -> Option<u64> {
        let rest = s.split("STOP NOT CONFIRMED (").nth(1)?;
        rest.split(" s ago)").next()?.parse().ok()
    };
    let s = c.wait_for("the unconfirmed STOP past a message's 8 s", |s| {
        ago(s).is_some_and(|a| a >= 9)
    });
    assert!(s.contains("no reply from adrive within 3 s"), "{s}");
    assert!(common::signal(&svc.child, libc::SIGCONT));
    c.wait_for("adrive's word that the vehicle is disengaged", |s| {
        s.contains("adrive answers again: the vehicle is disengaged")
            && !s.contains("STOP NOT CONFIRMED")
            && s.lines().next().is_some_and(|l| l.contains("DISENGAGED"))
    });
    let gate = svc.gate();
    assert_eq!(gate["engaged"], false, "{gate}");
    c.keys("q");
    assert_eq!(c.wait_exit(), Some(0));
}

/// An attached console says how its adrive ended: stopping (adrive's own word), or
/// gone without a word (killed: nothing answers at its socket any more).
#[test]
fn an_attached_console_says_whether_adrive_stopped_or_went_away() {
    let mut svc = Service::start("attach-ends", None);
    let mut c = attach(&svc.socket);
    common::signal(&svc.child, libc::SIGTERM);
    assert_eq!(c.wait_exit(), Some(1));
    let text = String::from_utf8_lossy(&c.term.bytes()).into_owned();
    assert!(text.contains("adrive: adrive is stopping"), "{text}");
    let _ = wait_exit(&mut svc.child);

    let mut svc = Service::start("attach-killed", None);
    let mut c = attach(&svc.socket);
    common::signal(&svc.child, libc::SIGKILL);
    let _ = wait_exit(&mut svc.child);
    assert_eq!(c.wait_exit(), Some(1));
    let text = String::from_utf8_lossy(&c.term.bytes()).into_owned();
    assert!(
        text.contains("adrive went away (the connection closed); nothing answers at its socket"),
        "{text}"
    );
    // Its simulator's directory of port links is left behind (nothing runs after
    // SIGKILL): the test's to remove.
    let killed = format!("adrive-sim-{}-", svc.child.id());
    for left in common::sim_dirs(&std::env::temp_dir()) {
        if left.starts_with(&killed) {
            std::fs::remove_dir_all(std::env::temp_dir().join(left)).unwrap();
        }
    }
}

#[test]
fn operator_commands_engage_release_stop_with_exit_statuses() {
    // Held engaged to prove the operator's commands, not device timing: on the tolerant Alice.
    let svc = Service::start_tolerant("attach-ctl");
    let out = svc.ctl(&["status"]);
    assert!(out.status.success(), "{out:?}");
    let table = String::from_utf8_lossy(&out.stdout);
    for d in ["steer", "gas", "brake", "trans", "estop", "obd"] {
        assert!(table.contains(d), "{table}");
    }
    // Engage as an operator (retrying while devices have not all reported).
    let end = Instant::now() + DEADLINE;
    let out = loop {
        let out = svc.ctl(&["engage"]);
        if out.status.success() || Instant::now() > end {
            break out;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    assert!(out.status.success(), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("engaged"));
    let gate = svc.gate();
    assert!(
        gate["commander"].as_str().unwrap().starts_with("operator"),
        "{gate}"
    );
    // The operator's vehicle is not a planner's: its engage is refused (status 1).
    let planner = svc.send(&["engage", "steer", "0.2"]);
    assert!(
        String::from_utf8_lossy(&planner.stdout).contains("commanded by operator"),
        "{planner:?}"
    );
    // Release, then stop; stopping a stopped vehicle is no error.
    let out = svc.ctl(&["release"]);
    assert!(out.status.success(), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("released"));
    let out = svc.ctl(&["release"]);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("release refused"));
    let out = svc.ctl(&["stop"]);
    assert!(out.status.success(), "{out:?}");
    assert_eq!(svc.gate()["engaged"], false);
    let out = svc.ctl(&["disengage"]);
    assert!(out.status.success(), "{out:?}");
    // Nothing at the socket: status 1, saying where it looked.
    let nowhere = svc.dir.path().join("nobody.sock");
    let out = ctl(&nowhere, &["status"]);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no adrive at") && err.contains("nobody.sock"),
        "{err}"
    );
}

#[allow(unsafe_code)]
#[test]
fn the_socket_is_0660_in_the_process_group_and_a_second_adrive_on_it_is_refused() {
    let svc = Service::start("attach-socket", None);
    let meta = std::fs::metadata(&svc.socket).unwrap();
    assert_eq!(meta.permissions().mode() & 0o777, 0o660);
    // SAFETY: getegid has no preconditions.
    assert_eq!(meta.gid(), unsafe { libc::getegid() });
    let out = Command::new(BIN)
        .args([
            "--sim",
            "--headless",
            "--listen",
            "127.0.0.1:0",
            "--log-dir",
        ])
        .arg(svc.dir.path().join("log2"))
        .arg("--socket")
        .arg(&svc.socket)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("in use by another adrive")
            && err.contains(&format!("pid {}", svc.child.id())),
        "{err}"
    );
    // The first is untouched.
    assert!(svc.ctl(&["status"]).status.success());
}

/// Start adrive `args` with its socket at `socket`; once it listens, `end` it; the
/// socket must be gone after.
#[allow(unsafe_code)]
fn socket_removed_after(
    name: &str,
    extra: &[&str],
    end: impl FnOnce(&mut Child, &mut Option<Master>),
) {
    // The default path a user without a runtime directory gets: under the temporary
    // directory, in a directory of its own that must go with it.
    let dir = tempdir(name);
    // SAFETY: getuid cannot fail.
    let uid = unsafe { libc::getuid() };
    let own = dir.path().join(format!("adrive-{uid}"));
    let socket = own.join("adrive.sock");
    let mut cmd = Command::new(BIN);
    cmd.args(["--sim", "--listen", "127.0.0.1:0", "--log-dir"])
        .arg(dir.path().join("log"))
        .args(extra)
        .env("TERM", "xterm-256color")
        .env("TMPDIR", dir.path())
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("RUNTIME_DIRECTORY");
    let (mut child, mut term) = if extra.contains(&"--headless") {
        let c = cmd
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        (c, None)
    } else {
        let (c, m) = Master::spawn(&mut cmd, 100, 30, true);
        (c, Some(m))
    };
    common::wait_for("the socket", || ctl(&socket, &["status"]).status.success());
    end(&mut child, &mut term);
    let status = wait_exit(&mut child);
    assert!(status.is_some(), "{name}: adrive did not exit");
    assert!(!socket.exists(), "{name}: the socket was left behind");
    assert!(!own.exists(), "{name}: its directory was left behind");
}

#[test]
fn the_socket_is_removed_on_every_exit_path_and_a_stale_one_is_replaced() {
    for (name, sig) in [
        ("sock-term", libc::SIGTERM),
        ("sock-int", libc::SIGINT),
        ("sock-hup", libc::SIGHUP),
    ] {
        socket_removed_after(name, &["--headless"], |c, _| {
            common::signal(c, sig);
        });
    }
    // A panic in a thread.
    socket_removed_after(
        "sock-panic",
        &["--headless", "--inject-panic", "supervisor:300ms"],
        |_, _| {},
    );
    // The embedded console: `q`, and its terminal closing.
    socket_removed_after("sock-quit", &[], |_, t| t.as_mut().unwrap().write(b"q"));
    socket_removed_after("sock-drop", &[], |_, t| t.as_mut().unwrap().hang_up());

    // kill -9 leaves the socket behind; the next adrive replaces it.
    let svc = Service::start("sock-stale", None);
    let socket = svc.socket.clone();
    let mut svc = svc;
    common::signal(&svc.child, libc::SIGKILL);
    let _ = wait_exit(&mut svc.child);
    assert!(socket.exists(), "nothing stale to replace");
    // Its simulator's directory of port links is left behind too (nothing runs after
    // SIGKILL): the test's to remove.
    let killed = format!("adrive-sim-{}-", svc.child.id());
    for left in common::sim_dirs(&std::env::temp_dir()) {
        if left.starts_with(&killed) {
            std::fs::remove_dir_all(std::env::temp_dir().join(left)).unwrap();
        }
    }
    let out = ctl(&socket, &["status"]);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let mut cmd = Command::new(BIN);
    let mut child = common::Reaped(
        cmd.args([
            "--sim",
            "--headless",
            "--listen",
            "127.0.0.1:0",
            "--log-dir",
        ])
        .arg(svc.dir.path().join("log"))
        .arg("--socket")
        .arg(&socket)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap(),
    );
    let log = lines(child.stderr.take().unwrap());
    common::until(&log, "replaced a stale socket");
    common::wait_for("the new socket", || {
        ctl(&socket, &["status"]).status.success()
    });
}

/// A client past the control socket's limits had its connection closed with no word:
/// past 32 clients `adrive ctl` is told the limit, and so is a client whose request
/// line is too long.
#[test]
fn clients_past_the_control_socket_s_limits_are_told_the_limit() {
    use std::io::{BufRead, BufReader, Write};
    use std::os::unix::net::UnixStream;
    let svc = Service::start("attach-full", None);
    // A line longer than any request: told so, then closed.
    let mut long = UnixStream::connect(&svc.socket).unwrap();
    long.set_read_timeout(Some(DEADLINE)).unwrap();
    long.write_all(&[b'x'; 5000]).unwrap();
    // The farewell starts a line of its own (after a line break), whatever came before.
    let mut bye = String::new();
    let mut lines = BufReader::new(&long);
    while bye.trim().is_empty() {
        bye.clear();
        if lines.read_line(&mut bye).unwrap() == 0 {
            break;
        }
    }
    assert!(
        bye.contains("bye") && bye.contains("at most 4096 bytes"),
        "{bye}"
    );
    // 32 clients that only stay connected: the 33rd, a real `adrive ctl`, is told.
    let held: Vec<UnixStream> = (0..32)
        .map(|_| UnixStream::connect(&svc.socket).unwrap())
        .collect();
    let out = svc.ctl(&["status"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("32 clients at most"), "{err}");
    drop(held);
    common::wait_for("a client served again", || {
        svc.ctl(&["status"]).status.success()
    });
}

/// The bound a commanding console's terminal must answer within (the vehicle file's
/// `[console] terminal_timeout`, by default).
const TERMINAL_TIMEOUT: Duration = Duration::from_secs(1);

impl Service {
    /// Wait until the gate disengages; how long after `from` it was seen, and why.
    fn wait_disengaged(&self, from: Instant) -> (Duration, String) {
        let end = Instant::now() + DEADLINE;
        loop {
            let g = self.gate();
            if g["engaged"] != true {
                return (from.elapsed(), g["reason"].as_str().unwrap_or("").into());
            }
            assert!(Instant::now() < end, "still engaged after {DEADLINE:?}");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Read the state broadcast until a snapshot's gate satisfies `want`; that gate.
    fn broadcast_until(
        &self,
        what: &str,
        want: impl Fn(&serde_json::Value) -> bool,
    ) -> serde_json::Value {
        let end = Instant::now() + DEADLINE;
        let mut buf = vec![0u8; 65536];
        loop {
            assert!(Instant::now() < end, "no broadcast with {what}");
            let Ok(n) = self.broadcast.recv(&mut buf) else {
                continue;
            };
            let snap: serde_json::Value = serde_json::from_slice(&buf[..n]).expect("a snapshot");
            if want(&snap["gate"]) {
                return snap["gate"].clone();
            }
        }
    }

    /// Engaged, for `d`, checked all along.
    fn stays_engaged(&self, d: Duration) {
        let end = Instant::now() + d;
        while Instant::now() < end {
            let g = self.gate();
            assert_eq!(g["engaged"], true, "disengaged: {}", g["reason"]);
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

/// The incident as reported: `ssh -t vehicle adrive attach`, engaged, then the
/// operator's session froze — its terminal stopped reading (and so answering) what the
/// console writes. A watcher's terminal freezing first changes nothing; the
/// commander's brings the safe state within the bound, said as such in the gate's
/// reason, the log and the state broadcast; the commander who comes back, and a
/// console attaching afterwards, read why.
#[test]
fn an_attached_commander_whose_terminal_stops_reading_stops_the_vehicle_and_a_watcher_never_does() {
    commander_stalls("attach-stall", Player::stop_reading);
}

/// The same with a terminal that still reads what the console draws but answers no
/// round trip any more (the way back is what stalled).
#[test]
fn an_attached_commander_whose_terminal_stops_answering_stops_the_vehicle() {
    commander_stalls("attach-mute", Player::stop_answering);
}

/// A watcher and a commander attached; the watcher's terminal stalls as `stall` says,
/// then the commander's.
fn commander_stalls(name: &str, stall: fn(&Player)) {
    let svc = Service::start_tolerant(name);
    let watcher = attach(&svc.socket);
    let mut driver = attach(&svc.socket);
    driver.engage();
    // The watcher's terminal stalls: command is held, well past the bound.
    stall(&watcher.term);
    svc.stays_engaged(TERMINAL_TIMEOUT * 3);
    assert!(
        driver.term.cursor_answers() > 4,
        "the commander's terminal answered"
    );
    assert_eq!(
        watcher.term.cursor_requests(),
        0,
        "a watcher asks its terminal nothing"
    );
    let stalled = Instant::now();
    stall(&driver.term);
    let (after, why) = svc.wait_disengaged(stalled);
    // The engine's own measure of the silence when it acted: the bound, and its tick.
    assert!(
        why.contains("watchdog: console #2: its terminal stopped answering for 1."),
        "{why}"
    );
    assert!(
        after < TERMINAL_TIMEOUT + Duration::from_millis(1500),
        "the safe state came {after:?} after the stall"
    );
    svc.until("watchdog: console #2: its terminal stopped answering for 1.");
    // The state broadcast says it (read on from the datagrams queued since the start).
    svc.broadcast_until("the reason", |g| {
        g["engaged"] == false
            && g["reason"]
                .as_str()
                .is_some_and(|r| r.contains("console #2: its terminal stopped answering"))
    });
    // The commander comes back: its screen says why.
    driver.term.set(|p| {
        p.reading = true;
        p.cursor = Answer::Now;
    });
    driver.wait_for("why", |s| s.contains("stopped answering"));
    // So does a console that attaches afterwards.
    let later = attach(&svc.socket);
    later.wait_for("why", |s| s.contains("stopped answering"));
    // And the watcher was never dropped: it reads on once its terminal does.
    watcher.term.set(|p| p.reading = true);
    watcher.wait_for("why", |s| s.contains("stopped answering"));
}

/// The client itself frozen (its process stopped, as a laptop asleep stops ssh): its
/// proofs stop, and so does the vehicle, within the bound.
#[test]
fn a_frozen_attach_client_stops_the_vehicle_within_the_bound() {
    let svc = Service::start_tolerant("attach-frozen-proof");
    let mut driver = attach(&svc.socket);
    driver.engage();
    svc.stays_engaged(TERMINAL_TIMEOUT * 2);
    let frozen = Instant::now();
    assert!(common::signal(&driver.child, libc::SIGSTOP));
    let (after, why) = svc.wait_disengaged(frozen);
    assert!(common::signal(&driver.child, libc::SIGCONT));
    assert!(
        why.contains("console #1: its terminal stopped answering for 1."),
        "{why}"
    );
    assert!(
        after < TERMINAL_TIMEOUT + Duration::from_millis(1500),
        "the safe state came {after:?} after the freeze"
    );
}

/// A slow but live link through `adrive attach`: answers 300 ms late keep command for
/// a minute — the bound runs from the last answer.
#[test]
fn an_attached_console_on_a_slow_but_live_link_keeps_command_for_a_minute() {
    let svc = Service::start_tolerant("attach-slow");
    let play = Play {
        cursor: Answer::After(Duration::from_millis(300)),
        ..Play::default()
    };
    let mut driver = attach_playing(&svc.socket, play);
    driver.engage();
    svc.stays_engaged(Duration::from_secs(60));
    assert!(driver.term.cursor_answers() > 150);
}

/// An attached console's bench key for characterize is refused at once, saying where it
/// runs; nothing is engaged or moved.
#[test]
fn an_attached_console_is_told_where_characterize_runs() {
    let svc = Service::start("attach-characterize", None);
    let mut c = attach(&svc.socket);
    c.keys("x");
    c.wait_for("the bench", |s| s.contains("BENCH") && s.contains("┌STEER"));
    c.keys("M");
    let s = c.wait_for("refused", |s| s.contains("characterize steer refused"));
    assert!(
        s.contains("characterize runs where the vehicle's engine runs"),
        "{s}"
    );
    assert!(!s.contains("Characterize steer ("), "{s}");
    assert_eq!(svc.gate()["engaged"], false);
    c.keys("q");
    assert_eq!(c.wait_exit(), Some(0));
}
