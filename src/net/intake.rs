//! What the listener does with one datagram, without the socket, in three steps:
//!
//! 1. **admit**, under the [`NetStatus`] lock: the sender (allow-list, its table
//!    entry), the grammar against the vehicle's words, the key and the counter;
//! 2. **apply**, without any lock of its own: each command goes, tagged with its
//!    sender, to the one intake below every front end ([`Gate::admit`]), which
//!    decides who commands, feeds the commander's watchdog, checks the interlocks and
//!    wakes the command thread; the outcome becomes the reply;
//! 3. **record**, under the lock again: counters, the latch, the reply.
//!
//! What is the network's own: the allow-list, `allow_engage`, the rolling counter and
//! the key, and the latch — a sender whose command ended against its will (the
//! watchdog, a console taking command, a fault) and that repeats `engage` in every
//! datagram is not engaged again until it sends one datagram without `engage`. The
//! path of an accepted command datagram does not touch the heap: the parser and the
//! key check are allocation-free, the sender table is a fixed array, and a reply is
//! written into an inline [`Reply`] buffer. Only refusals are logged (rate-limited).

use super::auth::Auth;
use super::counters::{Inner, NetRefusal, NetStatus};
use super::proto::{parse, BadDatagram, Datagram, NetCommand, Vocabulary};
use crate::config::NetworkConfig;
use crate::engine::Gate;
use crate::logging::RateLimit;
use crate::safety::gate_state::remote_may_engage;
use crate::safety::{Ask, Done, Refused};
use crate::snapshot::Blocker;
use crate::value::Source;
use crate::vehicle::tap::Event;
use arrayvec::ArrayString;
use std::fmt::Write;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A reply datagram: one line per thing refused (or engaged / disengaged).
pub type Reply = ArrayString<512>;

/// At most this often a reply goes to one sender.
pub(crate) const REPLY_EVERY: Duration = Duration::from_millis(20);
/// At most this many replies a second in all.
pub(crate) const REPLY_BUDGET: u32 = 500;

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
    /// It gave command up, or disengaged the vehicle itself: not latched.
    let_go: bool,
    /// Its commands were refused because another source commands.
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
            st.count_refusal(NetRefusal::NotOnAllowList);
            if self.log.allow(received) {
                tracing::warn!(%from, "refused datagram: {}", NetRefusal::NotOnAllowList.describe());
            }
            return None;
        }
        if self.closing.load(Relaxed) {
            st.count_refusal(NetRefusal::Closing);
            return None;
        }
        let (i, d) = match self.admit(bytes, from, received) {
            Ok(admitted) => admitted,
            Err(reply) => return reply,
        };
        crate::probe::stamp(crate::probe::Step::Parsed);
        let mut out = Outcome::new();
        let effects = self.apply(&d, from, received, &mut out);
        self.record(i, from, effects, out, received)
    }

    /// Step 1, under the lock: sender table, grammar, key, counter. Returns the
    /// sender's slot, the datagram, and who commands now; or the reply to a rejection.
    // The reply is inline (no heap on the command path).
    #[allow(clippy::type_complexity)]
    fn admit(
        &mut self,
        bytes: &[u8],
        from: SocketAddr,
        received: Instant,
    ) -> Result<(usize, Datagram), Option<Reply>> {
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
        let vocab = Vocabulary::of(self.gate.vehicle().config());
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
                self.gate.frozen(Source::Network(from));
                self.reject(&mut inner, i, BadDatagram::Replayed);
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
        Ok((i, d))
    }

    /// Step 2, without the lock: every command to the one intake, in order.
    fn apply(
        &mut self,
        d: &Datagram,
        from: SocketAddr,
        received: Instant,
        out: &mut Outcome,
    ) -> Effects {
        let st = self.status.clone();
        let mut fx = Effects::default();
        let gate = self.gate.clone();
        let vocab = Vocabulary::of(gate.vehicle().config());
        let source = Source::Network(from);
        for c in &d.commands {
            let ask = match *c {
                NetCommand::Engage => {
                    fx.asked_engage = true;
                    if let Some(why) = self.may_engage(from) {
                        st.count_refusal(why);
                        out.refused = true;
                        out.gate = true;
                        match why {
                            NetRefusal::EngageLatched => out.line(format_args!(
                                "refused engage: {} ({})",
                                why.describe(),
                                gate.reason()
                            )),
                            _ => out.line(format_args!("refused engage: {}", why.describe())),
                        }
                        continue;
                    }
                    Ask::Engage
                }
                NetCommand::Disengage => Ask::Disengage,
                NetCommand::Release => Ask::Release,
                NetCommand::Clear => Ask::Clear,
                NetCommand::Set(id, command) => Ask::Set(id, command),
                NetCommand::Accel(a) => Ask::Accel(a),
            };
            match gate.admit(source, ask, received) {
                Ok(Done::Commanded) => match *c {
                    NetCommand::Set(id, _) => st.count_command(id),
                    _ => st.count_accel(),
                },
                Ok(Done::Same) => {}
                Ok(done) => {
                    fx.let_go |= matches!(done, Done::Released | Done::Disengaged(_));
                    out.gate = true;
                    out.line(format_args!("ok {done}"));
                }
                Err(Refused::Owner(r)) => {
                    if !fx.refused_other {
                        st.count_refusal(NetRefusal::OtherCommander);
                        out.line(format_args!("refused {}: {r}", vocab.line(c)));
                    }
                    out.refused = true;
                    fx.refused_other = true;
                    if matches!(c, NetCommand::Engage | NetCommand::Release) {
                        out.gate = true;
                    }
                    gate.vehicle().tap().send(|| Event::Refused {
                        at: received,
                        from,
                        reason: NetRefusal::OtherCommander.as_str(),
                    });
                }
                Err(Refused::Rule(r)) => {
                    st.count_intake(r);
                    out.refused = true;
                    out.line(format_args!(
                        "rejected {}: {}: {r}",
                        vocab.line(c),
                        r.as_str()
                    ));
                }
                Err(Refused::Blocked(why)) => {
                    st.count_refusal(NetRefusal::EngageBlocked);
                    out.refused = true;
                    out.gate = true;
                    out.line(format_args!("refused engage: {}", Blocker::said(&why)));
                }
                Err(Refused::Clear(why)) => {
                    out.refused = true;
                    out.gate = true;
                    out.line(format_args!("refused clear: {why}"));
                }
                // Only a client of the control socket or a replay says this; the
                // intake itself never does.
                Err(r @ Refused::Unanswered(_)) => {
                    out.refused = true;
                    out.line(format_args!("refused: {r}"));
                }
            }
        }
        fx
    }

    /// Whether this sender's `engage` may go to the intake: `None`, or the network's
    /// own refusal (the vehicle file does not allow it; the sender is latched).
    fn may_engage(&self, from: SocketAddr) -> Option<NetRefusal> {
        // Picking up a vehicle a console engaged and released engages nothing.
        if !remote_may_engage(self.config.allow_engage, self.gate.is_engaged()) {
            return Some(NetRefusal::EngageNotAllowed);
        }
        let latched = self
            .status
            .inner
            .lock()
            .find(from)
            .is_some_and(|s| s.latched);
        (latched && !self.gate.is_engaged()).then_some(NetRefusal::EngageLatched)
    }

    /// Step 3, under the lock: the latch, counters, the reply.
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
        if fx.let_go && inner.commanding == Some(from) {
            inner.commanding = None;
        }
        sync(&self.gate, &mut inner);
        if self.gate.commander() == Some(Source::Network(from)) {
            inner.commanding = Some(from);
        }
        let s = inner.get(i);
        if !fx.asked_engage || fx.let_go {
            s.latched = false;
        }
        if fx.refused_other {
            s.rejected += 1;
        } else {
            s.accepted += 1;
            st.count_accepted();
        }
        self.reply(&mut inner, i, out, received)
    }

    fn reject(&self, inner: &mut Inner, i: usize, r: BadDatagram) {
        self.status.count_reject(r);
        let s = inner.get(i);
        s.rejected += 1;
        let from = s.addr;
        self.gate.vehicle().tap().send(|| Event::Refused {
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

/// Notice that the command of the sender this listener saw commanding ended without
/// its asking (the watchdog, a console taking command, a fault, a disengage by someone
/// else): latch it, so that a planner repeating `engage` must re-engage on purpose.
pub(crate) fn sync(gate: &Gate, inner: &mut Inner) {
    let Some(c) = inner.commanding else {
        return;
    };
    if gate.commander() == Some(Source::Network(c)) {
        return;
    }
    inner.commanding = None;
    if let Some(s) = inner.find(c) {
        s.latched = true;
    }
    tracing::info!(commander = %c, "network command ended: {}", gate.reason());
}
