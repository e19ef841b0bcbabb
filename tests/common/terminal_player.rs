//! A pseudo-terminal's master side that plays a terminal, for tests and the benchmark
//! that drive the real binary.
//!
//! A terminal does more than show bytes: it answers what a program asks of it. adrive
//! asks whether the terminal speaks the kitty keyboard protocol (`CSI ? u`, then the
//! primary device attributes `CSI c`, which every terminal answers), pushes and pops the
//! protocol's flags (`CSI > 3 u`, `CSI < u`), and, while its console commands, asks
//! for the cursor position (`CSI 6 n`) every few hundred milliseconds to prove that the
//! whole way to the operator's screen and back still works. The [`Player`] reads
//! everything the program writes (so the program never blocks on a full terminal)
//! and answers those requests as [`Play`] says — at once, late, or not at all — and it
//! can stop reading altogether, as a frozen SSH session does. It also types: keys as a
//! legacy terminal sends them, and the kitty protocol's press, repeat and release
//! events ([`Key`], [`Kind`]).
//!
//! `pty::Master` is a `Player`: every test that runs the console in a pseudo-terminal
//! has a terminal that answers, as a real one does.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::{AsRawFd, OwnedFd};
use std::process::{Child, Command};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How the terminal answers a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Answer {
    /// At once.
    Now,
    /// This long after the request was read (a slow link: the answer's way back).
    After(Duration),
    /// Never (the request is read and dropped).
    Never,
}

/// What the played terminal does. The default is a terminal of the legacy kind (an
/// xterm without the kitty protocol): it answers the device attributes and the cursor
/// position at once, and does not know `CSI ? u`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Play {
    /// It speaks the kitty keyboard protocol: answers `CSI ? u` with its flags, and
    /// keeps the stack of flags pushed and popped.
    pub kitty: bool,
    /// The primary device attributes (`CSI c`).
    pub attributes: Answer,
    /// The cursor position report (`CSI 6 n`).
    pub cursor: Answer,
    /// It reads what the program writes. A terminal that stops reading answers nothing
    /// either, and the program's writes fill the pseudo-terminal's buffer, then block.
    pub reading: bool,
}

impl Default for Play {
    fn default() -> Self {
        Play {
            kitty: false,
            attributes: Answer::Now,
            cursor: Answer::Now,
            reading: true,
        }
    }
}

impl Play {
    /// A terminal that speaks the kitty keyboard protocol (kitty, foot, WezTerm…).
    pub fn kitty() -> Play {
        Play {
            kitty: true,
            ..Play::default()
        }
    }

    /// A terminal that answers nothing at all (no device attributes either).
    pub fn silent() -> Play {
        Play {
            attributes: Answer::Never,
            cursor: Answer::Never,
            ..Play::default()
        }
    }
}

/// What the player saw the program ask, in order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Asked {
    /// `CSI ? u`: the kitty protocol's flags.
    Flags,
    /// `CSI c`: the primary device attributes.
    Attributes,
    /// `CSI 6 n`: the cursor position.
    Cursor,
    /// `CSI > flags u`: push the kitty protocol's flags.
    Push(u32),
    /// `CSI < n u`: pop that many.
    Pop(u32),
}

/// A key the player types.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Key {
    Up,
    Down,
    Left,
    Right,
    Esc,
    Enter,
    Char(char),
}

/// A kitty keyboard protocol event type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Press,
    Repeat,
    Release,
}

impl Key {
    /// The bytes a legacy terminal sends for a press (and for each of its repeats).
    pub fn legacy(self) -> Vec<u8> {
        match self {
            Key::Up => b"\x1b[A".to_vec(),
            Key::Down => b"\x1b[B".to_vec(),
            Key::Right => b"\x1b[C".to_vec(),
            Key::Left => b"\x1b[D".to_vec(),
            Key::Esc => b"\x1b".to_vec(),
            Key::Enter => b"\r".to_vec(),
            Key::Char(c) => c.to_string().into_bytes(),
        }
    }

    /// The bytes a terminal in the kitty protocol with flags 3 (disambiguate, report
    /// event types) sends for this event: an arrow's press as legacy (`CSI A`), its
    /// repeat and release with the event type (`CSI 1;1:2A`); a text key's press as its
    /// text, its repeat and release as `CSI code;1:kind u`; Esc always as `CSI 27 u`.
    /// Enter's repeat and release are not reported at these flags.
    pub fn kitty(self, kind: Kind) -> Vec<u8> {
        let k = match kind {
            Kind::Press => 1,
            Kind::Repeat => 2,
            Kind::Release => 3,
        };
        let arrow = |f: char| {
            if kind == Kind::Press {
                format!("\x1b[{f}")
            } else {
                format!("\x1b[1;1:{k}{f}")
            }
        };
        let s = match self {
            Key::Up => arrow('A'),
            Key::Down => arrow('B'),
            Key::Right => arrow('C'),
            Key::Left => arrow('D'),
            Key::Esc if kind == Kind::Press => "\x1b[27u".into(),
            Key::Esc => format!("\x1b[27;1:{k}u"),
            Key::Enter if kind == Kind::Press => "\r".into(),
            Key::Enter => String::new(),
            Key::Char(c) if kind == Kind::Press => c.to_string(),
            Key::Char(c) => format!("\x1b[{};1:{k}u", c as u32),
        };
        s.into_bytes()
    }
}

/// The state the reading thread shares with the test.
#[derive(Default)]
struct Shared {
    out: Mutex<Vec<u8>>,
    play: Mutex<Play>,
    asked: Mutex<Vec<(Instant, Asked)>>,
    /// Cursor position reports written.
    answered: Mutex<usize>,
    /// When the last cursor position report was written.
    last_answer: Mutex<Option<Instant>>,
    /// The kitty protocol's stack of flags (the top applies).
    stack: Mutex<Vec<u32>>,
    close: AtomicBool,
    /// The reading thread's turns, for [`Player::set`] to wait on.
    turns: AtomicU64,
}

/// The master side of a pseudo-terminal, playing a terminal (see the module's doc).
pub struct Player {
    shared: Arc<Shared>,
    reader: Option<JoinHandle<()>>,
    /// The master side again, for typing and answering.
    keys: Option<Arc<Mutex<File>>>,
}

impl Player {
    /// Start `cmd` on a new `cols`×`rows` terminal playing the default terminal.
    /// `controlling`: the terminal is its controlling terminal (as in an SSH session).
    pub fn spawn(cmd: &mut Command, cols: u16, rows: u16, controlling: bool) -> (Child, Player) {
        Player::spawn_playing(cmd, cols, rows, controlling, Play::default())
    }

    /// The same, playing `play` from the first byte.
    pub fn spawn_playing(
        cmd: &mut Command,
        cols: u16,
        rows: u16,
        controlling: bool,
        play: Play,
    ) -> (Child, Player) {
        let (master, slave) = super::pty::openpty(cols, rows);
        super::pty::attach(cmd, &slave, controlling);
        let child = cmd.spawn().expect("start the program on the terminal");
        // Only the child holds the slave now: the master is the last link to it.
        drop(slave);
        (child, Player::start(master, play))
    }

    /// Play the terminal on `master` (a program runs on its slave side).
    pub fn start(master: OwnedFd, play: Play) -> Player {
        let shared = Arc::new(Shared {
            play: Mutex::new(play),
            ..Shared::default()
        });
        let keys = Arc::new(Mutex::new(File::from(
            master.try_clone().expect("the master again"),
        )));
        let (s, k) = (shared.clone(), keys.clone());
        let reader = std::thread::Builder::new()
            .name("terminal player".into())
            .spawn(move || play_until_closed(File::from(master), &s, &k))
            .expect("the player's thread");
        Player {
            shared,
            reader: Some(reader),
            keys: Some(keys),
        }
    }

    /// Everything the program wrote so far (that the terminal read).
    pub fn bytes(&self) -> Vec<u8> {
        self.shared.out.lock().unwrap().clone()
    }

    /// Read everything the program wrote before this call: once nothing waits unread
    /// on the terminal and the reading thread took two turns since (or it ended at the
    /// hang-up). For a program that has exited, [`Player::bytes`] is then all it wrote:
    /// its last words (said after it left the screen) were read late otherwise. A
    /// terminal that stopped reading reads nothing more: it returns at once.
    #[allow(unsafe_code)]
    pub fn read_to_end(&self) {
        if !self.shared.play.lock().unwrap().reading {
            return;
        }
        let end = Instant::now() + super::DEADLINE;
        let finished = || self.reader.as_ref().is_none_or(|r| r.is_finished());
        loop {
            let mut unread: libc::c_int = 0;
            if let Some(keys) = &self.keys {
                let fd = keys.lock().unwrap().as_raw_fd();
                // SAFETY: FIONREAD writes an int; the descriptor is the open master.
                if unsafe { libc::ioctl(fd, libc::FIONREAD, &mut unread) } != 0 {
                    unread = 0;
                }
            }
            if unread == 0 || finished() {
                break;
            }
            assert!(
                Instant::now() < end,
                "the terminal never read {unread} bytes"
            );
            std::thread::sleep(Duration::from_millis(2));
        }
        let turn = self.shared.turns.load(Ordering::SeqCst);
        while self.shared.turns.load(Ordering::SeqCst) < turn + 2 && !finished() {
            assert!(Instant::now() < end, "the terminal player stopped turning");
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// How many bytes the program wrote so far (that the terminal read).
    pub fn len(&self) -> usize {
        self.shared.out.lock().unwrap().len()
    }

    /// Change how the terminal plays from now on: once this returns, the reading
    /// thread plays the change (a turn it was in when the change came has ended), and
    /// answers it was to write late are dropped when it no longer answers them.
    pub fn set(&self, change: impl FnOnce(&mut Play)) {
        change(&mut self.shared.play.lock().unwrap());
        let turn = self.shared.turns.load(Ordering::SeqCst);
        while self.shared.turns.load(Ordering::SeqCst) < turn + 2
            && !self.shared.close.load(Ordering::Relaxed)
            && self.reader.as_ref().is_some_and(|r| !r.is_finished())
        {
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// Stop answering the cursor position and the device attributes; keep reading.
    pub fn stop_answering(&self) {
        self.set(|p| {
            p.cursor = Answer::Never;
            p.attributes = Answer::Never;
        });
    }

    /// Stop reading what the program writes (and so answering anything): a frozen
    /// session.
    pub fn stop_reading(&self) {
        self.set(|p| p.reading = false);
    }

    /// Everything the program asked so far, with when it was read.
    pub fn asked(&self) -> Vec<(Instant, Asked)> {
        self.shared.asked.lock().unwrap().clone()
    }

    /// How many cursor position requests the program made so far.
    pub fn cursor_requests(&self) -> usize {
        self.asked()
            .iter()
            .filter(|(_, a)| *a == Asked::Cursor)
            .count()
    }

    /// How many cursor position reports the terminal wrote so far.
    pub fn cursor_answers(&self) -> usize {
        *self.shared.answered.lock().unwrap()
    }

    /// When the terminal last wrote a cursor position report.
    pub fn last_answer(&self) -> Option<Instant> {
        *self.shared.last_answer.lock().unwrap()
    }

    /// The kitty protocol's flags in force now (0: the legacy encoding).
    pub fn kitty_flags(&self) -> u32 {
        self.shared
            .stack
            .lock()
            .unwrap()
            .last()
            .copied()
            .unwrap_or(0)
    }

    /// Type `bytes` on the terminal, as a user at its keyboard would.
    pub fn write(&mut self, bytes: &[u8]) {
        let keys = self.keys.as_ref().expect("the terminal is open");
        let mut k = keys.lock().unwrap();
        k.write_all(bytes).and_then(|()| k.flush()).expect("typing");
    }

    /// A key as a legacy terminal sends it.
    pub fn key(&mut self, key: Key) {
        self.write(&key.legacy());
    }

    /// One kitty protocol event of `key`.
    pub fn kitty(&mut self, key: Key, kind: Kind) {
        self.write(&key.kitty(kind));
    }

    /// Hold `key` as a legacy terminal's key repeat does: the press, then after `delay`
    /// a repeat every `interval`, `repeats` of them; nothing marks the release.
    pub fn hold_legacy(&mut self, key: Key, delay: Duration, interval: Duration, repeats: u32) {
        let start = Instant::now();
        self.key(key);
        for i in 0..repeats {
            sleep_until(start + delay + interval * i);
            self.key(key);
        }
    }

    /// Hold `key` in the kitty protocol: the press, then after `delay` a repeat event
    /// every `interval`, `repeats` of them, then the release if `release`.
    pub fn hold_kitty(
        &mut self,
        key: Key,
        delay: Duration,
        interval: Duration,
        repeats: u32,
        release: bool,
    ) {
        let start = Instant::now();
        self.kitty(key, Kind::Press);
        for i in 0..repeats {
            sleep_until(start + delay + interval * i);
            self.kitty(key, Kind::Repeat);
        }
        if release {
            sleep_until(start + delay + interval * repeats);
            self.kitty(key, Kind::Release);
        }
    }

    /// Resize the terminal as a terminal window does: the kernel signals SIGWINCH to
    /// the program on it.
    #[allow(unsafe_code)]
    pub fn resize(&self, cols: u16, rows: u16) {
        let keys = self
            .keys
            .as_ref()
            .expect("the terminal is open")
            .lock()
            .unwrap();
        let ws = libc::winsize {
            ws_row: rows,
            ws_col: cols,
            ws_xpixel: 0,
            ws_ypixel: 0,
        };
        // SAFETY: TIOCSWINSZ reads the struct from a valid terminal fd.
        let r = unsafe { libc::ioctl(keys.as_raw_fd(), libc::TIOCSWINSZ as _, &ws) };
        assert_eq!(r, 0, "TIOCSWINSZ: {}", std::io::Error::last_os_error());
    }

    /// Close the master side (every descriptor of it): the terminal hangs up.
    pub fn hang_up(&mut self) {
        self.keys = None;
        self.shared.close.store(true, Ordering::Relaxed);
        if let Some(r) = self.reader.take() {
            r.join().expect("the terminal player");
        }
    }
}

impl Drop for Player {
    fn drop(&mut self) {
        self.hang_up();
    }
}

fn sleep_until(t: Instant) {
    std::thread::sleep(t.saturating_duration_since(Instant::now()));
}

/// A request the terminal found in what the program wrote, from `from`: what it is and
/// where it ends, `None` when it is not complete yet. Anything else is skipped.
fn next_request(out: &[u8], from: usize) -> (Option<Asked>, usize) {
    let mut i = from;
    while i < out.len() {
        if out[i] != 0x1b {
            i += 1;
            continue;
        }
        if i + 1 >= out.len() {
            return (None, i);
        }
        if out[i + 1] != b'[' {
            i += 1;
            continue;
        }
        // A control sequence: parameters and intermediates, then the final byte.
        let mut j = i + 2;
        while j < out.len() && (0x20..0x40).contains(&out[j]) {
            j += 1;
        }
        if j >= out.len() {
            return (None, i);
        }
        let body = &out[i + 2..j];
        let number = |b: &[u8]| std::str::from_utf8(b).ok()?.parse::<u32>().ok();
        let asked = match (out[j], body) {
            (b'u', b"?") => Some(Asked::Flags),
            (b'c', b"" | b"0") => Some(Asked::Attributes),
            (b'n', b"6") => Some(Asked::Cursor),
            (b'u', [b'>', rest @ ..]) => Some(Asked::Push(number(rest).unwrap_or(0))),
            (b'u', [b'<', rest @ ..]) => Some(Asked::Pop(number(rest).unwrap_or(1))),
            _ => None,
        };
        if let Some(a) = asked {
            return (Some(a), j + 1);
        }
        i = j + 1;
    }
    (None, i)
}

/// Keep what the program writes and answer its requests, until told to close; the
/// master is dropped (closed) on return.
#[allow(unsafe_code)]
fn play_until_closed(mut master: File, s: &Shared, keys: &Mutex<File>) {
    let mut buf = [0u8; 4096];
    let mut scanned = 0;
    // Answers to write, each at its time.
    let mut due: VecDeque<(Instant, Vec<u8>)> = VecDeque::new();
    while !s.close.load(Ordering::Relaxed) {
        s.turns.fetch_add(1, Ordering::SeqCst);
        let now = Instant::now();
        let play = s.play.lock().unwrap().clone();
        // A terminal that stalled writes nothing it was still to write.
        due.retain(|(_, bytes)| {
            play.reading
                && match bytes.last() {
                    Some(b'R') => play.cursor != Answer::Never,
                    Some(b'c') => play.attributes != Answer::Never,
                    _ => true,
                }
        });
        while due.front().is_some_and(|(t, _)| *t <= now) {
            let (_, bytes) = due.pop_front().unwrap();
            if keys.lock().unwrap().write_all(&bytes).is_err() {
                return;
            }
            if bytes.ends_with(b"R") {
                *s.answered.lock().unwrap() += 1;
                *s.last_answer.lock().unwrap() = Some(Instant::now());
            }
        }
        let reading = play.reading;
        let wait = due
            .front()
            .map(|(t, _)| t.saturating_duration_since(now).as_millis() as i32)
            .unwrap_or(20)
            .clamp(0, 20);
        let mut p = libc::pollfd {
            fd: master.as_raw_fd(),
            events: if reading { libc::POLLIN } else { 0 },
            revents: 0,
        };
        // SAFETY: one valid pollfd, a short timeout.
        if unsafe { libc::poll(&mut p, 1, wait) } <= 0 || p.revents & libc::POLLIN == 0 {
            if p.revents & (libc::POLLHUP | libc::POLLERR) != 0 && reading {
                return;
            }
            continue;
        }
        let n = match master.read(&mut buf) {
            Ok(0) | Err(_) => return,
            Ok(n) => n,
        };
        let mut out = s.out.lock().unwrap();
        out.extend_from_slice(&buf[..n]);
        let read_at = Instant::now();
        loop {
            let (asked, end) = next_request(&out, scanned);
            scanned = end;
            let Some(asked) = asked else { break };
            let play = s.play.lock().unwrap().clone();
            s.asked.lock().unwrap().push((read_at, asked.clone()));
            let (answer, bytes) = match asked {
                Asked::Flags if play.kitty => {
                    let flags = s.stack.lock().unwrap().last().copied().unwrap_or(0);
                    (Answer::Now, format!("\x1b[?{flags}u").into_bytes())
                }
                Asked::Flags => (Answer::Never, Vec::new()),
                Asked::Attributes => (play.attributes, b"\x1b[?62;22c".to_vec()),
                Asked::Cursor => (play.cursor, b"\x1b[1;1R".to_vec()),
                Asked::Push(f) => {
                    if play.kitty {
                        s.stack.lock().unwrap().push(f);
                    }
                    (Answer::Never, Vec::new())
                }
                Asked::Pop(n) => {
                    let mut stack = s.stack.lock().unwrap();
                    let keep = stack.len().saturating_sub(n as usize);
                    stack.truncate(keep);
                    (Answer::Never, Vec::new())
                }
            };
            match answer {
                Answer::Now => due.push_back((read_at, bytes)),
                Answer::After(d) => due.push_back((read_at + d, bytes)),
                Answer::Never => {}
            }
        }
    }
}
