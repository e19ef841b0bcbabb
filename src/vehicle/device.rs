//! One device of the vehicle: its configuration, its command slot and shared port,
//! the cache its status thread fills, its statistics, health and the settings the
//! console may change while running. Threads share it through the
//! [`Vehicle`](super::Vehicle); readers only ever read the cache.

use super::estimate::{Correction, Estimate, Estimator};
use super::stats::Stats;
use super::tap::{Event, Tap};
use crate::config::{DeviceConfig, Role, Violation};
use crate::driver::DriverError;
use crate::port::slot::CommandSlot;
use crate::port::trace::Trace;
use crate::port::wake::PortWake;
use crate::port::{Conn, Opener, Port, PortHealth};
use crate::value::{Command, DeviceId, Kind, Reading};
use parking_lot::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// After this many failed transactions in a row a device counts as faulty.
pub const FAULT_AFTER: u32 = 3;

/// The latest state a device reported.
#[derive(Clone, Copy, Debug, Default)]
pub struct Cached {
    pub reading: Reading,
    /// When it was read; `None` before the first good poll.
    pub at: Option<Instant>,
    /// When the request that read it went out (its first byte taken by the kernel):
    /// the device took the reading between this and [`Cached::at`]. `None` for a
    /// reading no request of ours asked for (a bus's frames).
    pub asked: Option<Instant>,
}

impl Cached {
    pub fn age(&self) -> Option<Duration> {
        self.at.map(|t| t.elapsed())
    }
}

/// What the command thread of a device on a serial line sleeps on, so that a request
/// handed over to it wakes it by its reply ([`crate::port::wake`]). A device on a CAN
/// bus has its replies read by the bus's reader: its command thread sleeps on its slot's
/// condition variable, as does a sensor's (it has none) and, should the system refuse
/// the descriptors, any device's.
fn port_wake(config: &DeviceConfig) -> Option<Arc<PortWake>> {
    if !config.is_actuator() || config.on_bus() {
        return None;
    }
    match PortWake::new() {
        Ok(w) => Some(Arc::new(w)),
        Err(e) => {
            tracing::warn!(device = %config.name, "cannot wait on the port ({e}): the command thread is woken by a signal");
            None
        }
    }
}

/// Error codes shown per thread, as on the paper's screen: 0 is good, ≥ 1 is bad.
pub fn error_code(e: &DriverError) -> u32 {
    match e {
        DriverError::Timeout(_) | DriverError::Late { .. } => 1,
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
    pub(crate) consecutive_errors: AtomicU32,
    pub connected: AtomicBool,
    pub(crate) last_error: Mutex<Option<(Instant, String)>>,
    /// When the device last answered (a good status or an acknowledged command), in
    /// nanoseconds after [`Device::started`] plus one; 0 before its first answer.
    answered_ns: AtomicU64,
    /// Errors that repeat, logged when they start or change, then once a minute.
    errors_logged: Mutex<crate::logging::Repeats>,
}

impl Health {
    pub(crate) fn last_error(&self) -> Option<String> {
        self.last_error.lock().as_ref().map(|(_, m)| m.clone())
    }

    /// When the last error happened.
    pub(crate) fn last_error_at(&self) -> Option<Instant> {
        self.last_error.lock().as_ref().map(|(t, _)| *t)
    }
}

/// Settings the console can change while running.
pub struct Settings {
    status_period_us: AtomicU64,
    command_timeout_us: AtomicU64,
    pub(crate) status_enabled: AtomicBool,
    pub(crate) command_enabled: AtomicBool,
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

/// Why a device has no reading yet: a fact the engage gate says in words
/// (`crate::safety::gate_state::blockers`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Unreported {
    /// It has not reported yet.
    NotYet,
    /// Its port is open and its first answer comes once its adapter has searched the
    /// car's protocols, which takes up to this long (an ELM327).
    SearchingProtocols(Duration),
}

/// One device of the vehicle.
pub struct Device {
    id: DeviceId,
    config: DeviceConfig,
    /// The safety roles it plays (from the vehicle's bindings).
    roles: Vec<Role>,
    slot: CommandSlot,
    port: Port,
    cache: Mutex<Cached>,
    stats: Stats,
    settings: Settings,
    health: Health,
    /// Raw traffic on the port.
    trace: Arc<Trace>,
    /// Times the port was opened, and whether it is missing.
    port_health: Arc<PortHealth>,
    /// When the device was set up (the engine starts right after).
    started: Instant,
    /// The state estimator of a setpoint device with a declared response, and the
    /// index of the `position` reading it is corrected by.
    estimator: Option<(Mutex<Estimator>, usize)>,
    /// The vehicle's recording tap.
    tap: Arc<Tap>,
}

impl Device {
    pub fn new(
        id: DeviceId,
        config: DeviceConfig,
        roles: Vec<Role>,
        opener: Opener,
        tap: Arc<Tap>,
        buses: &[Arc<crate::driver::slcan::Bus>],
    ) -> Device {
        let driver = crate::driver::build_on(&config, buses);
        let raw = Arc::new(super::tap::RawOf {
            device: id,
            tap: tap.clone(),
        });
        let trace = Arc::new(Trace::new(config.name.as_str()).tapped(raw));
        let port_health = Arc::new(PortHealth::default());
        let estimator = config
            .response
            .zip(config.position())
            .map(|(r, i)| (Mutex::new(Estimator::new(r, config.range)), i));
        let mut conn = Conn::new(driver, opener, trace.clone(), port_health.clone(), &config);
        let slot = match port_wake(&config) {
            Some(w) => {
                conn = conn.woken_by(w.clone());
                CommandSlot::woken_by(w)
            }
            None => CommandSlot::default(),
        };
        Device {
            estimator,
            id,
            roles,
            port: Port::new(config.port_rule, conn),
            port_health,
            trace,
            settings: Settings::new(&config),
            config,
            slot,
            cache: Mutex::new(Cached::default()),
            stats: Stats::default(),
            health: Health::default(),
            started: Instant::now(),
            tap,
        }
    }

    /// Tap a command transaction for a recording: `command` as written (after the
    /// wire check), received at `received`, its first byte at `first`, answered at
    /// `done`. Heap-free; one atomic load when nothing records.
    #[inline]
    pub(crate) fn tap_written(
        &self,
        command: crate::value::Command,
        received: Instant,
        first: Option<Instant>,
        done: Instant,
        fresh: bool,
        error: Option<&DriverError>,
    ) {
        self.tap.send(|| Event::Written {
            device: self.id,
            command,
            received,
            first,
            done,
            fresh,
            error: error.map_or(0, error_code),
        });
    }

    /// Tap a status transaction for a recording: the reading, or the error.
    #[inline]
    pub(crate) fn tap_polled(
        &self,
        first: Option<Instant>,
        done: Instant,
        result: Result<&Reading, &DriverError>,
    ) {
        self.tap.send(|| Event::Polled {
            device: self.id,
            first,
            done,
            reading: result.ok().copied(),
            error: result.err().map_or(0, error_code),
        });
    }

    /// Change the settings the console edits in place (`st delay`, `cm delay`): the
    /// device's configuration with the change must pass the very checks a vehicle file
    /// does ([`DeviceConfig::check_limits`]), or nothing changes.
    pub(crate) fn change_settings(
        &self,
        change: impl FnOnce(&mut DeviceConfig),
    ) -> Result<(), Violation> {
        let mut c = self.config.clone();
        c.status_period = self.settings.status_period();
        c.command_timeout = self.settings.command_timeout();
        change(&mut c);
        c.check_limits()?;
        self.settings.set_status_period(c.status_period);
        self.settings.set_command_timeout(c.command_timeout);
        Ok(())
    }

    pub fn id(&self) -> DeviceId {
        self.id
    }

    /// The device as the vehicle file describes it (checked).
    pub fn config(&self) -> &DeviceConfig {
        &self.config
    }

    /// The safety roles it plays (from the vehicle's bindings).
    pub fn roles(&self) -> &[Role] {
        &self.roles
    }

    /// Its command slot: the latest command, in flight, sent and acknowledged.
    pub fn slot(&self) -> &CommandSlot {
        &self.slot
    }

    /// Its port, under the port's rule.
    pub fn port(&self) -> &Port {
        &self.port
    }

    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// What the console may change while it runs (delays, threads on and off).
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    pub fn health(&self) -> &Health {
        &self.health
    }

    /// Raw traffic on the port.
    pub fn trace(&self) -> &Arc<Trace> {
        &self.trace
    }

    /// Why the device has no reading yet (`None`: it has one).
    pub fn unreported(&self) -> Option<Unreported> {
        if self.cached().at.is_some() {
            return None;
        }
        let opened = self.port_health.opens.load(Relaxed) > 0;
        Some(match crate::driver::protocol_search(self.config.driver) {
            Some(up_to) if opened => Unreported::SearchingProtocols(up_to),
            _ => Unreported::NotYet,
        })
    }

    /// Times the port was opened, and whether it is missing.
    pub fn port_health(&self) -> &PortHealth {
        &self.port_health
    }

    /// When the device was set up (the engine starts right after).
    pub fn started(&self) -> Instant {
        self.started
    }

    /// Store what a status poll read (the status thread; test fixtures).
    pub fn store(&self, cached: Cached) {
        *self.cache.lock() = cached;
    }

    pub fn name(&self) -> &str {
        &self.config.name
    }

    pub fn kind(&self) -> Kind {
        self.config.kind
    }

    pub fn is_actuator(&self) -> bool {
        self.config.is_actuator()
    }

    pub fn plays(&self, role: Role) -> bool {
        self.roles.contains(&role)
    }

    pub fn cached(&self) -> Cached {
        *self.cache.lock()
    }

    /// What the estimator believes at `now` (`None` without a declared response, or
    /// before the first reading).
    pub fn estimate(&self, now: Instant) -> Option<Estimate> {
        self.estimator.as_ref()?.0.lock().at(now)
    }

    /// A copy of the estimator, to plan by (`None` without a declared response).
    pub fn estimator(&self) -> Option<Estimator> {
        self.estimator.as_ref().map(|(e, _)| e.lock().clone())
    }

    /// The device acknowledged `command` at `at`: the estimate moves toward it.
    pub(crate) fn estimate_command(&self, command: Command, at: Instant) {
        if let (Some((e, _)), Command::Set(v)) = (&self.estimator, command) {
            e.lock().command(v, at);
        }
    }

    /// A good status taken at `at` corrects the estimate.
    pub(crate) fn estimate_reading(&self, reading: &Reading, at: Instant) -> Option<Correction> {
        let (e, i) = self.estimator.as_ref()?;
        let position = reading.get(*i)?;
        Some(e.lock().correct(position, at))
    }

    /// A reading of the last good status, if there is one.
    pub fn reading(&self, i: usize) -> Option<f64> {
        let c = self.cached();
        c.at.and(c.reading.get(i))
    }

    /// Faulty: failing repeatedly (its port gone, too), or silent.
    pub fn is_faulty(&self) -> bool {
        self.fault().is_some()
    }

    /// Why the device is faulty, if it is: its last error after [`FAULT_AFTER`] failed
    /// transactions in a row, or its silence ([`Device::silence`]).
    pub fn fault(&self) -> Option<String> {
        // A port that is gone (a bus's adapter: every device on it at once), without
        // waiting for errors to add up: the engine tries it again only as often as its
        // backoff allows, and engage must not slip in meanwhile.
        if self.port_health.missing.load(Relaxed) {
            return Some(
                self.health
                    .last_error()
                    .unwrap_or_else(|| "port gone".into()),
            );
        }
        if self.health.consecutive_errors.load(Relaxed) >= FAULT_AFTER {
            return Some(self.health.last_error().unwrap_or_else(|| "failing".into()));
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
    pub(crate) fn quiet_for(&self, now: Instant) -> Option<Duration> {
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
    pub(crate) fn is_silent_after(&self, quiet: Duration) -> bool {
        quiet > self.config.status_max_age && self.settings.status_enabled.load(Relaxed)
    }

    /// A transaction succeeded at `at`.
    pub(crate) fn record_ok(&self, at: Instant) {
        self.health.consecutive_errors.store(0, Relaxed);
        self.health.connected.store(true, Relaxed);
        let ns = at.saturating_duration_since(self.started).as_nanos() as u64 + 1;
        self.health.answered_ns.fetch_max(ns, Relaxed);
    }

    /// One of its own transactions failed (`is_command`: a command's, else a poll's):
    /// the error is stored, then counted — a reader that sees the count finds the
    /// error's code and message.
    pub(crate) fn transaction_failed(&self, e: &DriverError, is_command: bool) {
        self.record_error(e, is_command);
        let count = if is_command {
            &self.stats.command_errors
        } else {
            &self.stats.status_errors
        };
        count.fetch_add(1, std::sync::atomic::Ordering::Release);
    }

    /// An error of the device (a transaction's, or its bus's) is stored: its code, its
    /// message, and whether it says the device is gone.
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
        *self.health.last_error.lock() = Some((now, msg.clone()));
        // Log the first error of a run and every change of message; an error that
        // persists (a port that is not there) is repeated once a minute with a count,
        // not at the poll rate.
        let repeats = {
            let mut logged = self.health.errors_logged.lock();
            if n == 1 {
                logged.clear();
            }
            logged.note(&msg, now)
        };
        if let Some(repeats) = repeats {
            let thread = if is_command { "command" } else { "status" };
            tracing::warn!(device = %self.name(), errors_in_a_row = n, "{thread}: {e}{repeats}");
        }
    }
}
