//! Shared helpers for the integration tests: a simulated vehicle on real
//! pseudo-terminals with the real engine on top, and waiting for events with a deadline.
#![allow(dead_code)]

pub mod attached;
pub mod headless;
pub mod pty;
pub mod simproc;
pub mod terminal_player;
#[cfg(feature = "fleet")]
pub mod zenoh_router;

use adrive::config::{self, VehicleConfig};
use adrive::driver;
use adrive::engine::Engine;
use adrive::engine::Gate;
use adrive::sim::{Sim, SimEvent};
use adrive::threads::Shutdown;
use adrive::value::{Command, DeviceId};
use adrive::vehicle::{Device, Vehicle};
use crossbeam_channel::Receiver;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Generous: these machines are slow and shared; a passing test never waits this long.
pub const DEADLINE: Duration = Duration::from_secs(20);

/// Wait until `cond` holds, checking often; panics with `what` at the deadline.
pub fn wait_for(what: &str, mut cond: impl FnMut() -> bool) {
    let end = Instant::now() + DEADLINE;
    while !cond() {
        assert!(Instant::now() < end, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// What a terminal of `cols` × `rows` shows once it has taken `bytes`.
pub fn screen_of(bytes: &[u8], cols: u16, rows: u16) -> String {
    let nz = |n: u16| std::num::NonZeroU16::new(n).unwrap();
    let mut p = vt100::Parser::new(nz(rows), nz(cols), 0);
    p.process(bytes);
    p.screen().contents()
}

/// Wait until the screen `screen` reads (every `every`) satisfies `ok`. At the
/// deadline, panic with what was waited for, every message line seen meanwhile (a
/// message that came and went is most often the clue) and the last screen.
pub fn wait_screen(
    what: &str,
    every: Duration,
    screen: impl Fn() -> String,
    ok: impl Fn(&str) -> bool,
) -> String {
    let end = Instant::now() + DEADLINE;
    let mut seen: Vec<String> = Vec::new();
    loop {
        let s = screen();
        if ok(&s) {
            return s;
        }
        let line = said(&s).to_string();
        if seen.last() != Some(&line) {
            seen.push(line);
        }
        assert!(
            Instant::now() < end,
            "waited for {what}; said {seen:?}; screen:\n{s}"
        );
        std::thread::sleep(every);
    }
}

/// A console's screen once its engage question was answered: the question gone, and
/// what its answer did said on the message line (`engaged`, as every front end says
/// it, or `engage refused: …`). Waiting for the refusal alone read a refusal left on
/// the screen by an earlier try as this one's, and the next `E` `y` then landed on
/// whatever the test did next; a refusal is read on the message line, not in the log
/// pane, which keeps earlier tries' refusals.
pub fn engage_answered(screen: &str) -> bool {
    !screen.contains("Engage?")
        && (engaged_said(screen) || said(screen).starts_with("engage refused"))
}

/// The console's message line (the row above the key hints) says the engage was done:
/// `engaged`, every front end's one answer. The log pane may still show refusals of
/// earlier tries; the message line is this answer's.
pub fn engaged_said(screen: &str) -> bool {
    said(screen) == "engaged"
}

/// The console's message line: the last row but one that is not blank.
pub fn said(screen: &str) -> &str {
    screen
        .lines()
        .filter(|l| !l.trim().is_empty())
        .rev()
        .nth(1)
        .map_or("", str::trim)
}

/// Alice for `--sim --config`, her devices' readings allowed to be 2 s old and their
/// replies 1 s late. For tests that hold the vehicle engaged for seconds to prove
/// something other than device timing: the machine they run on is shared and stalls
/// now and then (a stall of 300 ms froze every process at once), and Alice's own
/// deadlines (200 ms for the e-stop) then rightly find a device faulty and disengage.
pub fn tolerant_alice(dir: &std::path::Path) -> std::path::PathBuf {
    let path = dir.join("tolerant-alice.toml");
    std::fs::write(&path, tolerant_text(config::ALICE_TOML)).unwrap();
    path
}

/// The vehicle file at `path` (Alice pointed at `adrive sim`'s ports, as
/// [`simproc::vehicle_file`] writes her) made tolerant as [`tolerant_alice`].
pub fn tolerant(path: std::path::PathBuf) -> std::path::PathBuf {
    let text = tolerant_text(&std::fs::read_to_string(&path).unwrap());
    std::fs::write(&path, text).unwrap();
    path
}

/// `vehicle` (a vehicle file's text) with every device's readings allowed to be 2 s old
/// and its replies 1 s late.
pub fn tolerant_text(vehicle: &str) -> String {
    let mut text = String::new();
    for line in vehicle.lines() {
        if line.starts_with("status_max_age = ") {
            text.push_str("status_max_age = \"2s\"\n");
        } else if line.starts_with("reply_timeout = ") {
            text.push_str("reply_timeout = \"1s\"\n");
        } else {
            text.push_str(line);
            text.push('\n');
        }
    }
    text
}

pub struct Rig {
    pub sim: Sim,
    pub vehicle: Arc<Vehicle>,
    pub gate: Arc<Gate>,
    pub engine: Option<Engine>,
    pub events: Receiver<SimEvent>,
    /// With [`Rig::supervised`]: the gate monitor, the supervisor, and where the
    /// supervisor asks the process to end.
    pub monitor: Option<adrive::engine::monitor::Monitor>,
    pub supervisor: Option<adrive::supervisor::Running>,
    pub exits: Option<Receiver<adrive::exit::Exit>>,
}

impl Rig {
    /// Simulate the vehicle described by `toml` and run the engine on it.
    pub fn start(toml: &str) -> Rig {
        let config = config::parse(toml, "test.toml").expect("test config parses");
        Rig::with_config(config)
    }

    pub fn with_config(mut config: VehicleConfig) -> Rig {
        let (tx, events) = crossbeam_channel::unbounded();
        let sim = Sim::start(&config, Some(tx)).expect("sim starts");
        sim.patch(&mut config);
        let vehicle = Arc::new(Vehicle::new(config, |c| {
            let (path, baud, timeout) = (c.port.clone(), c.baud, c.reply_timeout);
            Box::new(move || driver::open_serial(&path, baud, timeout))
        }));
        let gate = Arc::new(Gate::new(vehicle.clone()));
        let engine = Engine::start(gate.clone()).expect("engine starts");
        Rig {
            sim,
            vehicle,
            gate,
            engine: Some(engine),
            events,
            monitor: None,
            supervisor: None,
            exits: None,
        }
    }

    /// The same, with the gate monitor and the supervisor running as in `adrive run`.
    pub fn supervised(toml: &str) -> Rig {
        let mut rig = Rig::start(toml);
        let (tx, rx) = crossbeam_channel::unbounded();
        let cfg = rig.vehicle.config().supervisor.clone();
        rig.monitor = Some(adrive::engine::monitor::Monitor::start(rig.gate.clone()).unwrap());
        rig.supervisor = Some(
            adrive::supervisor::start(
                rig.gate.clone(),
                cfg,
                Box::new(move |e| {
                    let _ = tx.send(e);
                }),
            )
            .unwrap(),
        );
        rig.exits = Some(rx);
        rig
    }

    /// The supervisor's history so far.
    pub fn history(&self) -> Vec<String> {
        self.vehicle.supervision().snapshot().history
    }

    /// Wait for every device to report, then engage.
    pub fn engage(&self) {
        wait_for("every device to report", || self.gate.blockers().is_empty());
        self.gate.engage("test").expect("engage");
    }

    /// Every command the simulated devices applied so far.
    pub fn received(&self) -> Vec<SimEvent> {
        self.events.try_iter().collect()
    }

    /// A device by name.
    pub fn device(&self, name: &str) -> &Device {
        self.vehicle
            .find(name)
            .unwrap_or_else(|| panic!("no device {name}"))
    }

    pub fn id(&self, name: &str) -> DeviceId {
        self.device(name).id()
    }

    /// Intake of a command to a device by name, as the network or console would.
    pub fn submit(&self, name: &str, command: Command) -> Result<(), adrive::safety::Reject> {
        self.gate.submit(self.id(name), command, Instant::now())
    }

    /// A state by name, for a state device.
    pub fn state(&self, name: &str, state: &str) -> Command {
        Command::State(
            self.device(name)
                .config()
                .state_index(state)
                .expect("a state"),
        )
    }

    /// A reading of a device's cache by reading name (`None` before it reported).
    pub fn reading(&self, name: &str, reading: &str) -> Option<f64> {
        let d = self.device(name);
        d.reading(d.config().reading(reading)?)
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        if let Some(s) = self.supervisor.take() {
            s.shutdown(Duration::from_secs(1));
        }
        if let Some(g) = self.monitor.take() {
            g.shutdown(Duration::from_secs(1));
        }
        if let Some(e) = self.engine.take() {
            e.shutdown(Duration::from_secs(2));
        }
    }
}

/// A one-device vehicle: steering, simulated with the given extra settings.
pub fn steer_only(extra: &str, sim: &str) -> String {
    format!(
        r#"
[vehicle]
name = "bench"

[vehicle.roles]
steering = "steer"

[[device]]
name = "steer"
kind = "setpoint"
range = [-1.0, 1.0]
driver = "line"
baud = 38400
{extra}

[device.sim]
{sim}
"#
    )
}

/// The command listener's address, from a headless adrive's log up to its start
/// (`network up listen=ADDR`).
pub fn listen_address(log: &[String]) -> String {
    log.iter()
        .find_map(|l| l.split("network up listen=").nth(1)?.split(' ').next())
        .expect("the network's address in the log")
        .to_string()
}

/// Send `datagram` to the listener at `listen` from a socket of its own (replies to
/// one sender are spaced) and return adrive's reply: proof it was handled.
pub fn reply_to(listen: &str, datagram: &[u8]) -> String {
    let s = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    s.connect(listen).unwrap();
    s.set_read_timeout(Some(DEADLINE)).unwrap();
    s.send(datagram).unwrap();
    let mut buf = [0u8; 1024];
    let n = s.recv(&mut buf).expect("a reply");
    String::from_utf8_lossy(&buf[..n]).into_owned()
}

/// Lines of a child's output, delivered through a channel so reads can time out.
pub fn lines(stream: impl std::io::Read + Send + 'static) -> std::sync::mpsc::Receiver<String> {
    use std::io::BufRead;
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stream)
            .lines()
            .map_while(Result::ok)
        {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// Every line of an output whose process has ended, to its end: the reading thread
/// may still be behind the exit, so what is queued now is not all there is.
pub fn to_the_end(rx: &std::sync::mpsc::Receiver<String>) -> Vec<String> {
    let end = Instant::now() + DEADLINE;
    let mut out = Vec::new();
    loop {
        match rx.recv_timeout(end.saturating_duration_since(Instant::now())) {
            Ok(line) => out.push(line),
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => return out,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                panic!("the output did not end within {DEADLINE:?}: {out:?}")
            }
        }
    }
}

/// Read lines until one contains `pattern`; returns every line read.
pub fn until(rx: &std::sync::mpsc::Receiver<String>, pattern: &str) -> Vec<String> {
    until_within(rx, pattern, DEADLINE)
}

/// [`until`], waiting up to `within` (for an event known to come later than
/// [`DEADLINE`]).
pub fn until_within(
    rx: &std::sync::mpsc::Receiver<String>,
    pattern: &str,
    within: Duration,
) -> Vec<String> {
    let end = Instant::now() + within;
    let mut seen = Vec::new();
    loop {
        let left = end.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(l) => {
                let hit = l.contains(pattern);
                seen.push(l);
                if hit {
                    return seen;
                }
            }
            Err(_) => panic!("no line with {pattern:?}; got:\n{}", seen.join("\n")),
        }
    }
}

/// Send `sig` to a child process; false if it is already gone.
#[allow(unsafe_code)]
pub fn signal(child: &std::process::Child, sig: i32) -> bool {
    // SAFETY: plain kill(2) on our own child.
    unsafe { libc::kill(child.id() as i32, sig) == 0 }
}

/// What `cmd` printed and how it ended, as [`std::process::Command::output`] gives it,
/// within the deadline: a program that should have ended by itself (a refusal before
/// anything starts) and runs on instead is stopped, and the test fails saying what it
/// printed, rather than waiting for ever.
pub fn output_within(cmd: &mut std::process::Command) -> std::process::Output {
    use std::io::Read;
    use std::process::Stdio;
    let mut child = Reaped(
        cmd.stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let read = |mut from: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut all = Vec::new();
            let _ = from.read_to_end(&mut all);
            all
        })
    };
    let stdout = read(Box::new(child.stdout.take().unwrap()));
    let stderr = read(Box::new(child.stderr.take().unwrap()));
    let end = Instant::now() + DEADLINE;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if Instant::now() >= end {
            stop(&mut child.0);
            let said = |t: std::thread::JoinHandle<Vec<u8>>| {
                String::from_utf8_lossy(&t.join().unwrap()).into_owned()
            };
            panic!(
                "{cmd:?} still ran after {DEADLINE:?}; it printed:\n{}\n{}",
                said(stdout),
                said(stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    std::process::Output {
        status,
        stdout: stdout.join().unwrap(),
        stderr: stderr.join().unwrap(),
    }
}

/// Wait for a child to exit; its status code (`None` when a signal ended it).
pub fn wait_exit(child: &mut std::process::Child) -> Option<i32> {
    let end = Instant::now() + DEADLINE;
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return s.code();
        }
        assert!(Instant::now() < end, "the process did not exit");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A UDP port free on loopback right now.
pub fn free_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A fresh, empty directory for one test under the system's temporary directory
/// (`$TMPDIR`), removed when the guard drops: when the test ends, passing or failing.
pub fn tempdir(tag: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("adrive-{tag}-"))
        .tempdir()
        .expect("a temporary directory")
}

/// End a child the way a service manager does: SIGTERM, so that it cleans up after
/// itself (`adrive sim` removes its directory of links), then SIGKILL if it has not
/// exited by the deadline.
pub fn stop(child: &mut std::process::Child) {
    if matches!(child.try_wait(), Ok(Some(_))) {
        return;
    }
    signal(child, libc::SIGTERM);
    let end = Instant::now() + DEADLINE;
    while Instant::now() < end {
        if !matches!(child.try_wait(), Ok(None)) {
            return;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let _ = child.kill();
    let _ = child.wait();
}

/// A child process that is stopped ([`stop`]) when the test ends, passing or failing.
pub struct Reaped(pub std::process::Child);

impl Drop for Reaped {
    fn drop(&mut self) {
        stop(&mut self.0);
    }
}

impl std::ops::Deref for Reaped {
    type Target = std::process::Child;
    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl std::ops::DerefMut for Reaped {
    fn deref_mut(&mut self) -> &mut Self::Target {
        &mut self.0
    }
}

/// The entries named `adrive-sim-*` in `dir`: a simulator's directory of links.
pub fn sim_dirs(dir: &std::path::Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with("adrive-sim-"))
                .collect()
        })
        .unwrap_or_default()
}

/// `adrive --sim --headless ARGS` listening on a free port, logging into `dir` (its
/// runtime directory too), its output and error piped: for a test that reads its
/// summary.
pub fn headless_piped(dir: &std::path::Path, args: &[&str]) -> Reaped {
    Reaped(
        std::process::Command::new(env!("CARGO_BIN_EXE_adrive"))
            .args([
                "--sim",
                "--headless",
                "--listen",
                "127.0.0.1:0",
                "--log-dir",
            ])
            .arg(dir)
            .args(args)
            .env("XDG_RUNTIME_DIR", dir)
            .env_remove("NO_COLOR")
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap(),
    )
}

/// `adrive --sim --headless ARGS`, its runtime directory and its log in `dir`, once it
/// says it runs: the child and what it has said so far (its standard error keeps being
/// read into the receiver).
pub fn headless_sim(
    dir: &std::path::Path,
    args: &[&str],
) -> (Reaped, Vec<String>, std::sync::mpsc::Receiver<String>) {
    let mut child = Reaped(
        std::process::Command::new(env!("CARGO_BIN_EXE_adrive"))
            .args(["--sim", "--headless"])
            .args(args)
            .arg("--log-dir")
            .arg(dir.join("log"))
            .env("XDG_RUNTIME_DIR", dir)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let err = lines(child.stderr.take().unwrap());
    let seen = until(&err, "running headless");
    (child, seen, err)
}
