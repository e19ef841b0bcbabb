//! Every way the process can be asked to end, funnelled into one channel: SIGINT,
//! SIGTERM, SIGHUP (an SSH session dropping), a panic in any thread, or the operator's
//! quit. Whoever owns the run waits on it and then always takes the same road out:
//! safe state first, then terminal, then logs.

use crossbeam_channel::{Receiver, Sender};
use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
use std::sync::OnceLock;

/// Why the run ends.
#[derive(Clone, Debug, PartialEq)]
pub enum Exit {
    /// The operator quit (`q`).
    Quit,
    /// A signal arrived.
    Signal(i32),
    /// A thread panicked; the message says which and why.
    Panic(String),
    /// A device failed for good (a recovery procedure gave up).
    Fatal(String),
}

impl Exit {
    /// The process status for this way out.
    pub fn code(&self) -> i32 {
        match self {
            Exit::Quit | Exit::Signal(SIGINT) | Exit::Signal(SIGTERM) => 0,
            Exit::Signal(s) => 128 + s,
            Exit::Panic(_) => 101,
            Exit::Fatal(_) => 4,
        }
    }

    pub fn describe(&self) -> String {
        match self {
            Exit::Quit => "operator quit".into(),
            Exit::Signal(SIGINT) => "SIGINT".into(),
            Exit::Signal(SIGTERM) => "SIGTERM".into(),
            Exit::Signal(SIGHUP) => "SIGHUP (terminal hung up)".into(),
            Exit::Signal(s) => format!("signal {s}"),
            Exit::Panic(m) => format!("panic: {m}"),
            Exit::Fatal(m) => format!("fatal device error: {m}"),
        }
    }
}

static EXITS: OnceLock<Sender<Exit>> = OnceLock::new();

/// Ask the run to end (from any thread).
pub fn request(why: Exit) {
    if let Some(tx) = EXITS.get() {
        let _ = tx.send(why);
    }
}

/// Install the signal thread and the panic hook; returns where exits arrive.
/// The previous panic hook (e.g. the terminal restorer) still runs after ours.
pub fn install() -> std::io::Result<Receiver<Exit>> {
    let (tx, rx) = crossbeam_channel::unbounded();
    if EXITS.set(tx).is_err() {
        return Err(std::io::Error::other("exit handling installed twice"));
    }
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP])?;
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            for s in signals.forever() {
                request(Exit::Signal(s));
            }
        })?;
    let previous = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let thread = std::thread::current();
        let name = thread.name().unwrap_or("unnamed").to_string();
        let msg = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_default();
        let at = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        tracing::error!(thread = %name, "panic: {msg}{at}");
        request(Exit::Panic(format!("thread {name}: {msg}{at}")));
        previous(info);
    }));
    Ok(rx)
}
