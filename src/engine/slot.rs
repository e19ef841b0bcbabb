//! The latest-wins command slot between the command intake (network, console) and an
//! actuator's command thread: the paper's cached command plus condition variable.
//! It holds at most one pending command — never a queue. A command that arrives while
//! another is still pending replaces it, and the replaced one is counted as superseded.

use crate::value::Command;
use parking_lot::{Condvar, Mutex};
use std::time::{Duration, Instant};

/// A command waiting for the wire, stamped where it was born.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pending {
    pub command: Command,
    /// When intake accepted it: the start of the receipt → first-byte delay.
    pub received: Instant,
}

/// What woke the command thread.
#[derive(Debug, PartialEq)]
pub enum Wake {
    /// A new command.
    Command(Pending),
    /// `command_timeout` passed with no new command: resend the last one.
    Timeout,
    /// Someone asked the thread to run now (the console's wake key): resend the last.
    Nudge,
    /// Shut down.
    Stop,
}

#[derive(Default)]
struct State {
    pending: Option<Pending>,
    /// The last command taken for the wire: in flight from the moment the command
    /// thread takes it, then what the device was last given. Never forgotten.
    last: Option<Command>,
    /// What to send again after `command_timeout`; engage clears it.
    resend: Option<Command>,
    /// The last command the device acknowledged.
    executed: Option<Command>,
    /// The last command whose transaction finished (its bytes are on the wire,
    /// acknowledged or not).
    sent: Option<Command>,
    nudged: bool,
    stopped: bool,
}

#[derive(Default)]
pub struct CommandSlot {
    state: Mutex<State>,
    cv: Condvar,
}

impl CommandSlot {
    /// Store a command and wake the command thread. Returns true when it replaced a
    /// command that had not reached the wire yet.
    pub fn submit(&self, command: Command, received: Instant) -> bool {
        let mut s = self.state.lock();
        let superseded = s.pending.is_some();
        s.pending = Some(Pending { command, received });
        drop(s);
        self.cv.notify_all();
        superseded
    }

    /// Wake the command thread without a new command (it resends the last one).
    pub fn nudge(&self) {
        self.state.lock().nudged = true;
        self.cv.notify_all();
    }

    pub fn stop(&self) {
        self.state.lock().stopped = true;
        self.cv.notify_all();
    }

    /// Sleep until something happens, at most `timeout`.
    pub fn wait(&self, timeout: Duration) -> Wake {
        let deadline = Instant::now() + timeout;
        let mut s = self.state.lock();
        loop {
            if s.stopped {
                return Wake::Stop;
            }
            if let Some(p) = s.pending.take() {
                s.nudged = false;
                // Taken is in flight: readers never see the slot empty meanwhile.
                s.last = Some(p.command);
                s.resend = Some(p.command);
                return Wake::Command(p);
            }
            if std::mem::take(&mut s.nudged) {
                return Wake::Nudge;
            }
            if self.cv.wait_until(&mut s, deadline).timed_out() {
                if s.stopped {
                    return Wake::Stop;
                }
                return match s.pending.take() {
                    Some(p) => {
                        s.last = Some(p.command);
                        s.resend = Some(p.command);
                        Wake::Command(p)
                    }
                    None => Wake::Timeout,
                };
            }
        }
    }

    /// Take a command that arrived after the thread woke (while it waited for the port),
    /// so the newest one goes out instead.
    pub fn take_newer(&self) -> Option<Pending> {
        let mut s = self.state.lock();
        let p = s.pending.take();
        if let Some(p) = p {
            s.last = Some(p.command);
            s.resend = Some(p.command);
        }
        p
    }

    /// Sleep until `until` unless stopped; a new command may arrive meanwhile and stays
    /// pending. Returns false when stopped.
    pub fn sleep_until(&self, until: Instant) -> bool {
        let mut s = self.state.lock();
        while !s.stopped && Instant::now() < until {
            self.cv.wait_until(&mut s, until);
        }
        !s.stopped
    }

    /// Record what goes to the wire.
    pub fn set_last(&self, command: Command) {
        let mut s = self.state.lock();
        s.last = Some(command);
        s.resend = Some(command);
    }

    /// What the command thread sends again when nothing new arrives.
    pub fn resend(&self) -> Option<Command> {
        self.state.lock().resend
    }

    /// Record what the device acknowledged, and wake anyone waiting for it.
    pub fn set_executed(&self, command: Command) {
        self.state.lock().executed = Some(command);
        self.cv.notify_all();
    }

    /// Record that a transaction finished, and wake anyone waiting for it.
    pub fn set_sent(&self, command: Command) {
        self.state.lock().sent = Some(command);
        self.cv.notify_all();
    }

    /// Pending, last handed to the wire, last finished on the wire.
    pub fn wire(&self) -> (Option<Command>, Option<Command>, Option<Command>) {
        let s = self.state.lock();
        (s.pending.map(|p| p.command), s.last, s.sent)
    }

    /// Wait until `done(pending, last, sent)` holds or the deadline passes.
    pub fn wait_wire(
        &self,
        done: impl Fn(Option<Command>, Option<Command>, Option<Command>) -> bool,
        deadline: Instant,
    ) -> bool {
        let mut s = self.state.lock();
        loop {
            if done(s.pending.map(|p| p.command), s.last, s.sent) {
                return true;
            }
            if s.stopped || self.cv.wait_until(&mut s, deadline).timed_out() {
                return done(s.pending.map(|p| p.command), s.last, s.sent);
            }
        }
    }

    /// Undo `set_last` for a command that did not go out after all.
    pub fn restore_last(&self, last: Option<Command>) {
        let mut s = self.state.lock();
        s.last = last;
        s.resend = last;
        drop(s);
        self.cv.notify_all();
    }

    pub fn sent(&self) -> Option<Command> {
        self.state.lock().sent
    }

    pub fn executed(&self) -> Option<Command> {
        self.state.lock().executed
    }

    /// Every value this actuator has or is about to have: pending, last sent,
    /// acknowledged. Interlocks judge by the extremes of these.
    pub fn in_flight(&self) -> [Option<Command>; 3] {
        let s = self.state.lock();
        [s.pending.map(|p| p.command), s.last, s.executed]
    }

    pub fn has_pending(&self) -> bool {
        self.state.lock().pending.is_some()
    }

    /// Wait until the device acknowledged a command matching `done`, or the deadline.
    pub fn wait_executed(&self, done: impl Fn(Command) -> bool, deadline: Instant) -> bool {
        let mut s = self.state.lock();
        loop {
            if s.executed.is_some_and(&done) {
                return true;
            }
            if self.cv.wait_until(&mut s, deadline).timed_out() {
                return s.executed.is_some_and(&done);
            }
        }
    }

    pub fn last(&self) -> Option<Command> {
        self.state.lock().last
    }

    /// The command the device will have next: the pending one, else the last sent.
    pub fn latest(&self) -> Option<Command> {
        let s = self.state.lock();
        s.pending.map(|p| p.command).or(s.last)
    }

    /// Drop the pending command and forget the one to resend (e.g. on engage, so
    /// nothing resends a stale set point). What the device was sent and acknowledged
    /// stays known: the interlocks judge by it.
    pub fn reset(&self, to: Option<Command>) {
        let mut s = self.state.lock();
        s.pending = None;
        s.resend = to;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn a_newer_command_replaces_a_pending_one() {
        let slot = CommandSlot::default();
        let t = Instant::now();
        assert!(!slot.submit(Command::Set(0.1), t));
        assert!(slot.submit(Command::Set(0.2), t));
        assert_eq!(
            slot.wait(Duration::ZERO),
            Wake::Command(Pending {
                command: Command::Set(0.2),
                received: t
            })
        );
        assert_eq!(slot.wait(Duration::from_millis(1)), Wake::Timeout);
    }

    #[test]
    fn submit_wakes_a_waiting_thread() {
        let slot = Arc::new(CommandSlot::default());
        let s2 = slot.clone();
        let waiter = std::thread::spawn(move || s2.wait(Duration::from_secs(30)));
        slot.submit(Command::Set(0.5), Instant::now());
        assert!(matches!(waiter.join().unwrap(), Wake::Command(_)));
    }

    #[test]
    fn nudge_and_stop_wake_without_a_command() {
        let slot = CommandSlot::default();
        slot.nudge();
        assert_eq!(slot.wait(Duration::from_secs(30)), Wake::Nudge);
        slot.stop();
        assert_eq!(slot.wait(Duration::from_secs(30)), Wake::Stop);
    }
}
