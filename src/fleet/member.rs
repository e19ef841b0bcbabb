//! A running adrive in the fleet (`adrive --fleet ID`, or a `[fleet]` section): one
//! Zenoh session, the liveliness token `adrive/<id>` that says the vehicle is there,
//! and the thread `fleet/publish` that publishes its state under `adrive/<id>/state`
//! every [`PERIOD`] and within [`LOOK`] of a change the fleet watches for
//! ([`Change`]). An id another vehicle already announces on the network is refused at
//! start, before the vehicle is announced: two vehicles under one key space would be
//! one to whoever watches, and commands meant for one would reach both.
//!
//! Once the control socket runs, [`Member::serve`] takes links from the fleet to it
//! ([`super::serve`]): consoles and operators' commands from elsewhere, as clients of
//! the socket, under its rules and the fleet's (who may command).

use super::keys;
use super::state::{compact, Change, LOOK, PERIOD};
use crate::config::FleetConfig;
use crate::engine::Gate;
use crate::threads::Group;
use std::sync::Arc;
use std::time::{Duration, Instant};
use zenoh::Wait;

/// How long the network is asked whether the id is taken.
const CLAIM: Duration = Duration::from_secs(2);

/// The running member.
pub struct Member {
    session: zenoh::Session,
    threads: Group,
    id: String,
    token: Option<zenoh::liveliness::LivelinessToken>,
    /// Whether links may command ([`FleetConfig::command`]).
    command: bool,
    /// The links' subscriptions live as long as the member.
    links: Option<super::serve::Subscriptions>,
    /// Answers pings (`adrive fleet`'s round-trip time) as long as the member lives.
    ping: Option<zenoh::query::Queryable<()>>,
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
            command: c.command,
            links: None,
            ping: None,
        })
    }

    /// Start publishing the state of the vehicle `gate` keeps.
    pub fn publish(&mut self, gate: Arc<Gate>) -> anyhow::Result<()> {
        let state_key = keys::state(&self.id);
        let publisher = self
            .session
            .declare_publisher(state_key.clone())
            .wait()
            .map_err(|e| anyhow::anyhow!("fleet: publisher {state_key}: {e}"))?;
        let mut publish = Publish {
            gate,
            publisher,
            seq: 0,
            told: None,
        };
        // A ping is answered at once by a thread of its own, whatever else the member
        // does: what `adrive fleet` times is the network and the router.
        let ping_key = keys::ping(&self.id);
        let (tx, rx) = crossbeam_channel::bounded::<zenoh::query::Query>(64);
        let me = zenoh::key_expr::KeyExpr::try_from(ping_key.clone())
            .map_err(|e| anyhow::anyhow!("fleet: {ping_key}: {e}"))?;
        let ping = self
            .session
            .declare_queryable(ping_key.clone())
            .callback(move |q| {
                let _ = tx.try_send(q);
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("fleet: queryable {ping_key}: {e}"))?;
        // Answered under its own key, which names the vehicle (the question's may be
        // every vehicle's, `adrive/*/ping`).
        self.threads.spawn("fleet/ping", move |stop| {
            while !stop.is_stopped() {
                if let Ok(q) = rx.recv_timeout(LOOK) {
                    let _ = q.reply(me.clone(), Vec::<u8>::new()).wait();
                }
            }
        })?;
        self.ping = Some(ping);
        self.threads.spawn("fleet/publish", move |stop| {
            crate::threads::every(LOOK, stop, || publish.turn(Instant::now()));
            // The last word: the state as it stops (disengaged, stopping).
            publish.tell();
        })?;
        Ok(())
    }

    /// Take links from the fleet to the control socket behind `door`; `key` is the
    /// vehicle's (`[network] key_file`), which a link proves to command.
    pub(crate) fn serve(
        &mut self,
        door: crate::socket::server::Door,
        key: Option<crate::net::auth::Auth>,
    ) -> anyhow::Result<()> {
        let rule = super::serve::Rule {
            key,
            command: self.command,
        };
        let subs = super::serve::start(&self.session, &self.id, door, rule, &mut self.threads)?;
        self.links = Some(subs);
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
        drop(self.links.take());
        drop(self.ping.take());
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
