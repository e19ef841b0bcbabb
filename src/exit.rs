//! Every way the process can be asked to end, funnelled into one channel: SIGINT,
//! SIGTERM, SIGHUP or the console's terminal dying (an SSH session dropping), a panic
//! in any thread, or the operator's quit. Whoever owns the run waits on it and then always takes the same road out:
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
    /// The console's terminal went away without a word (it cannot be written, its
    /// input hung up): a hang-up like SIGHUP, which may come with it or not at all.
    HangUp(String),
    /// A thread panicked; the message says which and why.
    Panic(String),
    /// A device failed for good (a recovery procedure gave up).
    Fatal(String),
    /// An attached console's connection to adrive ended: adrive stopped, went away, or
    /// dropped it (in words, as far as the console knows).
    Lost(String),
}

impl Exit {
    /// The process status for this way out.
    pub fn code(&self) -> i32 {
        match self {
            Exit::Quit | Exit::Signal(SIGINT) | Exit::Signal(SIGTERM) => 0,
            Exit::Signal(s) => 128 + s,
            Exit::HangUp(_) => 128 + SIGHUP,
            Exit::Panic(_) => 101,
            Exit::Fatal(_) => 4,
            Exit::Lost(_) => 1,
        }
    }

    pub fn describe(&self) -> String {
        match self {
            Exit::Quit => "operator quit".into(),
            Exit::Signal(SIGINT) => "SIGINT".into(),
            Exit::Signal(SIGTERM) => "SIGTERM".into(),
            Exit::Signal(SIGHUP) => "SIGHUP (terminal hung up)".into(),
            Exit::Signal(s) => format!("signal {s}"),
            Exit::HangUp(why) => format!("terminal hung up ({why})"),
            Exit::Panic(m) => format!("panic: {m}"),
            Exit::Fatal(m) => format!("fatal device error: {m}"),
            Exit::Lost(m) => m.clone(),
        }
    }
}

/// The status of a run whose safe state was not acknowledged.
pub(crate) const UNSAFE: i32 = 3;

/// The process status once the run has stopped: `why`'s own, unless the stop went
/// wrong. A safe state that was not acknowledged (`safe` false) is the worst news
/// there is — the vehicle may still be moving — so it says [`UNSAFE`] whatever ended
/// the run, a recovery that gave up included. Threads that would not stop
/// (`all_stopped` false) raise a clean status to [`UNSAFE`] too.
pub fn status(why: &Exit, safe: bool, all_stopped: bool) -> i32 {
    match (safe, all_stopped) {
        (false, _) => UNSAFE,
        (true, false) => why.code().max(UNSAFE),
        (true, true) => why.code(),
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A recovery gave up (4) and then the safe state was not acknowledged: the worse
    /// news, 3, is what a service manager must see (it once said 4).
    #[test]
    fn a_safe_state_not_acknowledged_outranks_a_recovery_that_gave_up() {
        let fatal = Exit::Fatal("recovery reconnect brake gave up".into());
        assert_eq!(status(&fatal, true, true), 4);
        assert_eq!(status(&fatal, false, true), UNSAFE);
        for why in [
            Exit::Quit,
            Exit::Signal(SIGHUP),
            Exit::HangUp("input: hung up".into()),
            Exit::Panic("p".into()),
        ] {
            assert_eq!(status(&why, false, true), UNSAFE, "{why:?}");
            assert_eq!(status(&why, false, false), UNSAFE, "{why:?}");
        }
    }

    #[test]
    fn a_clean_stop_keeps_the_status_of_its_reason() {
        assert_eq!(status(&Exit::Quit, true, true), 0);
        assert_eq!(status(&Exit::Signal(SIGINT), true, true), 0);
        assert_eq!(status(&Exit::Signal(SIGHUP), true, true), 129);
        assert_eq!(status(&Exit::HangUp("x".into()), true, true), 129);
        assert_eq!(status(&Exit::Panic("p".into()), true, true), 101);
        // A thread that would not stop: never a clean 0.
        assert_eq!(status(&Exit::Quit, true, false), UNSAFE);
        assert_eq!(status(&Exit::Signal(SIGHUP), true, false), 129);
    }
}
