//! The latest-wins command slot between the command intake (network, console) and an
//! actuator's command thread: the paper's cached command plus condition variable.
//! It holds at most one pending command — never a queue. A command that arrives while
//! another is still pending replaces it, and the replaced one is counted as superseded.
//!
//! On the fast path ([`crate::engine::fast`]) the thread that admitted a command
//! [claims](CommandSlot::claim) the slot of an idle command thread, writes the request
//! itself and [hands the transaction over](CommandSlot::hand_over): the command thread
//! wakes to a [`Wake::Handed`] and reads the reply. While a claim stands, the command
//! thread takes nothing else from its slot.
//!
//! A device on a serial line has its command thread sleep on its port as well
//! ([`super::wake`]): a transaction handed over wakes it by its reply, not by a signal
//! from the thread that wrote the request — nothing else runs between the request's
//! first byte and the device's answer. Everything else (a command, a nudge, stop) rings
//! it at once. A slot without ([`CommandSlot::default`]) has its thread sleep on the
//! condition variable, woken by all of these.

use super::wake::PortWake;
use crate::driver::DriverError;
use crate::value::Command;
use parking_lot::{Condvar, Mutex, MutexGuard};
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A command waiting for the wire, stamped where it was born.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pending {
    pub command: Command,
    /// When intake accepted it: the start of the receipt → first-byte delay.
    pub received: Instant,
}

/// A command whose request another thread already wrote to the port, which it left
/// held ([`super::PortGuard::hand_over`]): the command thread reads the
/// reply and does the bookkeeping.
#[derive(Debug)]
pub struct Handover {
    pub pending: Pending,
    /// When the kernel took the request's first byte (`None`: nothing went out).
    pub first: Option<Instant>,
    /// How writing the request went: an error ends the transaction without a reply.
    pub sent: Result<(), DriverError>,
}

/// What woke the command thread.
#[derive(Debug)]
pub enum Wake {
    /// A new command.
    Command(Pending),
    /// A new command already on the wire: read its reply.
    Handed(Handover),
    /// `command_timeout` passed with no new command: resend the last one.
    Timeout,
    /// Someone asked the thread to run now (the console's wake key): resend the last.
    Nudge,
    /// Shut down.
    Stop,
}

/// Where an actuator's commands are on their way to the device.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WireState {
    /// Waiting in the slot for the command thread.
    pub pending: Option<Command>,
    /// Taken by the command thread and not finished: being checked, waiting for the
    /// port, or on the wire.
    pub flight: Option<Command>,
    /// The last command whose transaction finished (its bytes went out, acknowledged
    /// or not).
    pub sent: Option<Command>,
    /// The last command the device acknowledged.
    pub(crate) acked: Option<Command>,
    /// When the device first acknowledged `acked` since another command went out (a
    /// resend of it does not move this): a status taken after it reports the command's
    /// effect.
    pub(crate) acked_at: Option<Instant>,
    /// When the transaction that acknowledged `acked` (the one `acked_at` counts) wrote
    /// its first byte, where known: the device took the command about half a
    /// transaction later. Unlike `acked_at`, no late wake-up of the command thread on
    /// a busy machine moves it.
    pub(crate) acked_from: Option<Instant>,
}

impl WireState {
    /// Every value the device has or is about to have: pending, in flight, last sent,
    /// acknowledged. The interlocks judge by these.
    pub fn values(&self) -> impl Iterator<Item = Command> {
        [self.pending, self.flight, self.sent, self.acked]
            .into_iter()
            .flatten()
    }

    /// The set points among [`WireState::values`].
    pub(crate) fn set_points(&self) -> impl Iterator<Item = f64> {
        self.values().filter_map(Command::set_point)
    }

    /// What the device will have next: pending, else in flight, else last sent.
    pub fn latest(&self) -> Option<Command> {
        self.pending.or(self.flight).or(self.sent)
    }
}

/// The fast path's hold on the slot.
#[derive(Debug, Default)]
enum Fast {
    #[default]
    Off,
    /// Another thread is writing `command`, in flight; `before` is what was to be
    /// resent before the claim.
    Claimed {
        command: Command,
        before: Option<Command>,
    },
    /// ... and wrote it: the command thread is to finish the transaction.
    Handed(Handover),
}

#[derive(Default)]
struct State {
    wire: WireState,
    /// The command thread is asleep in [`CommandSlot::wait`].
    waiting: bool,
    /// In this wait, the port or the reply's deadline woke the thread while a claim
    /// stood: its request was armed and the handover is still to come, which must
    /// then wake the thread itself.
    armed_fired: bool,
    fast: Fast,
    /// When the pending command was born.
    received: Option<Instant>,
    /// What to send again after `command_timeout`; engage clears it.
    resend: Option<Command>,
    /// The last [`RECENT`] set points acknowledged, and when.
    recent: VecDeque<(Instant, f64)>,
    nudged: bool,
    stopped: bool,
}

/// How many acknowledged set points [`CommandSlot::acked_span`] looks back over at most
/// (a third of a second of commands at 100 Hz).
pub(crate) const RECENT: usize = 32;

impl State {
    /// See [`CommandSlot::is_idle`].
    fn idle(&self) -> bool {
        self.waiting
            && self.wire.pending.is_none()
            && self.wire.flight.is_none()
            && matches!(self.fast, Fast::Off)
    }

    /// The command thread takes the pending command: it is in flight from now on.
    fn take(&mut self) -> Option<Pending> {
        let command = self.wire.pending.take()?;
        let received = self.received.take().unwrap_or_else(Instant::now);
        self.wire.flight = Some(command);
        self.resend = Some(command);
        Some(Pending { command, received })
    }
}

#[derive(Default)]
pub struct CommandSlot {
    state: Mutex<State>,
    cv: Condvar,
    /// What the command thread sleeps on instead of `cv`, if anything.
    port_wake: Option<Arc<PortWake>>,
}

impl CommandSlot {
    /// A slot whose command thread sleeps on `wake`, which the device's port arms for a
    /// request handed over ([`super::PortGuard::hand_over`]).
    pub(crate) fn woken_by(wake: Arc<PortWake>) -> CommandSlot {
        CommandSlot {
            port_wake: Some(wake),
            ..CommandSlot::default()
        }
    }

    /// Whether the command thread sleeps on its port ([`super::wake`]).
    pub fn waits_on_port(&self) -> bool {
        self.port_wake.is_some()
    }

    /// Wake everyone waiting on the slot; `thread`: the command thread too, if it
    /// sleeps on its port (`waiting` read under the lock, so a thread that was not
    /// asleep yet finds what woke it before it sleeps).
    fn notify(&self, thread: bool) {
        if thread {
            if let Some(w) = &self.port_wake {
                w.ring();
            }
        }
        self.cv.notify_all();
    }

    /// Store a command and wake the command thread. Returns true when it replaced a
    /// command that had not reached the wire yet.
    pub fn submit(&self, command: Command, received: Instant) -> bool {
        let mut s = self.state.lock();
        let superseded = s.wire.pending.is_some();
        s.wire.pending = Some(command);
        s.received = Some(received);
        let waiting = s.waiting;
        drop(s);
        self.notify(waiting);
        superseded
    }

    /// Wake the command thread without a new command (it resends the last one).
    pub(crate) fn nudge(&self) {
        let mut s = self.state.lock();
        s.nudged = true;
        let waiting = s.waiting;
        drop(s);
        self.notify(waiting);
    }

    pub fn stop(&self) {
        let mut s = self.state.lock();
        s.stopped = true;
        drop(s);
        // Rung whether asleep or not: stop also ends the thread's other waits.
        self.notify(true);
    }

    /// Sleep until something happens, at most `timeout`. A command taken here is in
    /// flight until [`CommandSlot::finish`] or [`CommandSlot::drop_flight`]. A claim on
    /// the slot is waited out whatever the timeout: its transaction comes first.
    pub fn wait(&self, timeout: Duration) -> Wake {
        let deadline = Instant::now() + timeout;
        let mut s = self.state.lock();
        s.waiting = true;
        s.armed_fired = false;
        let wake = self.wait_locked(&mut s, deadline);
        s.waiting = false;
        s.armed_fired = false;
        wake
    }

    fn wait_locked(&self, s: &mut MutexGuard<'_, State>, deadline: Instant) -> Wake {
        loop {
            // Checked, then slept on, under the lock (or, on the port, with `waiting`
            // set under it): whatever comes in between wakes the sleep.
            let claimed = match std::mem::take(&mut s.fast) {
                Fast::Handed(h) => return Wake::Handed(h),
                claimed @ Fast::Claimed { .. } => {
                    s.fast = claimed;
                    true
                }
                Fast::Off => false,
            };
            let now = Instant::now();
            if !claimed {
                if s.stopped {
                    return Wake::Stop;
                }
                if let Some(p) = s.take() {
                    s.nudged = false;
                    return Wake::Command(p);
                }
                if std::mem::take(&mut s.nudged) {
                    return Wake::Nudge;
                }
                if now >= deadline {
                    return Wake::Timeout;
                }
            }
            // A claim is waited out with no deadline: its handover or its end wakes.
            let until = (!claimed).then_some(deadline);
            match &self.port_wake {
                None => match until {
                    Some(d) => {
                        self.cv.wait_until(s, d);
                    }
                    None => self.cv.wait(s),
                },
                Some(w) => {
                    let woken = MutexGuard::unlocked(s, || {
                        w.wait(until.map(|d| d.saturating_duration_since(now)))
                    });
                    if woken.port || woken.timer {
                        s.armed_fired = true;
                    }
                }
            }
        }
    }

    /// Claim the slot for the fast path: only while the command thread sleeps in
    /// [`CommandSlot::wait`] with nothing pending and nothing in flight. `command` is in
    /// flight from here on (the wire check of the other devices sees it); the claim ends
    /// with [`CommandSlot::hand_over`] or [`CommandSlot::unclaim`].
    pub(crate) fn claim(&self, command: Command) -> bool {
        let mut s = self.state.lock();
        if s.stopped || !s.idle() {
            return false;
        }
        // As when the command thread takes a command: it is the one to resend from now
        // on — unless a reset comes before the claim ends (an override that forgets
        // what is resent to a device), which then holds.
        let before = s.resend.replace(command);
        s.fast = Fast::Claimed { command, before };
        s.wire.flight = Some(command);
        true
    }

    /// The claimed command's request went out (or failed to): the command thread is to
    /// finish its transaction. `armed`: its port wakes the thread by the reply, or by
    /// the reply's deadline ([`super::PortGuard::hand_over`]), and nothing else does —
    /// unless the port already did, before the handover was here to take; else the
    /// thread is woken now.
    pub(crate) fn hand_over(&self, h: Handover, armed: bool) {
        let mut s = self.state.lock();
        debug_assert!(matches!(s.fast, Fast::Claimed { .. }));
        s.fast = Fast::Handed(h);
        let fired = std::mem::take(&mut s.armed_fired);
        drop(s);
        if !armed || fired || self.port_wake.is_none() {
            self.notify(true);
        }
    }

    /// The claimed command did not go out: end the claim, in one step with what becomes
    /// of its command. With `requeue`, the command (received then) is pending for the
    /// command thread, as if it had been submitted — unless one stored meanwhile (a
    /// safe state) is pending already, which stands: then returns true, the claimed one
    /// superseded. Without, the slot is as before the claim.
    pub(crate) fn unclaim(&self, requeue: Option<Instant>) -> bool {
        let mut s = self.state.lock();
        let Fast::Claimed { command, before } = std::mem::take(&mut s.fast) else {
            debug_assert!(false, "unclaimed without a claim");
            return false;
        };
        s.wire.flight = None;
        if s.resend == Some(command) {
            s.resend = before;
        }
        let superseded = match requeue {
            Some(_) if s.wire.pending.is_some() => true,
            Some(received) => {
                s.wire.pending = Some(command);
                s.received = Some(received);
                false
            }
            None => false,
        };
        drop(s);
        // The command thread waits out a claim with no deadline: back to its resend
        // timeout, or to the command.
        self.notify(true);
        superseded
    }

    /// A command waits for the port: pending, or claimed by the fast path.
    pub(crate) fn has_pending(&self) -> bool {
        let s = self.state.lock();
        s.wire.pending.is_some() || matches!(s.fast, Fast::Claimed { .. })
    }

    /// Take a command that arrived after the thread woke (while it waited for the port),
    /// so the newest one goes out instead.
    pub(crate) fn take_newer(&self) -> Option<Pending> {
        self.state.lock().take()
    }

    /// Sleep until `until` unless stopped; a new command may arrive meanwhile and stays
    /// pending. Returns false when stopped.
    pub(crate) fn sleep_until(&self, until: Instant) -> bool {
        let mut s = self.state.lock();
        while !s.stopped && Instant::now() < until {
            self.cv.wait_until(&mut s, until);
        }
        !s.stopped
    }

    /// Put `command` in flight (a resend, or what the wire check sends instead).
    pub fn fly(&self, command: Command) {
        let mut s = self.state.lock();
        s.wire.flight = Some(command);
        s.resend = Some(command);
        drop(s);
        self.cv.notify_all();
    }

    /// The command in flight did not go out after all (the wire check dropped it).
    pub(crate) fn drop_flight(&self) {
        let mut s = self.state.lock();
        s.wire.flight = None;
        s.resend = s.wire.sent;
        drop(s);
        self.cv.notify_all();
    }

    /// The transaction of the command in flight finished: its bytes are on the wire,
    /// and `acked` says whether the device acknowledged it. Wakes anyone waiting.
    pub fn finish(&self, command: Command, acked: bool) {
        self.finish_sent(command, acked, None);
    }

    /// [`CommandSlot::finish`], knowing when the transaction wrote its first byte.
    pub(crate) fn finish_sent(&self, command: Command, acked: bool, first: Option<Instant>) {
        let mut s = self.state.lock();
        s.wire.flight = None;
        let before = s.wire.sent.replace(command);
        if acked {
            let now = Instant::now();
            if let Command::Set(v) = command {
                if s.recent.len() == RECENT {
                    s.recent.pop_front();
                }
                s.recent.push_back((now, v));
            }
            // A resend does not move it; the same command again after another one
            // went out does: the device's state may have followed the other since.
            if s.wire.acked != Some(command) || before != Some(command) {
                s.wire.acked = Some(command);
                s.wire.acked_at = Some(now);
                s.wire.acked_from = first;
            }
        }
        drop(s);
        self.cv.notify_all();
    }

    /// The lowest and highest set point acknowledged since `since` (of the last
    /// [`RECENT`]), the one in force at `since` and the last always included: every
    /// command that can have driven the device meanwhile. `None` before the first.
    pub(crate) fn acked_span(&self, since: Instant) -> Option<[f64; 2]> {
        let s = self.state.lock();
        let (_, last) = *s.recent.back()?;
        // The last acknowledged at or before `since` still drove it then.
        let from = s.recent.iter().rposition(|(t, _)| *t <= since).unwrap_or(0);
        let span = s
            .recent
            .iter()
            .skip(from)
            .fold([last, last], |[lo, hi], &(_, v)| [lo.min(v), hi.max(v)]);
        Some(span)
    }

    /// When the device last acknowledged a set point (a resend included): a device
    /// with a watchdog of its own acts by itself once this is too long ago.
    pub(crate) fn acked_last_at(&self) -> Option<Instant> {
        self.state.lock().recent.back().map(|(t, _)| *t)
    }

    /// What the command thread sends again when nothing new arrives.
    pub(crate) fn resend(&self) -> Option<Command> {
        self.state.lock().resend
    }

    /// Where its commands are.
    pub fn wire(&self) -> WireState {
        self.state.lock().wire
    }

    /// Wait until `done` holds for the wire state or the deadline passes; returns
    /// whether it held.
    pub(crate) fn wait_wire(&self, done: impl Fn(&WireState) -> bool, deadline: Instant) -> bool {
        let mut s = self.state.lock();
        loop {
            if done(&s.wire) {
                return true;
            }
            if s.stopped || self.cv.wait_until(&mut s, deadline).timed_out() {
                return done(&s.wire);
            }
        }
    }

    pub fn sent(&self) -> Option<Command> {
        self.state.lock().wire.sent
    }

    /// The last command the device acknowledged.
    pub fn executed(&self) -> Option<Command> {
        self.state.lock().wire.acked
    }

    /// The command thread sleeps in [`CommandSlot::wait`] with nothing pending and
    /// nothing in flight: a claim would be granted now.
    pub fn is_idle(&self) -> bool {
        self.state.lock().idle()
    }

    /// Wait until the device acknowledged a command matching `done`, or the deadline.
    pub(crate) fn wait_executed(&self, done: impl Fn(Command) -> bool, deadline: Instant) -> bool {
        self.wait_wire(|w| w.acked.is_some_and(&done), deadline)
    }

    /// The command in flight, else the last sent.
    pub fn last(&self) -> Option<Command> {
        let s = self.state.lock();
        s.wire.flight.or(s.wire.sent)
    }

    /// The command the device will have next: the pending one, else in flight, else
    /// the last sent.
    pub fn latest(&self) -> Option<Command> {
        self.state.lock().wire.latest()
    }

    /// Drop the pending command and forget the one to resend (e.g. on engage, so
    /// nothing resends a stale set point). What the device was sent and acknowledged
    /// stays known: the interlocks judge by it.
    pub fn reset(&self, to: Option<Command>) {
        let mut s = self.state.lock();
        s.wire.pending = None;
        s.received = None;
        s.resend = to;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    /// A reading is judged against the commands that were driving the device when it
    /// was taken: the set point acknowledged before `since` and still in force then is
    /// part of the span, not only those after it. (The brake held full by the safe
    /// state, then released by the manual state: a reading taken just before the
    /// release was once compared with the release alone.)
    #[test]
    fn the_span_holds_the_set_point_in_force_at_its_start() {
        let slot = CommandSlot::default();
        let ack = |v: f64| {
            slot.fly(Command::Set(v));
            slot.finish(Command::Set(v), true);
        };
        ack(1.0);
        std::thread::sleep(std::time::Duration::from_millis(5));
        let since = Instant::now();
        std::thread::sleep(std::time::Duration::from_millis(5));
        ack(0.0);
        assert_eq!(slot.acked_span(since), Some([0.0, 1.0]));
        assert_eq!(slot.acked_span(Instant::now()), Some([0.0, 0.0]));
        let last = slot.acked_last_at().expect("acknowledged");
        assert!(last > since);
    }

    /// The stamps of an acknowledgement move with a new command, not with a resend of
    /// the one acknowledged: a resend's first byte is not when the device took it.
    #[test]
    fn a_resend_moves_neither_stamp_of_the_acknowledgement() {
        let slot = CommandSlot::default();
        let (a, b) = (Instant::now(), Instant::now() + Duration::from_millis(7));
        let sent = |v: f64, first: Instant| {
            slot.fly(Command::Set(v));
            slot.finish_sent(Command::Set(v), true, Some(first));
            slot.wire()
        };
        let w = sent(0.5, a);
        assert_eq!((w.acked, w.acked_from), (Some(Command::Set(0.5)), Some(a)));
        let again = sent(0.5, b);
        assert_eq!((again.acked_at, again.acked_from), (w.acked_at, Some(a)));
        let other = sent(0.6, b);
        assert_eq!(other.acked_from, Some(b));
        assert!(other.acked_at >= w.acked_at);
    }

    #[test]
    fn a_newer_command_replaces_a_pending_one() {
        let slot = CommandSlot::default();
        let t = Instant::now();
        assert!(!slot.submit(Command::Set(0.1), t));
        assert!(slot.submit(Command::Set(0.2), t));
        assert!(matches!(
            slot.wait(Duration::ZERO),
            Wake::Command(Pending {
                command: Command::Set(0.2),
                received
            }) if received == t
        ));
        assert!(matches!(slot.wait(Duration::from_millis(1)), Wake::Timeout));
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
        assert!(matches!(slot.wait(Duration::from_secs(30)), Wake::Nudge));
        slot.stop();
        assert!(matches!(slot.wait(Duration::from_secs(30)), Wake::Stop));
    }

    /// Wait until the thread sleeps in its slot, then claim it for `command`.
    /// The claimed `command` was written: hand its transaction over.
    fn hand_over_written(slot: &CommandSlot, command: Command) {
        let t = Instant::now();
        slot.hand_over(
            Handover {
                pending: Pending {
                    command,
                    received: t,
                },
                first: Some(t),
                sent: Ok(()),
            },
            false,
        );
    }

    fn claim_when_asleep(slot: &CommandSlot, command: Command) {
        let end = Instant::now() + Duration::from_secs(20);
        while !slot.claim(command) {
            assert!(Instant::now() < end, "the command thread never slept");
            std::thread::yield_now();
        }
    }

    /// A claim holds the command thread — past its timeout, and past a command that
    /// arrives meanwhile — until the transaction is handed over; the newer command is
    /// taken after it. (A thread that took its timeout while claimed would resend and
    /// queue for a port only it can release.)
    #[test]
    fn a_claim_holds_the_thread_until_its_transaction_is_handed_over() {
        let slot = Arc::new(CommandSlot::default());
        let s2 = slot.clone();
        let waiter = std::thread::spawn(move || {
            let first = loop {
                match s2.wait(Duration::from_millis(5)) {
                    // A claim can only be made while the thread waits: in flight here
                    // means it timed out under a claim.
                    Wake::Timeout => assert_eq!(s2.wire().flight, None, "timed out while claimed"),
                    w => break w,
                }
            };
            let second = s2.wait(Duration::from_secs(30));
            (first, second)
        });
        claim_when_asleep(&slot, Command::Set(0.1));
        assert_eq!(slot.wire().flight, Some(Command::Set(0.1)), "in flight");
        assert!(!slot.claim(Command::Set(0.2)), "one claim at a time");
        slot.submit(Command::Set(0.3), Instant::now());
        // Several of the thread's timeouts pass while the claim stands.
        std::thread::sleep(Duration::from_millis(30));
        hand_over_written(&slot, Command::Set(0.1));
        let (first, second) = waiter.join().unwrap();
        assert!(
            matches!(first, Wake::Handed(Handover { pending, .. }) if pending.command == Command::Set(0.1)),
            "{first:?}"
        );
        assert!(
            matches!(second, Wake::Command(p) if p.command == Command::Set(0.3)),
            "{second:?}"
        );
    }

    #[test]
    fn an_unclaimed_slot_is_as_before() {
        let slot = Arc::new(CommandSlot::default());
        slot.reset(Some(Command::Set(0.5)));
        let s2 = slot.clone();
        let waiter = std::thread::spawn(move || s2.wait(Duration::from_secs(30)));
        claim_when_asleep(&slot, Command::Set(0.1));
        assert_eq!(slot.resend(), Some(Command::Set(0.1)));
        assert!(!slot.unclaim(None));
        assert_eq!(slot.wire().flight, None);
        assert_eq!(slot.resend(), Some(Command::Set(0.5)), "resend as before");
        slot.submit(Command::Set(0.1), Instant::now());
        assert!(matches!(waiter.join().unwrap(), Wake::Command(_)));
    }

    /// A claimed command that cannot go out after all is queued for the command thread
    /// in the same step — unless a command stored during the claim (the safe state of a
    /// disengage that raced it) is pending: that one stands, never overwritten by the
    /// older command.
    #[test]
    fn an_unclaimed_command_is_queued_unless_a_newer_one_is_pending() {
        for newer in [None, Some(Command::Set(-1.0))] {
            let slot = Arc::new(CommandSlot::default());
            let s2 = slot.clone();
            let waiter = std::thread::spawn(move || s2.wait(Duration::from_secs(30)));
            claim_when_asleep(&slot, Command::Set(0.1));
            if let Some(c) = newer {
                slot.submit(c, Instant::now());
            }
            assert_eq!(slot.unclaim(Some(Instant::now())), newer.is_some());
            let Wake::Command(p) = waiter.join().unwrap() else {
                panic!("woken without a command")
            };
            assert_eq!(p.command, newer.unwrap_or(Command::Set(0.1)));
        }
    }

    /// A reset during a claim (an override forgetting what is resent to a device the
    /// manual state does not command) holds after the claimed command went out: the
    /// command thread does not send it again and again.
    #[test]
    fn a_reset_during_a_claim_holds_after_the_hand_over() {
        let slot = Arc::new(CommandSlot::default());
        let s2 = slot.clone();
        let waiter = std::thread::spawn(move || s2.wait(Duration::from_secs(30)));
        claim_when_asleep(&slot, Command::Set(0.1));
        slot.reset(None);
        hand_over_written(&slot, Command::Set(0.1));
        assert!(matches!(waiter.join().unwrap(), Wake::Handed(_)));
        assert_eq!(slot.resend(), None, "nothing to resend after the reset");
    }

    /// The reply can wake the command thread before its handover is stored (the thread
    /// that wrote the request held up between arming the port and handing over): the
    /// command thread, finding the claim still standing, sleeps again — and the
    /// handover then wakes it itself. The port's one shot is spent: nothing else would
    /// wake it before the reply's deadline, long after the reply came.
    #[test]
    fn a_reply_before_its_handover_still_wakes_the_thread() {
        use crate::driver::Link;
        use serialport::TTYPort;
        use std::io::Write;
        let (mut device, host) = TTYPort::pair().expect("a pseudo-terminal pair");
        let wake = Arc::new(PortWake::new().unwrap());
        let slot = Arc::new(CommandSlot::woken_by(wake.clone()));
        let (tid_tx, tid) = std::sync::mpsc::channel();
        let (woke_tx, woke) = std::sync::mpsc::channel();
        let s2 = slot.clone();
        std::thread::spawn(move || {
            let me = std::fs::read_link("/proc/thread-self").unwrap();
            tid_tx.send(me.file_name().unwrap().to_owned()).unwrap();
            let _ = woke_tx.send(s2.wait(Duration::from_secs(60)));
        });
        let stat = std::path::Path::new("/proc/self/task")
            .join(tid.recv().unwrap())
            .join("stat");
        let asleep = || {
            let s = std::fs::read_to_string(&stat).unwrap();
            s.rsplit(')').next().unwrap().trim_start().starts_with('S')
        };
        claim_when_asleep(&slot, Command::Set(0.1));
        device.write_all(b"ok\n").unwrap();
        wake.arm(host.reply_fd().unwrap(), Duration::from_secs(60))
            .unwrap();
        // The reply woke the thread, which found the claim and sleeps again.
        let end = Instant::now() + Duration::from_secs(20);
        while wake.port_armed() || !asleep() {
            assert!(Instant::now() < end, "the reply never woke the thread");
            std::thread::sleep(Duration::from_millis(1));
        }
        slot.hand_over(
            Handover {
                pending: Pending {
                    command: Command::Set(0.1),
                    received: Instant::now(),
                },
                first: Some(Instant::now()),
                sent: Ok(()),
            },
            true,
        );
        let got = woke
            .recv_timeout(Duration::from_secs(20))
            .expect("the handover woke the thread");
        assert!(matches!(got, Wake::Handed(_)), "{got:?}");
    }
}
