//! The console's terminal, which can die under it.
//!
//! An operator's SSH session can drop at any moment: sshd closes the master side of
//! the pseudo-terminal. From then on every write to the terminal fails (EIO), every
//! read returns end of file, and the kernel usually, not always, sends SIGHUP. The
//! console must then take the same road out as for SIGHUP — safe state, terminal,
//! logs — and nothing on that road may panic: a panic on the way out of a panic
//! aborts the process before the vehicle is stopped. Three things in the crates below
//! stood in the way, and this module owns each of them:
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
//! - crossterm 0.29's event reader spins forever once its terminal reads end of file
//!   (crossterm issue 793), even inside `poll` with a timeout. [`Keyboard::wait`]
//!   watches the terminal itself and lets crossterm read only bytes that are there;
//!   a hang-up is reported, never read.
//! - crossterm's default event source (mio, edge-triggered) returns a resize and drops
//!   the terminal's readiness reported with it: a key pressed after a window resize
//!   stayed unread until the next key — a STOP pressed once did nothing. adrive uses
//!   its `use-dev-tty` source, which polls level-triggered, and drains it with
//!   [`DRAIN`].
//! - tmux pushes the top lines of a grown alternate screen into the scrollback as it
//!   is left; [`restore`] leaves it blank.

use crossterm::execute;
use crossterm::terminal::{
    disable_raw_mode, enable_raw_mode, Clear, ClearType, EnterAlternateScreen, LeaveAlternateScreen,
};
use ratatui::backend::CrosstermBackend;
use rustix::event::{PollFd, PollFlags, Timespec};
use std::io::{self, IsTerminal, Write};
use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::sync::atomic::{AtomicBool, Ordering::SeqCst};
use std::sync::{Arc, Once};
use std::time::Duration;

/// How long the input thread lets crossterm look for more events once the keys
/// waiting are parsed (its `use-dev-tty` source reads nothing with a zero timeout).
pub(crate) const DRAIN: Duration = Duration::from_millis(1);

/// The ratatui terminal the console draws on.
pub(crate) type Term = ratatui::Terminal<CrosstermBackend<Output>>;

/// Raw mode and the alternate screen are on (set by [`enter`], cleared by [`restore`]).
static ENTERED: AtomicBool = AtomicBool::new(false);
static PANIC_HOOK: Once = Once::new();

/// The console's standard output. The first failed write or flush marks the terminal
/// dead (and is returned); from then on everything written is dropped.
pub struct Output {
    out: io::Stdout,
    dead: Arc<AtomicBool>,
}

impl Output {
    fn check<T>(&self, r: io::Result<T>) -> io::Result<T> {
        if r.is_err() {
            self.dead.store(true, SeqCst);
        }
        r
    }
}

impl Write for Output {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        if self.dead.load(SeqCst) {
            return Ok(buf.len());
        }
        let r = self.out.write(buf);
        self.check(r)
    }

    fn flush(&mut self) -> io::Result<()> {
        if self.dead.load(SeqCst) {
            return Ok(());
        }
        let r = self.out.flush();
        self.check(r)
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
    dead: Arc<AtomicBool>,
}

impl Screen {
    /// A write to the terminal failed: it is gone.
    pub(crate) fn is_dead(&self) -> bool {
        self.dead.load(SeqCst)
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
    let setup = || {
        enable_raw_mode()?;
        execute!(io::stdout(), EnterAlternateScreen)?;
        let out = Output {
            out: io::stdout(),
            dead: dead.clone(),
        };
        ratatui::Terminal::new(CrosstermBackend::new(out))
    };
    match setup() {
        Ok(terminal) => Ok(Screen { terminal, dead }),
        Err(e) => {
            restore();
            Err(e)
        }
    }
}

/// Leave raw mode and the alternate screen if the console had them. Each step is
/// tried whatever the other did; a failure (a dead terminal) is logged, never
/// printed, never a panic. Safe to call twice and from a panic hook.
///
/// The alternate screen is cleared before it is left: tmux, leaving an alternate
/// screen that grew with its window, shrinks it back first and pushes its top lines
/// into the scrollback unless they are blank — quitting after a resize once left the
/// console's top lines there.
pub fn restore() {
    if !ENTERED.swap(false, SeqCst) {
        return;
    }
    let raw = disable_raw_mode();
    let screen = execute!(io::stdout(), Clear(ClearType::All), LeaveAlternateScreen);
    if let Some(e) = raw.err().or(screen.err()) {
        tracing::debug!("terminal not restored: {e}");
    }
}

/// What [`Keyboard::wait`] found.
#[derive(Debug, PartialEq)]
pub enum Input {
    /// Bytes are waiting: crossterm may read them.
    Pending,
    /// Nothing yet.
    Idle,
    /// The terminal is gone (hung up, end of file, an error): the cause.
    Closed(String),
}

/// The terminal the keys come from: the one crossterm reads, standard input when it
/// is a terminal, else `/dev/tty`.
pub(crate) struct Keyboard {
    tty: Option<OwnedFd>,
}

impl Keyboard {
    pub fn open() -> io::Result<Keyboard> {
        let tty = if io::stdin().is_terminal() {
            None
        } else {
            let f = std::fs::OpenOptions::new().read(true).open("/dev/tty")?;
            Some(OwnedFd::from(f))
        };
        Ok(Keyboard { tty })
    }

    fn fd(&self) -> BorrowedFd<'_> {
        match &self.tty {
            Some(fd) => fd.as_fd(),
            None => rustix::stdio::stdin(),
        }
    }

    /// Wait up to `timeout` for keys. Readable with nothing to read is end of file:
    /// a hung-up terminal reads that way for ever.
    pub fn wait(&self, timeout: Duration) -> Input {
        let fd = self.fd();
        let mut fds = [PollFd::new(&fd, PollFlags::IN)];
        let timeout = Timespec::try_from(timeout).unwrap_or(Timespec {
            tv_sec: 0,
            tv_nsec: 0,
        });
        match rustix::event::poll(&mut fds, Some(&timeout)) {
            Ok(0) => return Input::Idle,
            Ok(_) => {}
            Err(rustix::io::Errno::INTR) => return Input::Idle,
            Err(e) => return Input::Closed(format!("poll: {e}")),
        }
        let got = fds[0].revents();
        if got.intersects(PollFlags::HUP | PollFlags::ERR | PollFlags::NVAL) {
            return Input::Closed("hung up".into());
        }
        match rustix::io::ioctl_fionread(fd) {
            Ok(0) => Input::Closed("end of file".into()),
            Ok(_) => Input::Pending,
            Err(e) => Input::Closed(format!("{e}")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An output whose first write fails: the error is returned once, then the
    /// terminal is dead and writes are dropped.
    #[test]
    fn a_failed_write_marks_the_terminal_dead_and_later_writes_are_dropped() {
        let dead = Arc::new(AtomicBool::new(false));
        let o = Output {
            out: io::stdout(),
            dead: dead.clone(),
        };
        assert!(o.check(Err::<(), _>(io::Error::other("EIO"))).is_err());
        assert!(dead.load(SeqCst));
        let mut o = o;
        assert_eq!(o.write(b"lost").unwrap(), 4);
        assert!(o.flush().is_ok());
    }
}
