//! Every way adrive ends, with the real binary driving `adrive sim` (another process)
//! over pseudo-terminals: SIGINT, SIGTERM, SIGHUP, a panic in a thread, a panic in the
//! main thread, a fatal device error — each first brings the simulated gas to 0 and the
//! brake on, then flushes its log and exits with its status — and `kill -9`, after
//! which the simulated actuators' own watchdogs brake the vehicle.

mod common;

use common::pty::Master;
use common::simproc::{vehicle_file, SimProcess};
use common::{free_port, tempdir, DEADLINE};
use std::process::{Child, Command as Process, ExitStatus, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_adrive");

struct Adrive {
    child: Child,
    port: u16,
    dir: tempfile::TempDir,
    /// With the console: the master side of its terminal.
    terminal: Option<Master>,
}

impl Adrive {
    fn start(name: &str, sim: &SimProcess, extra_args: &[&str], supervisor: &str) -> Adrive {
        Adrive::start_on(name, sim, extra_args, supervisor, false)
    }

    /// `tolerant`: Alice made tolerant of this shared machine's stalls
    /// ([`common::tolerant`]), for a run held engaged for seconds.
    fn start_on(
        name: &str,
        sim: &SimProcess,
        extra_args: &[&str],
        supervisor: &str,
        tolerant: bool,
    ) -> Adrive {
        let (dir, port, mut cmd) = Adrive::command(name, sim, supervisor, tolerant);
        let child = cmd
            .arg("--headless")
            .args(extra_args)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        Adrive {
            child,
            port,
            dir,
            terminal: None,
        }
    }

    /// adrive on a pseudo-terminal, as over SSH, once it `shows` a word there;
    /// `controlling`: the terminal is its controlling terminal (the kernel sends
    /// SIGHUP when it hangs up).
    fn on_terminal(
        name: &str,
        sim: &SimProcess,
        args: &[&str],
        shows: &str,
        controlling: bool,
    ) -> Adrive {
        let (dir, port, mut cmd) = Adrive::command(name, sim, "", false);
        cmd.args(args).env("TERM", "xterm-256color");
        let (child, terminal) = Master::spawn(&mut cmd, 100, 30, controlling);
        let adrive = Adrive {
            child,
            port,
            dir,
            terminal: Some(terminal),
        };
        common::wait_for(shows, || {
            let out = adrive.terminal.as_ref().unwrap().bytes();
            out.windows(shows.len()).any(|w| w == shows.as_bytes())
        });
        adrive
    }

    /// adrive on the simulator's ports with its own command port and log directory.
    fn command(
        name: &str,
        sim: &SimProcess,
        supervisor: &str,
        tolerant: bool,
    ) -> (tempfile::TempDir, u16, Process) {
        let dir = tempdir(name);
        let mut config = vehicle_file(dir.path(), sim, supervisor);
        if tolerant {
            config = common::tolerant(config);
        }
        let port = free_port();
        let mut cmd = Process::new(BIN);
        cmd.arg("--config")
            .arg(&config)
            .args(["--listen", &format!("127.0.0.1:{port}"), "--log-dir"])
            .arg(dir.path().join("log"))
            .env("XDG_RUNTIME_DIR", dir.path().join("log"));
        (dir, port, cmd)
    }

    /// A planner: engage, drive, gas 0.3, twenty times a second.
    fn planner(&self) -> Child {
        Process::new(BIN)
            .args([
                "send",
                "--to",
                &format!("127.0.0.1:{}", self.port),
                "--rate",
                "20",
            ])
            .args(["engage", "trans", "drive", "accel", "0.3"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap()
    }

    #[allow(unsafe_code)]
    fn signal(&self, sig: i32) {
        // SAFETY: kill(2) on our own child.
        assert_eq!(unsafe { libc::kill(self.child.id() as i32, sig) }, 0);
    }

    fn wait(&mut self) -> Option<i32> {
        self.wait_status().code()
    }

    fn wait_status(&mut self) -> ExitStatus {
        let end = Instant::now() + DEADLINE;
        loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                return s;
            }
            assert!(Instant::now() < end, "adrive did not exit");
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    fn log(&self) -> String {
        // The log files (the control socket's directory is beside them).
        std::fs::read_dir(self.dir.path().join("log"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.is_file())
            .map(|p| std::fs::read_to_string(p).unwrap())
            .collect()
    }
}

impl Drop for Adrive {
    fn drop(&mut self) {
        common::stop(&mut self.child);
    }
}

/// Drive the simulated Alice until gas 0.3 reaches the gas device; returns the planner.
fn drive(sim: &SimProcess, adrive: &Adrive) -> common::Reaped {
    let planner = common::Reaped(adrive.planner());
    sim.wait_for(&["gas", "<-", "0.300"]);
    planner
}

/// End adrive the given way while the vehicle drives; check the safe state reached the
/// devices first, the exit status, and the log. `tolerant`: on the tolerant Alice, for
/// a way that holds the vehicle engaged for seconds first.
fn ends_safely(
    name: &str,
    args: &[&str],
    supervisor: &str,
    tolerant: bool,
    end: impl FnOnce(&mut SimProcess, &Adrive),
    status: i32,
    stopping: &str,
) {
    let mut sim = SimProcess::start();
    let mut adrive = Adrive::start_on(name, &sim, args, supervisor, tolerant);
    let mut planner = drive(&sim, &adrive);
    end(&mut sim, &adrive);
    assert_eq!(adrive.wait(), Some(status), "exit status after {name}");
    let _ = planner.kill();
    let _ = planner.wait();
    assert_eq!(
        sim.last_command("gas").as_deref(),
        Some("0.000"),
        "gas after {name}"
    );
    assert_eq!(
        sim.last_command("brake").as_deref(),
        Some("1.000"),
        "brake after {name}"
    );
    let log = adrive.log();
    assert!(
        log.contains(stopping),
        "{name}: log lacks {stopping:?}:\n{log}"
    );
    assert!(
        log.contains("safe state acknowledged"),
        "{name}: log lacks the safe state:\n{log}"
    );
}

#[test]
fn sigint_stops_safely() {
    ends_safely(
        "int",
        &[],
        "",
        false,
        |_, a| a.signal(libc::SIGINT),
        0,
        "stopping: SIGINT",
    );
}

#[test]
fn sigterm_stops_safely() {
    ends_safely(
        "term",
        &[],
        "",
        false,
        |_, a| a.signal(libc::SIGTERM),
        0,
        "stopping: SIGTERM",
    );
}

#[test]
fn sighup_stops_safely() {
    ends_safely(
        "hup",
        &[],
        "",
        false,
        |_, a| a.signal(libc::SIGHUP),
        129,
        "stopping: SIGHUP",
    );
}

#[test]
fn a_panic_in_a_thread_stops_safely() {
    ends_safely(
        "panic-thread",
        &["--inject-panic", "supervisor:5s"],
        "",
        // Held engaged for 5 s to prove the exit path, not device timing.
        true,
        |_, _| {},
        101,
        "stopping: panic: thread supervisor",
    );
}

#[test]
fn a_panic_in_the_main_thread_stops_safely() {
    ends_safely(
        "panic-main",
        &["--inject-panic", "main:5s"],
        "",
        // Held engaged for 5 s to prove the exit path, not device timing.
        true,
        |_, _| {},
        101,
        "engine dropped without shutdown",
    );
}

#[test]
fn a_fatal_device_error_stops_safely() {
    ends_safely(
        "fatal",
        &[],
        "attempts = 1\nstep_timeout = \"1s\"\ngive_up_after = \"1s\"",
        false,
        |sim, _| {
            sim.say("nostart on");
            sim.say("stall");
        },
        4,
        "stopping: fatal device error: recovery engine_stall gave up",
    );
}

/// The brake vanishes for good while the vehicle drives, on a service told to give up
/// (`--give-up-after 2s`): a fatal device error, 4, and the safe state cannot be acknowledged
/// (3). The status must say the worse, 3: the vehicle may still be moving. It once said
/// 4.
#[test]
fn a_recovery_that_gives_up_without_the_safe_state_acknowledged_exits_3() {
    let mut sim = SimProcess::start();
    let mut adrive = Adrive::start("unsafe-fatal", &sim, &["--give-up-after", "2s"], "");
    let mut planner = drive(&sim, &adrive);
    sim.say("vanish brake 600000");
    let status = adrive.wait_status();
    let _ = planner.kill();
    let _ = planner.wait();
    let log = adrive.log();
    assert_eq!(status.code(), Some(3), "{status}; log:\n{log}");
    assert!(
        log.contains("stopping: fatal device error: brake gone for"),
        "{log}"
    );
    assert!(log.contains("safe state was NOT acknowledged"), "{log}");
    sim.stop();
}

/// An SSH session drops while the console drives: sshd closes the master side of the
/// console's terminal. The console must not die with its terminal (it once aborted on
/// a failed write to it, leaving the vehicle to the devices' own watchdogs): it stops
/// as on a hang-up, the safe state first.
#[test]
fn dropped_ssh_session_closes_the_terminal_and_the_vehicle_is_braked() {
    the_terminal_goes_away("ssh-drop", &[], "STEER", true);
}

/// The same without SIGHUP (the terminal was not the console's controlling terminal):
/// the dead terminal alone must be noticed and end the run the same way.
#[test]
fn a_terminal_closed_without_a_hangup_signal_still_brakes_the_vehicle() {
    the_terminal_goes_away("tty-gone", &[], "STEER", false);
}

/// Headless in an SSH session that drops: SIGHUP stops it safely, and the summary it
/// prints on the way out to the dead terminal must not turn that into a panic (101).
#[test]
fn dropped_ssh_session_under_headless_exits_as_a_hang_up() {
    the_terminal_goes_away("ssh-headless", &["--headless"], "running headless", true);
}

fn the_terminal_goes_away(name: &str, args: &[&str], shows: &str, controlling: bool) {
    let sim = SimProcess::start();
    let mut adrive = Adrive::on_terminal(name, &sim, args, shows, controlling);
    let mut planner = drive(&sim, &adrive);
    adrive.terminal.as_mut().unwrap().hang_up();
    let status = adrive.wait_status();
    let _ = planner.kill();
    let _ = planner.wait();
    let log = adrive.log();
    assert_eq!(status.code(), Some(129), "{status}; log:\n{log}");
    assert_eq!(sim.last_command("gas").as_deref(), Some("0.000"), "gas");
    assert_eq!(sim.last_command("brake").as_deref(), Some("1.000"), "brake");
    let stopping = log.lines().find(|l| l.contains("stopping: "));
    assert!(
        stopping.is_some_and(|l| l.contains("terminal hung up")),
        "no hang-up stopping line:\n{log}"
    );
    assert!(
        log.contains("safe state acknowledged"),
        "the log lacks the safe state:\n{log}"
    );
    sim.stop();
}

/// `kill -9` leaves adrive no chance: the simulated actuators' own watchdogs release
/// the gas and apply the brake.
#[test]
fn kill_9_leaves_the_vehicle_braked_by_the_device_watchdogs() {
    let sim = SimProcess::start();
    let mut adrive = Adrive::start("kill9", &sim, &[], "");
    let mut planner = drive(&sim, &adrive);
    adrive.signal(libc::SIGKILL);
    assert_eq!(adrive.wait(), None, "killed by a signal");
    let gas = sim.wait_for(&["gas", "device watchdog", "went to 0.000"]);
    let brake = sim.wait_for(&["brake", "device watchdog", "went to 1.000"]);
    assert!(gas.contains("no command for 1s"), "{gas}");
    assert!(brake.contains("no command for 1s"), "{brake}");
    // The device acted on its own: nothing arrived.
    assert!(
        !gas.contains("<-") && !brake.contains("<-"),
        "{gas}\n{brake}"
    );
    let _ = planner.kill();
    let _ = planner.wait();
}
