//! Section 15: hold-to-drive teleop, from the operator's key to the throttle. The real
//! binary's console — embedded, or `adrive attach` on adrive headless — runs in a
//! pseudo-terminal played by the terminal player (tests/common/terminal_player.rs): a
//! terminal that speaks the kitty keyboard protocol (press, repeat and release events),
//! or a legacy one whose held key is its key repeat. The vehicle is Alice in drive, her
//! devices `adrive sim`'s in a process of their own but for the throttle, whose end of
//! its port this process holds: a Modbus RTU slave that answers as the actuator and
//! stamps the first byte of every command it reads, in this process's clock — the one
//! the key events are stamped in when they are written.
//!
//! Rows: `hold` (releases reported): key release → the throttle's 0 over holds of random
//! length; `repeat` at 25 and 33 Hz (presses only, the key repeat learnt from a first
//! hold): last repeat → the throttle's 0, and every 0 the throttle got while the repeats
//! still came (a mid-hold drop); `hold` with the release lost (press, repeats, then
//! nothing): last repeat → the throttle's 0. Each embedded and through `adrive attach`.

// The throttle's end is a pseudo-terminal driven through libc; each block says why it
// is sound.
#![allow(unsafe_code)]

use super::common::pty::openpty;
use super::common::simproc::SimProcess;
use super::common::terminal_player::{Key, Kind, Play, Player};
use super::floor::quantile;
use super::rig;
use adrive::driver::modbus::proto::{self, Incoming, Request, Response};
use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::{AsRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Alice's throttle: Modbus slave 2, the target in holding register 0, ×0.0001.
const SLAVE: u8 = 2;
const SCALE: f64 = 0.0001;
/// The teleop gas level (the vehicle file's default).
const GAS: f64 = 0.2;
/// The key repeat's delay, as played.
const DELAY: Duration = Duration::from_millis(300);
/// Long enough for anything that works.
const DEADLINE: Duration = Duration::from_secs(30);

/// The throttle's end of its port: every command it read, with when its first byte was.
struct Throttle {
    path: String,
    got: Arc<Mutex<Vec<(Instant, f64)>>>,
    _slave: OwnedFd,
}

impl Throttle {
    fn open() -> Throttle {
        let (master, slave) = openpty(80, 24);
        // SAFETY: tcgetattr fills the struct; cfmakeraw and tcsetattr read it.
        unsafe {
            let mut t = std::mem::zeroed::<libc::termios>();
            libc::tcgetattr(slave.as_raw_fd(), &mut t);
            libc::cfmakeraw(&mut t);
            libc::tcsetattr(slave.as_raw_fd(), libc::TCSANOW, &t);
        }
        let mut buf = [0u8; 128];
        // SAFETY: ptsname_r writes a NUL-terminated path into the buffer given.
        let r = unsafe { libc::ptsname_r(master.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
        assert_eq!(r, 0, "ptsname");
        let n = buf.iter().position(|&b| b == 0).unwrap();
        let path = String::from_utf8_lossy(&buf[..n]).into_owned();
        let got = Arc::new(Mutex::new(Vec::new()));
        let g = got.clone();
        std::thread::Builder::new()
            .name("throttle-end".into())
            .spawn(move || serve(File::from(master), &g))
            .unwrap();
        Throttle {
            path,
            got,
            _slave: slave,
        }
    }

    /// The first command after `from` that `ok` takes, waiting up to `within`.
    fn first_after(
        &self,
        from: Instant,
        within: Duration,
        ok: impl Fn(f64) -> bool,
    ) -> Option<Instant> {
        let end = Instant::now() + within;
        loop {
            if let Some((t, _)) = self
                .got
                .lock()
                .unwrap()
                .iter()
                .find(|(t, v)| *t >= from && ok(*v))
            {
                return Some(*t);
            }
            if Instant::now() > end {
                return None;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Every command read between `from` and `to`.
    fn between(&self, from: Instant, to: Instant) -> Vec<f64> {
        self.got
            .lock()
            .unwrap()
            .iter()
            .filter(|(t, _)| *t >= from && *t < to)
            .map(|(_, v)| *v)
            .collect()
    }
}

/// Answer as the throttle: writes to register 0 are commands (stamped), reads get the
/// last command as the position and a clear status word.
fn serve(mut m: File, got: &Mutex<Vec<(Instant, f64)>>) {
    let mut w = m.try_clone().unwrap();
    let (mut buf, mut started) = (Vec::new(), Instant::now());
    let mut pos = 0u16;
    let mut chunk = [0u8; 256];
    while let Ok(n) = m.read(&mut chunk) {
        if n == 0 {
            return;
        }
        if buf.is_empty() {
            started = Instant::now();
        }
        buf.extend_from_slice(&chunk[..n]);
        loop {
            match proto::decode_request(&buf) {
                Incoming::Incomplete => break,
                Incoming::Request { slave, len, .. } if slave != SLAVE => {
                    buf.drain(..len);
                }
                Incoming::Request {
                    slave,
                    request,
                    len,
                } => {
                    let reply = match request {
                        Request::WriteSingle { addr, value } => {
                            got.lock()
                                .unwrap()
                                .push((started, f64::from(value) * SCALE));
                            pos = value;
                            Response::WriteSingle { addr, value }
                        }
                        Request::ReadInput { count, .. } | Request::ReadHolding { count, .. } => {
                            let mut regs = vec![0u16; count as usize];
                            if let Some(r) = regs.first_mut() {
                                *r = pos;
                            }
                            Response::ReadInput(regs)
                        }
                        Request::WriteMultiple { addr, values } => Response::WriteMultiple {
                            addr,
                            count: values.len() as u16,
                        },
                    };
                    let _ = w.write_all(&proto::encode_response(slave, &reply));
                    buf.drain(..len);
                }
                Incoming::Refuse { len, .. } | Incoming::Garbage { len, .. } => {
                    buf.drain(..len.max(1));
                }
            }
            if buf.is_empty() {
                break;
            }
            started = Instant::now();
        }
    }
}

/// Alice on `sim`'s ports, her throttle on `throttle`; her devices' readings allowed to
/// be 2 s old and their replies 1 s late, so that a stall of the shared machine does not
/// disengage her between holds.
fn vehicle(dir: &Path, sim: &SimProcess, throttle: &str, name: &str) -> PathBuf {
    let mut paths = sim.paths.iter();
    let mut text = String::new();
    let mut device = String::new();
    for line in adrive::config::ALICE_TOML.lines() {
        if let Some(n) = line.strip_prefix("name = \"") {
            device = n.split('"').next().unwrap_or("").to_string();
        }
        let l = match line {
            _ if line.starts_with("port = ") => {
                let sim = paths.next().expect("a simulated device for each");
                let p = if device == "gas" { throttle } else { sim };
                format!("port = \"{p}\"")
            }
            _ if line.starts_with("status_max_age = ") => "status_max_age = \"2s\"".into(),
            _ if line.starts_with("reply_timeout = ") => "reply_timeout = \"1s\"".into(),
            _ => line.to_string(),
        };
        text.push_str(&l);
        text.push('\n');
    }
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

/// How the console reaches adrive.
#[derive(Clone, Copy, PartialEq)]
enum Via {
    Embedded,
    Attach,
}

/// The simulated Alice, her throttle's end, adrive and a console on a played terminal.
struct Rig {
    _sim: SimProcess,
    throttle: Throttle,
    console: Child,
    service: Option<Child>,
    term: Player,
    socket: PathBuf,
}

impl Rig {
    fn start(dir: &Path, name: &str, via: Via, play: Play) -> Rig {
        let sim = SimProcess::start();
        let throttle = Throttle::open();
        let file = vehicle(dir, &sim, &throttle.path, name);
        let socket = dir.join(format!("{name}.sock"));
        let adrive = |cmd: &mut Command| {
            cmd.arg("--config")
                .arg(&file)
                .args(["--listen", "127.0.0.1:0", "--log-dir"])
                .arg(dir.join(format!("{name}-logs")))
                .arg("--socket")
                .arg(&socket);
        };
        let mut service = None;
        let mut cmd = Command::new(rig::adrive());
        match via {
            Via::Embedded => adrive(&mut cmd),
            Via::Attach => {
                let mut s = Command::new(rig::adrive());
                adrive(&mut s);
                s.arg("--headless")
                    .stdin(Stdio::null())
                    .stdout(Stdio::null())
                    .stderr(Stdio::null());
                service = Some(s.spawn().expect("adrive starts"));
                let end = Instant::now() + DEADLINE;
                while !socket.exists() {
                    assert!(Instant::now() < end, "adrive never opened its socket");
                    std::thread::sleep(Duration::from_millis(50));
                }
                cmd.arg("attach").arg("--socket").arg(&socket);
            }
        }
        cmd.env("TERM", "xterm-256color")
            .env_remove("TMUX")
            .env_remove("STY");
        let (console, term) = Player::spawn_playing(&mut cmd, 100, 30, true, play);
        let r = Rig {
            _sim: sim,
            throttle,
            console,
            service,
            term,
            socket,
        };
        let end = Instant::now() + DEADLINE;
        while !r.gate()["blockers"].as_array().is_some_and(Vec::is_empty) {
            assert!(Instant::now() < end, "the devices never all reported");
            std::thread::sleep(Duration::from_millis(100));
        }
        r
    }

    fn status(&self) -> serde_json::Value {
        let out = Command::new(rig::adrive())
            .args(["ctl", "status", "--json", "--socket"])
            .arg(&self.socket)
            .output()
            .unwrap();
        serde_json::from_slice(&out.stdout).unwrap_or_default()
    }

    fn gate(&self) -> serde_json::Value {
        self.status()["gate"].clone()
    }

    /// Keys, each after the frame that shows what it acts on had time to be drawn.
    fn keys(&mut self, k: &str) {
        self.term.write(k.as_bytes());
        std::thread::sleep(Duration::from_millis(250));
    }

    /// Engaged, in drive, in teleop (again after something stopped the vehicle).
    fn drive(&mut self) {
        let end = Instant::now() + DEADLINE;
        self.keys("\x1b");
        while self.gate()["engaged"] != true {
            assert!(Instant::now() < end, "could not engage: {}", self.gate());
            self.keys("E");
            self.keys("y");
        }
        self.keys("t");
        self.keys("\x15d\r");
        self.keys("d");
    }

    /// Hold `key` for `repeats` repeats `interval` apart after [`DELAY`], as kitty
    /// events or (`kitty` false) a legacy key repeat; let go if `release`. Returns when
    /// the last event was written, and when the hold's first and last were.
    fn hold(
        &mut self,
        kitty: bool,
        interval: Duration,
        repeats: u32,
        release: Option<Duration>,
    ) -> (Instant, Instant) {
        let start = Instant::now();
        match kitty {
            true => self.term.kitty(Key::Up, Kind::Press),
            false => self.term.key(Key::Up),
        }
        let mut last = start;
        for i in 0..repeats {
            sleep_until(start + DELAY + interval * i);
            last = Instant::now();
            match kitty {
                true => self.term.kitty(Key::Up, Kind::Repeat),
                false => self.term.key(Key::Up),
            }
        }
        if let Some(after) = release {
            sleep_until(start + after.max(last - start + Duration::from_millis(1)));
            last = Instant::now();
            self.term.kitty(Key::Up, Kind::Release);
        }
        (start, last)
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        for c in [Some(&mut self.console), self.service.as_mut()]
            .into_iter()
            .flatten()
        {
            // SAFETY: kill(2) on our own child.
            unsafe { libc::kill(c.id() as i32, libc::SIGTERM) };
            let _ = c.wait();
        }
    }
}

fn sleep_until(t: Instant) {
    std::thread::sleep(t.saturating_duration_since(Instant::now()));
}

/// A small generator for the holds' random lengths and pauses.
struct Rand(u64);

impl Rand {
    fn below(&mut self, n: u64) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0 % n
    }
}

/// What a row is.
#[derive(Clone, Copy)]
enum Row {
    /// Releases reported, each hold let go.
    Hold,
    /// Presses only, the key repeat at this interval.
    Repeat(Duration),
    /// Releases reported, the release lost.
    Lost,
}

/// A row's figures.
struct Figures {
    /// From the release (or the last repeat) to the throttle's first 0.
    stops: Vec<Duration>,
    /// Throttle 0s while the key was held.
    drops: usize,
    /// Holds whose gas reached the throttle.
    gassed: usize,
    /// Holds left out: the vehicle was stopped by something else (a device the loaded
    /// machine starved past its deadline, the deadman).
    disturbed: usize,
}

fn run_row(dir: &Path, via: Via, row: Row, holds: usize, seed: u64) -> Figures {
    let (kitty, interval) = match row {
        Row::Hold | Row::Lost => (true, Duration::from_millis(30)),
        Row::Repeat(i) => (false, i),
    };
    let play = if kitty {
        Play::kitty()
    } else {
        Play::default()
    };
    let name = format!(
        "s15-{}-{seed}",
        if via == Via::Attach {
            "attach"
        } else {
            "embedded"
        }
    );
    let mut r = Rig::start(dir, &name, via, play);
    r.drive();
    // The first hold teaches the console the key repeat.
    let (_, last) = r.hold(kitty, interval, 20, kitty.then_some(DELAY + interval * 20));
    r.throttle
        .first_after(last, Duration::from_secs(2), |v| v == 0.0);
    std::thread::sleep(Duration::from_millis(300));
    let mut rand = Rand(seed);
    let mut f = Figures {
        stops: Vec::new(),
        drops: 0,
        gassed: 0,
        disturbed: 0,
    };
    while f.stops.len() < holds {
        let (release, repeats) = match row {
            // A hold of 50 … 1000 ms, its repeats as long as it lasts.
            Row::Hold => {
                let len = Duration::from_millis(50 + rand.below(950));
                let repeats = len.saturating_sub(DELAY).as_millis() / interval.as_millis();
                (Some(len), repeats as u32)
            }
            Row::Repeat(_) | Row::Lost => (None, 1 + rand.below(20) as u32),
        };
        let (start, end) = r.hold(kitty, interval, repeats, release);
        let stop = r
            .throttle
            .first_after(end, Duration::from_secs(3), |v| v == 0.0);
        let gas = r
            .throttle
            .first_after(start, Duration::ZERO, |v| (v - GAS).abs() < 1e-6);
        let engaged = r.gate()["engaged"] == true;
        match (stop, engaged) {
            (Some(at), true) => {
                f.stops.push(at.saturating_duration_since(end));
                if let Some(g) = gas.filter(|g| *g < end) {
                    f.gassed += 1;
                    f.drops += r
                        .throttle
                        .between(g, end)
                        .iter()
                        .filter(|v| **v == 0.0)
                        .count();
                }
            }
            _ => {
                // Something else stopped the vehicle: drive again, and say so.
                f.disturbed += 1;
                assert!(
                    f.disturbed <= holds / 10 + 5,
                    "the vehicle kept stopping: {}",
                    r.gate()
                );
                r.drive();
            }
        }
        std::thread::sleep(Duration::from_millis(50 + rand.below(200)));
    }
    f.stops.sort();
    f
}

fn ms(us: f64) -> String {
    format!("{:.1}", us / 1000.0)
}

/// `holds` holds a row (hold and repeat rows); the lost release's rows and the attached
/// console's take a third of that.
pub fn section15_teleop(dir: &tempfile::TempDir, holds: usize) {
    println!(
        "\n== 15. Hold-to-drive teleop: the key → the throttle's 0 at the device, Alice in drive, {holds} holds a row (a third for the lost release and through attach) =="
    );
    super::precise_timers();
    println!(
        "{:<38} {:>6} {:>9} {:>9} {:>9} {:>9} {:>7} {:>7} {:>6}",
        "row", "holds", "p50 ms", "p99 ms", "max ms", "goal ms", "gassed", "drops", "left"
    );
    let rows = [
        ("hold: release → 0", Row::Hold, 50.0),
        (
            "repeat 25 Hz: last repeat → 0",
            Row::Repeat(Duration::from_millis(40)),
            120.0,
        ),
        (
            "repeat 33 Hz: last repeat → 0",
            Row::Repeat(Duration::from_millis(30)),
            90.0,
        ),
        ("hold, release lost: last → 0", Row::Lost, 90.0),
    ];
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    for via in [Via::Embedded, Via::Attach] {
        for (label, row, goal) in rows {
            let n = match (via, row) {
                (Via::Embedded, Row::Hold | Row::Repeat(_)) => holds,
                _ => holds.div_ceil(3),
            };
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
            let f = run_row(dir.path(), via, row, n, seed | 1);
            let label = match via {
                Via::Embedded => label.to_string(),
                Via::Attach => format!("attach, {label}"),
            };
            println!(
                "{label:<38} {:>6} {:>9} {:>9} {:>9} {:>9.0} {:>7} {:>7} {:>6}",
                f.stops.len(),
                ms(quantile(&f.stops, 0.5)),
                ms(quantile(&f.stops, 0.99)),
                ms(quantile(&f.stops, 1.0)),
                goal,
                f.gassed,
                f.drops,
                f.disturbed
            );
        }
    }
    println!("(goal: hold p99 ≤ 50 ms; repeat and a lost release ≤ 3 repeat intervals; 0 drops. gassed: holds whose gas reached the throttle before the key came up; drops: throttle 0s while the key was held; left: holds left out because something else stopped the vehicle first)");
}
