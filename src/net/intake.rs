//! What the listener does with one datagram, without the socket, in three steps:
//!
//! 1. **admit**, under the [`NetStatus`] lock: the sender (allow-list, its table
//!    entry), the grammar against the vehicle's words, the key and the counter, and who
//!    commands now;
//! 2. **apply**, without any lock of its own: each command goes to the
//!    [`Gate`] (which checks the interlocks and wakes the command
//!    thread), `engage` and `disengage` to the gate;
//! 3. **record**, under the lock again: the commander, the watchdog, counters and the
//!    reply.
//!
//! The watchdog's tick shares the same table. The path of an accepted command
//! datagram does not touch the heap: the parser and the key check are allocation-free,
//! the sender table is a fixed array, and a reply is written into an inline [`Reply`]
//! buffer. Only refusals are logged (rate-limited), and only engaging and disengaging
//! format a reason string.

use super::auth::Auth;
use super::proto::{parse, Datagram, NetCommand, Reject, Vocabulary};
use super::status::{Inner, NetStatus, Refusal};
use crate::config::NetworkConfig;
use crate::logging::RateLimit;
use crate::safety::Gate;
use crate::snapshot::WatchdogState;
use crate::vehicle::tap::{Event, Source};
use arrayvec::ArrayString;
use std::fmt::Write;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A reply datagram: one line per thing refused (or engaged / disengaged).
pub type Reply = ArrayString<512>;

/// At most this often a reply goes to one sender.
pub const REPLY_EVERY: Duration = Duration::from_millis(20);
/// At most this many replies a second in all.
pub const REPLY_BUDGET: u32 = 500;

/// The listener's decisions. Owned by the listener thread.
pub struct Intake {
    gate: Arc<Gate>,
    config: NetworkConfig,
    auth: Option<Auth>,
    status: Arc<NetStatus>,
    closing: Arc<AtomicBool>,
    log: RateLimit,
}

/// What one datagram led to, for its reply.
struct Outcome {
    reply: Reply,
    /// Something was refused or rejected.
    refused: bool,
    /// It engaged, disengaged or handed command to this sender: worth a reply.
    gate: bool,
}

impl Outcome {
    fn new() -> Outcome {
        Outcome {
            reply: Reply::new(),
            refused: false,
            gate: false,
        }
    }

    fn line(&mut self, args: std::fmt::Arguments) {
        // A full buffer drops the rest of the reply, never the command.
        let _ = self.reply.write_fmt(args);
        let _ = self.reply.try_push('\n');
    }
}

/// What applying a datagram changed, for the record step.
#[derive(Default)]
struct Effects {
    /// The sender asked to engage.
    asked_engage: bool,
    /// It sent a command for a device (or accel).
    commanded: bool,
    /// It disengaged the vehicle; the commander it took command from, if another.
    disengaged: Option<Option<SocketAddr>>,
    /// It engaged the vehicle, or took command of a vehicle the console engaged.
    took_command: bool,
    /// Its commands were refused because another sender commands.
    refused_other: bool,
}

impl Intake {
    pub fn new(
        gate: Arc<Gate>,
        config: NetworkConfig,
        auth: Option<Auth>,
        status: Arc<NetStatus>,
        closing: Arc<AtomicBool>,
    ) -> Intake {
        Intake {
            gate,
            config,
            auth,
            status,
            closing,
            log: RateLimit::new(10),
        }
    }

    pub fn status(&self) -> &Arc<NetStatus> {
        &self.status
    }

    /// Handle one datagram from `from`, received at `received` (stamped right after
    /// `recv_from`). Returns the reply to send back, if any.
    pub fn handle(&mut self, bytes: &[u8], from: SocketAddr, received: Instant) -> Option<Reply> {
        let st = self.status.clone();
        st.count_datagram();
        if !self.config.allows(from) {
            st.count_refusal(Refusal::NotOnAllowList);
            if self.log.allow(received) {
                tracing::warn!(%from, "refused datagram: {}", Refusal::NotOnAllowList.describe());
            }
            return None;
        }
        if self.closing.load(Relaxed) {
            st.count_refusal(Refusal::Closing);
            return None;
        }
        let (i, d, commander) = match self.admit(bytes, from, received) {
            Ok(admitted) => admitted,
            Err(reply) => return reply,
        };
        let mut out = Outcome::new();
        let effects = self.apply(&d, from, commander, received, &mut out);
        self.record(i, from, effects, out, received)
    }

    /// Step 1, under the lock: sender table, grammar, key, counter. Returns the
    /// sender's slot, the datagram, and who commands now; or the reply to a rejection.
    // The reply is inline (no heap on the command path).
    #[allow(clippy::type_complexity, clippy::result_large_err)]
    fn admit(
        &mut self,
        bytes: &[u8],
        from: SocketAddr,
        received: Instant,
    ) -> Result<(usize, Datagram, Option<SocketAddr>), Option<Reply>> {
        let st = self.status.clone();
        let mut inner = st.inner.lock();
        let i = inner.sender(from, received);
        let quiet_for = received.saturating_duration_since(inner.get(i).last_seen);
        {
            let s = inner.get(i);
            s.datagrams += 1;
            s.last_seen = received;
            if quiet_for >= self.config.watchdog_timeout {
                s.latched = false;
            }
        }
        let mut out = Outcome::new();
        let vocab = Vocabulary::of(&self.gate.vehicle.config);
        let d = match parse(bytes, &vocab) {
            Ok(d) => d,
            Err(e) => {
                self.reject(&mut inner, i, e.reason);
                if self.log.allow(received) {
                    tracing::warn!(%from, "rejected datagram: {e}");
                }
                out.line(format_args!("rejected: {e}"));
                out.refused = true;
                return Err(self.reply(&mut inner, i, out, received));
            }
        };
        if let Some(auth) = &self.auth {
            if let Err(r) = auth.verify(&d, bytes, inner.keyed_seq) {
                self.reject(&mut inner, i, r);
                if self.log.allow(received) {
                    tracing::warn!(%from, "rejected datagram: {r}");
                }
                out.line(format_args!("rejected: {r}"));
                out.refused = true;
                return Err(self.reply(&mut inner, i, out, received));
            }
            inner.keyed_seq = d.seq;
        }
        if let Some(seq) = d.seq {
            if self.auth.is_none() && inner.get(i).seq == Some(seq) {
                // Alive but frozen: the same counter again. Not a valid command, so
                // the watchdog keeps counting.
                inner.get(i).stale = true;
                self.reject(&mut inner, i, Reject::Replayed);
                if self.log.allow(received) {
                    tracing::warn!(%from, seq, "rejected datagram: the rolling counter did not advance");
                }
                out.line(format_args!(
                    "rejected: replayed: the rolling counter did not advance (seq {seq})"
                ));
                out.refused = true;
                return Err(self.reply(&mut inner, i, out, received));
            }
            inner.get(i).seq = Some(seq);
        }
        inner.get(i).stale = false;
        sync(&self.gate, &mut inner);
        Ok((i, d, inner.commander))
    }

    /// Step 2, without the lock: every command to the gate, in order.
    fn apply(
        &mut self,
        d: &Datagram,
        from: SocketAddr,
        mut commander: Option<SocketAddr>,
        received: Instant,
        out: &mut Outcome,
    ) -> Effects {
        let st = self.status.clone();
        let mut fx = Effects::default();
        let gate = self.gate.clone();
        let vocab = Vocabulary::of(&gate.vehicle.config);
        for c in &d.commands {
            let engaged = self.gate.is_engaged();
            let other = commander.filter(|c| *c != from && engaged);
            match *c {
                NetCommand::Disengage => {
                    // Anyone allowed to send may stop the vehicle.
                    out.gate = true;
                    let mut why = ArrayString::<96>::new();
                    let _ = write!(why, "disengage from {from}");
                    self.gate.disengage(&why);
                    fx.disengaged = Some(commander.take().filter(|c| *c != from));
                    out.line(format_args!("ok disengaged"));
                }
                NetCommand::Clear => {
                    // Clearing moves nothing: it lets an engage through again once
                    // the driver has let go.
                    out.gate = true;
                    match self.gate.clear_overrides() {
                        Ok(c) if c.is_empty() => out.line(format_args!("ok nothing to clear")),
                        Ok(c) => out.line(format_args!("ok cleared override on {}", c.join(", "))),
                        Err(why) => {
                            out.refused = true;
                            out.line(format_args!("refused clear: {why}"));
                        }
                    }
                }
                _ if other.is_some() => {
                    if !out.refused {
                        st.count_refusal(Refusal::OtherCommander);
                        if self.log.allow(received) {
                            tracing::warn!(%from, commander = %other.unwrap_or(from), "refused: {}", Refusal::OtherCommander.describe());
                        }
                        out.line(format_args!(
                            "refused: {} ({})",
                            Refusal::OtherCommander.describe(),
                            other.unwrap_or(from)
                        ));
                    }
                    out.refused = true;
                    fx.refused_other = true;
                    self.gate.vehicle.tap.send(|| Event::Refused {
                        at: received,
                        from,
                        reason: Refusal::OtherCommander.as_str(),
                    });
                    if matches!(c, NetCommand::Engage) {
                        out.gate = true;
                    }
                }
                NetCommand::Engage => {
                    fx.asked_engage = true;
                    if self.engage(from, commander, out) {
                        commander = Some(from);
                        fx.took_command = true;
                    }
                }
                NetCommand::Set(id, command) => {
                    fx.commanded = true;
                    match self
                        .gate
                        .submit_from(Source::Network(from), id, command, received)
                    {
                        Ok(()) => st.count_command(id),
                        Err(r) => {
                            st.count_intake(r);
                            out.refused = true;
                            out.line(format_args!(
                                "rejected {}: {}: {r}",
                                vocab.line(c),
                                r.as_str()
                            ));
                        }
                    }
                }
                NetCommand::Accel(a) => {
                    fx.commanded = true;
                    match self
                        .gate
                        .submit_accel_from(Source::Network(from), a, received)
                    {
                        Ok(()) => st.count_accel(),
                        Err(r) => {
                            st.count_intake(r);
                            out.refused = true;
                            out.line(format_args!(
                                "rejected {}: {}: {r}",
                                vocab.line(c),
                                r.as_str()
                            ));
                        }
                    }
                }
            }
            if fx.commanded
                && commander.is_none()
                && self.gate.is_engaged()
                && fx.disengaged.is_none()
            {
                // Engaged from the console: the first network sender to command takes
                // over, and the watchdog watches it from now on.
                commander = Some(from);
                fx.took_command = true;
            }
        }
        fx
    }

    /// Step 3, under the lock: who commands, the watchdog, counters, the reply.
    fn record(
        &mut self,
        i: usize,
        from: SocketAddr,
        fx: Effects,
        out: Outcome,
        received: Instant,
    ) -> Option<Reply> {
        let st = self.status.clone();
        let mut inner = st.inner.lock();
        if let Some(previous) = fx.disengaged {
            if let Some(c) = inner.commander.take() {
                if c != from {
                    if let Some(s) = inner.find(c) {
                        s.latched = true;
                    }
                }
            }
            if let Some(p) = previous {
                if let Some(s) = inner.find(p) {
                    s.latched = true;
                }
            }
            inner.get(i).latched = false;
            inner.watchdog = WatchdogState::Off;
        }
        let engaged = self.gate.is_engaged();
        if engaged && fx.took_command && inner.commander.is_none() {
            inner.commander = Some(from);
            inner.watchdog = WatchdogState::Armed;
            tracing::info!(%from, "network sender commands the engaged vehicle");
        }
        if engaged && inner.commander == Some(from) {
            inner.last_valid = Some(received);
        }
        let refused_whole = fx.refused_other;
        let s = inner.get(i);
        if !fx.asked_engage {
            s.latched = false;
        }
        if refused_whole {
            s.rejected += 1;
        } else {
            s.accepted += 1;
            st.count_accepted();
        }
        self.reply(&mut inner, i, out, received)
    }

    /// `engage` from `from`; true when it engaged the vehicle or took command of it.
    /// A repeat from the sender already commanding changes nothing and is not answered.
    fn engage(
        &mut self,
        from: SocketAddr,
        commander: Option<SocketAddr>,
        out: &mut Outcome,
    ) -> bool {
        let st = &self.status;
        if !self.config.allow_engage {
            st.count_refusal(Refusal::EngageNotAllowed);
            out.refused = true;
            out.gate = true;
            out.line(format_args!(
                "refused engage: {}",
                Refusal::EngageNotAllowed.describe()
            ));
            return false;
        }
        if self.gate.is_engaged() {
            // Already engaged: by this sender (a planner repeats `engage` in every
            // datagram; nothing changes, nothing is said), or from the console (this
            // sender takes over).
            if commander == Some(from) {
                return false;
            }
            out.gate = true;
            out.line(format_args!("ok engaged"));
            return true;
        }
        let latched = st.inner.lock().find(from).is_some_and(|s| s.latched);
        if latched {
            st.count_refusal(Refusal::EngageLatched);
            out.refused = true;
            out.gate = true;
            out.line(format_args!(
                "refused engage: {} ({})",
                Refusal::EngageLatched.describe(),
                self.gate.reason()
            ));
            return false;
        }
        let mut by = ArrayString::<96>::new();
        let _ = write!(by, "network {from}");
        out.gate = true;
        match self.gate.engage(&by) {
            Ok(()) => {
                out.line(format_args!("ok engaged"));
                true
            }
            Err(why) => {
                st.count_refusal(Refusal::EngageBlocked);
                out.refused = true;
                out.line(format_args!("refused engage: {}", why.join("; ")));
                false
            }
        }
    }

    fn reject(&self, inner: &mut Inner, i: usize, r: Reject) {
        self.status.count_reject(r);
        let s = inner.get(i);
        s.rejected += 1;
        let from = s.addr;
        self.gate.vehicle.tap.send(|| Event::Refused {
            at: Instant::now(),
            from,
            reason: r.as_str(),
        });
    }
    /// The reply for `out`, if it says something and the budgets allow.
    fn reply(&self, inner: &mut Inner, i: usize, out: Outcome, now: Instant) -> Option<Reply> {
        if !self.config.replies || out.reply.is_empty() || !(out.refused || out.gate) {
            return None;
        }
        let s = inner.get(i);
        if s.last_reply
            .is_some_and(|t| now.saturating_duration_since(t) < REPLY_EVERY)
        {
            return None;
        }
        s.last_reply = Some(now);
        let (window, n) = &mut inner.replies;
        if now.saturating_duration_since(*window) >= Duration::from_secs(1) {
            *window = now;
            *n = 0;
        }
        if *n >= REPLY_BUDGET {
            return None;
        }
        *n += 1;
        Some(out.reply)
    }
}

/// Notice a disengage by someone else (console, gate monitor, shutdown): the commander
/// loses command and must re-engage on purpose. Notice an engage from the console.
pub(crate) fn sync(gate: &Gate, inner: &mut Inner) {
    let engaged = gate.is_engaged();
    if !engaged {
        if let Some(c) = inner.commander.take() {
            if let Some(s) = inner.find(c) {
                s.latched = true;
            }
            tracing::info!(commander = %c, "network command ended: {}", gate.reason());
        }
        if inner.watchdog != WatchdogState::Tripped {
            inner.watchdog = WatchdogState::Off;
        }
    } else if inner.commander.is_none() {
        inner.watchdog = WatchdogState::Idle;
    }
}

/// One watchdog tick: while a network sender commands the engaged vehicle, no valid
/// datagram from it for `timeout` (silence, or a counter that stopped advancing) brings
/// the vehicle to the safe state and disengages it. Returns the cause when it tripped.
pub fn watchdog_tick(gate: &Gate, status: &NetStatus, now: Instant) -> Option<String> {
    let mut inner = status.inner.lock();
    sync(gate, &mut inner);
    let c = inner.commander?;
    let last = inner.last_valid?;
    let quiet = now.saturating_duration_since(last);
    if quiet < status.watchdog_timeout {
        return None;
    }
    let ms = quiet.as_millis();
    let cause = match inner.find(c) {
        Some(s) if s.stale && s.last_seen > last => format!(
            "the rolling counter of {c} stopped advancing at {} for {ms} ms",
            s.seq.unwrap_or_default()
        ),
        _ => format!("no valid command from {c} for {ms} ms"),
    };
    inner.commander = None;
    if let Some(s) = inner.find(c) {
        s.latched = true;
    }
    inner.watchdog = WatchdogState::Tripped;
    inner.last_trip = Some(cause.clone());
    // Under the lock, so no datagram slips in between the decision and the safe state.
    gate.disengage(&format!("watchdog: {cause}"));
    drop(inner);
    tracing::warn!("watchdog: {cause}; safe state commanded");
    Some(cause)
}
