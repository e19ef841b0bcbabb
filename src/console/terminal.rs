//! The console's terminal, which can die under it, or stop reading.
//!
//! An operator's SSH session can drop at any moment: sshd closes the master side of
//! the pseudo-terminal. From then on every write to the terminal fails (EIO), every
//! read returns end of file, and the kernel usually, not always, sends SIGHUP. The
//! console must then take the same road out as for SIGHUP — safe state, terminal,
//! logs — and nothing on that road may panic: a panic on the way out of a panic
//! aborts the process before the vehicle is stopped. Things in the crates below stood
//! in the way, and this module owns each of them:
//!
//! - `ratatui::restore` prints its failure with `eprintln!`, which panics when stderr
//!   is the dead terminal, and the panic hook of `ratatui::init` calls it again: the
//!   process aborted (SIGABRT). [`enter`] and [`restore`] set the terminal up and put
//!   it back themselves, from the console's exit, from [`Screen`]'s drop and from the
//!   panic hook, and never print: a failure goes to the log.
//! - ratatui's `Terminal` shows the cursor again when dropped and prints that
//!   failure with `eprintln!` too. The terminal writes through [`Output`]: once one
//!   write failed, the terminal is dead for good, later writes are dropped, and that
//!   cleanup has nothing left to fail on.
//! - tmux pushes the top lines of a grown alternate screen into the scrollback as it
//!   is left; [`restore`] leaves it blank.
//!
//! A session can also freeze without closing: a laptop asleep, a Wi-Fi link gone
//! without a reset, ssh stopped. The terminal then stops reading; the pseudo-terminal's
//! buffer fills, and a blocking write waits for ever — the console's loop with it,
//! deaf to SIGTERM, and the panic hook's restore too. So the console never blocks on
//! its terminal: [`Output`] writes through a file description of its own, opened
//! non-blocking (the flags of the one it shares with the shell would outlive adrive),
//! keeps what the terminal did not take, and the loop draws the next frame only once
//! the last one is written ([`Screen::ready`]); [`restore`] gives its bytes
//! [`RESTORE_WITHIN`]. Such a terminal also stops answering the console's round trips
//! (`console/input/link.rs`), which is what stops the vehicle.
//!
//! The kitty keyboard protocol's flags, once pushed ([`Screen::push_keyboard`], where
//! the terminal reports releases), are popped by [`restore`] on every way out, before
//! the alternate screen is left (each screen keeps its own stack of flags): the
//! operator's shell must never be left receiving key events it does not understand.
//!
//! Reading the terminal is `console/input/`'s.

use crossterm::terminal::{
    disable_raw_mode, enable_raw_mode, Clear, ClearType, EnterAlternateScreen, LeaveAlternateScreen,
};
use crossterm::{queue, Command};
use ratatui::backend::CrosstermBackend;
use rustix::event::{PollFd, PollFlags, Timespec};
use rustix::fs::{Mode, OFlags};
use std::io::{self, IsTerminal, Write};
use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering::SeqCst};
use std::sync::{Arc, Once, OnceLock};
use std::time::{Duration, Instant};

/// The ratatui terminal the console draws on.
pub(crate) type Term = ratatui::Terminal<CrosstermBackend<Output>>;

/// How long [`restore`] waits for a terminal that does not read.
pub(crate) const RESTORE_WITHIN: Duration = Duration::from_millis(300);
/// The kitty keyboard protocol's flags the console pushes: disambiguate (1) and report
/// event types (2) — presses, repeats and releases.
pub(crate) const KEYBOARD_FLAGS: u8 = 3;

/// Raw mode and the alternate screen are on (set by [`enter`], cleared by [`restore`]).
static ENTERED: AtomicBool = AtomicBool::new(false);
/// The kitty keyboard protocol's flags are pushed ([`Screen::push_keyboard`]).
static PUSHED: AtomicBool = AtomicBool::new(false);
/// Bytes queued for the terminal were not all written: it may be inside a sequence.
static CUT: AtomicBool = AtomicBool::new(false);
static PANIC_HOOK: Once = Once::new();
/// The terminal, open for writing without blocking (see the module's doc).
static OUT: OnceLock<OwnedFd> = OnceLock::new();

/// The terminal's output: a file description of its own, non-blocking, when one could
/// be opened; else standard output's, blocking.
fn out_fd() -> io::Result<BorrowedFd<'static>> {
    if let Some(fd) = OUT.get() {
        return Ok(fd.as_fd());
    }
    let flags = OFlags::WRONLY | OFlags::NONBLOCK | OFlags::NOCTTY | OFlags::CLOEXEC;
    let fd = rustix::fs::open("/proc/self/fd/1", flags, Mode::empty())
        .or_else(|_| rustix::fs::open("/dev/tty", flags, Mode::empty()))
        .or_else(|e| {
            tracing::warn!("the terminal cannot be written without blocking ({e})");
            rustix::io::dup(rustix::stdio::stdout())
        })?;
    Ok(OUT.get_or_init(|| fd).as_fd())
}

/// Write what the terminal takes now: how much (0: nothing, it is full).
fn write_now(bytes: &[u8]) -> io::Result<usize> {
    loop {
        match rustix::io::write(out_fd()?, bytes) {
            Ok(n) => return Ok(n),
            Err(rustix::io::Errno::AGAIN) => return Ok(0),
            Err(rustix::io::Errno::INTR) => continue,
            Err(e) => return Err(e.into()),
        }
    }
}

/// Write all of `bytes` by `deadline`, waiting for the terminal to take them; what it
/// has not taken by then is dropped (`Err(TimedOut)`).
fn write_by(mut bytes: &[u8], deadline: Instant) -> io::Result<()> {
    while !bytes.is_empty() {
        let n = write_now(bytes)?;
        bytes = &bytes[n..];
        if n > 0 {
            continue;
        }
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(io::Error::new(
                io::ErrorKind::TimedOut,
                "the terminal stopped reading",
            ));
        }
        let fd = out_fd()?;
        let mut fds = [PollFd::new(&fd, PollFlags::OUT)];
        let t = Timespec::try_from(left).unwrap_or(Timespec {
            tv_sec: 0,
            tv_nsec: 0,
        });
        let _ = rustix::event::poll(&mut fds, Some(&t));
    }
    Ok(())
}

/// The console's output to its terminal. Written bytes wait in the output until
/// [`Output::pump`] (or a flush) hands the terminal what it takes; what it does not
/// take keeps waiting, and nothing blocks. The first failed write marks the terminal
/// dead (and is returned); from then on everything written is dropped.
pub(crate) struct Output {
    pending: Vec<u8>,
    /// How many bytes wait, for the [`Screen`].
    waiting: Arc<AtomicUsize>,
    dead: Arc<AtomicBool>,
}

impl Output {
    /// Hand the terminal what it takes now.
    pub(crate) fn pump(&mut self) -> io::Result<()> {
        let r = self.write_pending();
        self.waiting.store(self.pending.len(), SeqCst);
        r
    }

    fn write_pending(&mut self) -> io::Result<()> {
        if self.dead.load(SeqCst) {
            self.pending.clear();
            return Ok(());
        }
        while !self.pending.is_empty() {
            match write_now(&self.pending) {
                Ok(0) => break,
                Ok(n) => {
                    self.pending.drain(..n);
                }
                Err(e) => {
                    self.dead.store(true, SeqCst);
                    self.pending.clear();
                    CUT.store(false, SeqCst);
                    return Err(e);
                }
            }
        }
        CUT.store(!self.pending.is_empty(), SeqCst);
        Ok(())
    }
}

impl Write for Output {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        if !self.dead.load(SeqCst) {
            self.pending.extend_from_slice(buf);
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        self.pump()
    }
}

/// How to go on without a terminal, for each program that opens the console.
pub(crate) const RUN_WITHOUT: &str =
    "over SSH give it one with `ssh -t HOST adrive`, or run without a console: \
     `adrive --headless`";
pub(crate) const ATTACH_WITHOUT: &str =
    "over SSH give it one with `ssh -t HOST adrive attach`; for a one-shot look without \
     a terminal, `adrive ctl status` (`adrive ctl stop` stops)";
pub(crate) const REPLAY_WITHOUT: &str =
    "over SSH give it one with `ssh -t HOST adrive replay FILE`, or play it without a \
     console: `adrive replay FILE --headless --broadcast ADDR`";

/// The console draws on standard output and reads keys from standard input: both must
/// be a terminal. Checked before anything starts, so that `adrive < /dev/null` or
/// `ssh host adrive` (no `-t`: no terminal) is refused with the way forward for that
/// program (`without`: [`RUN_WITHOUT`], [`ATTACH_WITHOUT`], [`REPLAY_WITHOUT`])
/// instead of starting the engine and failing inside crossterm.
pub(crate) fn check_standard_streams(without: &str) -> Result<(), String> {
    let which = match (io::stdin().is_terminal(), io::stdout().is_terminal()) {
        (true, true) => return Ok(()),
        (false, false) => "standard input and output are not one",
        (false, true) => "standard input is not one",
        (true, false) => "standard output is not one",
    };
    Err(format!(
        "the console needs a terminal, and {which}; {without}"
    ))
}

/// The terminal in the console's hands: raw mode and the alternate screen until it
/// is dropped, on every way out, unwinding included.
pub(crate) struct Screen {
    pub terminal: Term,
    /// Bytes its [`Output`] holds that the terminal has not taken yet.
    waiting: Arc<AtomicUsize>,
    dead: Arc<AtomicBool>,
}

impl Screen {
    /// A write to the terminal failed: it is gone.
    pub(crate) fn is_dead(&self) -> bool {
        self.dead.load(SeqCst)
    }

    /// Hand the terminal what it takes now: `Ok(true)` when everything written so far
    /// is written (the next frame may be drawn), `Ok(false)` while the terminal has
    /// not taken it all (it reads slowly, or stopped reading), `Err` when it is gone.
    pub(crate) fn ready(&mut self) -> io::Result<bool> {
        self.terminal.backend_mut().flush()?;
        Ok(self.waiting.load(SeqCst) == 0)
    }

    /// Write `bytes` (a request to the terminal) after what was drawn.
    pub(crate) fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        let out = self.terminal.backend_mut();
        out.write_all(bytes)?;
        out.flush()
    }

    /// Ask the terminal for key presses, repeats and releases: the kitty keyboard
    /// protocol's flags, pushed (and popped by [`restore`]). Once.
    pub(crate) fn push_keyboard(&mut self) -> io::Result<()> {
        if PUSHED.swap(true, SeqCst) {
            return Ok(());
        }
        self.send(format!("\x1b[>{KEYBOARD_FLAGS}u").as_bytes())
    }
}

impl Drop for Screen {
    fn drop(&mut self) {
        if !self.is_dead() {
            let _ = self.terminal.show_cursor();
        }
        restore();
        // Whatever is left (the terminal's own drop) has nowhere to go.
        self.dead.store(true, SeqCst);
    }
}

/// Take the terminal over: raw mode, the alternate screen, and a panic hook (once)
/// that puts it back before the panic is reported, so the message lands on the normal
/// screen.
pub(crate) fn enter() -> io::Result<Screen> {
    PANIC_HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            restore();
            previous(info);
        }));
    });
    ENTERED.store(true, SeqCst);
    let dead = Arc::new(AtomicBool::new(false));
    let waiting = Arc::new(AtomicUsize::new(0));
    let setup = || {
        out_fd()?;
        enable_raw_mode()?;
        let mut out = Output {
            pending: Vec::new(),
            waiting: waiting.clone(),
            dead: dead.clone(),
        };
        queue!(out, EnterAlternateScreen)?;
        out.pump()?;
        ratatui::Terminal::new(CrosstermBackend::new(out))
    };
    match setup() {
        Ok(terminal) => Ok(Screen {
            terminal,
            waiting,
            dead,
        }),
        Err(e) => {
            restore();
            Err(e)
        }
    }
}

/// Leave raw mode and the alternate screen if the console had them, popping the kitty
/// keyboard protocol's flags first if they were pushed. Each step is tried whatever
/// the other did; a failure (a dead terminal, one that took nothing within
/// [`RESTORE_WITHIN`]) is logged, never printed, never a panic. Safe to call twice and
/// from a panic hook.
///
/// The alternate screen is cleared before it is left: tmux, leaving an alternate
/// screen that grew with its window, shrinks it back first and pushes its top lines
/// into the scrollback unless they are blank — quitting after a resize once left the
/// console's top lines there.
pub(crate) fn restore() {
    if !ENTERED.swap(false, SeqCst) {
        return;
    }
    let raw = disable_raw_mode();
    let mut bytes = Vec::new();
    // A frame cut short may have left the terminal inside a sequence: CAN ends it.
    if CUT.swap(false, SeqCst) {
        bytes.push(0x18);
    }
    if PUSHED.swap(false, SeqCst) {
        bytes.extend_from_slice(b"\x1b[<u");
    }
    let mut ansi = String::new();
    let _ = Clear(ClearType::All).write_ansi(&mut ansi);
    let _ = LeaveAlternateScreen.write_ansi(&mut ansi);
    bytes.extend_from_slice(ansi.as_bytes());
    let screen = write_by(&bytes, Instant::now() + RESTORE_WITHIN);
    if let Some(e) = raw.err().or(screen.err()) {
        tracing::debug!("terminal not restored: {e}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An output whose terminal is gone drops what is written, and a flush has
    /// nothing left to fail on.
    #[test]
    fn a_dead_terminal_drops_what_is_written() {
        let mut o = Output {
            pending: Vec::new(),
            waiting: Arc::default(),
            dead: Arc::new(AtomicBool::new(true)),
        };
        assert_eq!(o.write(b"lost").unwrap(), 4);
        assert!(o.flush().is_ok());
        assert_eq!(o.waiting.load(SeqCst), 0);
    }
}
