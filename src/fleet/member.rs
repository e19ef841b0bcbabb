//! A running adrive in the fleet (`adrive --fleet ID`, or a `[fleet]` section): one
//! Zenoh session, the liveliness token `adrive/<id>` that says the vehicle is there,
//! and the thread `fleet/publish` that publishes its state under `adrive/<id>/state`
//! every [`PERIOD`] and within [`LOOK`] of a change the fleet watches for
//! ([`Change`]). An id another vehicle already announces on the network is refused at
//! start, before the vehicle is announced: two vehicles under one key space would be
//! one to whoever watches, and commands meant for one would reach both.
//!
//! The thread `fleet/ctl` answers the control socket's operations asked at
//! `adrive/<id>/ctl` (`adrive ctl --vehicle ID`), in the socket's own messages: the
//! status (the whole snapshot, the network's part included), and for every other
//! operation a refusal that says why. The member only reads the engine's snapshot: it
//! takes no command, and a query names one vehicle's key, so no vehicle answers
//! another's.

use super::keys;
use super::state::{compact, Change, LOOK, PERIOD};
use crate::config::FleetConfig;
use crate::engine::Gate;
use crate::net::NetStatus;
use crate::socket::proto::{Answer, Msg, Op, Request};
use crate::threads::{Group, StopSignal};
use crossbeam_channel::Receiver;
use std::sync::Arc;
use std::time::{Duration, Instant};
use zenoh::Wait;

/// How long the network is asked whether the id is taken.
const CLAIM: Duration = Duration::from_secs(2);
/// Operations waiting for `fleet/ctl` at most; past that a query goes unanswered.
const BACKLOG: usize = 64;
/// What every operation but the status is answered over the fleet.
pub(crate) const WATCH_ONLY: &str =
    "over the fleet a vehicle answers status only: commanding it from the fleet is not built yet";

/// The running member.
pub struct Member {
    session: zenoh::Session,
    threads: Group,
    id: String,
    token: Option<zenoh::liveliness::LivelinessToken>,
    /// The `ctl` queryable lives as long as the member.
    queryable: Option<zenoh::query::Queryable<()>>,
}

impl Member {
    /// Open the session, refuse an id already taken and announce the vehicle `vehicle`
    /// (its name): all that can fail, before the vehicle runs.
    pub fn join(c: &FleetConfig, vehicle: &str) -> anyhow::Result<Member> {
        let id = c.id_for(vehicle);
        let session = super::open(&super::Network {
            mode: c.mode,
            connect: &c.connect,
            listen: &c.listen,
            multicast_scouting: c.multicast_scouting,
        })?;
        let key = keys::token(&id);
        let replies = session
            .liveliness()
            .get(&key)
            .timeout(CLAIM)
            .wait()
            .map_err(|e| anyhow::anyhow!("fleet: asking whether {id} is taken: {e}"))?;
        if let Ok(reply) = replies.recv() {
            if reply.result().is_ok() {
                let _ = session.close().wait();
                anyhow::bail!(
                    "fleet: the id {id} is taken: another vehicle on the network announces \
                     {key} (give this one its own with --fleet ID or [fleet] id)"
                );
            }
        }
        let token = session
            .liveliness()
            .declare_token(&key)
            .wait()
            .map_err(|e| anyhow::anyhow!("fleet: liveliness token {key}: {e}"))?;
        tracing::info!(
            id = %id,
            mode = c.mode.as_str(),
            connect = ?c.connect,
            listen = ?c.listen,
            zid = %session.zid(),
            "fleet up: {key}"
        );
        Ok(Member {
            session,
            threads: Group::default(),
            id,
            token: Some(token),
            queryable: None,
        })
    }

    /// Start publishing the state of the vehicle `gate` keeps, and answering the
    /// status (with the network's part from `net`).
    pub fn publish(&mut self, gate: Arc<Gate>, net: Arc<NetStatus>) -> anyhow::Result<()> {
        let state_key = keys::state(&self.id);
        let publisher = self
            .session
            .declare_publisher(state_key.clone())
            .wait()
            .map_err(|e| anyhow::anyhow!("fleet: publisher {state_key}: {e}"))?;
        let ctl_key = keys::ctl(&self.id);
        let (tx, rx) = crossbeam_channel::bounded(BACKLOG);
        let queryable = self
            .session
            .declare_queryable(ctl_key.clone())
            .complete(true)
            .callback(move |q| {
                let _ = tx.try_send(q);
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("fleet: queryable {ctl_key}: {e}"))?;
        self.queryable = Some(queryable);
        let ctl = Ctl {
            gate: gate.clone(),
            net,
        };
        self.threads
            .spawn("fleet/ctl", move |stop| ctl.run(&rx, stop))?;
        let mut publish = Publish {
            gate,
            publisher,
            seq: 0,
            told: None,
        };
        self.threads.spawn("fleet/publish", move |stop| {
            crate::threads::every(LOOK, stop, || publish.turn(Instant::now()));
            // The last word: the state as it stops (disengaged, stopping).
            publish.tell();
        })?;
        Ok(())
    }

    /// The vehicle's id in the fleet.
    pub fn id(&self) -> &str {
        &self.id
    }

    pub fn thread_names(&self) -> Vec<&str> {
        self.threads.names()
    }
}

impl crate::threads::Shutdown for Member {
    /// Publish the last state, withdraw the token and close the session; returns the
    /// names of the threads that did not stop.
    fn shutdown(mut self, deadline: Duration) -> Vec<String> {
        let stuck = self.threads.stop(Instant::now() + deadline);
        if let Some(q) = self.queryable.take() {
            if let Err(e) = q.undeclare().wait() {
                tracing::debug!("fleet: withdrawing the queryable: {e}");
            }
        }
        if let Some(t) = self.token.take() {
            if let Err(e) = t.undeclare().wait() {
                tracing::debug!("fleet: withdrawing the token: {e}");
            }
        }
        if let Err(e) = self.session.close().wait() {
            tracing::debug!("fleet: closing the session: {e}");
        }
        stuck
    }
}

/// The `fleet/publish` thread's state.
struct Publish {
    gate: Arc<Gate>,
    publisher: zenoh::pubsub::Publisher<'static>,
    seq: u64,
    /// What was told last, and when.
    told: Option<(Change, Instant)>,
}

impl Publish {
    /// One look: tell the state when it changed, or when the period is up.
    fn turn(&mut self, now: Instant) {
        let due = self
            .told
            .as_ref()
            .is_none_or(|(_, at)| now.duration_since(*at) >= PERIOD);
        let snap = self.gate.snapshot(self.seq);
        let change = Change::of(&snap);
        if due || self.told.as_ref().is_some_and(|(c, _)| *c != change) {
            self.put(&snap);
            self.told = Some((change, now));
        }
    }

    /// Tell the state now.
    fn tell(&mut self) {
        let snap = self.gate.snapshot(self.seq);
        self.put(&snap);
    }

    fn put(&mut self, snap: &crate::snapshot::Snapshot) {
        let bytes = match serde_json::to_vec(&compact(snap)) {
            Ok(b) => b,
            Err(e) => return tracing::warn!("fleet: the state does not serialize: {e}"),
        };
        self.seq += 1;
        if let Err(e) = self.publisher.put(bytes).wait() {
            tracing::debug!("fleet: publishing the state: {e}");
        }
    }
}

/// The `fleet/ctl` thread's state.
struct Ctl {
    gate: Arc<Gate>,
    net: Arc<NetStatus>,
}

impl Ctl {
    fn run(&self, rx: &Receiver<zenoh::query::Query>, stop: &StopSignal) {
        while !stop.is_stopped() {
            match rx.recv_timeout(Duration::from_millis(50)) {
                Ok(q) => self.reply(&q),
                Err(crossbeam_channel::RecvTimeoutError::Timeout) => {}
                Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
            }
        }
    }

    /// Answer one query: a [`Request`] in, a [`Msg::Reply`] out, as over the socket.
    fn reply(&self, q: &zenoh::query::Query) {
        let payload = q.payload().map(|p| p.to_bytes().into_owned());
        let (id, answer) = match payload.as_deref().map(serde_json::from_slice::<Request>) {
            Some(Ok(r)) => (r.id, self.answer(r.op)),
            Some(Err(e)) => (0, Answer::Error(format!("not a request: {e}"))),
            None => (0, Answer::Error("not a request: no payload".into())),
        };
        let bytes = match serde_json::to_vec(&Msg::Reply { id, answer }) {
            Ok(b) => b,
            Err(e) => return tracing::warn!("fleet: a reply does not serialize: {e}"),
        };
        if let Err(e) = q.reply(q.key_expr().clone(), bytes).wait() {
            tracing::debug!("fleet: replying: {e}");
        }
    }

    fn answer(&self, op: Op) -> Answer {
        match op {
            Op::Status => {
                Answer::Snapshot(Box::new(crate::net::snapshot(&self.gate, &self.net, 0)))
            }
            _ => Answer::Error(WATCH_ONLY.into()),
        }
    }
}
