//! adrive under systemd, with a datagram socket standing in for the service manager's
//! `NOTIFY_SOCKET`: the real binary, headless on the simulated vehicle, reports
//! readiness, feeds the watchdog at half `WATCHDOG_USEC` only while every engine thread
//! runs and turns its loop within its bound, and reports stopping before its safe stop.
//! And the unit file shipped in `dist/systemd/` is checked.

mod common;

use common::{free_port, lines, signal, tempdir, until, wait_exit, Reaped, DEADLINE};
use std::os::unix::net::UnixDatagram;
use std::path::Path;
use std::process::{Command as Process, Stdio};
use std::sync::mpsc::{self, Receiver};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_adrive");

/// What the stand-in service manager received, and when.
struct Manager {
    rx: Receiver<(Instant, String)>,
    seen: Vec<(Instant, String)>,
}

impl Manager {
    /// Bind the socket at `path`.
    fn bind(path: &Path) -> Manager {
        let socket = UnixDatagram::bind(path).unwrap();
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            while let Ok(n) = socket.recv(&mut buf) {
                let text = String::from_utf8_lossy(&buf[..n]).into_owned();
                if tx.send((Instant::now(), text)).is_err() {
                    break;
                }
            }
        });
        Manager {
            rx,
            seen: Vec::new(),
        }
    }

    /// Wait for a datagram holding the line `line`; when it came.
    fn until(&mut self, line: &str) -> Instant {
        self.until_starting(line).0
    }

    /// Wait for a datagram holding a line that starts with `start`; when it came, and
    /// that line.
    fn until_starting(&mut self, start: &str) -> (Instant, String) {
        let end = Instant::now() + DEADLINE;
        loop {
            let left = end.saturating_duration_since(Instant::now());
            let Ok((at, text)) = self.rx.recv_timeout(left) else {
                panic!("no {start:?} from adrive; it sent:\n{:#?}", self.seen);
            };
            let hit = text
                .lines()
                .find(|l| l.starts_with(start))
                .map(String::from);
            self.seen.push((at, text));
            if let Some(line) = hit {
                return (at, line);
            }
        }
    }

    /// Everything received so far.
    fn drain(&mut self) -> &[(Instant, String)] {
        self.seen.extend(self.rx.try_iter());
        &self.seen
    }
}

/// Half of this is how often adrive must feed the watchdog. Two seconds: a gap as long
/// is what systemd would take for a hang, and a loaded machine must not stall so long.
const WATCHDOG_USEC: u64 = 2_000_000;

/// `adrive --sim --headless` as systemd starts it (`NOTIFY_SOCKET`, `WATCHDOG_USEC`,
/// `WATCHDOG_PID` unset as for the main process), with `args`; its stderr's lines.
fn start(dir: &Path, args: &[&str]) -> (Reaped, Receiver<String>) {
    let mut child = Reaped(
        Process::new(BIN)
            .args(["--sim", "--headless", "--listen", "127.0.0.1:0"])
            .args(["--broadcast-to", &format!("127.0.0.1:{}", free_port())])
            .arg("--log-dir")
            .arg(dir.join("log"))
            .args(args)
            .env("NOTIFY_SOCKET", dir.join("notify"))
            .env("WATCHDOG_USEC", WATCHDOG_USEC.to_string())
            .env_remove("WATCHDOG_PID")
            // A control socket of its own, in this test's directory.
            .env("XDG_RUNTIME_DIR", dir)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let err = lines(child.stderr.take().unwrap());
    (child, err)
}

/// Started under systemd: `READY=1` once the engine runs, `WATCHDOG=1` every half
/// `WATCHDOG_USEC` (never a gap systemd would count as a hang), and on SIGTERM —
/// `systemctl stop` — `STOPPING=1`, then the safe state, then status 0.
#[test]
fn ready_watchdog_and_stopping_reach_the_service_manager() {
    let dir = tempdir("service");
    let mut manager = Manager::bind(&dir.path().join("notify"));
    let (mut adrive, err) = start(dir.path(), &[]);
    let ready = manager.until("READY=1");
    let mut fed = Vec::new();
    while fed.len() < 4 {
        let at = manager.until("WATCHDOG=1");
        if at > ready {
            fed.push(at);
        }
    }
    let half = Duration::from_micros(WATCHDOG_USEC / 2);
    for pair in fed.windows(2) {
        let gap = pair[1] - pair[0];
        // At half the period (not at every supervisor turn), never near the whole.
        assert!(
            gap >= half - Duration::from_millis(50) && gap < 2 * half,
            "WATCHDOG=1 every {gap:?}, expected about {half:?}"
        );
    }
    assert!(signal(&adrive, libc::SIGTERM));
    manager.until("STOPPING=1");
    assert_eq!(
        manager.seen.last().unwrap().1,
        "STOPPING=1\nSTATUS=stopping: SIGTERM"
    );
    assert_eq!(wait_exit(&mut adrive), Some(0), "status after SIGTERM");
    let said: Vec<String> = err.iter().collect();
    let text = said.join("\n");
    assert!(
        text.contains("stopping: SIGTERM") && text.contains("safe state acknowledged"),
        "a safe stop:\n{text}"
    );
    let sent = manager.drain();
    let ready_status = sent
        .iter()
        .find(|(_, t)| t.contains("READY=1"))
        .map(|(_, t)| t.as_str());
    assert_eq!(ready_status, Some("READY=1\nSTATUS=running: 6 devices"));
}

/// A device thread that ends while adrive runs (here the steering's status thread
/// returns, as a bug would make it): the watchdog is fed no more, so systemd restarts
/// adrive; adrive says so once at ERROR; the steering is reported faulty meanwhile
/// (its status is no longer fresh), and a stop is still a safe stop.
#[test]
fn the_watchdog_is_no_longer_fed_once_a_device_thread_ended() {
    let dir = tempdir("service-dead");
    let mut manager = Manager::bind(&dir.path().join("notify"));
    let (mut adrive, err) = start(dir.path(), &["--inject-panic", "steer/status=return:2s"]);
    manager.until("READY=1");
    manager.until("WATCHDOG=1");
    let mut said = until(&err, "thread ended");
    let ended = Instant::now();
    // `systemctl status` says why.
    manager.until("STATUS=thread steer/status ended");
    // The supervisor still turns: it names the steering's fault, and goes on turning
    // for several watchdog periods.
    said.extend(until(&err, "fault: steer silent"));
    let half = Duration::from_micros(WATCHDOG_USEC / 2);
    let quiet_until = ended + 3 * half;
    while Instant::now() < quiet_until {
        if let Ok(l) = err.recv_timeout(quiet_until.saturating_duration_since(Instant::now())) {
            said.push(l);
        }
    }
    let text = said.join("\n");
    let fed_after: Vec<_> = manager
        .drain()
        .iter()
        .filter(|(at, t)| *at > ended && t.contains("WATCHDOG=1"))
        .map(|(at, _)| *at - ended)
        .collect();
    assert!(
        fed_after.is_empty(),
        "WATCHDOG=1 after the thread ended (at {fed_after:?}):\n{text}"
    );
    let error_lines: Vec<_> = said.iter().filter(|l| l.contains("thread ended")).collect();
    assert_eq!(error_lines.len(), 1, "said once:\n{text}");
    assert!(
        error_lines[0].contains("ERROR") && error_lines[0].contains("steer/status"),
        "{}",
        error_lines[0]
    );
    assert!(signal(&adrive, libc::SIGTERM));
    manager.until("STOPPING=1");
    assert_eq!(wait_exit(&mut adrive), Some(0), "status after SIGTERM");
    let text: String = err.iter().collect::<Vec<_>>().join("\n");
    assert!(text.contains("safe state acknowledged"), "{text}");
}

/// The incident: a device's status thread stuck in a system call (strace's
/// `delay_enter`) was named silent within 0.6 s, yet `WATCHDOG=1` kept arriving for as
/// long as it hung — the watchdog only asked whether threads had ended. Liveness is
/// progress: the steering's status thread blocks in a system call with its port held
/// (`--inject-hang`), and within its bound (one transaction) and the grace the feeding
/// stops, `systemctl status` and the log (ERROR) name the thread, the snapshot carries
/// it and engage is refused; for the rest of the hang — longer than `WATCHDOG_USEC`, so
/// systemd would act — nothing feeds the watchdog. Once the thread turns again the log
/// says so and the feeding resumes.
#[test]
fn the_watchdog_is_not_fed_while_a_device_thread_is_stuck_in_a_system_call() {
    let dir = tempdir("service-stuck");
    let mut manager = Manager::bind(&dir.path().join("notify"));
    let hang = Duration::from_secs(5);
    let (mut adrive, err) = start(
        dir.path(),
        &[
            "--inject-hang",
            &format!("steer/status:2s:{}s", hang.as_secs()),
        ],
    );
    manager.until("READY=1");
    manager.until("WATCHDOG=1");
    let mut said = until(&err, "injected hang: blocking in a system call");
    let hung = Instant::now();
    let (stalled_at, status) = manager.until_starting("STATUS=stalled: ");
    assert!(
        status.starts_with("STATUS=stalled: steer/status has not turned its loop for "),
        "{status}"
    );
    // Within the thread's bound (a Modbus poll at 100 ms), the grace (500 ms) and the
    // watchdog's look (100 ms), with room for a loaded machine: well inside the hang.
    assert!(
        stalled_at - hung < Duration::from_secs(3),
        "named {:?} after the hang began",
        stalled_at - hung
    );
    // The snapshot says it, and engage is refused for it.
    let ctl = Process::new(BIN)
        .args(["ctl", "status", "--json"])
        .env("XDG_RUNTIME_DIR", dir.path())
        .output()
        .unwrap();
    let snap: serde_json::Value = serde_json::from_slice(&ctl.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&ctl.stdout)));
    assert_eq!(
        snap["supervisor"]["stalled"][0]["thread"], "steer/status",
        "{snap}"
    );
    let blockers = snap["gate"]["blockers"].to_string();
    assert!(
        blockers.contains("thread steer/status has not turned its loop"),
        "{blockers}"
    );
    said.extend(until(&err, "turns its loop again"));
    let text = said.join("\n");
    let stalled_lines: Vec<_> = said.iter().filter(|l| l.contains("stalled: ")).collect();
    assert_eq!(stalled_lines.len(), 1, "said once:\n{text}");
    assert!(
        stalled_lines[0].contains("ERROR") && stalled_lines[0].contains("steer/status"),
        "{text}"
    );
    assert!(text.contains("the service watchdog is fed again"), "{text}");
    // `systemctl status` is back to running, and the watchdog fed again.
    manager.until("STATUS=running: 6 devices");
    let resumed = manager.until("WATCHDOG=1");
    let sent = manager.drain().to_vec();
    let fed: Vec<Instant> = sent
        .iter()
        .filter(|(_, t)| t.contains("WATCHDOG=1"))
        .map(|(at, _)| *at)
        .collect();
    // Nothing between the stall and the resume (the datagrams arrive in order) …
    let during: Vec<_> = fed
        .iter()
        .filter(|at| **at > stalled_at && **at < resumed)
        .collect();
    assert!(during.is_empty(), "WATCHDOG=1 while stalled: {during:?}");
    // … and the gap is one systemd would have acted on.
    let last_before = fed
        .iter()
        .filter(|at| **at < stalled_at)
        .max()
        .expect("fed before the stall");
    assert!(
        resumed - *last_before > Duration::from_micros(WATCHDOG_USEC),
        "the feeding stopped for {:?} only",
        resumed - *last_before
    );
    assert!(signal(&adrive, libc::SIGTERM));
    manager.until("STOPPING=1");
    assert_eq!(wait_exit(&mut adrive), Some(0), "status after SIGTERM");
}

/// A device thread that panics: as any panic, adrive stops at once, safely — the
/// service manager hears `STOPPING=1`, the safe state is acknowledged, and the status
/// is 101, which `Restart=on-failure` restarts.
#[test]
fn a_panic_in_a_device_thread_is_a_safe_stop() {
    let dir = tempdir("service-panic");
    let mut manager = Manager::bind(&dir.path().join("notify"));
    let (mut adrive, err) = start(dir.path(), &["--inject-panic", "steer/status:2s"]);
    manager.until("READY=1");
    manager.until("STOPPING=1");
    assert_eq!(wait_exit(&mut adrive), Some(101), "status after a panic");
    let text: String = err.iter().collect::<Vec<_>>().join("\n");
    assert!(
        text.contains("stopping: panic: thread steer/status")
            && text.contains("safe state acknowledged"),
        "{text}"
    );
}

/// Whether a journald listens here, as tracing-journald checks it, with `journalctl`
/// to read it back.
fn journald_here() -> bool {
    let reachable = UnixDatagram::unbound()
        .and_then(|s| s.send_to(&[], "/run/systemd/journal/socket"))
        .is_ok();
    reachable
        && Process::new("journalctl")
            .arg("--version")
            .stdout(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
}

/// Run by systemd with its stderr connected to the journal (`JOURNAL_STREAM` names
/// stderr's device and inode): the log lines go to the journal with their fields as
/// journal fields (`DEVICE=gas`), not as text on stderr. Where no journald listens,
/// the lines stay on stderr (a journal that cannot be reached loses nothing).
#[test]
fn under_systemd_the_log_goes_to_the_journal_with_the_device_as_a_field() {
    use std::os::unix::fs::MetadataExt;
    let dir = tempdir("service-journal");
    let mut manager = Manager::bind(&dir.path().join("notify"));
    let err_path = dir.path().join("stderr");
    let err_file = std::fs::File::create(&err_path).unwrap();
    let meta = err_file.metadata().unwrap();
    let mut adrive = Reaped(
        Process::new(BIN)
            .args(["--sim", "--headless", "--listen", "127.0.0.1:0"])
            .args(["--broadcast-to", &format!("127.0.0.1:{}", free_port())])
            .arg("--log-dir")
            .arg(dir.path().join("log"))
            .env("NOTIFY_SOCKET", dir.path().join("notify"))
            .env("JOURNAL_STREAM", format!("{}:{}", meta.dev(), meta.ino()))
            .env("XDG_RUNTIME_DIR", dir.path())
            .stdout(Stdio::null())
            .stderr(err_file)
            .spawn()
            .unwrap(),
    );
    manager.until("READY=1");
    let pid = adrive.id().to_string();
    let journal = journald_here();
    if journal {
        // The simulated gas pedal says it went safe a second after the start, with
        // nothing commanded: a line with a device field.
        let end = Instant::now() + DEADLINE;
        let entry = loop {
            let out = Process::new("journalctl")
                .args([
                    "--no-pager",
                    "-o",
                    "json",
                    &format!("_PID={pid}"),
                    "DEVICE=gas",
                ])
                .output()
                .unwrap();
            let text = String::from_utf8_lossy(&out.stdout).into_owned();
            if let Some(line) = text.lines().next() {
                break serde_json::from_str::<serde_json::Value>(line).unwrap();
            }
            assert!(
                Instant::now() < end,
                "no journal entry with DEVICE=gas from {pid}"
            );
            std::thread::sleep(Duration::from_millis(100));
        };
        assert_eq!(entry["SYSLOG_IDENTIFIER"], "adrive");
        assert_eq!(entry["DEVICE"], "gas");
        assert_eq!(entry["THREAD_NAME"], "sim/gas");
        // The line as the log file has it, fields included, for `journalctl -u`.
        assert!(
            entry["MESSAGE"]
                .as_str()
                .is_some_and(|m| m.ends_with(" device=gas")),
            "{entry}"
        );
        assert_eq!(entry["PRIORITY"], "6", "info");
    }
    assert!(signal(&adrive, libc::SIGTERM));
    assert_eq!(wait_exit(&mut adrive), Some(0));
    let stderr = std::fs::read_to_string(&err_path).unwrap();
    if journal {
        assert!(
            !stderr.contains("engine started"),
            "logged to stderr too, so twice in the journal:\n{stderr}"
        );
    } else {
        eprintln!("no journald here: checked that the lines stay on stderr");
        assert!(stderr.contains("engine started"), "{stderr}");
    }
}

/// A systemd unit file's `[section]` → `key` → values (a key may repeat).
type Unit = std::collections::BTreeMap<String, Vec<(String, String)>>;

/// Parse a unit file as systemd reads it: sections, `Key=value`, `#`/`;` comments.
fn parse_unit(text: &str) -> Unit {
    let mut unit = Unit::new();
    let mut section = String::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with(';') {
            continue;
        }
        assert!(
            !line.ends_with('\\'),
            "line {}: no continuations here",
            n + 1
        );
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = name.to_string();
            continue;
        }
        let (k, v) = line
            .split_once('=')
            .unwrap_or_else(|| panic!("line {}: expected Key=value: {line}", n + 1));
        assert!(
            !section.is_empty(),
            "line {}: a key before any section",
            n + 1
        );
        unit.entry(section.clone())
            .or_default()
            .push((k.trim().to_string(), v.trim().to_string()));
    }
    unit
}

fn key<'u>(unit: &'u Unit, section: &str, key: &str) -> &'u str {
    let values: Vec<&str> = unit
        .get(section)
        .into_iter()
        .flatten()
        .filter(|(k, _)| k == key)
        .map(|(_, v)| v.as_str())
        .collect();
    assert_eq!(values.len(), 1, "[{section}] {key}= once: {values:?}");
    values[0]
}

fn dist(path: &str) -> String {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("dist")
        .join(path);
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// The units shipped in `dist/systemd/`: a notify service whose watchdog adrive can
/// feed, stopped safely by SIGTERM within its stop timeout, restarted on failure, in
/// the serial ports' group with its runtime directory for the control socket and an
/// rtprio limit — and an ExecStart this adrive accepts.
#[test]
fn the_unit_files_say_what_the_service_needs() {
    use adrive::cli::Cli;
    use clap::Parser;
    let duration = |s: &str| humantime::parse_duration(s).unwrap();
    for (file, sim) in [
        ("systemd/adrive.service", false),
        ("systemd/adrive-sim.service", true),
    ] {
        let unit = parse_unit(&dist(file));
        let s = "Service";
        assert_eq!(key(&unit, s, "Type"), "notify", "{file}");
        assert_eq!(key(&unit, s, "NotifyAccess"), "main", "{file}");
        // Fed at half, by a supervisor turning at most every second.
        let watchdog = duration(key(&unit, s, "WatchdogSec"));
        assert!(watchdog >= Duration::from_secs(3), "{file}: {watchdog:?}");
        assert_eq!(key(&unit, s, "WatchdogSignal"), "SIGTERM", "{file}");
        assert_eq!(key(&unit, s, "KillSignal"), "SIGTERM", "{file}");
        // The safe stop's own deadlines add up to about 6 s.
        let stop = duration(key(&unit, s, "TimeoutStopSec"));
        assert!(stop >= Duration::from_secs(8), "{file}: {stop:?}");
        assert_eq!(key(&unit, s, "Restart"), "on-failure", "{file}");
        assert_eq!(key(&unit, s, "User"), "adrive", "{file}");
        assert_eq!(key(&unit, s, "Group"), "dialout", "{file}");
        assert_eq!(key(&unit, s, "RuntimeDirectory"), "adrive", "{file}");
        assert_eq!(key(&unit, s, "StateDirectory"), "adrive", "{file}");
        let rtprio: u32 = key(&unit, s, "LimitRTPRIO").parse().unwrap();
        assert!((1..=99).contains(&rtprio), "{file}: LimitRTPRIO={rtprio}");
        assert_eq!(key(&unit, "Install", "WantedBy"), "multi-user.target");
        let exec: Vec<&str> = key(&unit, s, "ExecStart").split_whitespace().collect();
        assert_eq!(exec[0], "/usr/local/bin/adrive", "{file}");
        let has = |pair: &[&str]| exec.windows(pair.len()).any(|w| w == pair);
        assert!(has(&["--headless"]), "{file}: {exec:?}");
        assert!(
            has(&["--socket", "/run/adrive/adrive.sock"]),
            "{file}: {exec:?}"
        );
        match sim {
            true => assert!(has(&["--sim"]), "{file}: {exec:?}"),
            false => assert!(
                has(&["--config", "/etc/adrive/vehicle.toml"]) && !has(&["--sim"]),
                "{file}: {exec:?}"
            ),
        }
        // The command line is one this adrive takes.
        if let Err(e) = Cli::try_parse_from(&exec) {
            panic!("{file}: ExecStart: {e}");
        }
    }
}

/// `systemd-analyze verify` finds nothing to say about the units, where it is
/// installed (with this build's adrive in place of /usr/local/bin/adrive).
#[test]
fn systemd_analyze_verifies_the_unit_files() {
    let have = Process::new("systemd-analyze")
        .arg("--version")
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !have {
        eprintln!("systemd-analyze is not installed: the parse test checks the units");
        return;
    }
    let dir = tempdir("unit");
    let mut paths = Vec::new();
    for name in ["adrive.service", "adrive-sim.service"] {
        let text = dist(&format!("systemd/{name}")).replace("/usr/local/bin/adrive", BIN);
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        paths.push(path);
    }
    let out = Process::new("systemd-analyze")
        .args(["verify", "--man=no"])
        .args(&paths)
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&out.stderr);
    let about_ours: Vec<&str> = said
        .lines()
        .filter(|l| l.contains(dir.path().to_str().unwrap()) || l.contains("adrive"))
        .collect();
    assert!(
        out.status.success() && about_ours.is_empty(),
        "systemd-analyze verify:\n{said}"
    );
}

/// The udev rule names each adapter under /dev/adrive/ by its serial number, in the
/// service's group with mode 0660, and sets the FTDI latency timer to 1 ms.
#[test]
fn the_udev_rule_names_the_adapters_and_sets_the_latency_timer() {
    let text = dist("udev/99-adrive.rules");
    let rules: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .collect();
    let names: Vec<&str> = rules
        .iter()
        .filter(|r| r.contains("SYMLINK+="))
        .copied()
        .collect();
    assert!(!names.is_empty());
    for r in &names {
        assert!(r.starts_with("SUBSYSTEM==\"tty\""), "{r}");
        assert!(r.contains("ATTRS{serial}==\""), "{r}");
        assert!(r.contains("SYMLINK+=\"adrive/"), "{r}");
        assert!(
            r.contains("GROUP=\"dialout\"") && r.contains("MODE=\"0660\""),
            "{r}"
        );
    }
    assert!(
        rules.iter().any(|r| r.contains("SUBSYSTEM==\"usb-serial\"")
            && r.contains("DRIVER==\"ftdi_sio\"")
            && r.contains("ATTR{latency_timer}=\"1\"")),
        "{text}"
    );
}
