//! Vehicle configuration: which devices exist, how to reach them, how often to poll
//! them. Loaded from TOML; the built-in simulated Alice is `vehicles/alice.toml`,
//! compiled in. Loading is split into [`load`] (a path) and [`parse`] (text) so tests
//! feed bytes, and every error names the file, the line and what was expected.
//!
//! Safety-relevant values are held to the ranges of [`limits`]; where each key sits in
//! the file is [`document`]'s business, so that a check made after typing still names
//! its line.

pub mod document;
pub mod limits;

pub use crate::net::config::NetworkConfig;
use crate::value::Role;
use document::{Document, Lines};
pub use limits::Violation;
use serde::{Deserialize, Deserializer};
use std::fmt;
use std::path::Path;
use std::time::Duration;

/// The built-in vehicle, as shipped in `vehicles/alice.toml`.
pub const ALICE_TOML: &str = include_str!("../vehicles/alice.toml");
/// The name errors in the built-in vehicle are reported under.
pub const ALICE_PATH: &str = "vehicles/alice.toml";

/// A configuration error: `file:line: message` (`file: message` without a line, when
/// the file cannot be read at all).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct ConfigError {
    pub path: String,
    /// 1-based; 0 when the error is about the whole file.
    pub line: usize,
    pub message: String,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            0 => write!(f, "{}: {}", self.path, self.message),
            l => write!(f, "{}:{l}: {}", self.path, self.message),
        }
    }
}

/// How a device's two threads share its port.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum PortRule {
    /// adrive's rule: a status poll yields while a command waits for the port (but
    /// still runs at least every `status_max_age`).
    #[default]
    Priority,
    /// The paper's rule: first come, first served on a plain lock.
    Paper,
}

/// Which protocol a device speaks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DriverKind {
    /// The adrive ASCII line protocol.
    Line,
    /// Modbus RTU: servo drives, linear actuators, pedal robots.
    Modbus,
    /// An ELM327 OBD-II adapter.
    Elm327,
}

/// Settings of a Modbus RTU device: its slave id and register map.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModbusConfig {
    pub slave: u8,
    pub registers: crate::driver::modbus::RegisterMap,
}

/// Settings of the simulated device standing in for this one under `--sim`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimConfig {
    /// Time the device takes to start answering once a request is complete.
    #[serde(default = "default_turnaround", deserialize_with = "duration")]
    pub turnaround: Duration,
    /// Extra processing time for a status request (a slow device).
    #[serde(default, deserialize_with = "duration")]
    pub poll_delay: Duration,
    /// Extra processing time for a command.
    #[serde(default, deserialize_with = "duration")]
    pub command_delay: Duration,
    /// The device's own watchdog, as drive-by-wire firmware has: with no command frame
    /// for this long, a gas actuator goes to 0 and a brake actuator applies fully.
    #[serde(default, deserialize_with = "opt_duration")]
    pub watchdog: Option<Duration>,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            turnaround: default_turnaround(),
            poll_delay: limits::SIM_POLL_DELAY.default_value(),
            command_delay: limits::SIM_COMMAND_DELAY.default_value(),
            watchdog: None,
        }
    }
}

fn default_turnaround() -> Duration {
    limits::SIM_TURNAROUND.default_value()
}

/// One device.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceConfig {
    /// The device's role, which is also its name.
    pub name: Role,
    pub driver: DriverKind,
    /// Serial port path (`/dev/ttyUSB0`, `/dev/serial/by-id/…`). Unused under `--sim`.
    #[serde(default)]
    pub port: String,
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// How often the status thread polls the device.
    #[serde(default = "default_status_period", deserialize_with = "duration")]
    pub status_period: Duration,
    /// The command thread resends the last command when no new one came for this long.
    #[serde(default = "default_command_timeout", deserialize_with = "duration")]
    pub command_timeout: Duration,
    /// A status poll happens at least this often, even while commands keep the port busy.
    #[serde(default = "default_status_max_age", deserialize_with = "duration")]
    pub status_max_age: Duration,
    /// How long to wait for a reply.
    #[serde(default = "default_reply_timeout", deserialize_with = "duration")]
    pub reply_timeout: Duration,
    /// The paper's rate cap: at least this long between two commands. Off by default.
    #[serde(default, deserialize_with = "opt_duration")]
    pub min_command_interval: Option<Duration>,
    #[serde(default)]
    pub port_rule: PortRule,
    /// Value domain `[min, max]` of commands (steer, gas and brake only).
    #[serde(default, deserialize_with = "range")]
    pub range: Option<[f64; 2]>,
    #[serde(default)]
    pub sim: SimConfig,
    /// Required with `driver = "modbus"`.
    #[serde(default)]
    pub modbus: Option<ModbusConfig>,
}

fn default_baud() -> u32 {
    limits::BAUD.default_value() as u32
}
fn default_status_period() -> Duration {
    limits::STATUS_PERIOD.default_value()
}
fn default_command_timeout() -> Duration {
    limits::COMMAND_TIMEOUT.default_value()
}
fn default_status_max_age() -> Duration {
    limits::STATUS_MAX_AGE.default_value()
}
fn default_reply_timeout() -> Duration {
    limits::REPLY_TIMEOUT.default_value()
}

impl DeviceConfig {
    /// The command value domain: the configured range, or the role's natural one.
    pub fn range(&self) -> [f64; 2] {
        self.range.unwrap_or(domain(self.name))
    }

    /// Every limit and rule of one device, as the loader applies them to a vehicle
    /// file and the console to its in-place edits (`port` aside: see
    /// [`VehicleConfig::check_ports`]).
    pub fn check(&self) -> Result<(), Violation> {
        use limits::*;
        BAUD.check(u64::from(self.baud))?;
        STATUS_PERIOD.check(self.status_period)?;
        STATUS_MAX_AGE.check(self.status_max_age)?;
        COMMAND_TIMEOUT.check(self.command_timeout)?;
        REPLY_TIMEOUT.check(self.reply_timeout)?;
        if let Some(i) = self.min_command_interval {
            MIN_COMMAND_INTERVAL.check(i)?;
        }
        SIM_TURNAROUND.check(self.sim.turnaround)?;
        SIM_POLL_DELAY.check(self.sim.poll_delay)?;
        SIM_COMMAND_DELAY.check(self.sim.command_delay)?;
        if let Some(w) = self.sim.watchdog {
            SIM_WATCHDOG.check(w)?;
        }
        if let Some(m) = &self.modbus {
            MODBUS_SLAVE.check(u64::from(m.slave))?;
        }
        let show = fmt_duration;
        if self.status_max_age < self.status_period {
            return Err(MAX_AGE_COVERS_PERIOD.violation(
                &["status_max_age", "status_period"],
                format!(
                    "status_max_age {}, status_period {}",
                    show(self.status_max_age),
                    show(self.status_period)
                ),
            ));
        }
        if self.reply_timeout > self.status_max_age {
            return Err(REPLY_WITHIN_MAX_AGE.violation(
                &["reply_timeout", "status_max_age"],
                format!(
                    "reply_timeout {}, status_max_age {}",
                    show(self.reply_timeout),
                    show(self.status_max_age)
                ),
            ));
        }
        if let Some(w) = self.sim.watchdog.filter(|w| *w <= self.command_timeout) {
            return Err(WATCHDOG_OUTLASTS_RESEND.violation(
                &["sim.watchdog", "command_timeout"],
                format!(
                    "sim.watchdog {}, command_timeout {}",
                    show(w),
                    show(self.command_timeout)
                ),
            ));
        }
        if let Some([lo, hi]) = self.range {
            let [dlo, dhi] = domain(self.name);
            let safe = match self.name {
                Role::Gas => Some(crate::vehicle::SAFE_GAS),
                Role::Brake => Some(crate::vehicle::SAFE_BRAKE),
                _ => None,
            };
            let fits = matches!(self.name, Role::Steer | Role::Gas | Role::Brake)
                && lo.is_finite()
                && hi.is_finite()
                && dlo <= lo
                && lo < hi
                && hi <= dhi
                && safe.is_none_or(|v| lo <= v && v <= hi);
            if !fits {
                return Err(RANGE_FORM.violation(&["range"], format!("range [{lo}, {hi}]")));
            }
        }
        Ok(())
    }
}

/// The natural command domain of a role: steer −1 … 1, the pedals 0 … 1.
fn domain(role: Role) -> [f64; 2] {
    match role {
        Role::Steer => [-1.0, 1.0],
        _ => [0.0, 1.0],
    }
}

/// Vehicle-wide settings.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VehicleSettings {
    pub name: String,
}

/// How the supervisor watches and recovers (`[supervisor]` in the vehicle file).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SupervisorConfig {
    /// How often it looks (the paper's was 1 s).
    #[serde(deserialize_with = "duration")]
    pub period: Duration,
    /// Failed transactions over all transactions in `error_window` above which a device
    /// is at fault.
    pub error_rate: f64,
    #[serde(deserialize_with = "duration")]
    pub error_window: Duration,
    /// A measured value further than this from its command …
    pub follow_tolerance: f64,
    /// … for longer than this is "not following".
    #[serde(deserialize_with = "duration")]
    pub follow_time: Duration,
    /// Reported positions may stray this fraction of the range outside it.
    pub range_margin: f64,
    /// Tries of a recovery procedure before it gives up.
    pub attempts: u32,
    /// Time a recovery step may take.
    #[serde(deserialize_with = "duration")]
    pub step_timeout: Duration,
    /// A procedure that gives up is a fatal device error: end the process (status 4)
    /// after the safe state, so a service manager can act.
    pub exit_on_give_up: bool,
    /// Fault injection for tests (`--inject-panic supervisor:DELAY`).
    #[serde(skip)]
    pub panic_for_test: Option<Duration>,
}

impl Default for SupervisorConfig {
    fn default() -> Self {
        use limits::*;
        SupervisorConfig {
            period: SUPERVISOR_PERIOD.default_value(),
            error_rate: ERROR_RATE.default_value(),
            error_window: ERROR_WINDOW.default_value(),
            follow_tolerance: FOLLOW_TOLERANCE.default_value(),
            follow_time: FOLLOW_TIME.default_value(),
            range_margin: RANGE_MARGIN.default_value(),
            attempts: ATTEMPTS.default_value() as u32,
            step_timeout: STEP_TIMEOUT.default_value(),
            exit_on_give_up: true,
            panic_for_test: None,
        }
    }
}

impl SupervisorConfig {
    /// Every value within its limit.
    pub fn check(&self) -> Result<(), Violation> {
        use limits::*;
        SUPERVISOR_PERIOD.check(self.period)?;
        ERROR_RATE.check(self.error_rate)?;
        ERROR_WINDOW.check(self.error_window)?;
        FOLLOW_TOLERANCE.check(self.follow_tolerance)?;
        FOLLOW_TIME.check(self.follow_time)?;
        RANGE_MARGIN.check(self.range_margin)?;
        ATTEMPTS.check(u64::from(self.attempts))?;
        STEP_TIMEOUT.check(self.step_timeout)?;
        Ok(())
    }
}

/// A whole vehicle.
#[derive(Clone, Debug, PartialEq)]
pub struct VehicleConfig {
    pub vehicle: VehicleSettings,
    pub supervisor: SupervisorConfig,
    pub devices: Vec<DeviceConfig>,
    /// `[network]`: the command listener, watchdog and state broadcast.
    pub network: NetworkConfig,
    /// Where it was loaded from (for messages).
    pub source: String,
    /// The line of every key in that file, for errors found after loading.
    pub lines: Lines,
}

impl VehicleConfig {
    /// The built-in simulated Alice.
    pub fn alice() -> VehicleConfig {
        parse(ALICE_TOML, ALICE_PATH).expect("the built-in vehicle parses")
    }

    pub fn device(&self, role: Role) -> Option<&DeviceConfig> {
        self.devices.iter().find(|d| d.name == role)
    }

    /// Keep only the named devices (`--only`).
    pub fn retain_only(&mut self, only: &[Role]) {
        if !only.is_empty() {
            self.devices.retain(|d| only.contains(&d.name));
        }
    }

    /// A violation found after loading, inside `owner` (`device.steer`, `network`), as
    /// an error at the line of the key it blames.
    pub fn refuse(&self, owner: &str, v: Violation) -> ConfigError {
        refuse(&self.source, &self.lines, owner, v)
    }

    /// Every device that is not simulated needs a port to open.
    pub fn check_ports(&self) -> Result<(), ConfigError> {
        for d in &self.devices {
            if d.port.trim().is_empty() {
                let v = Violation {
                    paths: vec!["port".into()],
                    message: format!(
                        "port: expected the path of a serial port (\"/dev/ttyUSB0\", \
                         \"/dev/serial/by-id/…\"), got {:?}; without hardware, run with --sim",
                        d.port
                    ),
                };
                return Err(self.refuse(&format!("device.{}", d.name), v));
            }
        }
        Ok(())
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Raw {
    vehicle: VehicleSettings,
    #[serde(default)]
    supervisor: SupervisorConfig,
    #[serde(default)]
    device: Vec<toml::Spanned<DeviceConfig>>,
    #[serde(default)]
    network: Option<NetworkConfig>,
}

/// Load a vehicle from a file.
pub fn load(path: &Path) -> Result<VehicleConfig, ConfigError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| ConfigError {
        path: name.clone(),
        line: 0,
        message: format!("cannot read: {e}"),
    })?;
    parse(document::utf8(&bytes, &name)?, &name)
}

/// Parse a vehicle from TOML text; `path` names it in errors.
pub fn parse(text: &str, path: &str) -> Result<VehicleConfig, ConfigError> {
    let doc = Document::parse(text, path)?;
    let raw: Raw = toml::from_str(text).map_err(|e| doc.type_error(e.span(), e.message()))?;
    let lines = doc.lines();
    let mut devices: Vec<DeviceConfig> = Vec::new();
    for spanned in raw.device {
        let offset = spanned.span().start;
        let d = spanned.into_inner();
        let name = d.name;
        if devices.iter().any(|o| o.name == name) {
            return Err(doc.error_at(offset, format!("device {name} is defined twice")));
        }
        if let Some(why) = driver_mismatch(&d) {
            return Err(doc.error_at(offset, why));
        }
        d.check()
            .map_err(|v| refuse(path, &lines, &format!("device.{name}"), v))?;
        devices.push(d);
    }
    raw.supervisor
        .check()
        .map_err(|v| refuse(path, &lines, "supervisor", v))?;
    let network = raw.network.unwrap_or_default();
    network
        .check()
        .map_err(|v| refuse(path, &lines, "network", v))?;
    Ok(VehicleConfig {
        vehicle: raw.vehicle,
        supervisor: raw.supervisor,
        devices,
        network,
        source: path.to_string(),
        lines,
    })
}

/// A violation inside `owner` (`device.steer`, `network`, `supervisor`) of the file at
/// `path`, as an error at the line of the key it blames (else of its table).
fn refuse(path: &str, lines: &Lines, owner: &str, v: Violation) -> ConfigError {
    let mut keys: Vec<String> = v.paths.iter().map(|p| format!("{owner}.{p}")).collect();
    keys.push(owner.to_string());
    ConfigError {
        path: path.to_string(),
        line: lines.first(&keys),
        message: format!("{}{v}", document::context(owner)),
    }
}

/// What is wrong with the driver settings of a device, if anything.
fn driver_mismatch(d: &DeviceConfig) -> Option<String> {
    let name = d.name;
    match (d.driver, &d.modbus) {
        (DriverKind::Modbus, None) => Some(format!(
            "{name}: driver \"modbus\" needs a [device.modbus] table with `slave` and `registers`"
        )),
        (DriverKind::Modbus, Some(m)) => {
            if !name.is_actuator() {
                Some(format!(
                    "{name}: the modbus driver is for actuators (steer, gas, brake, trans)"
                ))
            } else if (name == Role::Trans) != m.registers.is_gearbox() {
                Some(format!(
                    "{name}: registers.gear is expected {} (it makes the device a transmission)",
                    if name == Role::Trans {
                        "on trans"
                    } else {
                        "only on trans"
                    }
                ))
            } else {
                None
            }
        }
        (_, Some(_)) => Some(format!(
            "{name}: a [device.modbus] table goes with driver = \"modbus\" only"
        )),
        (DriverKind::Elm327, None) if name != Role::Obd => Some(format!(
            "{name}: the elm327 driver is for the obd sensor only"
        )),
        _ => None,
    }
}

struct Expected(&'static str);
impl serde::de::Expected for Expected {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.0)
    }
}

/// A duration written as `"250ms"`, `"1s"`, `"1m 30s"`.
pub fn parse_duration(s: &str) -> Result<Duration, String> {
    humantime::parse_duration(s.trim())
        .map_err(|_| format!("expected a duration such as \"250ms\" or \"1s\", got {s:?}"))
}

pub(crate) fn duration<'de, D: Deserializer<'de>>(d: D) -> Result<Duration, D::Error> {
    let s = String::deserialize(d).map_err(|_| {
        serde::de::Error::invalid_type(
            serde::de::Unexpected::Other("a non-string"),
            &Expected("a duration string such as \"250ms\""),
        )
    })?;
    parse_duration(&s).map_err(serde::de::Error::custom)
}

fn opt_duration<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Duration>, D::Error> {
    duration(d).map(Some)
}

/// `[min, max]`: exactly two numbers (a third is refused, never dropped).
fn range<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 2]>, D::Error> {
    let v = Vec::<f64>::deserialize(d).map_err(|_| {
        serde::de::Error::custom("range: expected [min, max], two numbers such as [-1.0, 1.0]")
    })?;
    match v[..] {
        [lo, hi] => Ok(Some([lo, hi])),
        _ => Err(serde::de::Error::custom(format!(
            "range: expected [min, max], two numbers, got {} number{}",
            v.len(),
            if v.len() == 1 { "" } else { "s" }
        ))),
    }
}

/// A duration as written in a vehicle file (`250ms`, `2s`).
pub use limits::fmt_duration;

#[cfg(test)]
mod tests;
