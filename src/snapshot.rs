//! The one state snapshot. The engine fills it from the caches (never the ports); the
//! state broadcast sends it, the console draws it, headless prints it, recordings keep
//! it, and `adrive watch` reads the very same type back. No reader builds a view of
//! its own. Plain data only — every part of adrive may depend on this module, and it
//! depends on none of them.
//!
//! [`SCHEMA`] is the broadcast's version: a field may be added without a new version;
//! renaming or removing one bumps it. `schemas/snapshot-4.json` is its JSON Schema,
//! checked by a test against real broadcasts.

use crate::value::{EstopState, Kind, Value};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::net::SocketAddr;

/// The version of the snapshot's JSON form.
pub const SCHEMA: u32 = 4;

/// The whole vehicle at one instant.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Snapshot {
    pub schema: u32,
    pub vehicle: String,
    /// Counts broadcasts from 0; a gap means a lost datagram.
    pub seq: u64,
    /// Wall clock, milliseconds since the Unix epoch.
    pub(crate) time_ms: u64,
    pub(crate) uptime_s: f64,
    pub gate: GateView,
    /// Every device, in the vehicle file's order.
    pub devices: Vec<DeviceView>,
    /// The supervisor: named faults, the recovery in progress, recent history.
    pub supervisor: SupervisorView,
    /// Intake rejections of every command (network and console), by reason.
    pub rejections: Pairs<u64>,
    /// The network side, when the listener runs.
    pub net: Option<NetView>,
    /// The recording, when one runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub record: Option<RecordView>,
    /// The CAN buses, in the vehicle file's order (absent on a vehicle without one):
    /// each adapter's state and the last frame of every identifier on the bus, decoded
    /// by its DBC.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub buses: Vec<BusView>,
    /// Which part of a broadcast this is, when the whole did not fit one datagram
    /// ([`Snapshot::datagrams`]); absent when it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub part: Option<Part>,
}

/// One part of a broadcast split over several datagrams: `index` of `count`, all with
/// the same `seq`. Every part is a whole snapshot with a share of the devices (in
/// order) and the gate and supervisor; the network part and the buses travel in part 0
/// only.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
pub struct Part {
    pub index: u16,
    pub count: u16,
}

impl Snapshot {
    pub fn device(&self, name: &str) -> Option<&DeviceView> {
        self.devices.iter().find(|d| d.name == name)
    }

    /// The device bound to a role (`"throttle"`), by the gate's bindings.
    pub fn bound(&self, role: &str) -> Option<&DeviceView> {
        let target = self.gate.roles.get(role)?;
        let name = target.split('.').next().unwrap_or(target);
        self.device(name)
    }

    /// The snapshot as broadcast datagrams of JSON, each at most `max` bytes where a
    /// device allows: one datagram when it fits, else parts ([`Part`]) that
    /// [`Assembler`] joins back. A vehicle of any number of devices is broadcast whole.
    pub fn datagrams(&self, max: usize) -> serde_json::Result<Vec<Vec<u8>>> {
        let whole = serde_json::to_vec(self)?;
        if whole.len() <= max {
            return Ok(vec![whole]);
        }
        // The devices in order, as many to a part as fit beside the head.
        let head = Snapshot {
            part: Some(Part {
                index: u16::MAX,
                count: u16::MAX,
            }),
            ..self.head()
        };
        let room = max.saturating_sub(serde_json::to_vec(&head)?.len() + 1);
        let net = serde_json::to_vec(&self.net)?.len() + serde_json::to_vec(&self.buses)?.len();
        let mut shares: Vec<Vec<DeviceView>> = vec![Vec::new()];
        let mut used = net;
        for d in &self.devices {
            let size = serde_json::to_vec(d)?.len() + 1;
            let last = shares.last_mut().expect("one share at least");
            if !last.is_empty() && used + size > room {
                shares.push(Vec::new());
                used = 0;
            }
            used += size;
            shares.last_mut().expect("just pushed").push(d.clone());
        }
        let count = shares.len() as u16;
        shares
            .into_iter()
            .enumerate()
            .map(|(i, devices)| {
                serde_json::to_vec(&Snapshot {
                    devices,
                    net: if i == 0 { self.net.clone() } else { None },
                    buses: if i == 0 {
                        self.buses.clone()
                    } else {
                        Vec::new()
                    },
                    part: Some(Part {
                        index: i as u16,
                        count,
                    }),
                    ..head.clone()
                })
            })
            .collect()
    }

    /// The snapshot without its devices, its network figures and its buses: the gate,
    /// the supervisor and the rejections, which every part of a split broadcast carries
    /// ([`Snapshot::datagrams`]) and a fleet member publishes as its state.
    pub fn head(&self) -> Snapshot {
        Snapshot {
            devices: Vec::new(),
            net: None,
            buses: Vec::new(),
            ..self.clone()
        }
    }

    /// Every faulty device with its last error, `gas: no reply within 100ms`.
    pub fn faulty(&self) -> impl Iterator<Item = &DeviceView> {
        self.devices.iter().filter(|d| d.health.faulty)
    }
}

/// The engage gate and the safety rules.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct GateView {
    pub engaged: bool,
    /// Why it is engaged or not ("engaged by network 127.0.0.1:40001",
    /// "disengaged: watchdog: …"): the words of `cause`.
    pub reason: String,
    /// The same, as a type: engaged and by whom, or each way it was disengaged with
    /// its particulars.
    #[serde(default)]
    pub cause: GateCause,
    /// What would refuse an engage right now (empty: it may engage), in words.
    pub blockers: Vec<String>,
    /// The same, as types: what blocks, and on which device or thread.
    #[serde(default)]
    pub blocked_by: Vec<Blocker>,
    /// The interlock rules are on.
    pub interlocks: bool,
    /// The rules active on this vehicle (those whose devices are bound).
    pub rules: Vec<String>,
    /// The role bindings: role → device or device.reading.
    pub roles: Pairs<String>,
    /// `accel` exists (throttle and brake are bound).
    pub accel: bool,
    /// Devices a driver has taken over (a latched `override`): the vehicle is in
    /// manual until they are cleared.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub overridden: Vec<String>,
    /// Who commands the engaged vehicle: `console`, `network 127.0.0.1:5555`,
    /// `ros2 /alice`; null when disengaged or handed over.
    #[serde(default)]
    pub commander: Option<String>,
    /// The commander's watchdog (the network's `watchdog_timeout`, the console's
    /// teleop deadman).
    #[serde(default)]
    pub watchdog: Option<WatchdogView>,
    /// Asks refused because another source commands the vehicle (or nobody does).
    #[serde(default)]
    pub refused: u64,
    /// The last of them, in words: `refused steer 0.500 from network 127.0.0.1:5555:
    /// commanded by console`.
    #[serde(default)]
    pub(crate) last_refused: Option<String>,
}

impl GateView {
    /// The watchdog stands tripped by a teleoperating console's deadman (until the next
    /// engage).
    pub fn deadman_tripped(&self) -> bool {
        self.watchdog
            .as_ref()
            .is_some_and(|w| w.state == WatchdogState::Tripped && w.trip == Some(TripKind::Deadman))
    }
}

/// One device.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct DeviceView {
    pub name: String,
    pub kind: Kind,
    /// The roles it plays (`throttle`, `gear`…).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub roles: Vec<String>,
    /// A setpoint actuator's range and units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub range: Option<[f64; 2]>,
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub units: String,
    /// A state actuator's states.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub states: Vec<String>,
    /// The last reading: every reading the device declares, by name (null until
    /// reported). Numbers in their units, flags as booleans, states by name.
    pub readings: Pairs<Option<Value>>,
    /// Units of each reading, by name (`""` when unitless).
    pub reading_units: Pairs<String>,
    /// Device-reported fault bits; 0 is good.
    pub fault: u16,
    /// The names of the bits set in `fault`, for a device on a CAN bus whose DBC names
    /// its fault codes (`OPERATOR_OVERRIDE`); empty otherwise.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub faults: Vec<String>,
    /// The CAN bus it is on (a [`BusView`]'s name), for a device with `driver = "can"`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bus: Option<String>,
    /// The command the device will have next (pending or last sent).
    pub commanded: Option<Value>,
    /// The last command the device acknowledged.
    pub executed: Option<Value>,
    /// A set point device: the lowest and highest set point it acknowledged over the
    /// last two supervisor periods (the last one always included) — everything its
    /// commands can have driven it toward since the supervisor last looked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) executed_span: Option<[f64; 2]>,
    /// A set point device: how long ago it last acknowledged a set point (a resend
    /// included), ms; null before the first. A device with a watchdog of its own goes
    /// to its safe value by itself once this passes that watchdog.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) executed_age_ms: Option<f64>,
    /// Age of the cached reading, ms (null before the first good poll).
    pub status_age_ms: Option<f64>,
    /// The reading is older than the device's `status_max_age` (or there is none).
    pub stale: bool,
    pub health: Health,
    pub settings: Settings,
    pub counters: Counters,
    /// Command receipt to first byte written, µs.
    pub delay_us: LatencySummary,
    /// One command transaction, µs.
    pub command_txn_us: LatencySummary,
    /// One status transaction, µs.
    pub(crate) status_txn_us: LatencySummary,
    /// What the estimator believes now, for a setpoint device with a declared
    /// response (null without one, or before its first reading).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub estimate: Option<EstimateView>,
}

/// A setpoint device's estimated state at the snapshot's instant (its units).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct EstimateView {
    /// The estimated position.
    pub position: f64,
    /// One standard deviation of it.
    pub sigma: f64,
    /// The estimated velocity, units a second.
    pub velocity: f64,
    /// The velocity its command does not explain (a stuck motor, a driver's hand),
    /// units a second.
    pub drift: f64,
}

impl DeviceView {
    pub fn is_actuator(&self) -> bool {
        self.kind.is_actuator()
    }

    /// A reading's value by name.
    pub fn reading(&self, name: &str) -> Option<&Value> {
        self.readings.get(name).and_then(Option::as_ref)
    }

    /// A number reading (a flag as 0/1).
    pub fn number(&self, name: &str) -> Option<f64> {
        self.reading(name).and_then(Value::as_f64)
    }

    /// The position of a setpoint actuator.
    pub fn position(&self) -> Option<f64> {
        self.number(crate::config::device::POSITION)
    }

    /// The state a state actuator reports, by name.
    pub fn state(&self) -> Option<&str> {
        self.reading(crate::config::device::STATE)?.as_str()
    }
}

/// A device's health, as its threads keep it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Health {
    /// Failing repeatedly, silent past its `status_max_age`, or its port is gone.
    pub faulty: bool,
    pub connected: bool,
    /// The last attempt to open its port failed (unplugged, wrong path).
    pub missing: bool,
    /// Times its port was opened (1 after start; more after reconnects).
    pub opens: u64,
    /// Error codes as on the paper's screen: 0 good, ≥ 1 bad (1 timeout, 2 garbled,
    /// 3 refused, 4 unsupported, 5 I/O).
    pub status_error: u32,
    pub command_error: u32,
    pub(crate) last_error: Option<String>,
    /// Age of `last_error`, ms.
    #[serde(default)]
    pub(crate) last_error_age_ms: Option<f64>,
    /// Time since the device last answered (a good status or an acknowledged
    /// command), ms; null before its first answer. Past `status_max_age` it is silent.
    #[serde(default)]
    pub(crate) quiet_ms: Option<f64>,
}

/// What the console may change while running.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Settings {
    pub(crate) status_period_ms: f64,
    pub(crate) command_timeout_ms: f64,
    pub(crate) status_max_age_ms: f64,
    pub(crate) status_on: bool,
    pub(crate) command_on: bool,
    /// How status polls are scheduled: `fixed` (every `status_period_ms`) or
    /// `adaptive` (by the estimate, from `status_period_ms` to `status_max_age_ms`).
    #[serde(default)]
    pub polling: String,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Counters {
    /// Commands accepted at intake into the device's slot.
    pub received: u64,
    /// Command transactions completed without error.
    pub executed: u64,
    /// Commands replaced by a newer one before they reached the wire.
    pub superseded: u64,
    /// Last command sent again after `command_timeout` (or a manual wake).
    pub resent: u64,
    /// Commands refused at intake (interlock, range, disengaged…).
    pub rejected: u64,
    pub command_errors: u64,
    pub polls: u64,
    pub status_errors: u64,
    /// Times the port was reopened after the first open.
    pub(crate) reconnects: u64,
}

/// Figures of one latency histogram, in microseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct LatencySummary {
    pub count: u64,
    pub p50_us: Option<f64>,
    pub p99_us: Option<f64>,
    pub max_us: Option<f64>,
    /// The average (the paper's Fig. 3 plots it), exact.
    #[serde(default)]
    pub mean_us: Option<f64>,
}

/// The kinds of fault the supervisor detects.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// No status for longer than the device's `status_max_age`.
    Silent,
    /// Its port is gone (USB unplugged).
    Disconnected,
    /// Too many failed transactions in the recent window.
    ErrorRate,
    /// It reports a value outside its range.
    OutOfRange,
    /// Its measured value stays away from the command.
    NotFollowing,
    /// It reports fault bits in its status word.
    DeviceFault,
    /// It moved in a way its command cannot explain: a driver's hand (not a failure).
    Override,
    /// Engine stopped while in gear.
    EngineStall,
    EstopPause,
    EstopDisable,
}

impl FaultKind {
    pub fn as_str(self) -> &'static str {
        match self {
            FaultKind::Silent => "silent",
            FaultKind::Disconnected => "disconnected",
            FaultKind::ErrorRate => "error_rate",
            FaultKind::OutOfRange => "out_of_range",
            FaultKind::NotFollowing => "not_following",
            FaultKind::DeviceFault => "device_fault",
            FaultKind::Override => "override",
            FaultKind::EngineStall => "engine_stall",
            FaultKind::EstopPause => "estop_pause",
            FaultKind::EstopDisable => "estop_disable",
        }
    }
}

impl fmt::Display for FaultKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A fault as the snapshot carries it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct FaultView {
    pub kind: FaultKind,
    pub device: Option<String>,
    pub cause: String,
    pub age_ms: f64,
}

impl FaultView {
    /// `steer not_following: measured 0.02, commanded 0.50 for 2.6 s`
    pub fn describe(&self) -> String {
        match &self.device {
            Some(d) => format!("{d} {}: {}", self.kind, self.cause),
            None => format!("{}: {}", self.kind, self.cause),
        }
    }
}

/// Where a recovery procedure is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct RecoveryView {
    /// `engine_stall`, `steering`, `reconnect brake`.
    pub name: String,
    /// Every step, in order.
    pub steps: Vec<String>,
    /// The step now running (index into `steps`).
    pub step: usize,
    /// This try, from 1, and how many are allowed.
    pub attempt: u32,
    pub attempts: u32,
    pub(crate) elapsed_ms: f64,
}

impl RecoveryView {
    /// `engine_stall 3/6 park (try 1/3)`
    pub fn describe(&self) -> String {
        format!(
            "{} {}/{} {} (try {}/{})",
            self.name,
            self.step + 1,
            self.steps.len(),
            self.steps
                .get(self.step)
                .map(String::as_str)
                .unwrap_or("done"),
            self.attempt,
            self.attempts
        )
    }
}

/// The supervisor's state.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct SupervisorView {
    pub faults: Vec<FaultView>,
    pub recovery: Option<RecoveryView>,
    /// The last procedure's outcome, in words, e.g. `recovery steering done in 0.9 s`.
    pub last_outcome: Option<String>,
    /// The last procedure's outcome, as a type.
    #[serde(default)]
    pub outcome: Option<OutcomeKind>,
    /// How many procedures have ended since adrive started: a reader tells a new
    /// outcome from the last one by this count (two alike are two).
    #[serde(default)]
    pub outcomes: u64,
    /// Recent steps and outcomes, newest last.
    pub history: Vec<String>,
    /// Engine threads that have not turned their loop within their bound (a thread
    /// stuck in a system call): the service watchdog is not fed, engage is refused.
    #[serde(default)]
    pub stalled: Vec<StallView>,
    /// Devices gone (unplugged, or never there) that adrive keeps reopening: what it
    /// waits for. A device gone never ends the run.
    #[serde(default)]
    pub waiting: Vec<WaitingView>,
}

/// How the supervisor's last procedure ended (its words: `last_outcome`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum OutcomeKind {
    /// A recovery procedure did its steps.
    Done,
    /// A recovery procedure gave up: the device stays faulty, the vehicle disengaged.
    GaveUp,
    /// A recovery stopped because the vehicle was disengaged.
    Stopped,
    /// A recovery waits for an engage to run.
    Waits,
    /// A device that was gone is back.
    Back,
}

/// A device gone, and what adrive does about it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct WaitingView {
    pub device: String,
    /// The port it is reopened on (a bus's adapter, for a device on a CAN bus).
    pub port: String,
    /// Why the last open failed: `No such file or directory`.
    pub error: String,
    /// Since it went, ms.
    pub gone_ms: f64,
    /// How long after a failed open it is tried again, ms (its backoff, up to 5 s).
    pub retry_ms: f64,
    /// The rules act on it (it is bound to a role): engage is refused while it is
    /// gone. Else it is shown, and holds nothing up.
    pub needed: bool,
}

/// How far a port's reopening backs off, at most (a device's, a bus adapter's): it
/// starts at 100 ms and doubles up to this. Here, below the port and the engine that
/// back off, because the waiting view says it.
pub const RETRY_AT_MOST: std::time::Duration = std::time::Duration::from_secs(5);

impl WaitingView {
    /// `waiting for horn on /dev/ttyUSB3: No such file or directory, retrying every 5s`;
    /// while its backoff still grows, `retrying in 200ms, then less often up to every 5s`
    /// (the first line read `retrying every 100ms`, which it was not).
    pub fn describe(&self) -> String {
        let every = std::time::Duration::from_millis(self.retry_ms.max(1.0) as u64);
        let most = RETRY_AT_MOST;
        let when = if every < most {
            format!(
                "retrying in {}, then less often up to every {}",
                humantime::format_duration(every),
                humantime::format_duration(most)
            )
        } else {
            format!("retrying every {}", humantime::format_duration(every))
        };
        format!(
            "waiting for {} on {}: {}, {when}",
            self.device, self.port, self.error
        )
    }
}

/// An engine thread past its bound.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct StallView {
    /// `steer/status`, `brake/command`, `bus/kit`, `gate/monitor`, `supervisor`.
    pub thread: String,
    /// Since its last turn, ms.
    pub quiet_ms: f64,
    /// When it was to turn again, ms after that turn: its bound.
    pub bound_ms: f64,
}

impl StallView {
    /// `steer/status has not turned its loop for 1.4 s (bound 0.45 s)`
    pub fn describe(&self) -> String {
        format!(
            "{} has not turned its loop for {:.1} s (bound {:.2} s)",
            self.thread,
            self.quiet_ms / 1e3,
            self.bound_ms / 1e3
        )
    }
}

/// What refuses an engage, and disengages an engaged vehicle: the cause as a type, its
/// words in [`Display`](std::fmt::Display) (the snapshot's `blockers`, an engage's
/// refusal, the disengage's reason).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Blocker {
    /// A driver took the device over (a latched override), not cleared yet.
    Overridden { device: String },
    /// The device is faulty; `fault` is its own error.
    Faulty { device: String, fault: String },
    /// The device (an OBD adapter) is searching the car's protocols, up to `up_to_s`.
    Searching { device: String, up_to_s: u64 },
    /// The device has not reported yet.
    NotReported { device: String },
    /// The e-stop is in pause or disable.
    Estop { state: EstopState },
    /// An engine thread has not turned its loop within its bound.
    Stalled { stall: StallView },
}

impl std::fmt::Display for Blocker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Blocker::Overridden { device } => write!(
                f,
                "{device} is in the driver's hands (override): clear it once the driver has let go"
            ),
            Blocker::Faulty { device, fault } => write!(f, "{device} is faulty ({fault})"),
            Blocker::Searching { device, up_to_s } => write!(
                f,
                "{device}: the adapter is searching the car's protocols, up to {up_to_s} s"
            ),
            Blocker::NotReported { device } => write!(f, "{device} has not reported yet"),
            Blocker::Estop { state } => write!(f, "e-stop is in {state}"),
            Blocker::Stalled { stall } => write!(f, "thread {}", stall.describe()),
        }
    }
}

impl Blocker {
    /// Blockers in words, one sentence: `steer is faulty (timeout); e-stop is in pause`.
    pub fn said(all: &[Blocker]) -> String {
        all.iter()
            .map(Blocker::to_string)
            .collect::<Vec<_>>()
            .join("; ")
    }
}

/// Why the vehicle is engaged or not: the gate's cause as a type (the snapshot's
/// `gate.cause`), its words in [`Display`](fmt::Display) — the snapshot's `gate.reason`,
/// the log's, a recording's and the network's — and nowhere else. Front ends match on
/// the type; they show the words.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum GateCause {
    /// Nothing has engaged the vehicle since adrive started.
    #[default]
    NotEngagedYet,
    /// Engaged by `by`, named as `commander` names it (`console`, `console #2`,
    /// `network 127.0.0.1:5555`, `ros2`).
    Engaged { by: String },
    /// Disengaged: `why`.
    Disengaged { why: DisengageCause },
}

impl fmt::Display for GateCause {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            GateCause::NotEngagedYet => f.write_str("not engaged yet"),
            GateCause::Engaged { by } => write!(f, "engaged by {by}"),
            GateCause::Disengaged { why } => write!(f, "disengaged: {why}"),
        }
    }
}

impl GateCause {
    /// The words without the state, for a front end that shows ENGAGED or DISENGAGED
    /// itself: `stop from console #2`, `not engaged yet`, `engaged by console`.
    pub fn why(&self) -> String {
        match self {
            GateCause::Disengaged { why } => why.to_string(),
            other => other.to_string(),
        }
    }
}

/// Each way the vehicle is disengaged, or refused to stay engaged: the cause as a type
/// with its particulars, its words in [`Display`](fmt::Display).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum DisengageCause {
    /// A source asked to disengage (`by`, named as [`GateCause::Engaged`]'s).
    Disengage { by: String },
    /// A source asked to STOP: the full safe state, even in a driver's hands.
    Stop { by: String },
    /// The commander's watchdog tripped: which bound ran out, and what happened in
    /// words (the same as `watchdog.last_trip`).
    Watchdog { trip: TripKind, what: String },
    /// A driver took `device` over (a latched override); `cleared` once the override
    /// is cleared.
    Override { device: String, cleared: bool },
    /// What refuses an engage came up while engaged (the gate monitor's check), or the
    /// e-stop went to pause or disable while disengaged.
    Blocked { blocker: Blocker },
    /// A fault the supervisor disengages for (as it was then).
    Fault { fault: FaultView },
    /// The recovery procedure `recovery` gave up, for `why`.
    GaveUp { recovery: String, why: String },
    /// The run ends, as the operator asked (`give_up_after`), for `why`.
    GivingUp { why: String },
    /// An engine thread stopped turning its loop (the service watchdog's check).
    Stalled { stall: StallView },
    /// adrive is stopping; `why`, when known, is what ends the run.
    Stopping { why: Option<String> },
    /// `adrive characterize` let the device go: its run done, or `ended` early for
    /// that reason (the device in its safe state).
    Characterize { ended: Option<String> },
}

impl fmt::Display for DisengageCause {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DisengageCause::Disengage { by } => write!(f, "disengage from {by}"),
            DisengageCause::Stop { by } => write!(f, "stop from {by}"),
            DisengageCause::Watchdog { what, .. } => write!(f, "watchdog: {what}"),
            DisengageCause::Override { device, cleared } => {
                write!(f, "driver override on {device}")?;
                if *cleared {
                    f.write_str(", cleared")?;
                }
                Ok(())
            }
            DisengageCause::Blocked { blocker } => write!(f, "{blocker}"),
            DisengageCause::Fault { fault } => write!(f, "supervisor: {}", fault.describe()),
            DisengageCause::GaveUp { recovery, why } => {
                write!(f, "recovery {recovery} gave up: {why}")
            }
            DisengageCause::GivingUp { why } => write!(f, "giving up: {why}"),
            DisengageCause::Stalled { stall } => write!(f, "stalled: {}", stall.describe()),
            DisengageCause::Stopping { why: None } => f.write_str("stopping"),
            DisengageCause::Stopping { why: Some(why) } => write!(f, "stopping: {why}"),
            DisengageCause::Characterize { ended: None } => f.write_str("characterize done"),
            DisengageCause::Characterize { ended: Some(why) } => {
                write!(f, "characterize ended: {why}")
            }
        }
    }
}

/// The commander's watchdog, as shown to people.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum WatchdogState {
    /// Disengaged.
    Off,
    /// Engaged, and the commander is not watched (a console outside teleop) or
    /// nobody commands.
    Idle,
    /// Engaged and the commander must keep sending (a network sender, ROS 2, a
    /// console teleoperating).
    Armed,
    /// It brought the vehicle to the safe state; stays so until the next engage.
    Tripped,
}

/// The network side: listener, watchdog, senders, counters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct NetView {
    pub listen: SocketAddr,
    /// Datagrams received, and those accepted (parsed, authentic, not refused whole).
    pub datagrams: u64,
    pub accepted: u64,
    /// Most recently seen first.
    pub senders: Vec<SenderView>,
    /// Network commands accepted, per device (and `accel`).
    pub commands: Pairs<u64>,
    pub rejected: Rejections,
    /// The live view for Foxglove / Lichtblick, when `--foxglove` serves one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub foxglove: Option<LiveView>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct WatchdogView {
    pub state: WatchdogState,
    pub(crate) timeout_ms: f64,
    /// Time since the commander's last valid datagram.
    pub(crate) last_command_age_ms: Option<f64>,
    /// Why it last tripped, in words.
    pub last_trip: Option<String>,
    /// Why it last tripped, as a type: the bound that ran out.
    #[serde(default)]
    pub trip: Option<TripKind>,
}

/// Which bound of the commander's watchdog ran out (its words: `last_trip`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum TripKind {
    /// A commanding console's terminal stopped answering round trips.
    Terminal,
    /// A teleoperating console sent no teleop key for its deadman.
    Deadman,
    /// The commander's rolling counter stopped advancing.
    Frozen,
    /// No valid command from the commander for its timeout.
    Silent,
    /// Released, and nobody took command within the handover.
    Handover,
    /// The commanding console went away (its connection closed, dropped).
    Gone,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct SenderView {
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
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Rejections {
    /// Whole datagrams: grammar, authentication, counter.
    pub datagram: Pairs<u64>,
    /// Single network commands refused at intake (interlocks, disengaged…).
    pub intake: Pairs<u64>,
    /// The listener's own refusals.
    pub refused: Pairs<u64>,
}

impl Rejections {
    pub fn get(&self, name: &str) -> u64 {
        [&self.datagram, &self.intake, &self.refused]
            .into_iter()
            .filter_map(|p| p.get(name))
            .sum()
    }
}

/// One CAN bus: its adapter and what it carries, as a bus monitor (`cantools monitor`)
/// shows it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct BusView {
    pub name: String,
    /// The adapter's serial port.
    pub port: String,
    /// Bits a second.
    pub bitrate: u32,
    /// Why the adapter is not on the bus (not opened yet, unplugged); null while it is.
    pub down: Option<String>,
    /// The adapter's status flags say the bus is in error (bus off, error passive).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bus_error: Option<String>,
    pub counters: BusCounters,
    /// The last frame of each identifier seen, sent or received, by identifier (at
    /// most [`BusView::MAX_FRAMES`]: the most recent ones).
    pub frames: Vec<FrameView>,
    /// Identifiers seen but left out of `frames` (the oldest, past the cap).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub left_out: u64,
}

impl BusView {
    /// The most identifiers a bus carries in the snapshot.
    pub const MAX_FRAMES: usize = 64;
}

fn is_zero(n: &u64) -> bool {
    *n == 0
}

/// A bus's counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct BusCounters {
    /// Frames received from the bus.
    pub received: u64,
    /// Frames adrive handed to the adapter.
    pub sent: u64,
    /// Frames the adapter took for transmission.
    pub acked: u64,
    /// Commands the adapter refused.
    pub refused: u64,
    /// Lines from the adapter that were none of SLCAN's.
    pub garbled: u64,
    /// Times the adapter was brought onto the bus.
    pub opens: u64,
}

/// The last frame of one identifier, decoded by the bus's DBC.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct FrameView {
    /// `0x083`; an extended identifier has eight digits and an `x`: `0x18DAF110x`.
    pub id: String,
    /// The DBC's message; null for an identifier the DBC does not know.
    pub message: Option<String>,
    /// adrive sent it (else it came from the bus).
    pub sent: bool,
    /// Frames of this identifier so far.
    pub count: u64,
    /// Time since the last one, ms.
    pub age_ms: f64,
    /// Its data bytes in hex (`05 CC 01 00 00 00 00 00`), or `remote [n]` for a
    /// remote request.
    pub data: String,
    /// Its signals in words, in the message's order: a value with its unit
    /// (`-12.5 deg`), a value table's name (`ENABLED`), a fault bitfield's names of the
    /// bits set (`INVALID_SENSOR_VAL|OPERATOR_OVERRIDE`). A constant that holds its
    /// value (a kit's magic bytes) is left out.
    pub signals: Pairs<String>,
}

/// The recording of this run (`--record`, `[record]`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct RecordView {
    /// The file being written (the last one, once recording stopped).
    pub file: String,
    /// Bytes written to it so far.
    pub bytes: u64,
    /// Messages written, all files of this run.
    pub messages: u64,
    /// Events left out because the recorder fell behind (the vehicle never waits).
    pub dropped: u64,
    /// Why recording stopped; the vehicle runs on.
    pub error: Option<String>,
}

/// The live view (`--foxglove`): where it listens and who watches. A viewer that reads
/// too slowly loses messages, counted here; the vehicle never waits for one.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct LiveView {
    pub listen: SocketAddr,
    /// Connected viewers, in the order they came.
    pub viewers: Vec<ViewerView>,
    /// Messages dropped for every viewer so far, those gone included.
    pub dropped: u64,
    /// Events the live view itself fell behind on (its tap channel was full).
    pub tap_dropped: u64,
}

/// One connected viewer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct ViewerView {
    pub addr: SocketAddr,
    /// The WebSocket subprotocol it speaks (`foxglove.sdk.v1`, `foxglove.websocket.v1`).
    pub subprotocol: String,
    /// Channels it subscribes to.
    pub subscriptions: u32,
    /// Messages sent to it, and dropped because it read too slowly.
    pub sent: u64,
    pub dropped: u64,
}

/// Named values in order, written as a JSON object (`{"steer": 3, "gas": 0}`) and read
/// back in the same order.
#[derive(Clone, Debug, PartialEq)]
pub struct Pairs<V>(pub Vec<(String, V)>);

impl<V> Default for Pairs<V> {
    fn default() -> Self {
        Pairs(Vec::new())
    }
}

impl<V> Pairs<V> {
    pub fn get(&self, name: &str) -> Option<&V> {
        self.0.iter().find(|(n, _)| n == name).map(|(_, v)| v)
    }

    pub fn iter(&self) -> impl Iterator<Item = (&str, &V)> {
        self.0.iter().map(|(n, v)| (n.as_str(), v))
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl<V> FromIterator<(String, V)> for Pairs<V> {
    fn from_iter<I: IntoIterator<Item = (String, V)>>(iter: I) -> Self {
        Pairs(iter.into_iter().collect())
    }
}

/// A JSON object whose values are all `V`.
impl<V: schemars::JsonSchema> schemars::JsonSchema for Pairs<V> {
    fn schema_name() -> std::borrow::Cow<'static, str> {
        format!("Pairs_of_{}", V::schema_name()).into()
    }

    fn json_schema(generator: &mut schemars::SchemaGenerator) -> schemars::Schema {
        schemars::json_schema!({
            "type": "object",
            "additionalProperties": generator.subschema_for::<V>(),
        })
    }
}

impl<V: Serialize> Serialize for Pairs<V> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for (k, v) in &self.0 {
            m.serialize_entry(k, v)?;
        }
        m.end()
    }
}

impl<'de, V: Deserialize<'de>> Deserialize<'de> for Pairs<V> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visit<V>(std::marker::PhantomData<V>);
        impl<'de, V: Deserialize<'de>> serde::de::Visitor<'de> for Visit<V> {
            type Value = Pairs<V>;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("an object")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut a: A,
            ) -> Result<Pairs<V>, A::Error> {
                let mut out = Vec::new();
                while let Some((k, v)) = a.next_entry::<String, V>()? {
                    out.push((k, v));
                }
                Ok(Pairs(out))
            }
        }
        d.deserialize_map(Visit(std::marker::PhantomData))
    }
}

/// Joins the parts of a broadcast ([`Snapshot::datagrams`]) back into one snapshot. A
/// part of a newer broadcast drops an older one still incomplete (a lost datagram).
#[derive(Default)]
pub struct Assembler {
    seq: u64,
    parts: Vec<Option<Snapshot>>,
}

impl Assembler {
    /// Take one datagram's snapshot; returns the whole snapshot once it is complete.
    pub fn push(&mut self, s: Snapshot) -> Option<Snapshot> {
        let Some(part) = s.part else {
            return Some(s);
        };
        let (index, count) = (usize::from(part.index), usize::from(part.count));
        if index >= count {
            return None;
        }
        if s.seq != self.seq || self.parts.len() != count {
            self.seq = s.seq;
            self.parts = vec![None; count];
        }
        self.parts[index] = Some(s);
        if self.parts.iter().any(Option::is_none) {
            return None;
        }
        let mut parts = std::mem::take(&mut self.parts).into_iter().flatten();
        let mut whole = parts.next()?;
        for p in parts {
            whole.devices.extend(p.devices);
        }
        whole.part = None;
        Some(whole)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every number anywhere in `v`, none subnormal.
    fn assert_no_subnormal(v: &serde_json::Value, at: &str) {
        match v {
            serde_json::Value::Number(n) => {
                let x = n.as_f64().unwrap_or(0.0);
                assert!(!x.is_subnormal(), "{at}: {x:e}");
            }
            serde_json::Value::Array(a) => a.iter().for_each(|x| assert_no_subnormal(x, at)),
            serde_json::Value::Object(o) => o
                .iter()
                .for_each(|(k, x)| assert_no_subnormal(x, &format!("{at}.{k}"))),
            _ => {}
        }
    }

    /// The incident: the gas estimate's velocity and drift read 1.5e-323 in the
    /// broadcast after a minute idle. Gas and brake settle on 0 and are polled every
    /// 100 ms for three minutes; the snapshot taken every second holds no subnormal
    /// number.
    #[test]
    fn minutes_idle_put_no_subnormal_number_in_the_snapshot() {
        let t0 = std::time::Instant::now();
        let gate = crate::testkit::gate(t0);
        let v = gate.vehicle();
        let pedals = ["gas", "brake"].map(|n| v.find(n).expect("alice's pedals"));
        for d in pedals {
            d.estimate_command(crate::value::Command::Set(0.0), t0);
        }
        for k in 0..1_800u32 {
            let t = t0 + std::time::Duration::from_millis(100 * u64::from(k));
            for d in pedals {
                let mut r = d.cached().reading;
                let i = d.config().position().expect("a setpoint device");
                r.set(
                    i,
                    if k < 10 {
                        0.8 * 0.3f64.powi(k as i32)
                    } else {
                        0.0
                    },
                );
                d.estimate_reading(&r, t);
            }
            if k % 10 == 5 {
                let json = serde_json::to_value(gate.snapshot_at(0, t)).unwrap();
                assert_no_subnormal(&json, &format!("snapshot after {} s", k / 10));
            }
        }
    }

    #[test]
    fn pairs_keep_their_order_through_json() {
        let p: Pairs<u64> = [
            ("steer".to_string(), 3),
            ("gas".to_string(), 0),
            ("a".to_string(), 1),
        ]
        .into_iter()
        .collect();
        let json = serde_json::to_string(&p).unwrap();
        assert_eq!(json, r#"{"steer":3,"gas":0,"a":1}"#);
        assert_eq!(serde_json::from_str::<Pairs<u64>>(&json).unwrap(), p);
    }

    /// A vehicle of 64 devices is broadcast whole: in parts of at most the datagram
    /// size (the buses in the first only), joined back into the very same snapshot.
    #[test]
    fn a_large_snapshot_goes_in_parts_and_joins_back() {
        let now = std::time::Instant::now();
        let mut snap = crate::testkit::gate(now).snapshot(7);
        let one = snap.devices[0].clone();
        snap.devices = (0..64)
            .map(|i| DeviceView {
                name: format!("device_{i}"),
                ..one.clone()
            })
            .collect();
        snap.buses = vec![BusView {
            name: "kit".into(),
            frames: vec![FrameView {
                id: "0x083".into(),
                message: Some("STEERING_REPORT".into()),
                sent: false,
                count: 3,
                age_ms: 12.0,
                data: "05 CC 01 00 00 00 00 00".into(),
                signals: [("enabled".to_string(), "ENABLED".to_string())]
                    .into_iter()
                    .collect(),
            }],
            ..BusView::default()
        }];
        let max = 8 * 1024;
        let datagrams = snap.datagrams(max).unwrap();
        assert!(datagrams.len() > 1);
        let mut asm = Assembler::default();
        let mut whole = None;
        // A stale part of an older broadcast first: it is dropped.
        let mut old: Snapshot = serde_json::from_slice(&datagrams[1]).unwrap();
        old.seq = 6;
        assert_eq!(asm.push(old), None);
        for d in &datagrams {
            assert!(d.len() <= max, "{} bytes", d.len());
            let part: Snapshot = serde_json::from_slice(d).unwrap();
            assert!(
                part.gate == snap.gate,
                "every part says whether it is engaged"
            );
            let index = part.part.map(|p| p.index);
            assert_eq!(
                part.buses.is_empty(),
                index != Some(0),
                "the buses travel in part 0 only"
            );
            whole = asm.push(part);
        }
        // (As sent: a number read back from JSON may differ in its last bit.)
        let sent: Snapshot = serde_json::from_slice(&serde_json::to_vec(&snap).unwrap()).unwrap();
        let whole = whole.expect("complete");
        assert_eq!(whole.devices.len(), 64);
        assert!(
            whole == sent,
            "the joined snapshot differs from the one sent"
        );
        // Small enough: one datagram, no parts.
        snap.devices.truncate(2);
        let one = snap.datagrams(max).unwrap();
        assert_eq!(one.len(), 1);
        assert!(!String::from_utf8_lossy(&one[0]).contains("\"part\""));
    }

    /// Every way the vehicle is disengaged, with its particulars, its `kind` in the
    /// snapshot's `gate.cause.why` and the words of `gate.reason`.
    fn every_disengage() -> Vec<(DisengageCause, &'static str, &'static str)> {
        let stall = StallView {
            thread: "steer/status".into(),
            quiet_ms: 1400.0,
            bound_ms: 450.0,
        };
        let fault = FaultView {
            kind: FaultKind::NotFollowing,
            device: Some("steer".into()),
            cause: "measured 0.02, commanded 0.50 for 2.6 s".into(),
            age_ms: 12.0,
        };
        let all = vec![
            (
                DisengageCause::Disengage {
                    by: "console #2".into(),
                },
                "disengage",
                "disengage from console #2",
            ),
            (
                DisengageCause::Stop {
                    by: "network 127.0.0.1:5555".into(),
                },
                "stop",
                "stop from network 127.0.0.1:5555",
            ),
            (
                DisengageCause::Watchdog {
                    trip: TripKind::Deadman,
                    what: "deadman: no teleop key for 0.5s".into(),
                },
                "watchdog",
                "watchdog: deadman: no teleop key for 0.5s",
            ),
            (
                DisengageCause::Override {
                    device: "steer".into(),
                    cleared: false,
                },
                "override",
                "driver override on steer",
            ),
            (
                DisengageCause::Override {
                    device: "steer".into(),
                    cleared: true,
                },
                "override",
                "driver override on steer, cleared",
            ),
            (
                DisengageCause::Blocked {
                    blocker: Blocker::Estop {
                        state: EstopState::Pause,
                    },
                },
                "blocked",
                "e-stop is in pause",
            ),
            (
                DisengageCause::Fault { fault },
                "fault",
                "supervisor: steer not_following: measured 0.02, commanded 0.50 for 2.6 s",
            ),
            (
                DisengageCause::GaveUp {
                    recovery: "steering".into(),
                    why: "no more tries".into(),
                },
                "gave_up",
                "recovery steering gave up: no more tries",
            ),
            (
                DisengageCause::GivingUp {
                    why: "horn gone for 30 s".into(),
                },
                "giving_up",
                "giving up: horn gone for 30 s",
            ),
            (
                DisengageCause::Stalled { stall },
                "stalled",
                "stalled: steer/status has not turned its loop for 1.4 s (bound 0.45 s)",
            ),
            (
                DisengageCause::Stopping { why: None },
                "stopping",
                "stopping",
            ),
            (
                DisengageCause::Stopping {
                    why: Some("SIGTERM".into()),
                },
                "stopping",
                "stopping: SIGTERM",
            ),
            (
                DisengageCause::Characterize { ended: None },
                "characterize",
                "characterize done",
            ),
            (
                DisengageCause::Characterize {
                    ended: Some("STOP".into()),
                },
                "characterize",
                "characterize ended: STOP",
            ),
        ];
        // A new way to disengage is added here, or this does not compile.
        for (c, _, _) in &all {
            match c {
                DisengageCause::Disengage { .. }
                | DisengageCause::Stop { .. }
                | DisengageCause::Watchdog { .. }
                | DisengageCause::Override { .. }
                | DisengageCause::Blocked { .. }
                | DisengageCause::Fault { .. }
                | DisengageCause::GaveUp { .. }
                | DisengageCause::GivingUp { .. }
                | DisengageCause::Stalled { .. }
                | DisengageCause::Stopping { .. }
                | DisengageCause::Characterize { .. } => {}
            }
        }
        all
    }

    /// Each cause of the gate says its words (the snapshot's `reason`, rendered from
    /// the cause alone), and travels in the snapshot's JSON as its `kind` with its
    /// particulars: what a front end matches on, never the words.
    #[test]
    fn every_gate_cause_says_its_words_and_round_trips_by_kind() {
        let mut causes = vec![
            (
                GateCause::NotEngagedYet,
                "not_engaged_yet",
                "not engaged yet",
            ),
            (
                GateCause::Engaged {
                    by: "console".into(),
                },
                "engaged",
                "engaged by console",
            ),
        ];
        let disengaged = every_disengage().into_iter().map(|(why, _, words)| {
            let said: &'static str = format!("disengaged: {words}").leak();
            (GateCause::Disengaged { why }, "disengaged", said)
        });
        causes.extend(disengaged);
        for (cause, kind, words) in causes {
            assert_eq!(cause.to_string(), words);
            let gate = GateView {
                reason: cause.to_string(),
                cause: cause.clone(),
                ..GateView::default()
            };
            let json = serde_json::to_value(&gate).unwrap();
            assert_eq!(json["cause"]["kind"], kind, "{json}");
            assert_eq!(json["reason"], words, "{json}");
            let back: GateView = serde_json::from_value(json).unwrap();
            assert_eq!(back.cause, cause);
            let why = cause.why();
            assert!(
                words.ends_with(&why) && !why.starts_with("disengaged"),
                "{why}"
            );
        }
        for (why, kind, words) in every_disengage() {
            assert_eq!(why.to_string(), words);
            let cause = GateCause::Disengaged { why: why.clone() };
            assert_eq!(cause.why(), words);
            let json = serde_json::to_value(&cause).unwrap();
            assert_eq!(json["why"]["kind"], kind, "{json}");
        }
        // A snapshot of before the cause (schema 4 as first broadcast) still reads.
        let old: GateView = serde_json::from_value(serde_json::json!({
            "engaged": false, "reason": "not engaged yet", "blockers": [],
            "interlocks": true, "rules": [], "roles": {}, "accel": false
        }))
        .unwrap();
        assert_eq!(old.cause, GateCause::NotEngagedYet);
    }

    /// Each blocker's words, in one sentence: what the broadcast's `blockers`, an
    /// engage's refusal and the disengage's reason say.
    #[test]
    fn blockers_say_what_blocks() {
        let all = [
            Blocker::Overridden {
                device: "steer".into(),
            },
            Blocker::Faulty {
                device: "gas".into(),
                fault: "timeout".into(),
            },
            Blocker::Searching {
                device: "obd".into(),
                up_to_s: 10,
            },
            Blocker::NotReported {
                device: "obd".into(),
            },
            Blocker::Estop {
                state: EstopState::Pause,
            },
            Blocker::Stalled {
                stall: StallView {
                    thread: "steer/status".into(),
                    quiet_ms: 1400.0,
                    bound_ms: 450.0,
                },
            },
        ];
        assert_eq!(
            Blocker::said(&all),
            "steer is in the driver's hands (override): clear it once the driver has let go; \
             gas is faulty (timeout); \
             obd: the adapter is searching the car's protocols, up to 10 s; \
             obd has not reported yet; e-stop is in pause; \
             thread steer/status has not turned its loop for 1.4 s (bound 0.45 s)"
        );
        let json = serde_json::to_value(&all[1]).unwrap();
        assert_eq!(
            json,
            serde_json::json!({"kind": "faulty", "device": "gas", "fault": "timeout"})
        );
    }

    /// A port's backoff doubles to its cap: until then the line says when the next try
    /// is and that the tries thin out, not that they come every 100 ms.
    #[test]
    fn a_waiting_device_says_how_its_retries_go() {
        let mut w = WaitingView {
            device: "horn".into(),
            port: "/dev/ttyUSB3".into(),
            error: "No such file or directory".into(),
            gone_ms: 0.0,
            retry_ms: 100.0,
            needed: false,
        };
        assert_eq!(
            w.describe(),
            "waiting for horn on /dev/ttyUSB3: No such file or directory, retrying in 100ms, \
             then less often up to every 5s"
        );
        w.retry_ms = 5_000.0;
        assert_eq!(
            w.describe(),
            "waiting for horn on /dev/ttyUSB3: No such file or directory, retrying every 5s"
        );
    }

    /// `schemas/snapshot-4.json` is the JSON Schema of exactly this type (its field
    /// documentation included); `UPDATE_SCHEMA=1 cargo test --lib snapshot` rewrites it
    /// after a change. tests/schema.rs checks real broadcasts against the file.
    #[test]
    fn the_schema_file_describes_this_snapshot() {
        let mut schema = schemars::schema_for!(Snapshot);
        schema.insert(
            "$id".into(),
            format!("urn:adrive:schema:snapshot-{SCHEMA}").into(),
        );
        schema.insert(
            "title".into(),
            format!("adrive state snapshot, schema {SCHEMA}").into(),
        );
        let text = serde_json::to_string_pretty(&schema).unwrap() + "\n";
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/schemas/snapshot-4.json");
        assert!(path.ends_with(&format!("snapshot-{SCHEMA}.json")));
        if std::env::var_os("UPDATE_SCHEMA").is_some() {
            std::fs::write(path, &text).unwrap();
        }
        let file = std::fs::read_to_string(path).unwrap_or_default();
        assert!(
            file == text,
            "{path} is not the schema of Snapshot: rerun with UPDATE_SCHEMA=1 and review the diff"
        );
    }
}
