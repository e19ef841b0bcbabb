//! The vehicle structure (the paper's "vehicle struct"): every device with its
//! configuration, cached state, command slot, port and statistics, plus command intake.
//! Threads share one `Arc<Vehicle>`; readers only ever read the cache.

use crate::config::{DeviceConfig, VehicleConfig, Violation};
use crate::driver::DriverError;
use crate::engine::port::{Conn, Opener, Port};
use crate::engine::slot::CommandSlot;
use crate::engine::stats::Stats;
use crate::engine::trace::Trace;
use crate::interlock::{self, Facts, Reject};
use crate::logging::RateLimit;
use crate::value::{Command, EstopState, Reading, Role};
use parking_lot::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering::Relaxed, Ordering::SeqCst};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// After this many failed transactions in a row a device counts as faulty.
pub const FAULT_AFTER: u32 = 3;

/// A command thread that waits at the wire for another device's command waits at most
/// two of that device's reply timeouts (the transaction on its wire, then this one) and
/// this much more.
const WIRE_SLACK: Duration = Duration::from_millis(50);

/// A device's error that persists unchanged is logged again this often.
pub const REPEAT_ERROR_EVERY: Duration = Duration::from_secs(60);

/// The safe state: gas released, brake full.
pub const SAFE_GAS: f64 = 0.0;
pub const SAFE_BRAKE: f64 = 1.0;

/// The latest state a device reported.
#[derive(Clone, Copy, Debug, Default)]
pub struct Cached {
    pub reading: Reading,
    /// When it was read; `None` before the first good poll.
    pub at: Option<Instant>,
}

impl Cached {
    pub fn age(&self) -> Option<Duration> {
        self.at.map(|t| t.elapsed())
    }
}

/// Error codes shown per thread, as on the paper's screen: 0 is good, ≥ 1 is bad.
pub fn error_code(e: &DriverError) -> u32 {
    match e {
        DriverError::Timeout(_) => 1,
        DriverError::Garbled(_) => 2,
        DriverError::Refused(_) => 3,
        DriverError::Unsupported(_) => 4,
        DriverError::Io(_) => 5,
    }
}

/// Health of a device, kept by its threads.
#[derive(Default)]
pub struct Health {
    pub status_error: AtomicU32,
    pub command_error: AtomicU32,
    pub consecutive_errors: AtomicU32,
    pub connected: AtomicBool,
    pub last_error: Mutex<Option<(Instant, String)>>,
    /// When the device last answered (a good status or an acknowledged command), in
    /// nanoseconds after [`Device::started`] plus one; 0 before its first answer.
    answered_ns: AtomicU64,
    /// When an error was last logged.
    error_logged: Mutex<Option<Instant>>,
}

/// Settings the console can change while running.
pub struct Settings {
    status_period_us: AtomicU64,
    command_timeout_us: AtomicU64,
    pub status_enabled: AtomicBool,
    pub command_enabled: AtomicBool,
}

impl Settings {
    fn new(c: &DeviceConfig) -> Settings {
        Settings {
            status_period_us: AtomicU64::new(c.status_period.as_micros() as u64),
            command_timeout_us: AtomicU64::new(c.command_timeout.as_micros() as u64),
            status_enabled: AtomicBool::new(true),
            command_enabled: AtomicBool::new(true),
        }
    }
    pub fn status_period(&self) -> Duration {
        Duration::from_micros(self.status_period_us.load(Relaxed))
    }
    pub fn command_timeout(&self) -> Duration {
        Duration::from_micros(self.command_timeout_us.load(Relaxed))
    }
    fn set_status_period(&self, d: Duration) {
        self.status_period_us
            .store(d.as_micros().max(1000) as u64, Relaxed);
    }
    fn set_command_timeout(&self, d: Duration) {
        self.command_timeout_us
            .store(d.as_micros().max(1000) as u64, Relaxed);
    }
}

/// One device of the vehicle.
pub struct Device {
    pub role: Role,
    pub config: DeviceConfig,
    pub slot: CommandSlot,
    pub port: Port,
    pub cache: Mutex<Cached>,
    pub stats: Stats,
    pub settings: Settings,
    pub health: Health,
    /// Raw traffic on the port.
    pub trace: Arc<Trace>,
    /// Times the port was opened, and whether it is missing.
    pub port_health: Arc<crate::engine::port::PortHealth>,
    /// When the device was set up (the engine starts right after).
    pub started: Instant,
}

impl Device {
    pub fn new(config: DeviceConfig, opener: Opener) -> Device {
        let driver = crate::driver::build(&config);
        let trace = Arc::new(Trace::new(config.name.as_str()));
        let port_health = Arc::new(crate::engine::port::PortHealth::default());
        Device {
            role: config.name,
            port: Port::new(
                config.port_rule,
                Conn::new(driver, opener, trace.clone(), port_health.clone()),
            ),
            port_health,
            trace,
            settings: Settings::new(&config),
            config,
            slot: CommandSlot::default(),
            cache: Mutex::new(Cached::default()),
            stats: Stats::default(),
            health: Health::default(),
            started: Instant::now(),
        }
    }

    pub fn is_actuator(&self) -> bool {
        self.role.is_actuator()
    }

    /// Change the settings the console edits in place (`st delay`, `cm delay`): the
    /// device's configuration with the change must pass the very checks a vehicle file
    /// does ([`DeviceConfig::check`]), or nothing changes.
    pub fn change_settings(&self, change: impl FnOnce(&mut DeviceConfig)) -> Result<(), Violation> {
        let mut c = self.config.clone();
        c.status_period = self.settings.status_period();
        c.command_timeout = self.settings.command_timeout();
        change(&mut c);
        c.check()?;
        self.settings.set_status_period(c.status_period);
        self.settings.set_command_timeout(c.command_timeout);
        Ok(())
    }

    pub fn cached(&self) -> Cached {
        *self.cache.lock()
    }

    /// Faulty: failing repeatedly (its port gone, too), or silent.
    pub fn is_faulty(&self) -> bool {
        self.fault().is_some()
    }

    /// Why the device is faulty, if it is: its last error after [`FAULT_AFTER`] failed
    /// transactions in a row, or its silence ([`Device::silence`]).
    pub fn fault(&self) -> Option<String> {
        let last = || {
            let last = self.health.last_error.lock();
            last.as_ref().map(|(_, m)| m.clone())
        };
        if self.health.consecutive_errors.load(Relaxed) >= FAULT_AFTER {
            return Some(last().unwrap_or_else(|| "failing".into()));
        }
        let quiet = self.silence(Instant::now())?;
        Some(format!(
            "no answer for {} ms (max {} ms)",
            quiet.as_millis(),
            self.config.status_max_age.as_millis()
        ))
    }

    /// How long since the device last answered — a good status or an acknowledged
    /// command; `None` before its first answer.
    pub fn quiet_for(&self, now: Instant) -> Option<Duration> {
        match self.health.answered_ns.load(Relaxed) {
            0 => None,
            ns => Some(now.saturating_duration_since(self.started + Duration::from_nanos(ns - 1))),
        }
    }

    /// The device is silent: it answered once, but nothing for longer than its
    /// `status_max_age` (while its status polls are on). This is the one silence rule:
    /// computed from the time of the last answer whenever it is asked, it holds by
    /// construction — the gate monitor, which looks every 10 ms, disengages within
    /// `status_max_age` + 10 ms of the last answer, whatever the reply timeout or the
    /// supervisor's period. Commands count as answers: a device busy acknowledging a
    /// command flood is not silent while its next status poll waits for the port.
    pub fn silence(&self, now: Instant) -> Option<Duration> {
        self.quiet_for(now)
            .filter(|quiet| self.is_silent_after(*quiet))
    }

    /// Quiet this long, the device counts as silent.
    pub fn is_silent_after(&self, quiet: Duration) -> bool {
        quiet > self.config.status_max_age && self.settings.status_enabled.load(Relaxed)
    }

    /// A transaction succeeded at `at`.
    pub(crate) fn record_ok(&self, at: Instant) {
        self.health.consecutive_errors.store(0, Relaxed);
        self.health.connected.store(true, Relaxed);
        let ns = at.saturating_duration_since(self.started).as_nanos() as u64 + 1;
        self.health.answered_ns.fetch_max(ns, Relaxed);
    }

    pub(crate) fn record_error(&self, e: &DriverError, is_command: bool) {
        let n = self.health.consecutive_errors.fetch_add(1, Relaxed) + 1;
        let code = error_code(e);
        if is_command {
            self.health.command_error.store(code, Relaxed);
        } else {
            self.health.status_error.store(code, Relaxed);
        }
        if e.is_disconnect() {
            self.health.connected.store(false, Relaxed);
        }
        let msg = e.to_string();
        let now = Instant::now();
        let mut last = self.health.last_error.lock();
        let fresh = n == 1 || last.as_ref().is_none_or(|(_, m)| *m != msg);
        *last = Some((now, msg));
        drop(last);
        // Log the first error of a run and every change of message; an error that
        // persists (a port that is not there) is repeated rarely, not at the poll rate.
        let mut logged = self.health.error_logged.lock();
        let due = fresh || logged.is_none_or(|t| now - t >= REPEAT_ERROR_EVERY);
        if due {
            *logged = Some(now);
        }
        drop(logged);
        if due {
            tracing::warn!(device = %self.role, errors_in_a_row = n, "{}: {e}", if is_command { "command" } else { "status" });
        }
    }
}

/// The whole vehicle.
pub struct Vehicle {
    pub name: String,
    pub config: VehicleConfig,
    pub devices: Vec<Device>,
    /// Interlock rules at intake; switched off only from the console, with confirmation.
    pub interlocks: AtomicBool,
    engaged: AtomicBool,
    /// What the supervisor sees: faults and the recovery in progress.
    pub supervision: Arc<crate::supervisor::status::Status>,
    /// Devices a recovery procedure has taken over (bit per role): intake refuses them.
    recovering: std::sync::atomic::AtomicU8,
    /// Why the vehicle is (dis)engaged, for the console and the broadcast.
    gate_reason: Mutex<String>,
    rejections: [AtomicU64; Reject::ALL.len()],
    /// Rejections are logged at most 10 a second (a planner at 100 Hz must not flood).
    reject_log: Mutex<RateLimit>,
}

impl Vehicle {
    /// Build the vehicle; `open` makes the opener of each device's port.
    pub fn new(config: VehicleConfig, mut open: impl FnMut(&DeviceConfig) -> Opener) -> Vehicle {
        let devices = config
            .devices
            .iter()
            .map(|c| Device::new(c.clone(), open(c)))
            .collect();
        Vehicle {
            name: config.vehicle.name.clone(),
            config,
            devices,
            interlocks: AtomicBool::new(true),
            engaged: AtomicBool::new(false),
            supervision: Default::default(),
            recovering: Default::default(),
            gate_reason: Mutex::new("not engaged yet".into()),
            rejections: Default::default(),
            reject_log: Mutex::new(RateLimit::new(10)),
        }
    }

    pub fn device(&self, role: Role) -> Option<&Device> {
        self.devices.iter().find(|d| d.role == role)
    }

    /// Rejections so far, by reason.
    pub fn rejections(&self) -> Vec<(Reject, u64)> {
        Reject::ALL
            .iter()
            .map(|r| (*r, self.rejections[r.index()].load(Relaxed)))
            .collect()
    }

    /// What the interlocks know right now, from caches and slots.
    pub fn facts(&self) -> Facts {
        let mut brake_releasing = false;
        let brake = self.device(Role::Brake).map(|d| {
            let vals = d.slot.in_flight();
            let [pending, last, _] = vals;
            brake_releasing = pending
                .or(last)
                .and_then(Command::set_point)
                .is_some_and(|v| v <= interlock::RELEASED);
            let nums = vals.iter().flatten().filter_map(|c| c.set_point());
            let (lo, hi) = nums.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            });
            if lo.is_finite() {
                (lo, hi)
            } else {
                // Nothing commanded yet: judge by what the brake reports.
                let p = d.cached().reading.position.unwrap_or(0.0);
                (p, p)
            }
        });
        let reading = |role| {
            let c = self.device(role)?.cached();
            c.at.map(|_| c.reading)
        };
        let trans = reading(Role::Trans);
        let shifting = self
            .device(Role::Trans)
            .is_some_and(|d| match d.slot.latest() {
                Some(Command::Gear(g)) => trans.and_then(|r| r.gear) != Some(g),
                _ => false,
            });
        let obd = reading(Role::Obd);
        let estop = reading(Role::Estop);
        Facts {
            brake_low: brake.map(|b| b.0),
            brake_high: brake.map(|b| b.1),
            brake_releasing,
            gear: trans.and_then(|r| r.gear),
            running: obd.and_then(|r| r.running),
            speed: obd.and_then(|r| r.speed),
            estop: estop.and_then(|r| r.estop),
            shifting,
        }
    }

    fn reject(&self, device: Option<&Device>, command: Option<Command>, why: Reject) -> Reject {
        self.rejections[why.index()].fetch_add(1, Relaxed);
        if let Some(d) = device {
            Stats::bump(&d.stats.rejected);
        }
        if !self.reject_log.lock().allow(Instant::now()) {
            return why;
        }
        tracing::info!(
            device = device.map(|d| d.role.as_str()).unwrap_or("-"),
            command = command.map(|c| c.to_string()).unwrap_or_default(),
            "rejected: {why}"
        );
        why
    }

    pub fn is_engaged(&self) -> bool {
        self.engaged.load(SeqCst)
    }

    /// Why the vehicle is engaged or not.
    pub fn gate_reason(&self) -> String {
        self.gate_reason.lock().clone()
    }

    /// Reasons engaging is refused right now (empty: it may engage).
    pub fn engage_blockers(&self) -> Vec<String> {
        let mut why = Vec::new();
        for d in &self.devices {
            if let Some(fault) = d.fault() {
                why.push(format!("{} is faulty ({fault})", d.role));
            } else if d.cached().at.is_none() {
                why.push(format!("{} has not reported yet", d.role));
            }
        }
        if let Some(EstopState::Pause | EstopState::Disable) = self.estop() {
            why.push(format!("e-stop is in {}", self.estop().expect("just read")));
        }
        why
    }

    /// Engage: accept commands from now on. Refused while any device is faulty. Every
    /// command slot is reset first so nothing resends a stale set point: gas 0, brake
    /// full, steering held where it is, the gear left as it is.
    pub fn engage(&self, by: &str) -> Result<(), Vec<String>> {
        let blockers = self.engage_blockers();
        if !blockers.is_empty() {
            tracing::warn!(by, "engage refused: {}", blockers.join("; "));
            return Err(blockers);
        }
        for d in &self.devices {
            if !d.is_actuator() {
                continue;
            }
            d.slot.reset(None);
        }
        self.command_safe_state();
        if let Some(s) = self.device(Role::Steer) {
            if let Some(p) = s.cached().reading.position {
                self.store(s, Command::Set(p), Instant::now());
            }
        }
        *self.gate_reason.lock() = format!("engaged by {by}");
        self.engaged.store(true, SeqCst);
        tracing::info!(by, "engaged");
        Ok(())
    }

    /// Disengage and command the safe state. Returns false if it was not engaged.
    pub fn disengage(&self, reason: &str) -> bool {
        let was = self.engaged.swap(false, SeqCst);
        *self.gate_reason.lock() = format!("disengaged: {reason}");
        self.command_safe_state();
        if was {
            tracing::warn!("disengaged: {reason}");
        }
        was
    }

    /// Command intake: check the command, then store it in the device's slot and wake
    /// its command thread. `received` is when the command was born (socket read, key
    /// press). Nothing is written here; a rejected command never reaches the slot.
    pub fn submit(&self, role: Role, command: Command, received: Instant) -> Result<(), Reject> {
        let Some(d) = self.device(role) else {
            return Err(self.reject(None, Some(command), Reject::NoSuchDevice));
        };
        if !d.is_actuator() {
            return Err(self.reject(Some(d), Some(command), Reject::NotAnActuator));
        }
        match (role, command) {
            (Role::Trans, Command::Gear(_)) | (_, Command::Control(_)) => {}
            (Role::Trans, Command::Set(_)) | (_, Command::Gear(_)) => {
                return Err(self.reject(Some(d), Some(command), Reject::WrongKind))
            }
            (_, Command::Set(v)) => {
                if !v.is_finite() {
                    return Err(self.reject(Some(d), Some(command), Reject::NotFinite));
                }
                let [lo, hi] = d.config.range();
                if v < lo || v > hi {
                    return Err(self.reject(Some(d), Some(command), Reject::OutOfRange));
                }
            }
        }
        if !self.is_engaged() {
            return Err(self.reject(Some(d), Some(command), Reject::Disengaged));
        }
        if self.is_recovering(role) {
            return Err(self.reject(Some(d), Some(command), Reject::Recovering));
        }
        if self.interlocks.load(Relaxed) {
            if let Err(why) = interlock::check(&self.facts(), role, command) {
                return Err(self.reject(Some(d), Some(command), why));
            }
        }
        self.store(d, command, received);
        // A disengage that raced this command (it checks the gate, then stores): the
        // safe state must be the last word.
        if !self.is_engaged() {
            self.command_safe_state();
        }
        Ok(())
    }

    fn store(&self, d: &Device, command: Command, received: Instant) {
        Stats::bump(&d.stats.received);
        if d.slot.submit(command, received) {
            Stats::bump(&d.stats.superseded);
        }
    }

    /// The follower's virtual `accel` command, −1…1: positive is gas, negative is brake;
    /// it never applies both. Going from braking to gas, the brake release is submitted
    /// first and the gas with it: the gas's command thread holds it back until the
    /// release has reached the brake ([`Vehicle::clear_to_send`]), so one `accel` is
    /// enough. While a shift is under way the brake holds and positive `accel` waits.
    pub fn submit_accel(&self, a: f64, received: Instant) -> Result<(), Reject> {
        if !a.is_finite() {
            return Err(self.reject(None, None, Reject::NotFinite));
        }
        if !(-1.0..=1.0).contains(&a) {
            return Err(self.reject(None, None, Reject::OutOfRange));
        }
        if a > 0.0 {
            if self.interlocks.load(Relaxed) && self.facts().shifting {
                tracing::debug!("accel {a}: the brake holds until the shift is through");
                return Ok(());
            }
            self.submit(Role::Brake, Command::Set(0.0), received)?;
            self.submit(Role::Gas, Command::Set(a), received)
        } else {
            self.submit(Role::Gas, Command::Set(0.0), received)?;
            self.submit(Role::Brake, Command::Set(-a), received)
        }
    }

    /// A recovery procedure takes these devices over (intake refuses them) or, with an
    /// empty list, hands everything back.
    pub fn set_recovering(&self, roles: &[Role]) {
        let mask = roles.iter().fold(0u8, |m, r| m | 1 << (*r as u8));
        self.recovering.store(mask, Relaxed);
    }

    pub fn is_recovering(&self, role: Role) -> bool {
        self.recovering.load(Relaxed) & (1 << (role as u8)) != 0
    }

    /// The supervisor's own commands: past the gate and the intake interlocks (the
    /// wire-level checks in [`Vehicle::clear_to_send`] still apply).
    pub fn override_command(&self, role: Role, command: Command) {
        if let Some(d) = self.device(role) {
            self.store(d, command, Instant::now());
        }
    }

    /// The last check, made by a command thread right before its command goes on the
    /// wire, against what the other actuators have on or are putting on the wire. Intake
    /// checked the same rules, but gas and brake have threads of their own, so a brake
    /// command submitted a moment after a gas command could otherwise reach its device
    /// first. Each thread has already recorded its own command in its slot before it
    /// looks at the others', so of two racing threads at least one sees the other.
    ///
    /// Returns what to send instead (`None`: nothing). Braking is never refused: it
    /// first has the gas released and waits a bounded time for that to reach the wire.
    /// Gas that follows a brake release (an `accel` from braking) likewise waits, a
    /// bounded time, for the release to reach the wire; if it does not, or the brake is
    /// applied again meanwhile, the gas goes out as 0.
    pub fn clear_to_send(&self, role: Role, command: Command) -> Option<Command> {
        if !self.interlocks.load(Relaxed) {
            return Some(command);
        }
        let set = |c: Option<Command>| c.and_then(Command::set_point);
        let released = |c: Option<Command>| set(c).is_none_or(|v| v <= interlock::RELEASED);
        // Nothing applied pending, in flight or on the wire.
        let clear = |p, l, s| released(p) && released(l) && released(s);
        match (role, command) {
            (Role::Gas, Command::Set(v)) if v > interlock::RELEASED => {
                let braking = self.device(Role::Brake).is_some_and(|b| {
                    let (p, l, s) = b.slot.wire();
                    if clear(p, l, s) {
                        return false;
                    }
                    if !released(p.or(l)) {
                        return true;
                    }
                    // The newest brake command releases it: wait for that to land, or
                    // for the brake to be applied again.
                    let deadline = Instant::now() + b.config.reply_timeout * 2 + WIRE_SLACK;
                    b.slot
                        .wait_wire(|p, l, s| clear(p, l, s) || !released(p.or(l)), deadline);
                    let (p, l, s) = b.slot.wire();
                    !clear(p, l, s)
                });
                let why = if braking {
                    Some(Reject::GasWhileBraking)
                } else if self.estop() != Some(EstopState::Run) {
                    Some(Reject::GasEstop)
                } else {
                    None
                };
                match why {
                    Some(why) => {
                        self.reject(self.device(Role::Gas), Some(command), why);
                        Some(Command::Set(0.0))
                    }
                    None => Some(command),
                }
            }
            (Role::Brake, Command::Set(v)) => {
                if v > interlock::RELEASED {
                    if let Some(g) = self.device(Role::Gas) {
                        let (p, l, _) = g.slot.wire();
                        if !(released(p) && released(l)) {
                            self.store(g, Command::Set(0.0), Instant::now());
                        }
                        let deadline = Instant::now() + g.config.reply_timeout * 2 + WIRE_SLACK;
                        g.slot.wait_wire(clear, deadline);
                    }
                }
                if v < interlock::SHIFT_BRAKE {
                    // A shift on its way keeps the brake on until it is through.
                    if let Some(t) = self.device(Role::Trans) {
                        let deadline = Instant::now() + t.config.reply_timeout * 2 + WIRE_SLACK;
                        t.slot.wait_wire(|p, l, s| p.is_none() && l == s, deadline);
                    }
                }
                Some(command)
            }
            (Role::Trans, Command::Gear(g)) => {
                let facts = self.facts();
                if Some(g) == facts.gear {
                    return Some(command);
                }
                let why = if !facts.speed.is_some_and(|s| s.abs() < interlock::STOPPED) {
                    Some(Reject::ShiftWhileMoving)
                } else if !facts.brake_low.is_some_and(|b| b >= interlock::SHIFT_BRAKE)
                    || self.device(Role::Brake).is_some_and(|b| {
                        let (p, l, s) = b.slot.wire();
                        [p, l, s]
                            .iter()
                            .any(|c| set(*c).is_some_and(|v| v < interlock::SHIFT_BRAKE))
                    })
                {
                    Some(Reject::ShiftWithoutBrake)
                } else {
                    None
                };
                match why {
                    Some(why) => {
                        self.reject(self.device(Role::Trans), Some(command), why);
                        None
                    }
                    None => Some(command),
                }
            }
            _ => Some(command),
        }
    }

    /// Command the safe state (gas 0, brake full) to every actuator there is,
    /// bypassing the interlocks (the safe state is always allowed).
    pub fn command_safe_state(&self) {
        let now = Instant::now();
        if let Some(g) = self.device(Role::Gas) {
            self.store(g, Command::Set(SAFE_GAS), now);
        }
        if let Some(b) = self.device(Role::Brake) {
            self.store(b, Command::Set(SAFE_BRAKE), now);
        }
    }

    /// Wait until every reachable gas and brake device acknowledged the safe state.
    /// Returns false if one did not by the deadline.
    pub fn wait_safe(&self, deadline: Instant) -> bool {
        let mut ok = true;
        for (role, value) in [(Role::Gas, SAFE_GAS), (Role::Brake, SAFE_BRAKE)] {
            if let Some(d) = self.device(role) {
                let done = d.slot.wait_executed(|c| c == Command::Set(value), deadline);
                if !done {
                    tracing::error!(device = %role, "did not acknowledge the safe state");
                    ok = false;
                }
            }
        }
        ok
    }

    /// The e-stop's last reported state.
    pub fn estop(&self) -> Option<EstopState> {
        let c = self.device(Role::Estop)?.cached();
        c.at.and(c.reading.estop)
    }
}
