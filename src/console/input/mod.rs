//! The console's terminal input: keys (with their kind, where the terminal reports
//! releases), window sizes, and the terminal's answers — read on a thread of its own
//! (`console/input`), each stamped where it is born, and delivered on a channel the
//! console's loop `select!`s over.
//!
//! adrive reads the terminal itself rather than through crossterm's event reader:
//! crossterm parses the terminal's replies (a cursor position, the kitty protocol's
//! flags, the device attributes) into events `event::read` never returns, its own probe
//! of the kitty protocol can wait 2 s, and its reader spun for ever on a terminal that
//! hung up (crossterm issue 793) and, with its default event source, left a key unread
//! after a resize. Here:
//!
//! - the terminal's file descriptor is polled level-triggered, and read only when
//!   bytes wait; readable with nothing to read is a hang-up ([`Input::Closed`]);
//! - [`decode`] turns the bytes into keys and replies (a pure module, tested on bytes);
//!   a lone `ESC` is the Esc key once [`decode::ESC_WAIT`] passed with nothing after it;
//! - [`probe`] decides from the replies whether the terminal reports releases, and
//!   never waits more than [`probe::WAIT`];
//! - a cursor position report is an [`Input::Answer`], the liveness check's round trip
//!   ([`link`]);
//! - SIGWINCH arrives through a pipe (signal-hook) polled beside the terminal, as
//!   [`Input::Resize`].

pub(crate) mod decode;
pub(crate) mod link;
pub(crate) mod probe;

use crate::controls::TICK;
use crossbeam_channel::{Receiver, Sender};
use decode::{Decoder, Reply, Token};
use probe::Probe;
use rustix::event::{PollFd, PollFlags, Timespec};
use std::io::{self, IsTerminal};
use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::os::unix::net::UnixStream;
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

/// What the console's input thread delivers.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Input {
    /// A key, with crossterm's `KeyEvent` (its `kind` is Press, Repeat or Release:
    /// Repeat and Release only where the terminal reports them), and when its bytes
    /// were read.
    Key(crossterm::event::KeyEvent, Instant),
    /// The window's new size (columns, rows).
    Resize(u16, u16),
    /// What the terminal was found to report, once its probe ended (at start, within
    /// [`probe::WAIT`]; again if a late answer upgrades it).
    Keyboard(Keyboard),
    /// The terminal answered a round trip (a cursor position report), read then.
    Answer(Instant),
    /// The terminal is gone; the cause.
    Closed(String),
}

/// How the operator's keys reach adrive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Keyboard {
    /// Presses, repeats and releases (the kitty keyboard protocol's event types).
    Releases,
    /// Presses only (legacy): a held key shows as the terminal's key repeat.
    PressesOnly,
}

impl Keyboard {
    /// In words, for the guide and the log.
    pub fn describe(self) -> &'static str {
        match self {
            Keyboard::Releases => "presses, repeats and releases (kitty keyboard protocol)",
            Keyboard::PressesOnly => "presses only",
        }
    }
}

/// The terminal the keys come from: standard input when it is a terminal, else
/// `/dev/tty`.
struct Tty {
    tty: Option<OwnedFd>,
}

/// What one wait found.
enum Ready {
    /// Bytes wait on the terminal.
    Bytes,
    /// The window changed size.
    Resized,
    /// Nothing before the timeout.
    Idle,
    /// The terminal is gone: the cause.
    Closed(String),
}

impl Tty {
    fn open() -> io::Result<Tty> {
        let tty = if io::stdin().is_terminal() {
            None
        } else {
            let f = std::fs::OpenOptions::new().read(true).open("/dev/tty")?;
            Some(OwnedFd::from(f))
        };
        Ok(Tty { tty })
    }

    fn fd(&self) -> BorrowedFd<'_> {
        match &self.tty {
            Some(fd) => fd.as_fd(),
            None => rustix::stdio::stdin(),
        }
    }

    /// Wait up to `timeout` for bytes or a resize (`winch` readable). Readable with
    /// nothing to read is end of file: a hung-up terminal reads that way for ever.
    fn wait(&self, winch: &UnixStream, timeout: std::time::Duration) -> Ready {
        let fd = self.fd();
        let mut fds = [
            PollFd::new(&fd, PollFlags::IN),
            PollFd::new(winch, PollFlags::IN),
        ];
        let timeout = Timespec::try_from(timeout).unwrap_or(Timespec {
            tv_sec: 0,
            tv_nsec: 0,
        });
        match rustix::event::poll(&mut fds, Some(&timeout)) {
            Ok(0) => return Ready::Idle,
            Ok(_) => {}
            Err(rustix::io::Errno::INTR) => return Ready::Idle,
            Err(e) => return Ready::Closed(format!("poll: {e}")),
        }
        if fds[1].revents().contains(PollFlags::IN) {
            return Ready::Resized;
        }
        let got = fds[0].revents();
        if got.intersects(PollFlags::HUP | PollFlags::ERR | PollFlags::NVAL) {
            return Ready::Closed("hung up".into());
        }
        if !got.contains(PollFlags::IN) {
            return Ready::Idle;
        }
        match rustix::io::ioctl_fionread(fd) {
            Ok(0) => Ready::Closed("end of file".into()),
            Ok(_) => Ready::Bytes,
            Err(e) => Ready::Closed(format!("{e}")),
        }
    }
}

/// Read the terminal on a thread of its own until `stop`. `probe`: the probe just
/// written (or what is known without one). A terminal that hung up is reported once
/// and the thread ends.
pub(crate) fn spawn(
    stop: Arc<AtomicBool>,
    probe: Probe,
) -> io::Result<(Receiver<Input>, JoinHandle<()>)> {
    let tty = Tty::open()?;
    let (winch, ring) = UnixStream::pair()?;
    winch.set_nonblocking(true)?;
    ring.set_nonblocking(true)?;
    let sig = signal_hook::low_level::pipe::register(signal_hook::consts::SIGWINCH, ring)?;
    let (tx, rx) = crossbeam_channel::bounded(256);
    let h = std::thread::Builder::new()
        .name("console/input".into())
        .spawn(move || {
            if let Some(why) = read(&tty, &winch, probe, &tx, &stop) {
                let _ = tx.send(Input::Closed(why));
            }
            signal_hook::low_level::unregister(sig);
        })?;
    Ok((rx, h))
}

/// The reading loop: `Some(cause)` when the terminal is gone, `None` when told to stop
/// (or nobody listens any more).
fn read(
    tty: &Tty,
    winch: &UnixStream,
    mut probe: Probe,
    tx: &Sender<Input>,
    stop: &AtomicBool,
) -> Option<String> {
    let mut decoder = Decoder::default();
    let mut tokens = Vec::new();
    let mut buf = [0u8; 1024];
    // Since when bytes wait in the decoder for the rest of their sequence.
    let mut waiting: Option<Instant> = None;
    if let Some(k) = probe.verdict() {
        tx.send(Input::Keyboard(k)).ok()?;
    }
    while !stop.load(Relaxed) {
        let now = Instant::now();
        let wake = [
            Some(now + TICK),
            waiting.map(|t| t + decode::ESC_WAIT),
            probe.deadline(),
        ]
        .into_iter()
        .flatten()
        .min()
        .unwrap_or(now + TICK);
        let ready = tty.wait(winch, wake.saturating_duration_since(now));
        let at = Instant::now();
        match ready {
            Ready::Closed(why) => return Some(why),
            Ready::Resized => {
                let mut drain = [0u8; 64];
                while rustix::io::read(winch, &mut drain).is_ok_and(|n| n > 0) {}
                if let Ok((cols, rows)) = crossterm::terminal::size() {
                    tx.send(Input::Resize(cols, rows)).ok()?;
                }
            }
            Ready::Bytes => match rustix::io::read(tty.fd(), &mut buf) {
                Ok(0) => return Some("end of file".into()),
                Ok(n) => {
                    decoder.feed(&buf[..n], &mut tokens);
                    waiting = decoder.waiting().then(|| waiting.unwrap_or(at));
                }
                Err(rustix::io::Errno::INTR | rustix::io::Errno::AGAIN) => {}
                Err(e) => return Some(e.to_string()),
            },
            Ready::Idle => {}
        }
        if waiting.is_some_and(|t| at >= t + decode::ESC_WAIT) {
            decoder.flush(&mut tokens);
            waiting = None;
        }
        for t in tokens.drain(..) {
            let input = match t {
                Token::Key(k) => Some(Input::Key(k, at)),
                Token::Reply(Reply::Cursor) => Some(Input::Answer(at)),
                Token::Reply(Reply::Flags(_)) => {
                    probe.flags();
                    None
                }
                Token::Reply(Reply::Attributes) => probe.attributes().map(Input::Keyboard),
            };
            if let Some(i) = input {
                tx.send(i).ok()?;
            }
        }
        if let Some(k) = probe.tick(at) {
            tx.send(Input::Keyboard(k)).ok()?;
        }
    }
    None
}
