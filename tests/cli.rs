//! The real `adrive` binary as a user runs it: a malformed config, a headless run
//! stopped by a signal, and `adrive sim` serving a device on a pseudo-terminal, with
//! its standard input open or closed, and cleaning up after itself when signalled.

mod common;

use adrive::config::VehicleConfig;
use adrive::driver;
use adrive::value::Command;
use common::{lines, signal, sim_dirs, tempdir, until, wait_exit};
use std::io::{Read, Write};
use std::process::{Command as Process, Stdio};
use std::time::Duration;

const BIN: &str = env!("CARGO_BIN_EXE_adrive");

/// `adrive --headless --config vehicle`, logging into `dir/log`, to its end.
fn headless_on(dir: &std::path::Path, vehicle: &std::path::Path) -> std::process::Output {
    common::output_within(
        Process::new(BIN)
            .args(["--headless", "--config"])
            .arg(vehicle)
            .arg("--log-dir")
            .arg(dir.join("log"))
            .env("XDG_RUNTIME_DIR", dir.join("log")),
    )
}

#[test]
fn a_malformed_config_names_file_and_line_and_exits_nonzero() {
    let dir = tempdir("cli");
    let path = dir.path().join("bad.toml");
    std::fs::write(
        &path,
        "[vehicle]\nname = \"x\"\n\n[[device]]\nname = \"steer\"\ndriver = \"modbsu\"\nport = \"/dev/ttyUSB0\"\n",
    )
    .unwrap();
    let out = headless_on(dir.path(), &path);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains(&format!("{}:6: ", path.display())), "{err}");
    assert!(err.contains("modbsu") && err.contains("line"), "{err}");
    // It stopped before starting anything: no log was even written.
    assert!(!dir.path().join("log").exists());
}

/// One port spelled two ways — a `/dev/serial/by-id/…`-style link and its target — once
/// passed as two, and both devices opened it. The real binary refuses the file before
/// anything starts, at the second one's port, naming the first with its line.
#[test]
fn one_port_spelled_two_ways_is_refused_at_the_second_s_line_before_anything_starts() {
    let dir = tempdir("cli-ports");
    let tty = dir.path().join("ttyUSB0");
    std::fs::write(&tty, "").unwrap();
    let link = dir.path().join("usb-FTDI_brake-if00-port0");
    std::os::unix::fs::symlink(&tty, &link).unwrap();
    let path = dir.path().join("vehicle.toml");
    std::fs::write(
        &path,
        format!(
            "[vehicle]\nname = \"x\"\n\n[[device]]\nname = \"brake\"\nkind = \"setpoint\"\nrange = [0.0, 1.0]\ndriver = \"line\"\nport = \"{}\"\n\n[[device]]\nname = \"horn\"\nkind = \"state\"\nstates = [\"off\", \"on\"]\ndriver = \"line\"\nport = \"{}\"\n",
            link.display(),
            tty.display()
        ),
    )
    .unwrap();
    let out = headless_on(dir.path(), &path);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    let canonical = std::fs::canonicalize(&tty).unwrap();
    assert!(
        err.contains(&format!(
            "{p}:16: horn: port: {} is brake's port, {}, by another name (both are {}) ({p}:9): a serial port has one device",
            tty.display(),
            link.display(),
            canonical.display(),
            p = path.display()
        )),
        "{err}"
    );
    assert!(!dir.path().join("log").exists(), "it started");
}

/// The exit summary: a line per device, and the network's — its datagrams, those
/// accepted and those refused whole, then the commands refused within accepted ones,
/// each group under its own words (one count of datagrams and commands mixed read as
/// a contradiction: `111 datagrams, 111 accepted; rejected: disengaged 60`).
#[test]
fn headless_sim_stops_safely_on_sigterm_with_a_summary() {
    let dir = tempdir("cli");
    let rec = tempdir("cli-rec");
    let file = rec.path().join("run.mcap");
    let mut child = common::headless_piped(dir.path(), &["--record", file.to_str().unwrap()]);
    let err = lines(child.stderr.take().unwrap());
    let listen = common::listen_address(&until(&err, "running headless"));
    // A datagram that is no command, and a command while disengaged: their replies say
    // they were handled.
    assert!(common::reply_to(&listen, b"\xff\x00").starts_with("rejected: "));
    assert!(common::reply_to(&listen, b"steer 0.2").starts_with("rejected steer 0.2: disengaged"));
    signal(&child, libc::SIGTERM);
    assert_eq!(wait_exit(&mut child), Some(0));
    let mut out = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut out)
        .unwrap();
    for device in ["steer", "gas", "brake", "trans", "estop", "obd"] {
        assert!(
            out.lines().any(|l| l.starts_with(device)),
            "summary lacks {device}:\n{out}"
        );
    }
    assert!(out.contains("delay p99"), "{out}");
    let network = out.lines().find(|l| l.starts_with("network ")).unwrap();
    let (head, commands) = network.split_once("; commands refused: ").unwrap();
    let (counts, whole) = head.split_once(", refused whole: ").unwrap();
    assert_eq!(
        counts,
        format!("network {listen}: 2 datagrams, 1 accepted"),
        "{network}"
    );
    assert!(
        !whole.contains(',') && whole.ends_with(" 1") && commands == "disengaged 1",
        "{network}"
    );
    // The recording's account is the same: one command, refused, and one datagram
    // refused whole (it counted the datagram as a command received).
    let info = Process::new(BIN)
        .args(["record", "info"])
        .arg(&file)
        .output()
        .unwrap();
    let info = String::from_utf8_lossy(&info.stdout);
    let commands = info
        .lines()
        .find(|l| l.starts_with("commands received"))
        .unwrap_or_default();
    assert_eq!(
        commands,
        format!(
            "commands received 1, accepted 0, refused 1 (disengaged 1); datagrams refused whole 1 ({whole})"
        ),
        "{info}"
    );
    // The rolling log file was flushed and tells the safe state was reached.
    // The log files (the control socket's directory is beside them).
    let log: String = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .map(|p| std::fs::read_to_string(p).unwrap())
        .collect();
    assert!(log.contains("stopping: SIGTERM"), "{log}");
    assert!(log.contains("safe state acknowledged"), "{log}");
}

#[test]
fn only_runs_just_the_named_devices() {
    let dir = tempdir("cli");
    let mut child = common::Reaped(
        Process::new(BIN)
            .args([
                "--sim",
                "--headless",
                "--listen",
                "127.0.0.1:0",
                "--only",
                "steer",
                "--only",
                "obd",
                "--log-dir",
            ])
            .arg(dir.path())
            .env("XDG_RUNTIME_DIR", dir.path())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let err = lines(child.stderr.take().unwrap());
    let seen = until(&err, "running headless");
    let started = seen.iter().find(|l| l.contains("engine started")).unwrap();
    assert!(
        started.contains("steer/command") && started.contains("obd/status"),
        "{started}"
    );
    assert!(!started.contains("gas/"), "{started}");
    signal(&child, libc::SIGINT);
    assert_eq!(wait_exit(&mut child), Some(0));
    let mut out = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut out)
        .unwrap();
    let devices: Vec<&str> = out
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .filter(|w| VehicleConfig::alice().device(w).is_some())
        .collect();
    assert_eq!(devices, ["steer", "obd"], "{out}");

    let bad =
        common::output_within(Process::new(BIN).args(["--sim", "--headless", "--only", "wiper"]));
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("wiper"));
}

/// `adrive sim ARGS` from the crate's directory, its standard input a pipe; the lines
/// it prints.
fn sim_process(args: &[&str]) -> (common::Reaped, std::sync::mpsc::Receiver<String>) {
    let mut child = common::Reaped(
        Process::new(BIN)
            .arg("sim")
            .args(args)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let out = lines(child.stdout.take().unwrap());
    (child, out)
}

#[test]
fn sim_prints_port_paths_and_each_command_a_device_receives() {
    let (mut child, out) = sim_process(&["--only", "steer,estop"]);
    let first = until(&out, "steer");
    let path = first
        .last()
        .unwrap()
        .split_whitespace()
        .nth(1)
        .unwrap()
        .to_string();
    let pty = std::fs::read_link(&path).unwrap();
    assert!(pty.starts_with("/dev/pts/"), "{path} -> {pty:?}");

    // Talk to it as adrive would: the built-in steering's Modbus driver and baud.
    let alice = VehicleConfig::alice();
    let steer = alice.device("steer").unwrap();
    let mut link = driver::open_serial(&path, steer.baud, Duration::from_secs(2)).unwrap();
    let mut drv = driver::build(steer);
    drv.command(link.as_mut(), Command::Set(0.25)).unwrap();
    let reading = drv.poll(link.as_mut()).unwrap();
    assert!(reading.get(0).is_some(), "position");
    let seen = until(&out, "<-");
    let line = seen.last().unwrap();
    assert!(line.contains("steer") && line.contains("0.250"), "{line}");

    // Its little command language describes itself, and says which devices a command
    // applies to.
    let stdin = child.stdin.as_mut().unwrap();
    writeln!(stdin, "help").unwrap();
    let help = until(&out, "DTC is a fault code").join("\n");
    assert!(help.contains("stuck SETPOINT on|off"), "{help}");
    assert!(help.contains("override SETPOINT X|on|off"), "{help}");
    assert!(
        help.contains(
            "SETPOINT is one of steer\n  STATEDEV is one of none in this vehicle; STATE one of its states\n  PORT is a device or a bus (a device on a bus: its bus's adapter): steer, estop"
        ),
        "{help}"
    );
    writeln!(stdin, "stuck estop on").unwrap();
    let e = until(&out, "error:").pop().unwrap();
    assert!(
        e.contains("it applies to setpoint devices (steer), not estop (a sensor)"),
        "{e}"
    );

    signal(&child, libc::SIGINT);
    assert_eq!(wait_exit(&mut child), Some(0));
}

/// `adrive sim` and what it prints: the port path of its only device.
fn sim_path(out: &std::sync::mpsc::Receiver<String>, device: &str) -> String {
    until(out, device)
        .last()
        .unwrap()
        .split_whitespace()
        .nth(1)
        .unwrap()
        .to_string()
}

/// The incident: run with its standard input closed (`adrive sim < /dev/null`, as from
/// a service), `adrive sim` stopped printing the commands its devices received, and
/// its memory grew with every one of them (an unbounded channel no longer drained).
#[test]
fn sim_with_stdin_closed_keeps_printing_every_command_its_devices_receive() {
    let mut child = common::Reaped(
        Process::new(BIN)
            .args(["sim", "--only", "gas"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let out = lines(child.stdout.take().unwrap());
    let path = sim_path(&out, "gas");
    until(&out, "Ctrl-C stops");
    let alice = VehicleConfig::alice();
    let gas = alice.device("gas").unwrap();
    let mut link = driver::open_serial(&path, gas.baud, Duration::from_secs(2)).unwrap();
    let mut drv = driver::build(gas);
    // Each command is printed, in order, long after standard input was seen closed.
    for i in 1..=50 {
        let v = f64::from(i) / 100.0;
        drv.command(link.as_mut(), Command::Set(v)).unwrap();
        let seen = until(&out, "<-");
        let line = seen.last().unwrap();
        assert!(
            line.contains("gas") && line.contains(&format!("{v:.3}")),
            "command {i}: {line}"
        );
    }
    signal(&child, libc::SIGTERM);
    assert_eq!(wait_exit(&mut child), Some(0));
}

/// Stopped by SIGTERM, SIGINT or SIGHUP, `adrive sim` removes its directory of links
/// (else every run leaves `adrive-sim-*` with dead links behind in /tmp).
#[test]
fn sim_removes_its_directory_of_links_when_signalled() {
    for sig in [libc::SIGTERM, libc::SIGINT, libc::SIGHUP] {
        let tmp = tempdir("sim-signal");
        let mut child = common::Reaped(
            Process::new(BIN)
                .args(["sim", "--only", "steer"])
                .env("TMPDIR", tmp.path())
                .stdin(Stdio::piped())
                .stdout(Stdio::piped())
                .stderr(Stdio::null())
                .spawn()
                .unwrap(),
        );
        let out = lines(child.stdout.take().unwrap());
        let path = sim_path(&out, "steer");
        assert!(path.starts_with(&*tmp.path().to_string_lossy()), "{path}");
        assert_eq!(sim_dirs(tmp.path()).len(), 1);
        signal(&child, sig);
        assert!(
            wait_exit(&mut child).is_some(),
            "signal {sig} ended it uncleanly"
        );
        assert_eq!(
            sim_dirs(tmp.path()),
            Vec::<String>::new(),
            "after signal {sig}"
        );
    }
}

/// `adrive sim | head -2` ended only at its next write, which a simulator nobody
/// drives never makes: it ran on, holding its ports, until Ctrl-C. Its reader gone, it
/// stops at once (and removes its directory of links).
#[test]
fn sim_stops_when_its_output_s_reader_goes() {
    let tmp = tempdir("sim-head");
    let mut child = common::Reaped(
        Process::new(BIN)
            .args(["sim", "--only", "steer"])
            .env("TMPDIR", tmp.path())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    // As `head` does: read what it wants, then close its end.
    let mut first = String::new();
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    std::io::BufRead::read_line(&mut out, &mut first).unwrap();
    assert!(first.starts_with("steer"), "{first}");
    drop(out);
    assert_eq!(wait_exit(&mut child), Some(0));
    assert_eq!(sim_dirs(tmp.path()), Vec::<String>::new());
}

#[test]
fn sim_takes_faults_as_flags_and_refuses_unknown_ones() {
    let (mut child, out) = sim_process(&["--only", "steer", "--fault", "silent steer on"]);
    let path = until(&out, "steer")
        .last()
        .unwrap()
        .split_whitespace()
        .nth(1)
        .unwrap()
        .to_string();
    let steer = VehicleConfig::alice();
    let steer = steer.device("steer").unwrap();
    let mut link = driver::open_serial(&path, steer.baud, Duration::from_millis(200)).unwrap();
    let mut drv = driver::build(steer);
    assert!(matches!(
        drv.poll(link.as_mut()),
        Err(driver::DriverError::Timeout(_))
    ));
    signal(&child, libc::SIGINT);
    assert_eq!(wait_exit(&mut child), Some(0));

    let bad = common::output_within(Process::new(BIN).args(["sim", "--fault", "wobble gas on"]));
    assert_eq!(bad.status.code(), Some(2));
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(err.contains("unknown command \"wobble\""), "{err}");
}

/// A headless run whose standard error goes to a file or a pipe (`2> adrive.err`, a
/// service manager's journal) logs plain text: colour escapes belong on a terminal
/// only. They once filled such files.
#[test]
fn headless_log_on_a_redirected_stderr_has_no_colour_escapes() {
    let dir = tempdir("cli-colour");
    let mut child = common::headless_piped(dir.path(), &[]);
    let err = lines(child.stderr.take().unwrap());
    let mut seen = until(&err, "running headless");
    signal(&child, libc::SIGINT);
    let status = wait_exit(&mut child);
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(status, Some(0));
    // The pipe closes when adrive exits: these are all the lines it wrote.
    seen.extend(err.iter());
    let text = seen.join("\n");
    assert!(text.contains("stopping: SIGINT"), "{text}");
    assert!(!text.contains('\x1b'), "colour escapes in:\n{text:?}");
}

/// No controlling terminal for `cmd`, as under `ssh host adrive` (no `-t`): the program
/// must not find one through /dev/tty either (nor take over the terminal running the
/// tests).
#[allow(unsafe_code)]
fn without_terminal(cmd: &mut Process) {
    use std::os::unix::process::CommandExt;
    // SAFETY: setsid is async-signal-safe.
    unsafe {
        cmd.pre_exec(|| {
            libc::setsid();
            Ok(())
        });
    }
}

/// The incident: `adrive --sim < /dev/null`, or `ssh host adrive` without `-t`, started
/// the engine, then printed "console: No such device or address" and a stray
/// `ESC[?1049l` and exited 101, as after a panic. Without a terminal on both standard
/// input and output the console is refused before anything starts: no log, no engine,
/// a message pointing to `--headless` and `ssh -t`, status 2, no escape codes.
#[test]
fn the_console_without_a_terminal_is_refused_before_anything_starts() {
    let (_master, slave) = common::pty::openpty(80, 24);
    // Standard input closed; then a terminal on standard input but a pipe on standard
    // output (`adrive | less`).
    let stdins = [Stdio::null(), Stdio::from(slave.try_clone().unwrap())];
    for (i, stdin) in stdins.into_iter().enumerate() {
        let dir = tempdir("cli-notty");
        let log = dir.path().join("log");
        let mut cmd = Process::new(BIN);
        cmd.args(["--sim", "--listen", "127.0.0.1:0", "--log-dir"])
            .arg(&log)
            .env("XDG_RUNTIME_DIR", &log)
            .stdin(stdin)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        without_terminal(&mut cmd);
        let child = common::Reaped(cmd.spawn().unwrap());
        let out = {
            let mut c = child;
            let mut out = String::new();
            let mut err = String::new();
            c.stdout.take().unwrap().read_to_string(&mut out).unwrap();
            c.stderr.take().unwrap().read_to_string(&mut err).unwrap();
            (wait_exit(&mut c), out, err)
        };
        let (status, out, err) = out;
        assert_eq!(status, Some(2), "case {i}: {err}");
        assert!(
            err.contains("needs a terminal")
                && err.contains("--headless")
                && err.contains("ssh -t"),
            "case {i}: {err}"
        );
        assert!(
            !out.contains('\x1b') && !err.contains('\x1b'),
            "case {i}: {out:?} {err:?}"
        );
        assert!(!err.contains("panic"), "case {i}: {err}");
        // Nothing started: not even the log.
        assert!(!log.exists(), "case {i}: a log was written");
    }
}

/// `adrive attach` without a terminal (`ssh host adrive attach`, no `-t`) gave the
/// embedded console's advice (`ssh -t HOST adrive`, `--headless`) and exited before
/// looking for an adrive. It says first when nothing is there to attach to (status 1,
/// as `adrive ctl`); with an adrive there, what applies to attach: `ssh -t HOST adrive
/// attach`, or `adrive ctl status` for a one-shot look (status 2).
#[test]
fn attach_without_a_terminal_says_whether_there_is_an_adrive_and_what_applies() {
    let run = |socket: &std::path::Path| {
        let mut cmd = Process::new(BIN);
        cmd.arg("attach")
            .arg("--socket")
            .arg(socket)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        without_terminal(&mut cmd);
        let out = cmd.output().unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let dir = tempdir("cli-attach-notty");
    let nobody = dir.path().join("nobody.sock");
    let (status, err) = run(&nobody);
    assert_eq!(status, Some(1), "{err}");
    assert!(
        err.contains("no adrive at") && err.contains("nobody.sock"),
        "{err}"
    );
    assert!(!err.contains("needs a terminal"), "{err}");
    let adrive =
        common::headless::Adrive::start("cli-attach-notty", adrive::config::ALICE_TOML, "");
    let socket = adrive.dir.path().join("adrive/adrive.sock");
    let (status, err) = run(&socket);
    assert_eq!(status, Some(2), "{err}");
    assert!(
        err.contains("needs a terminal")
            && err.contains("`ssh -t HOST adrive attach`")
            && err.contains("`adrive ctl status`"),
        "{err}"
    );
    assert!(!err.contains("--headless"), "{err}");
}

/// The incident: with `adrive sim` running, `adrive ports` listed `/dev/pts/*` without
/// saying which simulated device each is. Each of its pseudo-terminals is named by the
/// device it simulates, with the simulator's process and the link a vehicle file names.
#[test]
fn ports_names_each_pseudo_terminal_of_a_running_sim_by_its_device() {
    let sim = common::simproc::SimProcess::start();
    let out = Process::new(BIN).arg("ports").output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{text}");
    let pid = sim.child.id();
    for (device, link) in ["steer", "gas", "brake", "trans", "estop", "obd"]
        .iter()
        .zip(&sim.paths)
    {
        let pty = std::fs::read_link(link).unwrap();
        let line = text
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{} ", pty.display())))
            .unwrap_or_else(|| panic!("no line for {device} ({}):\n{text}", pty.display()));
        assert!(
            line.contains(device)
                && line.contains(&format!("adrive sim (pid {pid})"))
                && line.contains(link.as_str()),
            "{line}\n{text}"
        );
    }
    sim.stop();
}

/// The incident: a second adrive started on the serial ports of a running one showed
/// the exclusive-access failure as six `silent` faults, kept running and exited 3 (as
/// root it would have driven the devices beside the first). It is refused at start,
/// status 2, naming the device, the port and the process holding it; nothing starts.
#[test]
fn a_second_adrive_on_the_same_ports_is_refused_at_start_naming_the_holder() {
    let sim = common::simproc::SimProcess::start();
    let dir = tempdir("cli-twice");
    let vehicle = common::simproc::vehicle_file(dir.path(), &sim, "");
    let start = |log: &str, broadcast: u16| {
        Process::new(BIN)
            .args(["--headless", "--listen", "127.0.0.1:0", "--broadcast-to"])
            .arg(format!("127.0.0.1:{broadcast}"))
            .arg("--config")
            .arg(&vehicle)
            .arg("--log-dir")
            .arg(dir.path().join(log))
            .env("XDG_RUNTIME_DIR", dir.path().join(log))
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let broadcast = common::free_port();
    let mut first = common::Reaped(start("first", broadcast));
    let err = lines(first.stderr.take().unwrap());
    let seen = until(&err, "running headless");
    // `--broadcast-to`, as the troubleshooting section tells a second adrive on a host.
    assert!(
        seen.iter()
            .any(|l| l.contains(&format!("broadcast=[127.0.0.1:{broadcast}]"))),
        "{seen:#?}"
    );
    let mut second = common::Reaped(start("second", common::free_port()));
    let status = wait_exit(&mut second);
    let mut text = String::new();
    second
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut text)
        .unwrap();
    assert_eq!(status, Some(2), "{text}");
    assert!(
        text.contains(&format!("device steer: cannot open {}", sim.paths[0]))
            && text.contains(&format!("in use by process {} (adrive)", first.id())),
        "{text}"
    );
    assert!(
        !dir.path().join("second").exists(),
        "the second one started"
    );
    // The first one runs on, untouched.
    assert!(matches!(first.try_wait(), Ok(None)));
    drop(first);
    sim.stop();
}

/// The incident: every `adrive sim` printed `gas <- 0.000  device watchdog: no command
/// for 1s` a second after its start, as if a command had arrived, though nothing had
/// talked to it; and a `--fault` given at start was applied without a word, where the
/// same line typed is confirmed. Now a device that never heard a command stays quiet,
/// one that did and then heard nothing says what it did by itself (no arrow: nothing
/// arrived), and each `--fault` is confirmed as typed.
#[test]
fn sim_says_only_what_happened_at_start_and_confirms_each_fault_given() {
    let (mut child, out) = sim_process(&["--only", "gas", "--fault", "slow gas 20"]);
    let mut seen = until(&out, "Ctrl-C stops");
    assert!(
        seen.iter().any(|l| l == "gas: slow 20 ms"),
        "the --fault is confirmed: {seen:#?}"
    );
    let path = seen[0].split_whitespace().nth(1).unwrap().to_string();
    // Longer than its watchdog (1 s) with no command, then one command: the sentinel.
    std::thread::sleep(Duration::from_millis(1500));
    let alice = VehicleConfig::alice();
    let gas = alice.device("gas").unwrap();
    let mut link = driver::open_serial(&path, gas.baud, Duration::from_secs(2)).unwrap();
    driver::build(gas)
        .command(link.as_mut(), Command::Set(0.3))
        .unwrap();
    let before = until(&out, "<- 0.300");
    assert_eq!(
        before.len(),
        1,
        "nothing before the first command: {before:#?}"
    );
    // Then silence: its watchdog trips once, a second after that command.
    seen = until(&out, "device watchdog");
    let trip = seen.last().unwrap();
    assert!(
        trip.contains("gas") && trip.contains("no command for 1s; went to 0.000 by itself"),
        "{trip}"
    );
    assert!(!trip.contains("<-"), "nothing arrived: {trip}");
    signal(&child, libc::SIGINT);
    assert_eq!(wait_exit(&mut child), Some(0));
}

/// A headless run on the simulated vehicle logs no device watchdog: adrive talks to
/// every device it drives, and a device never commanded has nothing to time out.
#[test]
fn headless_sim_logs_no_device_watchdog_while_it_runs() {
    let dir = tempdir("cli-watchdog");
    let mut child = common::headless_piped(dir.path(), &[]);
    let err = lines(child.stderr.take().unwrap());
    let mut seen = until(&err, "running headless");
    // Past every simulated device's watchdog (1 s), then the sentinel: the stop.
    std::thread::sleep(Duration::from_millis(2500));
    signal(&child, libc::SIGINT);
    assert_eq!(wait_exit(&mut child), Some(0));
    seen.extend(err.iter());
    let text = seen.join("\n");
    assert!(text.contains("stopping: SIGINT"), "{text}");
    assert!(
        !text.contains("watchdog: no command") && !text.contains("going safe"),
        "{text}"
    );
}

/// The incident: `adrive sim --config vehicles/oscc.toml` answered `estop pause` with
/// "estop is now pause" and `stall` with "engine stalled", though nothing of that
/// vehicle reads an e-stop or the engine. Each is refused with what is missing, typed
/// or given as `--fault`, and `help` lists them apart.
#[test]
fn sim_refuses_faults_of_what_the_vehicle_does_not_have() {
    let (mut child, out) = sim_process(&["--config", "vehicles/oscc.toml"]);
    let seen = until(&out, "Ctrl-C stops");
    assert!(!seen.last().unwrap().contains("estop"), "{seen:#?}");
    let stdin = child.stdin.as_mut().unwrap();
    for line in [
        "estop pause",
        "stall",
        "nostart on",
        "jam steer",
        "bias gas 0.2",
    ] {
        writeln!(stdin, "{line}").unwrap();
    }
    writeln!(stdin, "help").unwrap();
    let text = until(&out, "DTC is a fault code").join("\n");
    for refusal in [
        "error: estop: no e-stop is bound on this vehicle (no device reads an e-stop state)",
        "error: stall: no device of this vehicle reports the engine (its rpm, or whether it runs)",
        "error: nostart: no device of this vehicle reports the engine",
        "error: jam: steer is driven by a kit's module on bus kit, which has no drive fault latch",
        "error: bias: nothing reports gas's position on this vehicle",
        "  not on this vehicle: estop (no e-stop is bound",
    ] {
        assert!(text.contains(refusal), "{refusal}:\n{text}");
    }
    assert!(
        !text.contains("estop is now") && !text.contains("engine stalled"),
        "{text}"
    );
    signal(&child, libc::SIGINT);
    assert_eq!(wait_exit(&mut child), Some(0));

    let bad = common::output_within(
        Process::new(BIN)
            .args([
                "sim",
                "--config",
                "vehicles/oscc.toml",
                "--fault",
                "estop pause",
            ])
            .current_dir(env!("CARGO_MANIFEST_DIR")),
    );
    assert_eq!(bad.status.code(), Some(2));
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.contains("--fault \"estop pause\": estop: no e-stop is bound"),
        "{err}"
    );
}

/// The incident: `adrive sim` printed `(modbus, 115200 baud)` where the guide shows
/// `(Modbus, 115200 baud)`. Each protocol has one display name: what the binary prints
/// for Alice's devices and the OSCC kit's adapter, and what every sample of those lines
/// in the guide shows.
#[test]
fn sim_names_each_protocol_as_the_guide_does() {
    let mut shown = std::collections::BTreeSet::new();
    for args in [&[][..], &["--config", "vehicles/oscc.toml"][..]] {
        let (mut child, out) = sim_process(args);
        for line in until(&out, "Ctrl-C stops") {
            if let Some((_, rest)) = line.split_once("  (") {
                shown.insert(rest.split(',').next().unwrap().to_string());
            }
        }
        signal(&child, libc::SIGINT);
        assert_eq!(wait_exit(&mut child), Some(0));
    }
    let want: std::collections::BTreeSet<String> = ["ELM327", "Modbus", "SLCAN", "line"]
        .map(String::from)
        .into();
    assert_eq!(shown, want);
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut pages: Vec<_> = std::fs::read_dir(root.join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .collect();
    pages.push(root.join("README.md"));
    let mut samples = 0;
    for page in pages {
        let text = std::fs::read_to_string(&page).unwrap();
        for (n, line) in text.lines().enumerate() {
            let Some((_, rest)) = line.split_once("-> /dev/pts/") else {
                continue;
            };
            let Some((_, named)) = rest.split_once("  (") else {
                continue;
            };
            samples += 1;
            let name = named.split(',').next().unwrap();
            assert!(
                shown.contains(name),
                "{}:{}: `{name}` is not how adrive sim names a protocol ({shown:?})",
                page.display(),
                n + 1
            );
        }
    }
    assert!(
        samples >= 3,
        "the guide's samples of adrive sim's lines were found"
    );
}
