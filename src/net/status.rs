//! What the network side publishes for the console, the broadcast and the headless
//! summary: counters as atomics, and the small per-sender table behind a
//! `parking_lot::Mutex` that the listener and the watchdog hold only for the few
//! microseconds one datagram or one tick takes. [`NetStatus::snapshot`] copies it all
//! into a plain [`NetSnapshot`]; readers never block the listener for longer.

use super::proto::{Reject, RejectCounts};
use crate::interlock;
use crate::value::Role;
use parking_lot::Mutex;
use serde::Serialize;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::{Duration, Instant};

/// The most senders remembered; the least recently seen one (never the commander)
/// makes room for a new one.
pub const MAX_SENDERS: usize = 16;

/// Why the listener refused a well-formed, authentic datagram (or one of its commands).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
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

impl Refusal {
    pub const ALL: [Refusal; 6] = [
        Refusal::NotOnAllowList,
        Refusal::OtherCommander,
        Refusal::EngageNotAllowed,
        Refusal::EngageBlocked,
        Refusal::EngageLatched,
        Refusal::Closing,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Refusal::NotOnAllowList => "not_on_allow_list",
            Refusal::OtherCommander => "other_commander",
            Refusal::EngageNotAllowed => "engage_not_allowed",
            Refusal::EngageBlocked => "engage_blocked",
            Refusal::EngageLatched => "engage_latched",
            Refusal::Closing => "closing",
        }
    }

    pub fn describe(self) -> &'static str {
        match self {
            Refusal::NotOnAllowList => "the sender is not on the allow list",
            Refusal::OtherCommander => "another sender is commanding the vehicle",
            Refusal::EngageNotAllowed => "this vehicle does not allow engaging from the network",
            Refusal::EngageBlocked => "engaging is blocked",
            Refusal::EngageLatched => {
                "disengaged while this sender commanded; send a datagram without engage first"
            }
            Refusal::Closing => "adrive is shutting down",
        }
    }

    pub fn index(self) -> usize {
        self as usize
    }
}

/// The watchdog, as shown to people.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum WatchdogState {
    /// Disengaged.
    Off,
    /// Engaged (from the console) with no network sender commanding yet.
    Idle,
    /// Engaged and a network sender commands: it must keep sending.
    Armed,
    /// It brought the vehicle to the safe state; stays so until the next engage.
    Tripped,
}

/// One sender in the table.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sender {
    pub addr: SocketAddr,
    pub last_seen: Instant,
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
    pub last_reply: Option<Instant>,
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
    /// The network sender commanding the engaged vehicle.
    pub commander: Option<SocketAddr>,
    /// The commander's last valid datagram (what the watchdog watches).
    pub last_valid: Option<Instant>,
    /// With a key: the last `seq` accepted (replay protection is per key).
    pub keyed_seq: Option<u64>,
    pub watchdog: WatchdogState,
    /// Why the watchdog last tripped.
    pub last_trip: Option<String>,
    /// Global reply budget: (window start, replies in it).
    pub replies: (Instant, u32),
}

impl Inner {
    /// The table slot of `addr`, inserted if new (evicting the least recently seen
    /// sender that is not the commander).
    pub fn sender(&mut self, addr: SocketAddr, now: Instant) -> usize {
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
                let commander = self.commander;
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

    pub fn get(&mut self, i: usize) -> &mut Sender {
        self.senders[i].as_mut().expect("slot filled by sender()")
    }

    pub fn find(&mut self, addr: SocketAddr) -> Option<&mut Sender> {
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
    pub rejects: RejectCounts,
    intake: [AtomicU64; interlock::Reject::ALL.len()],
    refused: [AtomicU64; Refusal::ALL.len()],
    commands: [AtomicU64; Role::ALL.len()],
    accel: AtomicU64,
    datagrams: AtomicU64,
    accepted: AtomicU64,
}

impl NetStatus {
    pub fn new(listen: SocketAddr, watchdog_timeout: Duration) -> NetStatus {
        let now = Instant::now();
        NetStatus {
            listen,
            watchdog_timeout,
            inner: Mutex::new(Inner {
                senders: [None; MAX_SENDERS],
                commander: None,
                last_valid: None,
                keyed_seq: None,
                watchdog: WatchdogState::Off,
                last_trip: None,
                replies: (now, 0),
            }),
            rejects: RejectCounts::new(),
            intake: Default::default(),
            refused: Default::default(),
            commands: Default::default(),
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
    pub(crate) fn count_reject(&self, r: Reject) {
        self.rejects.incr(r);
    }
    pub(crate) fn count_intake(&self, r: interlock::Reject) {
        self.intake[r.index()].fetch_add(1, Relaxed);
    }
    pub(crate) fn count_refusal(&self, r: Refusal) {
        self.refused[r.index()].fetch_add(1, Relaxed);
    }
    pub(crate) fn count_command(&self, role: Role) {
        if let Some(i) = Role::ALL.iter().position(|r| *r == role) {
            self.commands[i].fetch_add(1, Relaxed);
        }
    }
    pub(crate) fn count_accel(&self) {
        self.accel.fetch_add(1, Relaxed);
    }

    /// Refusals of one kind so far.
    pub fn refusals(&self, r: Refusal) -> u64 {
        self.refused[r.index()].load(Relaxed)
    }

    /// Network commands refused at intake (interlocks, disengaged…) for one reason.
    pub fn intake_rejections(&self, r: interlock::Reject) -> u64 {
        self.intake[r.index()].load(Relaxed)
    }

    /// A plain copy of everything, for display.
    pub fn snapshot(&self) -> NetSnapshot {
        let now = Instant::now();
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        let inner = self.inner.lock();
        let mut senders: Vec<SenderSnapshot> = inner
            .senders
            .iter()
            .flatten()
            .map(|s| SenderSnapshot {
                addr: s.addr,
                age_ms: ms(now.saturating_duration_since(s.last_seen)),
                seq: s.seq,
                datagrams: s.datagrams,
                accepted: s.accepted,
                rejected: s.rejected,
                commanding: inner.commander == Some(s.addr),
                frozen: s.stale,
                latched: s.latched,
            })
            .collect();
        let watchdog = WatchdogSnapshot {
            state: inner.watchdog,
            timeout_ms: ms(self.watchdog_timeout),
            last_command_age_ms: inner
                .commander
                .and(inner.last_valid)
                .map(|t| ms(now.saturating_duration_since(t))),
            last_trip: inner.last_trip.clone(),
        };
        let commander = inner.commander;
        drop(inner);
        senders.sort_by(|a, b| a.age_ms.total_cmp(&b.age_ms));
        NetSnapshot {
            listen: self.listen,
            datagrams: self.datagrams.load(Relaxed),
            accepted: self.accepted.load(Relaxed),
            commander,
            watchdog,
            senders,
            commands: Role::ALL
                .iter()
                .filter(|r| r.is_actuator())
                .map(|r| {
                    let i = Role::ALL.iter().position(|x| x == r).expect("listed");
                    (r.as_str(), self.commands[i].load(Relaxed))
                })
                .chain([("accel", self.accel.load(Relaxed))])
                .collect(),
            rejected: Rejections {
                datagram: self.rejects.iter().collect(),
                intake: interlock::Reject::ALL
                    .iter()
                    .map(|r| (r.as_str(), self.intake[r.index()].load(Relaxed)))
                    .collect(),
                refused: Refusal::ALL
                    .iter()
                    .map(|r| (r.as_str(), self.refused[r.index()].load(Relaxed)))
                    .collect(),
            },
        }
    }
}

/// A copy of [`NetStatus`].
#[derive(Clone, Debug, Serialize)]
pub struct NetSnapshot {
    pub listen: SocketAddr,
    /// Datagrams received, and those accepted (parsed, authentic, not refused whole).
    pub datagrams: u64,
    pub accepted: u64,
    /// The sender commanding the vehicle, if any.
    pub commander: Option<SocketAddr>,
    pub watchdog: WatchdogSnapshot,
    /// Most recently seen first.
    pub senders: Vec<SenderSnapshot>,
    /// Network commands accepted, per device (and `accel`).
    #[serde(serialize_with = "pairs")]
    pub commands: Vec<(&'static str, u64)>,
    pub rejected: Rejections,
}

#[derive(Clone, Debug, Serialize)]
pub struct WatchdogSnapshot {
    pub state: WatchdogState,
    pub timeout_ms: f64,
    /// Time since the commander's last valid datagram.
    pub last_command_age_ms: Option<f64>,
    /// Why it last tripped.
    pub last_trip: Option<String>,
}

#[derive(Clone, Debug, Serialize)]
pub struct SenderSnapshot {
    pub addr: SocketAddr,
    pub age_ms: f64,
    pub seq: Option<u64>,
    pub datagrams: u64,
    pub accepted: u64,
    pub rejected: u64,
    pub commanding: bool,
    pub frozen: bool,
    pub latched: bool,
}

/// Rejections by reason; every reason is listed, zeros included.
#[derive(Clone, Debug, Serialize)]
pub struct Rejections {
    /// Whole datagrams: grammar, authentication, counter (`net::proto::Reject`).
    #[serde(serialize_with = "pairs")]
    pub datagram: Vec<(&'static str, u64)>,
    /// Single network commands refused at intake (`interlock::Reject`).
    #[serde(serialize_with = "pairs")]
    pub intake: Vec<(&'static str, u64)>,
    /// The listener's own refusals ([`Refusal`]).
    #[serde(serialize_with = "pairs")]
    pub refused: Vec<(&'static str, u64)>,
}

impl Rejections {
    pub fn get(&self, name: &str) -> u64 {
        [&self.datagram, &self.intake, &self.refused]
            .into_iter()
            .flatten()
            .filter(|(n, _)| *n == name)
            .map(|(_, c)| c)
            .sum()
    }
}

/// `[(name, value)]` as a JSON object, in order.
pub(crate) fn pairs<S: serde::Serializer, V: Serialize>(
    v: &[(&'static str, V)],
    s: S,
) -> Result<S::Ok, S::Error> {
    use serde::ser::SerializeMap;
    let mut m = s.serialize_map(Some(v.len()))?;
    for (k, x) in v {
        m.serialize_entry(k, x)?;
    }
    m.end()
}

/// The console's network panel reads the live status through this.
impl crate::console::controls::NetSource for NetStatus {
    fn status(&self) -> crate::console::controls::NetStatus {
        use crate::console::controls::{NetStatus as Panel, Watchdog};
        let s = self.snapshot();
        let watchdog = match s.watchdog.state {
            WatchdogState::Off | WatchdogState::Idle => Watchdog::Idle,
            WatchdogState::Armed => Watchdog::Ok {
                since_last: Duration::from_secs_f64(
                    s.watchdog.last_command_age_ms.unwrap_or(0.0) / 1000.0,
                ),
                timeout: Duration::from_secs_f64(s.watchdog.timeout_ms / 1000.0),
            },
            WatchdogState::Tripped => Watchdog::Tripped,
        };
        let mut rejections: Vec<(String, u64)> = [
            &s.rejected.datagram,
            &s.rejected.intake,
            &s.rejected.refused,
        ]
        .into_iter()
        .flatten()
        .filter(|(_, n)| *n > 0)
        .map(|(r, n)| (r.to_string(), *n))
        .collect();
        rejections.sort_by_key(|r| std::cmp::Reverse(r.1));
        Panel {
            listen: s.listen.to_string(),
            senders: s
                .senders
                .iter()
                .map(|x| {
                    let mark = if x.commanding { "*" } else { "" };
                    format!("{}{mark}", x.addr)
                })
                .collect(),
            commands: s
                .commands
                .iter()
                .filter_map(|(name, n)| Some((name.parse().ok()?, *n)))
                .collect(),
            rejections,
            watchdog,
        }
    }
}
