//! The node `adrive` in the ROS 2 graph: one Zenoh session, its liveliness tokens, the
//! report publishers and the command subscriptions, on two threads of its own:
//!
//! - `ros2/intake` takes every command message (Zenoh's callbacks only stamp it and
//!   hand it over), turns it into typed asks ([`bridge`]) and gives them, as the
//!   source [`Source::Ros2`], to the one intake every source goes through
//!   ([`Gate::admit`]): one commander across the console, UDP and ROS 2, the
//!   commander's watchdog (the network's `watchdog_timeout`), ranges, interlocks and
//!   the engage gate; refusals are counted by reason for the console's NETWORK panel.
//!   Within ROS 2, one actuation publisher (by GID) commands the engaged vehicle at a
//!   time. The latest gear, turn-indicator and hazard-light commands go in just before
//!   the next actuation message, so the stream the watchdog watches is the stream that
//!   moves the vehicle; an actuation stream whose stamp or sequence number stops
//!   advancing is frozen and feeds nothing. An emergency disengages. The control mode
//!   service engages (`AUTONOMOUS`) and disengages (`MANUAL`).
//! - `ros2/report` publishes the reports at `report_rate` and `/diagnostics` once a
//!   second, from the engine's snapshot.

use super::bridge::{self, VehicleMap};
use super::keys::{self, Attachment, Entity, Gid, NodeInfo, TypeInfo, DEFAULT_QOS};
use super::msgs::{self, mode, Message, Time};
use crate::config::{Ros2Config, VehicleConfig};
use crate::engine::Gate;
use crate::logging::RateLimit;
use crate::net::proto::BadDatagram;
use crate::net::{NetRefusal, NetStatus};
use crate::safety::gate_state::remote_may_engage;
use crate::safety::{Ask, Done, Refused};
use crate::threads::{Group, StopSignal};
use crate::value::Source;
use crossbeam_channel::{Receiver, Sender};
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};
use zenoh::Wait;

/// The node's name in the graph.
pub(crate) const NODE_NAME: &str = "adrive";

/// The topics and service of Autoware's vehicle interface, relative to the namespace.
pub mod topics {
    pub const ACTUATION_CMD: &str = "control/command/actuation_cmd";
    pub const GEAR_CMD: &str = "control/command/gear_cmd";
    pub const TURN_INDICATORS_CMD: &str = "control/command/turn_indicators_cmd";
    pub const HAZARD_LIGHTS_CMD: &str = "control/command/hazard_lights_cmd";
    pub const EMERGENCY_CMD: &str = "control/command/emergency_cmd";
    pub(crate) const CONTROL_MODE_REQUEST: &str = "control/control_mode_request";
    pub const STEERING_STATUS: &str = "vehicle/status/steering_status";
    pub const VELOCITY_STATUS: &str = "vehicle/status/velocity_status";
    pub const GEAR_STATUS: &str = "vehicle/status/gear_status";
    pub const CONTROL_MODE: &str = "vehicle/status/control_mode";
    pub const TURN_INDICATORS_STATUS: &str = "vehicle/status/turn_indicators_status";
    pub const HAZARD_LIGHTS_STATUS: &str = "vehicle/status/hazard_lights_status";
    pub const ACTUATION_STATUS: &str = "vehicle/status/actuation_status";
    pub const DIAGNOSTICS: &str = "diagnostics";
}

/// The Zenoh session's settings from `[ros2]`.
pub(crate) fn zenoh_config(c: &Ros2Config) -> anyhow::Result<zenoh::Config> {
    let mut z = zenoh::Config::default();
    let json = |v: &dyn erased::Json| v.json();
    let set = |z: &mut zenoh::Config, key: &str, value: String| {
        z.insert_json5(key, &value)
            .map_err(|e| anyhow::anyhow!("[ros2] {key} = {value}: {e}"))
    };
    set(&mut z, "mode", json(&c.mode.as_str()))?;
    set(&mut z, "connect/endpoints", json(&c.connect))?;
    set(&mut z, "listen/endpoints", json(&c.listen))?;
    set(
        &mut z,
        "scouting/multicast/enabled",
        json(&c.multicast_scouting),
    )?;
    Ok(z)
}

mod erased {
    /// A value as JSON, for the Zenoh configuration.
    pub(crate) trait Json {
        fn json(&self) -> String;
    }
    impl<T: serde::Serialize> Json for T {
        fn json(&self) -> String {
            serde_json::to_string(self).expect("plain values serialize")
        }
    }
}

/// A command message, stamped where it arrived.
enum Inbound {
    Sample {
        topic: Topic,
        payload: Vec<u8>,
        attachment: Option<Vec<u8>>,
        at: Instant,
    },
    ControlMode(zenoh::query::Query, Instant),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Topic {
    Actuation,
    Gear,
    TurnIndicators,
    HazardLights,
    Emergency,
}

/// One report publisher with its token's GID and sequence number.
struct Publisher {
    publisher: zenoh::pubsub::Publisher<'static>,
    gid: Gid,
    seq: i64,
}

impl Publisher {
    fn put<M: Message>(&mut self, m: &M) {
        self.seq += 1;
        let att = Attachment {
            sequence_number: self.seq,
            source_timestamp: keys::now_ns(),
            gid: self.gid,
        };
        let r = self
            .publisher
            .put(msgs::encode(m))
            .attachment(att.encode().to_vec())
            .wait();
        if let Err(e) = r {
            tracing::debug!("ros2: publish {}: {e}", M::TYPE.name);
        }
    }
}

/// The running node.
pub struct Node {
    session: zenoh::Session,
    closing: Arc<AtomicBool>,
    threads: Group,
    namespace: String,
    /// Liveliness tokens and subscriptions live as long as the node.
    _keep: Vec<Box<dyn std::any::Any + Send>>,
}

/// What the graph knows this node by.
struct Graph<'a> {
    session: &'a zenoh::Session,
    info: NodeInfo,
    namespace: String,
    next_id: u32,
    keep: Vec<Box<dyn std::any::Any + Send>>,
}

impl Graph<'_> {
    /// Announce an entity; returns its key expression and GID.
    fn announce(
        &mut self,
        entity: Entity,
        topic: &str,
        ty: &TypeInfo,
    ) -> anyhow::Result<(String, Gid)> {
        self.next_id += 1;
        let name = keys::qualified(&self.namespace, topic);
        let token = keys::token(
            &self.info,
            self.next_id,
            entity,
            Some((&name, ty, DEFAULT_QOS)),
        );
        let t = self
            .session
            .liveliness()
            .declare_token(token.clone())
            .wait()
            .map_err(|e| anyhow::anyhow!("ros2: liveliness token {token}: {e}"))?;
        self.keep.push(Box::new(t));
        Ok((
            keys::topic_key(self.info.domain, &name, ty),
            keys::gid(&token),
        ))
    }

    fn publisher<M: Message>(&mut self, topic: &str) -> anyhow::Result<Publisher> {
        let (key, gid) = self.announce(Entity::Publisher, topic, &M::TYPE)?;
        let publisher = self
            .session
            .declare_publisher(key.clone())
            .wait()
            .map_err(|e| anyhow::anyhow!("ros2: publisher {key}: {e}"))?;
        Ok(Publisher {
            publisher,
            gid,
            seq: 0,
        })
    }

    fn subscribe<M: Message>(
        &mut self,
        topic: &str,
        t: Topic,
        tx: &Sender<Inbound>,
    ) -> anyhow::Result<()> {
        let (key, _) = self.announce(Entity::Subscription, topic, &M::TYPE)?;
        let tx = tx.clone();
        let sub = self
            .session
            .declare_subscriber(key.clone())
            .callback(move |s| {
                let at = Instant::now();
                let _ = tx.try_send(Inbound::Sample {
                    topic: t,
                    payload: s.payload().to_bytes().into_owned(),
                    attachment: s.attachment().map(|a| a.to_bytes().into_owned()),
                    at,
                });
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("ros2: subscription {key}: {e}"))?;
        self.keep.push(Box::new(sub));
        Ok(())
    }
}

/// Commands waiting in the channel at most; a flood past that is dropped (and the
/// watchdog sees the commander's stream as it really arrives).
const BACKLOG: usize = 1024;

impl Node {
    /// Open the session, announce the node and start its threads. `net` is the UDP
    /// listener's status, which ROS 2 commands share.
    pub fn start(
        gate: Arc<Gate>,
        net: Arc<NetStatus>,
        config: &VehicleConfig,
    ) -> anyhow::Result<Node> {
        let c = &config.ros2;
        let session = zenoh::open(zenoh_config(c)?)
            .wait()
            .map_err(|e| anyhow::anyhow!("ros2: cannot open the Zenoh session: {e}"))?;
        let namespace = c.namespace_for(&config.vehicle.name);
        let info = NodeInfo {
            domain: c.domain_id,
            zid: session.zid().to_string(),
            node_id: 0,
            namespace: namespace.clone(),
            name: NODE_NAME.into(),
            enclave: "/".into(),
        };
        let node_token = keys::token(&info, 0, Entity::Node, None);
        let mut g = Graph {
            session: &session,
            info,
            namespace: namespace.clone(),
            next_id: 0,
            keep: Vec::new(),
        };
        let t = session
            .liveliness()
            .declare_token(node_token.clone())
            .wait()
            .map_err(|e| anyhow::anyhow!("ros2: liveliness token {node_token}: {e}"))?;
        g.keep.push(Box::new(t));

        let map = VehicleMap::new(config, c);
        let (tx, rx) = crossbeam_channel::bounded(BACKLOG);
        use topics::*;
        g.subscribe::<msgs::ActuationCommandStamped>(ACTUATION_CMD, Topic::Actuation, &tx)?;
        g.subscribe::<msgs::GearCommand>(GEAR_CMD, Topic::Gear, &tx)?;
        g.subscribe::<msgs::VehicleEmergencyStamped>(EMERGENCY_CMD, Topic::Emergency, &tx)?;
        if map.has_turn_indicators() {
            g.subscribe::<msgs::TurnIndicatorsCommand>(
                TURN_INDICATORS_CMD,
                Topic::TurnIndicators,
                &tx,
            )?;
        }
        if map.has_hazard_lights() {
            g.subscribe::<msgs::HazardLightsCommand>(HAZARD_LIGHTS_CMD, Topic::HazardLights, &tx)?;
        }
        let (key, _) = g.announce(
            Entity::Service,
            CONTROL_MODE_REQUEST,
            &msgs::CONTROL_MODE_COMMAND,
        )?;
        let qtx = tx.clone();
        let q = session
            .declare_queryable(key.clone())
            .complete(true)
            .callback(move |q| {
                let _ = qtx.try_send(Inbound::ControlMode(q, Instant::now()));
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("ros2: service {key}: {e}"))?;
        g.keep.push(Box::new(q));

        let mut reports = Reporters {
            steering: g.publisher::<msgs::SteeringReport>(STEERING_STATUS)?,
            velocity: g.publisher::<msgs::VelocityReport>(VELOCITY_STATUS)?,
            gear: g.publisher::<msgs::GearReport>(GEAR_STATUS)?,
            control_mode: g.publisher::<msgs::ControlModeReport>(CONTROL_MODE)?,
            actuation: g.publisher::<msgs::ActuationStatusStamped>(ACTUATION_STATUS)?,
            turn_indicators: if map.has_turn_indicators() {
                Some(g.publisher::<msgs::TurnIndicatorsReport>(TURN_INDICATORS_STATUS)?)
            } else {
                None
            },
            hazard_lights: if map.has_hazard_lights() {
                Some(g.publisher::<msgs::HazardLightsReport>(HAZARD_LIGHTS_STATUS)?)
            } else {
                None
            },
            diagnostics: g.publisher::<msgs::DiagnosticArray>(DIAGNOSTICS)?,
        };
        let keep = std::mem::take(&mut g.keep);
        drop(g);

        let closing = Arc::new(AtomicBool::new(false));
        let mut threads = Group::default();
        // The allow-list and the key are the UDP listener's; Zenoh has its own access
        // control and transport security. Engaging follows `allow_engage`, as for UDP.
        let mut commands = Commands {
            allow_engage: config.network.allow_engage,
            closing: closing.clone(),
            gate: gate.clone(),
            net,
            map: map.clone(),
            commander: None,
            last: None,
            pending: Vec::new(),
            log: RateLimit::new(10),
        };
        threads.spawn("ros2/intake", move |stop| commands.run(&rx, stop))?;
        let period = Duration::from_secs_f64(1.0 / c.report_rate);
        let per_diag = (c.report_rate.round() as u64).max(1);
        threads.spawn("ros2/report", move |stop| {
            let mut tick = 0u64;
            crate::threads::every(period, stop, || {
                let snap = gate.snapshot(tick);
                reports.publish(&map, &snap, tick.is_multiple_of(per_diag));
                tick += 1;
            })
        })?;
        tracing::info!(
            namespace = %namespace,
            domain = c.domain_id,
            mode = c.mode.as_str(),
            connect = ?c.connect,
            listen = ?c.listen,
            zid = %session.zid(),
            "ros2 up: node {}",
            keys::qualified(&namespace, NODE_NAME)
        );
        Ok(Node {
            session,
            closing,
            threads,
            namespace,
            _keep: keep,
        })
    }

    /// The namespace the node's topics are under.
    pub fn namespace(&self) -> &str {
        &self.namespace
    }

    pub fn thread_names(&self) -> Vec<&str> {
        self.threads.names()
    }

    /// Refuse every command from now on (the first step of shutting down).
    pub fn close(&self) {
        self.closing.store(true, Relaxed);
    }
}

impl crate::threads::Shutdown for Node {
    /// Stop the threads, withdraw the tokens and close the session; returns the names
    /// of the threads that did not stop.
    fn shutdown(mut self, deadline: Duration) -> Vec<String> {
        self.close();
        let stuck = self.threads.stop(Instant::now() + deadline);
        self._keep.clear();
        if let Err(e) = self.session.close().wait() {
            tracing::debug!("ros2: closing the session: {e}");
        }
        stuck
    }
}

struct Reporters {
    steering: Publisher,
    velocity: Publisher,
    gear: Publisher,
    control_mode: Publisher,
    actuation: Publisher,
    turn_indicators: Option<Publisher>,
    hazard_lights: Option<Publisher>,
    diagnostics: Publisher,
}

impl Reporters {
    fn publish(&mut self, map: &VehicleMap, snap: &crate::snapshot::Snapshot, diagnostics: bool) {
        let stamp = Time::now();
        let r = map.reports(snap, stamp);
        if let Some(m) = &r.steering {
            self.steering.put(m);
        }
        if let Some(m) = &r.velocity {
            self.velocity.put(m);
        }
        if let Some(m) = &r.gear {
            self.gear.put(m);
        }
        self.control_mode.put(&r.control_mode);
        self.actuation.put(&r.actuation);
        if let (Some(p), Some(m)) = (&mut self.turn_indicators, &r.turn_indicators) {
            p.put(m);
        }
        if let (Some(p), Some(m)) = (&mut self.hazard_lights, &r.hazard_lights) {
            p.put(m);
        }
        if diagnostics {
            self.diagnostics.put(&bridge::diagnostics(snap, stamp));
        }
    }
}

/// The last actuation message: whose, its sequence number and stamp.
#[derive(Clone, Copy)]
struct Last {
    gid: Gid,
    seq: i64,
    stamp: Time,
}

/// The `ros2/intake` thread's state.
struct Commands {
    allow_engage: bool,
    /// adrive is shutting down: nothing more is handed to the intake.
    closing: Arc<AtomicBool>,
    gate: Arc<Gate>,
    net: Arc<NetStatus>,
    map: VehicleMap,
    /// The actuation publisher commanding the engaged vehicle.
    commander: Option<Gid>,
    last: Option<Last>,
    /// The latest gear, turn indicator and hazard light asks, for the next actuation.
    pending: Vec<(Topic, Ask)>,
    log: RateLimit,
}

impl Commands {
    fn run(&mut self, rx: &Receiver<Inbound>, stop: &StopSignal) {
        while !stop.is_stopped() {
            match rx.recv_timeout(Duration::from_millis(50)) {
                Ok(Inbound::Sample {
                    topic,
                    payload,
                    attachment,
                    at,
                }) => self.sample(topic, &payload, attachment.as_deref(), at),
                Ok(Inbound::ControlMode(q, at)) => self.control_mode(&q, at),
                Err(crossbeam_channel::RecvTimeoutError::Timeout) => {}
                Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
            }
        }
    }

    /// Hand one ask to the one intake, as ROS 2's; log what it refused. Returns
    /// whether it was admitted.
    fn submit(&mut self, ask: Ask, at: Instant) -> bool {
        if self.closing.load(Relaxed) {
            return false;
        }
        if ask == Ask::Engage && !remote_may_engage(self.allow_engage, self.gate.is_engaged()) {
            self.net.count_refusal(NetRefusal::EngageNotAllowed);
            if self.log.allow(at) {
                tracing::warn!(
                    "ros2: refused engage: {}",
                    NetRefusal::EngageNotAllowed.describe()
                );
            }
            return false;
        }
        match self.gate.admit(Source::Ros2, ask, at) {
            Ok(
                done @ (Done::Engaged | Done::Commanding | Done::Disengaged(_) | Done::Released),
            ) => {
                tracing::info!("ros2: {}: {done}", self.gate.ask_text(ask));
                true
            }
            Ok(_) => true,
            Err(why) => {
                match &why {
                    Refused::Owner(_) => self.net.count_refusal(NetRefusal::OtherCommander),
                    Refused::Rule(r) => self.net.count_intake(*r),
                    Refused::Blocked(_) => self.net.count_refusal(NetRefusal::EngageBlocked),
                    Refused::Clear(_) | Refused::Unanswered(_) => {}
                }
                if self.log.allow(at) {
                    tracing::warn!("ros2: refused {}: {why}", self.gate.ask_text(ask));
                }
                false
            }
        }
    }

    fn reject(&mut self, r: BadDatagram, what: &str, at: Instant) {
        self.net.count_reject(r);
        if self.log.allow(at) {
            tracing::warn!("ros2: rejected {what}: {}", r.describe());
        }
    }

    fn sample(&mut self, topic: Topic, payload: &[u8], attachment: Option<&[u8]>, at: Instant) {
        let unmapped = |r: Result<Option<Ask>, bridge::Unmapped>, me: &mut Commands| match r {
            Ok(Some(ask)) => {
                me.pending.retain(|(t, _)| *t != topic);
                me.pending.push((topic, ask));
            }
            Ok(None) => {}
            Err(e) => {
                if me.log.allow(at) {
                    tracing::warn!("ros2: {topic:?} command ignored: {e}");
                }
            }
        };
        match topic {
            Topic::Actuation => self.actuation(payload, attachment, at),
            Topic::Gear => match msgs::decode::<msgs::GearCommand>(payload) {
                Ok(m) => unmapped(self.map.gear(m.command), self),
                Err(e) => self.reject(BadDatagram::BadSyntax, &e, at),
            },
            Topic::TurnIndicators => match msgs::decode::<msgs::TurnIndicatorsCommand>(payload) {
                Ok(m) => unmapped(self.map.turn_indicators(m.command), self),
                Err(e) => self.reject(BadDatagram::BadSyntax, &e, at),
            },
            Topic::HazardLights => match msgs::decode::<msgs::HazardLightsCommand>(payload) {
                Ok(m) => unmapped(self.map.hazard_lights(m.command), self),
                Err(e) => self.reject(BadDatagram::BadSyntax, &e, at),
            },
            Topic::Emergency => match msgs::decode::<msgs::VehicleEmergencyStamped>(payload) {
                Ok(m) if m.emergency => {
                    tracing::warn!("ros2: emergency command: safe state");
                    self.submit(Ask::Disengage, at);
                }
                Ok(_) => {}
                Err(e) => self.reject(BadDatagram::BadSyntax, &e, at),
            },
        }
    }

    fn actuation(&mut self, payload: &[u8], attachment: Option<&[u8]>, at: Instant) {
        let m = match msgs::decode::<msgs::ActuationCommandStamped>(payload) {
            Ok(m) => m,
            Err(e) => return self.reject(BadDatagram::BadSyntax, &e, at),
        };
        let Some(att) = attachment.and_then(|a| Attachment::decode(a).ok()) else {
            return self.reject(
                BadDatagram::MissingSeq,
                "actuation without an rmw attachment",
                at,
            );
        };
        if !self.gate.is_engaged() {
            self.commander = None;
        }
        if let Some(c) = self.commander {
            if c != att.gid {
                self.net.count_refusal(NetRefusal::OtherCommander);
                if self.log.allow(at) {
                    tracing::warn!(
                        "ros2: refused actuation: {} (another actuation publisher)",
                        NetRefusal::OtherCommander.describe()
                    );
                }
                return;
            }
        }
        // A stream whose stamp (or sequence number) stops advancing is frozen: alive,
        // but nothing it sends is valid, and the commander's watchdog keeps counting.
        let frozen = self.last.is_some_and(|l| {
            l.gid == att.gid
                && (l.seq == att.sequence_number
                    || (!m.header.stamp.is_zero() && l.stamp == m.header.stamp))
        });
        self.last = Some(Last {
            gid: att.gid,
            seq: att.sequence_number,
            stamp: m.header.stamp,
        });
        if frozen {
            self.net.count_reject(BadDatagram::Replayed);
            self.gate.frozen(Source::Ros2);
            if self.log.allow(at) {
                tracing::warn!("ros2: rejected actuation: its stamp stopped advancing");
            }
            return;
        }
        // The gear first: a shift is asked while the brake still holds, and `accel`
        // after it waits for the shift (as `trans drive accel 0.3` does over UDP).
        let pending = std::mem::take(&mut self.pending);
        for (_, ask) in pending {
            self.submit(ask, at);
        }
        for ask in self.map.actuation(&m.actuation) {
            self.submit(ask, at);
        }
        if self.gate.commander() == Some(Source::Ros2) && self.commander.is_none() {
            self.commander = Some(att.gid);
        }
    }

    fn control_mode(&mut self, q: &zenoh::query::Query, at: Instant) {
        let request = q
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default();
        let att = q
            .attachment()
            .and_then(|a| Attachment::decode(&a.to_bytes()).ok());
        let success = match msgs::decode::<msgs::ControlModeRequest>(&request) {
            Ok(r) => match r.mode {
                mode::AUTONOMOUS => {
                    self.submit(Ask::Engage, at);
                    self.gate.commander() == Some(Source::Ros2)
                }
                mode::MANUAL => {
                    self.submit(Ask::Disengage, at);
                    true
                }
                mode::NO_COMMAND => true,
                other => {
                    tracing::warn!("ros2: control mode {other} refused: adrive engages fully (AUTONOMOUS) or not (MANUAL)");
                    false
                }
            },
            Err(e) => {
                self.reject(BadDatagram::BadSyntax, &e, at);
                false
            }
        };
        let reply = msgs::encode(&msgs::ControlModeResponse { success });
        let mut r = q.reply(q.key_expr().clone(), reply);
        if let Some(a) = att {
            let back = Attachment {
                source_timestamp: keys::now_ns(),
                ..a
            };
            r = r.attachment(back.encode().to_vec());
        }
        if let Err(e) = r.wait() {
            tracing::warn!("ros2: control mode reply: {e}");
        }
    }
}
