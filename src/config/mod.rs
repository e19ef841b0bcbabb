//! Vehicle configuration: which devices exist, by name and kind, how to reach them,
//! how often to poll them, and which of them the safety rules act on (the role
//! bindings). Loaded from TOML; the built-in simulated Alice is `vehicles/alice.toml`,
//! compiled in. Loading is split into [`load`] (a path) and [`parse`] (text) so tests
//! feed bytes, and every error names the file, the line and what was expected.
//!
//! - [`device`]: one device, its kind, states and readings;
//! - [`protocol_map`]: how each protocol maps a device to the wire;
//! - [`roles`]: the safety roles, bound to devices and readings;
//! - [`response`]: how a setpoint actuator answers its command (the estimator's model);
//! - [`limits`]: the sane range of every safety-relevant value, in one table;
//! - [`record`]: `[record]`, recording every run into rolling files;
//! - [`teleop`]: `[teleop]`, what hold-to-drive teleop commands while a key is held;
//! - [`fleet`]: `[fleet]`, how the vehicle joins a fleet over Zenoh;
//! - [`document`]: where each key sits in the file, so that a check made after typing
//!   still names its line.

pub(crate) mod can;
pub(crate) mod console;
pub(crate) mod device;
pub(crate) mod document;
pub mod fleet;
pub mod limits;
pub mod network;
pub(crate) mod placement;
pub(crate) mod ports;
pub mod protocol_map;
pub(crate) mod record;
pub(crate) mod response;
pub(crate) mod roles;
pub(crate) mod ros2;
pub(crate) mod teleop;

pub use console::ConsoleConfig;
pub use device::{DeviceConfig, DriverKind, PortRule, ReadingKind, ReadingSpec};
use document::{Document, Lines};
pub use fleet::FleetConfig;
pub use limits::{fmt_duration, Violation};
pub use network::NetworkConfig;
pub use record::RecordConfig;
pub use response::{Motion, Polling, Response};
pub use roles::{Bindings, Role};
pub use ros2::Ros2Config;
use serde::{Deserialize, Deserializer};
use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;
use std::time::Duration;
pub use teleop::TeleopConfig;
use toml::Spanned;

/// The built-in vehicle, as shipped in `vehicles/alice.toml`.
pub const ALICE_TOML: &str = include_str!("../../vehicles/alice.toml");
/// The name errors in the built-in vehicle are reported under.
pub(crate) const ALICE_PATH: &str = "vehicles/alice.toml";

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

/// How a simulated reading behaves: a value, optionally ramping and noisy, or a
/// multiple of the device's own position (a brake's pressure).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimReading {
    #[serde(default)]
    pub value: f64,
    /// Gaussian-ish noise of this standard deviation on every reading.
    #[serde(default)]
    pub noise: f64,
    /// Ramp from `value` to this over `ramp_time`, then stay.
    #[serde(default)]
    pub(crate) ramp_to: Option<f64>,
    #[serde(default = "default_ramp", deserialize_with = "duration")]
    pub(crate) ramp_time: Duration,
    /// Report the device's position times this instead.
    #[serde(default)]
    pub(crate) per_position: Option<f64>,
}

fn default_ramp() -> Duration {
    Duration::from_secs(60)
}

/// Settings of the simulated device standing in for this one under `--sim`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimConfig {
    /// Time the device takes to start answering once a request is complete.
    #[serde(default = "default_turnaround", deserialize_with = "duration")]
    pub(crate) turnaround: Duration,
    /// Extra processing time for a status request (a slow device).
    #[serde(default, deserialize_with = "duration")]
    pub poll_delay: Duration,
    /// Extra processing time for a command.
    #[serde(default, deserialize_with = "duration")]
    pub command_delay: Duration,
    /// The device's own watchdog, as drive-by-wire firmware has: with no command frame
    /// for this long, the device goes to its safe value by itself.
    #[serde(default, deserialize_with = "opt_duration")]
    pub watchdog: Option<Duration>,
    /// A setpoint actuator moves toward its command at most this fast (units/s) …
    #[serde(default)]
    pub rate: Option<f64>,
    /// … and follows it with this first-order lag (without either: at once; with
    /// both, the lag's motion held to the rate) …
    #[serde(default, deserialize_with = "opt_duration")]
    pub lag: Option<Duration>,
    /// … ignores a new command closer than this to the one it follows (units) …
    #[serde(default)]
    pub deadband: f64,
    /// … has this much play where its motion reverses (units): it settles this much
    /// lower approaching a point from below than from above …
    #[serde(default)]
    pub backlash: f64,
    /// … and acts on each command only this long after it arrives (transport delay).
    #[serde(default, deserialize_with = "duration")]
    pub delay: Duration,
    /// A state actuator settles into a new state after this long …
    #[serde(default, deserialize_with = "duration")]
    pub settle: Duration,
    /// … reporting this state meanwhile (default: the old one).
    #[serde(default)]
    pub transit: Option<String>,
    /// How sensor readings behave, by reading name. Readings bound to a role, and
    /// rpm and coolant, come from the simulated vehicle unless listed here.
    #[serde(default)]
    pub readings: BTreeMap<String, SimReading>,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            turnaround: default_turnaround(),
            poll_delay: limits::SIM_POLL_DELAY.default_value(),
            command_delay: limits::SIM_COMMAND_DELAY.default_value(),
            watchdog: None,
            rate: None,
            lag: None,
            deadband: 0.0,
            backlash: 0.0,
            delay: limits::SIM_DELAY.default_value(),
            settle: Duration::ZERO,
            transit: None,
            readings: BTreeMap::new(),
        }
    }
}

fn default_turnaround() -> Duration {
    limits::SIM_TURNAROUND.default_value()
}

/// Vehicle-wide settings.
#[derive(Clone, Debug, PartialEq)]
pub struct VehicleSettings {
    pub name: String,
    /// Where the command path runs (`cpus`, `realtime_priority`).
    pub placement: placement::Placement,
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
    pub(crate) error_window: Duration,
    /// A device without a declared response, measured further than this fraction of
    /// its range from its command …
    pub(crate) follow_tolerance: f64,
    /// … for longer than this is "not following".
    #[serde(deserialize_with = "duration")]
    pub follow_time: Duration,
    /// A device with a declared response that makes no headway toward its command for
    /// this long is "not following" (a stuck motor).
    #[serde(deserialize_with = "duration")]
    pub stall_time: Duration,
    /// Reported positions may stray this fraction of the range outside it.
    pub(crate) range_margin: f64,
    /// Tries of a recovery procedure before it gives up.
    pub attempts: u32,
    /// Time a recovery step may take.
    #[serde(deserialize_with = "duration")]
    pub step_timeout: Duration,
    /// End the run (status 4, after the safe state) once a device has been gone this
    /// long, or a recovery procedure gave up after trying this long. `None` (the
    /// default): never — adrive keeps the vehicle safe and waits.
    #[serde(deserialize_with = "opt_duration")]
    pub give_up_after: Option<Duration>,
    /// The key this one replaced, refused with a word on what to write instead.
    #[serde(rename = "exit_on_give_up")]
    pub(crate) old_exit_on_give_up: Option<toml::Value>,
    /// Fault injection for tests (`--inject-panic supervisor:DELAY`).
    #[serde(skip)]
    pub(crate) panic_for_test: Option<Duration>,
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
            stall_time: STALL_TIME.default_value(),
            range_margin: RANGE_MARGIN.default_value(),
            attempts: ATTEMPTS.default_value() as u32,
            step_timeout: STEP_TIMEOUT.default_value(),
            give_up_after: None,
            old_exit_on_give_up: None,
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
        STALL_TIME.check(self.stall_time)?;
        RANGE_MARGIN.check(self.range_margin)?;
        ATTEMPTS.check(u64::from(self.attempts))?;
        STEP_TIMEOUT.check(self.step_timeout)?;
        if let Some(d) = self.give_up_after {
            GIVE_UP_AFTER.check(d)?;
        }
        if self.old_exit_on_give_up.is_some() {
            return Err(Violation {
                paths: vec!["exit_on_give_up".into()],
                message: "exit_on_give_up: no longer a key: adrive keeps running while a \
                          device is gone or a recovery has given up; to end the run \
                          instead, write give_up_after = \"30s\" (or run with \
                          --give-up-after 30s)"
                    .into(),
            });
        }
        Ok(())
    }
}

/// A whole vehicle.
#[derive(Clone, Debug, PartialEq)]
pub struct VehicleConfig {
    pub vehicle: VehicleSettings,
    /// Which devices and readings the safety rules act on.
    pub roles: Bindings,
    pub supervisor: SupervisorConfig,
    pub devices: Vec<DeviceConfig>,
    /// `[[bus]]`: the CAN buses the devices with `driver = "can"` are on.
    pub buses: Vec<can::BusConfig>,
    /// `[network]`: the command listener, watchdog and state broadcast.
    pub network: NetworkConfig,
    /// `[console]`: what a commanding console must keep proving.
    pub console: ConsoleConfig,
    /// `[record]`: record every run (none: only with `--record`).
    pub record: Option<RecordConfig>,
    /// `[ros2]`: the ROS 2 / Autoware interface over Zenoh (`--ros2`).
    pub ros2: Ros2Config,
    /// `[teleop]`: what hold-to-drive teleop commands while a key is held.
    pub teleop: TeleopConfig,
    /// `[fleet]`: the vehicle joins a fleet over Zenoh (none: only with `--fleet`).
    pub fleet: Option<FleetConfig>,
    /// Where it was loaded from (for messages).
    pub source: String,
    /// The line of every key in that file, for errors found after loading.
    pub lines: Lines,
}

impl VehicleConfig {
    /// A violation found after loading, inside `owner` (`device.steer`, `network`), as
    /// an error at the line of the key it blames.
    pub(crate) fn refuse(&self, owner: &str, v: Violation) -> ConfigError {
        refuse(&self.source, &self.lines, owner, v)
    }

    /// The built-in simulated Alice.
    pub fn alice() -> VehicleConfig {
        parse(ALICE_TOML, ALICE_PATH).expect("the built-in vehicle parses")
    }

    /// A path the vehicle file names, relative to the file's directory.
    pub(crate) fn relative(&self, file: &Path) -> std::path::PathBuf {
        match Path::new(&self.source).parent() {
            Some(dir) if file.is_relative() => dir.join(file),
            _ => file.to_path_buf(),
        }
    }

    /// A device by name.
    pub fn device(&self, name: &str) -> Option<&DeviceConfig> {
        self.devices.iter().find(|d| d.name == name)
    }

    /// The device bound to `role`.
    pub fn bound(&self, role: Role) -> Option<&DeviceConfig> {
        self.roles.device(role).map(|id| &self.devices[id.index()])
    }

    /// Keep only the named devices (`--only`); bindings to the others are dropped.
    /// Every name must exist.
    pub(crate) fn retain_only(&mut self, only: &[String]) -> Result<(), String> {
        if only.is_empty() {
            return Ok(());
        }
        for n in only {
            if self.device(n).is_none() {
                return Err(format!(
                    "--only {n}: no such device ({})",
                    device_list(&self.devices)
                ));
            }
        }
        let keep: Vec<bool> = self
            .devices
            .iter()
            .map(|d| only.contains(&d.name))
            .collect();
        let mut map = Vec::new();
        let mut next = 0u16;
        for k in &keep {
            map.push(k.then(|| {
                next += 1;
                crate::value::DeviceId(next - 1)
            }));
        }
        let m = |id: crate::value::DeviceId| map[id.index()];
        let r = &mut self.roles;
        r.steering = r.steering.and_then(m);
        r.throttle = r.throttle.and_then(m);
        r.brake = r.brake.and_then(m);
        r.starter = r.starter.and_then(m);
        r.gear = r.gear.take().and_then(|mut g| {
            g.device = m(g.device)?;
            Some(g)
        });
        r.estop = r.estop.and_then(|mut e| {
            e.at.device = m(e.at.device)?;
            Some(e)
        });
        let reading = |x: Option<roles::ReadingRef>| {
            x.and_then(|mut x| {
                x.device = m(x.device)?;
                Some(x)
            })
        };
        r.speed = reading(r.speed);
        r.engine_running = reading(r.engine_running);
        let mut i = 0;
        self.devices.retain(|_| {
            i += 1;
            keep[i - 1]
        });
        Ok(())
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawVehicle {
    name: Spanned<String>,
    #[serde(default)]
    roles: Option<roles::RawRoles>,
    #[serde(default)]
    gear: Option<Spanned<roles::RawGear>>,
    #[serde(default)]
    cpus: Vec<usize>,
    #[serde(default)]
    realtime_priority: Option<u64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Raw {
    vehicle: RawVehicle,
    #[serde(default)]
    supervisor: SupervisorConfig,
    #[serde(default)]
    bus: Vec<can::RawBus>,
    #[serde(default)]
    device: Vec<Spanned<device::RawDevice>>,
    #[serde(default)]
    network: Option<NetworkConfig>,
    #[serde(default)]
    console: Option<ConsoleConfig>,
    #[serde(default)]
    record: Option<RecordConfig>,
    ros2: Option<Ros2Config>,
    #[serde(default)]
    teleop: TeleopConfig,
    #[serde(default)]
    fleet: Option<FleetConfig>,
}

/// Load a vehicle from a file.
pub fn load(path: &Path) -> Result<VehicleConfig, ConfigError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| ConfigError {
        path: name.clone(),
        line: 0,
        message: crate::paths::cannot_read(path, &e),
    })?;
    parse(document::utf8(&bytes, &name)?, &name)
}

/// Parse a vehicle from TOML text; `path` names it in errors.
pub fn parse(text: &str, path: &str) -> Result<VehicleConfig, ConfigError> {
    let doc = Document::parse(text, path)?;
    let raw: Raw = toml::from_str(text).map_err(|e| doc.type_error(e.span(), e.message()))?;
    let lines = doc.lines();
    let name_at = raw.vehicle.name.span().start;
    let name = raw.vehicle.name.into_inner();
    device::check_text("vehicle name", &name, false).map_err(|m| doc.error_at(name_at, m))?;
    let mut buses: Vec<can::BusConfig> = Vec::new();
    for b in raw.bus {
        let bus = b.check(path).map_err(|(o, m)| doc.error_at(o, m))?;
        if buses.iter().any(|o| o.name == bus.name) {
            return Err(doc.error_at(0, format!("bus {} is defined twice", bus.name)));
        }
        buses.push(bus);
    }
    let mut devices: Vec<DeviceConfig> = Vec::new();
    for spanned in raw.device {
        let at = spanned.span().start;
        let raw_device = spanned.into_inner();
        if devices.iter().any(|o| o.name == raw_device.name()) {
            return Err(doc.error_at(
                raw_device.at(),
                format!(
                    "device {} is defined twice (names must be unique)",
                    raw_device.name()
                ),
            ));
        }
        let d = raw_device
            .check(&buses)
            .map_err(|(o, m)| doc.error_at(o.max(at), m))?;
        let owner = format!("device.{}", d.name);
        d.check_limits()
            .map_err(|v| refuse(path, &lines, &owner, v))?;
        check_sim(&d).map_err(|m| doc.error_at(at, m))?;
        if devices.len() == usize::from(u16::MAX) {
            return Err(doc.error_at(
                at,
                format!("too many devices: a vehicle has at most {}", u16::MAX),
            ));
        }
        devices.push(d);
    }
    let roles = roles::bind(
        raw.vehicle.roles.unwrap_or_default(),
        raw.vehicle.gear,
        &devices,
        &|at| document::line_of(text, at),
    )
    .map_err(|(o, m)| doc.error_at(o, m))?;
    raw.supervisor
        .check()
        .map_err(|v| refuse(path, &lines, "supervisor", v))?;
    let placement = placement::Placement {
        cpus: raw.vehicle.cpus,
        realtime_priority: raw.vehicle.realtime_priority,
    };
    placement
        .check()
        .map_err(|v| refuse(path, &lines, "vehicle", v))?;
    let network = raw.network.unwrap_or_default();
    network
        .check()
        .map_err(|v| refuse(path, &lines, "network", v))?;
    let console = raw.console.unwrap_or_default();
    console
        .check()
        .map_err(|v| refuse(path, &lines, "console", v))?;
    if let Some(r) = &raw.record {
        r.check().map_err(|v| refuse(path, &lines, "record", v))?;
    }
    let ros2 = raw.ros2.unwrap_or_default();
    ros2.check(&devices)
        .map_err(|v| refuse(path, &lines, "ros2", v))?;
    raw.teleop
        .check()
        .map_err(|v| refuse(path, &lines, "teleop", v))?;
    if let Some(f) = &raw.fleet {
        f.check().map_err(|v| refuse(path, &lines, "fleet", v))?;
    }
    Ok(VehicleConfig {
        vehicle: VehicleSettings { name, placement },
        roles,
        supervisor: raw.supervisor,
        devices,
        buses,
        network,
        console,
        record: raw.record,
        ros2,
        teleop: raw.teleop,
        fleet: raw.fleet,
        source: path.to_string(),
        lines,
    })
}

/// The devices of a file for a message: `devices: steer, gas`, or that it has none
/// (never an empty list).
pub(crate) fn device_list(devices: &[DeviceConfig]) -> String {
    if devices.is_empty() {
        return "the file has no [[device]]".into();
    }
    let names: Vec<&str> = devices.iter().map(|d| d.name.as_str()).collect();
    format!("devices: {}", names.join(", "))
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

/// The simulator's settings must name the device's own states and readings.
fn check_sim(d: &DeviceConfig) -> Result<(), String> {
    let name = &d.name;
    if let Some(t) = &d.sim.transit {
        if d.state_index(t).is_none() {
            return Err(format!(
                "{name}: sim.transit: {t:?} is not one of its states ({})",
                d.states.join(", ")
            ));
        }
    }
    for r in d.sim.readings.keys() {
        if d.reading(r).is_none() {
            return Err(format!(
                "{name}: sim.readings: {r:?} is not one of its readings"
            ));
        }
    }
    Ok(())
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

pub(crate) fn opt_duration<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Duration>, D::Error> {
    duration(d).map(Some)
}

#[cfg(test)]
mod tests;

/// One device from a vehicle-file fragment (the lines of its `[[device]]` table), for
/// unit tests of drivers and simulated devices.
#[cfg(test)]
pub(crate) fn one_device(fragment: &str) -> DeviceConfig {
    let text = format!("[vehicle]\nname = \"t\"\n[[device]]\n{fragment}\n");
    match parse(&text, "test.toml") {
        Ok(mut v) => v.devices.remove(0),
        Err(e) => panic!("{e}\n{text}"),
    }
}
