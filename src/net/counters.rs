//! What the network side publishes for the console, the broadcast and the headless
//! summary: counters as atomics, and the small per-sender table behind a
//! `parking_lot::Mutex` that the listener and the watchdog hold only for the few
//! microseconds one datagram or one tick takes. [`NetStatus::snapshot`] copies it all
//! into a plain [`NetView`]; readers never block the listener for longer.

use super::proto::{BadDatagram, BadDatagramCounts};
use crate::safety;
use crate::snapshot::{NetView, Pairs, Rejections, SenderView};
use crate::value::DeviceId;
use parking_lot::Mutex;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::{Duration, Instant};

/// The most senders remembered; the least recently seen one (never the commander)
/// makes room for a new one.
pub(crate) const MAX_SENDERS: usize = 16;

/// Why the listener refused a well-formed, authentic datagram (or one of its commands).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NetRefusal {
    /// The sender is not on the `allow` list (no reply is sent).
    NotOnAllowList,
    /// Another sender is commanding the vehicle.
    OtherCommander,
    /// The vehicle file does not let the network engage (`allow_engage = false`).
    EngageNotAllowed,
    /// Engaging is blocked right now (a faulty device, the e-stop…).
    EngageBlocked,
    /// The sender was disengaged against its will (watchdog, console, fault) and keeps
    /// asking to engage: it must first send a datagram without `engage`.
    EngageLatched,
    /// adrive is shutting down.
    Closing,
}

impl NetRefusal {
    pub const ALL: [NetRefusal; 6] = [
        NetRefusal::NotOnAllowList,
        NetRefusal::OtherCommander,
        NetRefusal::EngageNotAllowed,
        NetRefusal::EngageBlocked,
        NetRefusal::EngageLatched,
        NetRefusal::Closing,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            NetRefusal::NotOnAllowList => "not_on_allow_list",
            NetRefusal::OtherCommander => "other_commander",
            NetRefusal::EngageNotAllowed => "engage_not_allowed",
            NetRefusal::EngageBlocked => "engage_blocked",
            NetRefusal::EngageLatched => "engage_latched",
            NetRefusal::Closing => "closing",
        }
    }

    pub fn describe(self) -> &'static str {
        match self {
            NetRefusal::NotOnAllowList => "the sender is not on the allow list",
            NetRefusal::OtherCommander => "another sender is commanding the vehicle",
            NetRefusal::EngageNotAllowed => "this vehicle does not allow engaging from the network",
            NetRefusal::EngageBlocked => "engaging is blocked",
            NetRefusal::EngageLatched => {
                "disengaged while this sender commanded; send a datagram without engage first"
            }
            NetRefusal::Closing => "adrive is shutting down",
        }
    }

    pub fn index(self) -> usize {
        self as usize
    }

    /// Whether it refuses a whole datagram (the datagram is not accepted), rather than
    /// one `engage` within an accepted one.
    pub fn refuses_datagram(self) -> bool {
        match self {
            NetRefusal::NotOnAllowList | NetRefusal::OtherCommander | NetRefusal::Closing => true,
            NetRefusal::EngageNotAllowed
            | NetRefusal::EngageBlocked
            | NetRefusal::EngageLatched => false,
        }
    }

    /// The refusal named `name` ([`NetRefusal::as_str`]).
    pub fn named(name: &str) -> Option<NetRefusal> {
        NetRefusal::ALL.into_iter().find(|r| r.as_str() == name)
    }
}

/// One sender in the table.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sender {
    pub addr: SocketAddr,
    pub(crate) last_seen: Instant,
    pub datagrams: u64,
    pub accepted: u64,
    pub rejected: u64,
    /// Its last `seq`.
    pub seq: Option<u64>,
    /// The last datagram repeated the counter: alive but frozen.
    pub stale: bool,
    /// Disengaged against its will; its `engage` is refused until it sends a datagram
    /// without one (or stays quiet for the watchdog timeout).
    pub latched: bool,
    pub(crate) last_reply: Option<Instant>,
}

impl Sender {
    fn new(addr: SocketAddr, now: Instant) -> Sender {
        Sender {
            addr,
            last_seen: now,
            datagrams: 0,
            accepted: 0,
            rejected: 0,
            seq: None,
            stale: false,
            latched: false,
            last_reply: None,
        }
    }
}

/// The state the listener and the watchdog share, under one short-held lock.
pub(crate) struct Inner {
    pub senders: [Option<Sender>; MAX_SENDERS],
    /// The sender this listener last saw command the engaged vehicle (the gate says
    /// who commands; this remembers whose command ended, to latch it).
    pub commanding: Option<SocketAddr>,
    /// With a key: the last `seq` accepted (replay protection is per key).
    pub(crate) keyed_seq: Option<u64>,
    /// Global reply budget: (window start, replies in it).
    pub replies: (Instant, u32),
}

impl Inner {
    /// The table slot of `addr`, inserted if new (evicting the least recently seen
    /// sender that is not the commander).
    pub(crate) fn sender(&mut self, addr: SocketAddr, now: Instant) -> usize {
        if let Some(i) = self
            .senders
            .iter()
            .position(|s| s.is_some_and(|s| s.addr == addr))
        {
            return i;
        }
        let i = match self.senders.iter().position(Option::is_none) {
            Some(i) => i,
            None => {
                let commander = self.commanding;
                self.senders
                    .iter()
                    .enumerate()
                    .filter(|(_, s)| s.is_some_and(|s| Some(s.addr) != commander))
                    .min_by_key(|(_, s)| s.map(|s| s.last_seen))
                    .map(|(i, _)| i)
                    .unwrap_or(0)
            }
        };
        self.senders[i] = Some(Sender::new(addr, now));
        i
    }

    pub(crate) fn get(&mut self, i: usize) -> &mut Sender {
        self.senders[i].as_mut().expect("slot filled by sender()")
    }

    pub(crate) fn find(&mut self, addr: SocketAddr) -> Option<&mut Sender> {
        self.senders.iter_mut().flatten().find(|s| s.addr == addr)
    }
}

/// Published by the network threads; read by anyone without blocking them.
pub struct NetStatus {
    /// The address the listener is bound to.
    pub listen: SocketAddr,
    pub watchdog_timeout: Duration,
    pub(crate) inner: Mutex<Inner>,
    /// Datagrams rejected whole, by reason (grammar, authentication, counter).
    pub(crate) rejects: BadDatagramCounts,
    intake: [AtomicU64; safety::Reject::ALL.len()],
    refused: [AtomicU64; NetRefusal::ALL.len()],
    /// Network commands accepted, by device.
    commands: Vec<AtomicU64>,
    /// The devices' names, by id.
    names: Vec<String>,
    accel: AtomicU64,
    datagrams: AtomicU64,
    accepted: AtomicU64,
}

impl NetStatus {
    /// The network's status for `vehicle`: a command count for each of its devices, by
    /// name.
    pub fn of(
        vehicle: &crate::vehicle::Vehicle,
        listen: SocketAddr,
        watchdog_timeout: Duration,
    ) -> NetStatus {
        let names = vehicle
            .devices()
            .iter()
            .map(|d| d.name().to_string())
            .collect();
        NetStatus::new(listen, watchdog_timeout, names)
    }

    pub fn new(listen: SocketAddr, watchdog_timeout: Duration, devices: Vec<String>) -> NetStatus {
        let now = Instant::now();
        NetStatus {
            listen,
            watchdog_timeout,
            inner: Mutex::new(Inner {
                senders: [None; MAX_SENDERS],
                commanding: None,
                keyed_seq: None,
                replies: (now, 0),
            }),
            rejects: BadDatagramCounts::new(),
            intake: Default::default(),
            refused: Default::default(),
            commands: devices.iter().map(|_| AtomicU64::new(0)).collect(),
            names: devices,
            accel: AtomicU64::new(0),
            datagrams: AtomicU64::new(0),
            accepted: AtomicU64::new(0),
        }
    }

    pub(crate) fn count_datagram(&self) {
        self.datagrams.fetch_add(1, Relaxed);
    }
    pub(crate) fn count_accepted(&self) {
        self.accepted.fetch_add(1, Relaxed);
    }
    pub(crate) fn count_reject(&self, r: BadDatagram) {
        self.rejects.incr(r);
    }
    pub(crate) fn count_intake(&self, r: safety::Reject) {
        self.intake[r.index()].fetch_add(1, Relaxed);
    }
    pub(crate) fn count_refusal(&self, r: NetRefusal) {
        self.refused[r.index()].fetch_add(1, Relaxed);
    }
    pub(crate) fn count_command(&self, id: DeviceId) {
        if let Some(c) = self.commands.get(id.index()) {
            c.fetch_add(1, Relaxed);
        }
    }
    pub(crate) fn count_accel(&self) {
        self.accel.fetch_add(1, Relaxed);
    }

    /// Datagrams received so far.
    pub(crate) fn datagrams(&self) -> u64 {
        self.datagrams.load(Relaxed)
    }

    /// Commands accepted so far, each device's by its index, then `accel`'s.
    pub(crate) fn each_command_count(&self, mut f: impl FnMut(usize, u64)) {
        for (i, c) in self.commands.iter().chain([&self.accel]).enumerate() {
            f(i, c.load(Relaxed));
        }
    }

    /// Refusals of one kind so far.
    pub fn refusals(&self, r: NetRefusal) -> u64 {
        self.refused[r.index()].load(Relaxed)
    }

    /// Network commands refused at intake (interlocks, disengaged…) for one reason.
    pub fn intake_rejections(&self, r: safety::Reject) -> u64 {
        self.intake[r.index()].load(Relaxed)
    }

    /// A plain copy of everything, for the snapshot, as of what `gate` says now: which
    /// sender commands, and whose command has ended (latched).
    pub fn snapshot(&self, gate: &crate::engine::Gate) -> NetView {
        let now = Instant::now();
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        let commander = super::commanding(gate);
        let mut inner = self.inner.lock();
        super::intake::sync(gate, &mut inner);
        let mut senders: Vec<SenderView> = inner
            .senders
            .iter()
            .flatten()
            .map(|s| SenderView {
                addr: s.addr,
                age_ms: ms(now.saturating_duration_since(s.last_seen)),
                seq: s.seq,
                datagrams: s.datagrams,
                accepted: s.accepted,
                rejected: s.rejected,
                commanding: commander == Some(s.addr),
                frozen: s.stale,
                latched: s.latched,
            })
            .collect();
        drop(inner);
        senders.sort_by(|a, b| a.age_ms.total_cmp(&b.age_ms));
        let named = |pairs: Vec<(&str, u64)>| -> Pairs<u64> {
            pairs.into_iter().map(|(n, c)| (n.to_string(), c)).collect()
        };
        NetView {
            listen: self.listen,
            datagrams: self.datagrams.load(Relaxed),
            accepted: self.accepted.load(Relaxed),
            senders,
            commands: self
                .names
                .iter()
                .zip(&self.commands)
                .map(|(n, c)| (n.clone(), c.load(Relaxed)))
                .chain([("accel".to_string(), self.accel.load(Relaxed))])
                .collect(),
            rejected: Rejections {
                datagram: named(self.rejects.iter().collect()),
                intake: named(
                    safety::Reject::ALL
                        .iter()
                        .map(|r| (r.as_str(), self.intake[r.index()].load(Relaxed)))
                        .collect(),
                ),
                refused: named(
                    NetRefusal::ALL
                        .iter()
                        .map(|r| (r.as_str(), self.refused[r.index()].load(Relaxed)))
                        .collect(),
                ),
            },
            foxglove: gate.vehicle().tap().live(),
        }
    }
}
