//! Vehicle configuration: which devices exist, how to reach them, how often to poll
//! them. Loaded from TOML; the built-in simulated Alice is `vehicles/alice.toml`,
//! compiled in. Loading is split into [`load`] (a path) and [`parse`] (text) so tests
//! feed bytes, and every error names the file, the line and what was expected.

pub use crate::net::config::NetworkConfig;
use crate::value::Role;
use serde::{Deserialize, Deserializer};
use std::fmt;
use std::path::Path;
use std::time::Duration;

/// The built-in vehicle, as shipped in `vehicles/alice.toml`.
pub const ALICE_TOML: &str = include_str!("../vehicles/alice.toml");
/// The name errors in the built-in vehicle are reported under.
pub const ALICE_PATH: &str = "vehicles/alice.toml";

/// A configuration error: `file:line: message`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{path}:{line}: {message}")]
pub struct ConfigError {
    pub path: String,
    pub line: usize,
    pub message: String,
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
            poll_delay: Duration::ZERO,
            command_delay: Duration::ZERO,
            watchdog: None,
        }
    }
}

fn default_turnaround() -> Duration {
    Duration::from_millis(2)
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
    /// Value domain `[min, max]` of commands (actuators only).
    #[serde(default)]
    pub range: Option<[f64; 2]>,
    #[serde(default)]
    pub sim: SimConfig,
    /// Required with `driver = "modbus"`.
    #[serde(default)]
    pub modbus: Option<ModbusConfig>,
}

fn default_baud() -> u32 {
    9600
}
fn default_status_period() -> Duration {
    Duration::from_millis(100)
}
fn default_command_timeout() -> Duration {
    Duration::from_millis(250)
}
fn default_status_max_age() -> Duration {
    Duration::from_millis(500)
}
fn default_reply_timeout() -> Duration {
    Duration::from_millis(200)
}

impl DeviceConfig {
    /// The command value domain: the configured range, or the role's natural one.
    pub fn range(&self) -> [f64; 2] {
        self.range.unwrap_or(match self.name {
            Role::Steer => [-1.0, 1.0],
            _ => [0.0, 1.0],
        })
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
        SupervisorConfig {
            period: Duration::from_millis(100),
            error_rate: 0.5,
            error_window: Duration::from_secs(2),
            follow_tolerance: 0.1,
            follow_time: Duration::from_millis(2500),
            range_margin: 0.05,
            attempts: 3,
            step_timeout: Duration::from_secs(4),
            exit_on_give_up: true,
            panic_for_test: None,
        }
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
    network: Option<toml::Spanned<NetworkConfig>>,
}

/// Load a vehicle from a file.
pub fn load(path: &Path) -> Result<VehicleConfig, ConfigError> {
    let name = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| ConfigError {
        path: name.clone(),
        line: 0,
        message: format!("cannot read: {e}"),
    })?;
    parse(&text, &name)
}

/// Parse a vehicle from TOML text; `path` names it in errors.
pub fn parse(text: &str, path: &str) -> Result<VehicleConfig, ConfigError> {
    let err = |offset: usize, message: String| ConfigError {
        path: path.to_string(),
        line: line_of(text, offset),
        message,
    };
    let raw: Raw = toml::from_str(text).map_err(|e| {
        let offset = e.span().map(|s| s.start).unwrap_or(0);
        err(offset, e.message().trim().to_string())
    })?;
    let mut devices: Vec<DeviceConfig> = Vec::new();
    for spanned in raw.device {
        let at = spanned.span().start;
        let d = spanned.into_inner();
        if devices.iter().any(|o| o.name == d.name) {
            return Err(err(at, format!("device {} is defined twice", d.name)));
        }
        let [lo, hi] = d.range();
        if !(lo.is_finite() && hi.is_finite() && lo < hi) {
            return Err(err(
                at,
                format!("range of {}: expected [min, max] with min < max", d.name),
            ));
        }
        if d.baud == 0 {
            return Err(err(
                at,
                format!("baud of {}: expected a positive number", d.name),
            ));
        }
        if d.status_period.is_zero() || d.reply_timeout.is_zero() || d.command_timeout.is_zero() {
            return Err(err(
                at,
                format!(
                    "{}: status_period, command_timeout and reply_timeout must be above zero",
                    d.name
                ),
            ));
        }
        if let Some(why) = driver_mismatch(&d) {
            return Err(err(at, why));
        }
        if d.status_max_age < d.status_period {
            return Err(err(
                at,
                format!(
                    "{}: status_max_age ({}) must be at least status_period ({})",
                    d.name,
                    humantime::format_duration(d.status_max_age),
                    humantime::format_duration(d.status_period)
                ),
            ));
        }
        devices.push(d);
    }
    let network = match raw.network {
        Some(n) => {
            let at = n.span().start;
            let n = n.into_inner();
            n.check().map_err(|m| err(at, format!("[network] {m}")))?;
            n
        }
        None => NetworkConfig::default(),
    };
    Ok(VehicleConfig {
        vehicle: raw.vehicle,
        supervisor: raw.supervisor,
        devices,
        network,
        source: path.to_string(),
    })
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

fn line_of(text: &str, offset: usize) -> usize {
    text.as_bytes()[..offset.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
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

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
[vehicle]
name = "bench"

[[device]]
name = "steer"
driver = "line"
port = "/dev/ttyUSB0"
status_period = "50ms"
"#;

    #[test]
    fn the_built_in_alice_parses_with_all_six_devices() {
        let a = VehicleConfig::alice();
        let names: Vec<_> = a.devices.iter().map(|d| d.name).collect();
        assert_eq!(names, Role::ALL.to_vec());
    }

    #[test]
    fn defaults_fill_what_is_not_said() {
        let v = parse(GOOD, "bench.toml").unwrap();
        let d = &v.devices[0];
        assert_eq!(d.status_period, Duration::from_millis(50));
        assert_eq!(d.baud, 9600);
        assert_eq!(d.port_rule, PortRule::Priority);
        assert_eq!(d.min_command_interval, None);
        assert_eq!(d.range(), [-1.0, 1.0]);
    }

    fn error(text: &str) -> String {
        parse(text, "v.toml").unwrap_err().to_string()
    }

    #[test]
    fn an_unknown_driver_names_file_line_and_the_choices() {
        let e = error(&GOOD.replace("driver = \"line\"", "driver = \"modbsu\""));
        assert!(e.starts_with("v.toml:7: "), "{e}");
        assert!(e.contains("modbsu") && e.contains("line"), "{e}");
    }

    #[test]
    fn a_bad_duration_names_its_line_and_form() {
        let e = error(&GOOD.replace("\"50ms\"", "\"fast\""));
        assert!(e.starts_with("v.toml:9: "), "{e}");
        assert!(e.contains("250ms"), "{e}");
    }

    #[test]
    fn an_unknown_device_or_field_is_refused() {
        let e = error(&GOOD.replace("\"steer\"", "\"wiper\""));
        assert!(
            e.starts_with("v.toml:6: ") && e.contains("`steer`, `gas`"),
            "{e}"
        );
        let e = error(&GOOD.replace("port =", "prot ="));
        assert!(e.starts_with("v.toml:8: ") && e.contains("prot"), "{e}");
    }

    #[test]
    fn cross_field_errors_point_at_the_device() {
        let e = error(&format!("{GOOD}range = [1.0, -1.0]\n"));
        assert!(
            e.starts_with("v.toml:5: ") && e.contains("min < max"),
            "{e}"
        );
        let e = error(&format!("{GOOD}status_max_age = \"10ms\"\n"));
        assert!(e.contains("status_max_age"), "{e}");
        let twice = format!("{GOOD}\n[[device]]\nname = \"steer\"\ndriver = \"line\"\n");
        assert!(error(&twice).contains("defined twice"));
    }

    #[test]
    fn a_modbus_device_needs_its_table_and_a_sensible_map() {
        let modbus = GOOD.replace("driver = \"line\"", "driver = \"modbus\"");
        let e = error(&modbus);
        assert!(
            e.starts_with("v.toml:5: ") && e.contains("[device.modbus]"),
            "{e}"
        );
        let ok = format!(
            "{modbus}\n[device.modbus]\nslave = 7\nregisters = {{ target = 0, position = 0 }}\n"
        );
        let d = &parse(&ok, "v.toml").unwrap().devices[0];
        assert_eq!(d.modbus.as_ref().unwrap().slave, 7);
        let geared = ok.replace("position = 0", "gear = 0");
        assert!(error(&geared).contains("registers.gear"));
        let typo = ok.replace("position = 0", "postion = 0");
        let e = error(&typo);
        assert!(e.starts_with("v.toml:13: ") && e.contains("postion"), "{e}");
    }

    #[test]
    fn broken_toml_names_the_line() {
        let e = error("[vehicle]\nname = \"x\"\n[[device]\n");
        assert!(e.starts_with("v.toml:3: "), "{e}");
    }
}
