//! The sane range of every safety-relevant duration and threshold, in one table.
//!
//! A vehicle file can switch safety off without a single syntax error: a watchdog of a
//! million seconds never trips, a reply timeout of a thousand hours never flags a silent
//! device, a supervisor period of zero spins, a Modbus slave 0 is the broadcast address.
//! Each such value has a [`Limit`] here, and the rules between two values a [`Rule`].
//! The loader refuses a file outside them (naming the file, the line, the key and the
//! range), the console's in-place edits go through the same checks, `--deadman` is
//! parsed by [`DEADMAN`], and the guide's table (docs/vehicles.md) is [`markdown`], compared by a test.
//! The defaults live here too, so a default can never fall outside its own range.

use std::fmt;
use std::time::Duration;

/// Where a key is written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Section {
    /// `[[device]]`.
    Device,
    /// `[device.sim]`: the simulated device used with `--sim`.
    DeviceSim,
    /// `[device.modbus]`.
    DeviceModbus,
    /// `[device.response]`: how the real device answers its command.
    DeviceResponse,
    Network,
    /// `[console]`: a commanding console.
    Console,
    Supervisor,
    /// `[ros2]`: the ROS 2 / Autoware interface.
    Ros2,
    /// `[teleop]`: hold-to-drive teleop from the console.
    Teleop,
    /// A command-line option of `adrive run`.
    CommandLine,
}

impl Section {
    /// The section as written in a vehicle file (or `adrive run` for an option).
    pub fn header(self) -> &'static str {
        match self {
            Section::Device => "[[device]]",
            Section::DeviceSim => "[device.sim]",
            Section::DeviceModbus => "[device.modbus]",
            Section::DeviceResponse => "[device.response]",
            Section::Network => "[network]",
            Section::Console => "[console]",
            Section::Supervisor => "[supervisor]",
            Section::Ros2 => "[ros2]",
            Section::Teleop => "[teleop]",
            Section::CommandLine => "adrive run",
        }
    }

    /// The prefix of a key of this section inside its device (`sim.`, `modbus.`).
    fn prefix(self) -> &'static str {
        match self {
            Section::DeviceSim => "sim.",
            Section::DeviceModbus => "modbus.",
            Section::DeviceResponse => "response.",
            Section::CommandLine => "--",
            _ => "",
        }
    }
}

/// A value that has a range: a duration, a number or a whole number.
pub trait Bounded: Copy + PartialOrd {
    /// What the value is, for "expected …": `a duration`.
    const FORM: &'static str;
    /// The value as a user writes it.
    fn show(self) -> String;
}

impl Bounded for Duration {
    const FORM: &'static str = "a duration (\"250ms\", \"2s\")";
    fn show(self) -> String {
        fmt_duration(self)
    }
}

impl Bounded for f64 {
    const FORM: &'static str = "a number";
    fn show(self) -> String {
        format!("{self}")
    }
}

impl Bounded for u64 {
    const FORM: &'static str = "a whole number";
    fn show(self) -> String {
        self.to_string()
    }
}

/// A duration as written in a vehicle file: `250ms`, `2s`, `1500ms`, `10µs`.
pub fn fmt_duration(d: Duration) -> String {
    if d.subsec_nanos() == 0 {
        format!("{}s", d.as_secs())
    } else if d.subsec_nanos().is_multiple_of(1_000_000) {
        format!("{}ms", d.as_millis())
    } else if d.subsec_nanos().is_multiple_of(1_000) {
        format!("{}µs", d.as_micros())
    } else {
        format!("{}ns", d.as_nanos())
    }
}

/// The accepted range of one key, both ends included.
#[derive(Debug)]
pub struct Limit<T> {
    pub section: Section,
    pub key: &'static str,
    pub min: T,
    pub max: T,
    /// The value when the key is not written (`None`: off, or required).
    pub default: Option<T>,
    /// Why the range is what it is, for the guide (docs/vehicles.md).
    pub why: &'static str,
}

/// A value outside its range or against a rule: the keys it is about, and a message
/// that names them and says what was expected.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct Violation {
    /// The keys, as paths inside their device (`sim.watchdog`) or section
    /// (`watchdog_timeout`), the one to blame first.
    pub paths: Vec<String>,
    pub message: String,
}

impl<T: Bounded> Limit<T> {
    /// The key as a message names it: `reply_timeout`, `sim.watchdog`, `--deadman`.
    pub fn name(&self) -> String {
        format!("{}{}", self.section.prefix(), self.key)
    }

    /// `a duration from 1ms to 10s`.
    pub fn expected(&self) -> String {
        format!(
            "{} from {} to {}",
            T::FORM,
            self.min.show(),
            self.max.show()
        )
    }

    /// `v` if it is in range; else a message naming the key, the range and `v`.
    pub fn check(&self, v: T) -> Result<T, Violation> {
        if v >= self.min && v <= self.max {
            Ok(v)
        } else {
            Err(self.violation(format!(
                "{}: expected {}, got {}",
                self.name(),
                self.expected(),
                v.show()
            )))
        }
    }

    /// A violation of this key with `message`.
    pub fn violation(&self, message: String) -> Violation {
        Violation {
            paths: vec![self.name()],
            message,
        }
    }

    /// The default; for keys that always have one.
    pub(crate) fn default_value(&self) -> T {
        match self.default {
            Some(v) => v,
            None => panic!("a limit without a default"),
        }
    }
}

const fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}
const fn s(n: u64) -> Duration {
    Duration::from_secs(n)
}

use Section::{
    CommandLine, Console, Device, DeviceModbus, DeviceResponse, DeviceSim, Network, Ros2,
    Supervisor, Teleop,
};

pub const BAUD: Limit<u64> = Limit {
    section: Device,
    key: "baud",
    min: 300,
    max: 4_000_000,
    default: Some(9600),
    why: "bits per second of the serial line",
};
pub(crate) const STATUS_PERIOD: Limit<Duration> = Limit {
    section: Device,
    key: "status_period",
    min: ms(1),
    max: s(10),
    default: Some(ms(100)),
    why: "how often the status thread polls (from the start of its last poll: after waiting for the port behind a command, it does not poll twice in a row)",
};
pub(crate) const STATUS_MAX_AGE: Limit<Duration> = Limit {
    section: Device,
    key: "status_max_age",
    min: ms(1),
    max: s(10),
    default: Some(ms(500)),
    why: "a status at least this often, even under a command flood; older is stale, and no status for long is `silent`",
};
pub(crate) const COMMAND_TIMEOUT: Limit<Duration> = Limit {
    section: Device,
    key: "command_timeout",
    min: ms(1),
    max: s(10),
    default: Some(ms(250)),
    why: "the last command is sent again after this long without a new one",
};
pub(crate) const REPLY_TIMEOUT: Limit<Duration> = Limit {
    section: Device,
    key: "reply_timeout",
    min: ms(1),
    max: s(5),
    default: Some(ms(200)),
    why: "the longest a transaction waits for the device (except an ELM327's first request, its protocol search: up to 10 s)",
};
pub(crate) const MIN_COMMAND_INTERVAL: Limit<Duration> = Limit {
    section: Device,
    key: "min_command_interval",
    min: ms(1),
    max: s(1),
    default: None,
    why: "the paper's rate cap (off when not written); longer would hold back a brake command",
};
pub(crate) const SIM_TURNAROUND: Limit<Duration> = Limit {
    section: DeviceSim,
    key: "turnaround",
    min: ms(0),
    max: s(1),
    default: Some(ms(2)),
    why: "the simulated device's time to start answering",
};
pub(crate) const SIM_POLL_DELAY: Limit<Duration> = Limit {
    section: DeviceSim,
    key: "poll_delay",
    min: ms(0),
    max: s(10),
    default: Some(ms(0)),
    why: "extra time a simulated status request takes",
};
pub(crate) const SIM_COMMAND_DELAY: Limit<Duration> = Limit {
    section: DeviceSim,
    key: "command_delay",
    min: ms(0),
    max: s(10),
    default: Some(ms(0)),
    why: "extra time a simulated command takes",
};
pub(crate) const SIM_WATCHDOG: Limit<Duration> = Limit {
    section: DeviceSim,
    key: "watchdog",
    min: ms(10),
    max: s(10),
    default: None,
    why: "the simulated actuator's own watchdog (off when not written): gas 0, brake full",
};
pub(crate) const SIM_LAG: Limit<Duration> = Limit {
    section: DeviceSim,
    key: "lag",
    min: ms(1),
    max: s(10),
    default: None,
    why: "the simulated setpoint actuator follows its command with this first-order lag (off when not written)",
};
pub(crate) const SIM_DELAY: Limit<Duration> = Limit {
    section: DeviceSim,
    key: "delay",
    min: ms(0),
    max: s(1),
    default: Some(ms(0)),
    why: "the simulated setpoint actuator acts on a command this long after it arrives (transport delay)",
};
pub(crate) const SIM_SETTLE: Limit<Duration> = Limit {
    section: DeviceSim,
    key: "settle",
    min: ms(0),
    max: s(10),
    default: Some(ms(0)),
    why:
        "the simulated state actuator takes this long to change state (its shift time; 0: at once)",
};
pub(crate) const MODBUS_SLAVE: Limit<u64> = Limit {
    section: DeviceModbus,
    key: "slave",
    min: 1,
    max: 247,
    default: None,
    why: "a Modbus RTU unit address, required (0 is broadcast, 248–255 reserved)",
};
pub(crate) const RESPONSE_LAG: Limit<Duration> = Limit {
    section: DeviceResponse,
    key: "lag",
    min: ms(1),
    max: s(10),
    default: None,
    why: "the real device follows its command with this first-order lag (or moves at its `rate`)",
};
pub const OVERRIDE_TIME: Limit<Duration> = Limit {
    section: DeviceResponse,
    key: "override_time",
    min: ms(50),
    max: s(2),
    default: Some(ms(300)),
    why: "moved `override_threshold` away from its command this long, the device is in a driver's hands (`override`)",
};
pub(crate) const WATCHDOG_TIMEOUT: Limit<Duration> = Limit {
    section: Network,
    key: "watchdog_timeout",
    min: ms(10),
    max: s(2),
    default: Some(ms(500)),
    why: "no valid network command this long: safe state, disengage",
};
/// Longer than two of a commanding console's round trips (it asks every 250 ms) and a
/// slow link's answer; at most what a moving vehicle may go unseen.
pub(crate) const TERMINAL_TIMEOUT: Limit<Duration> = Limit {
    section: Console,
    key: "terminal_timeout",
    min: ms(500),
    max: s(10),
    default: Some(s(1)),
    why: "a commanding console's terminal answers no round trip this long: safe state, disengage",
};
pub(crate) const BROADCAST_RATE: Limit<f64> = Limit {
    section: Network,
    key: "broadcast_rate",
    min: 0.1,
    max: 1000.0,
    default: Some(10.0),
    why: "state broadcasts a second",
};
pub(crate) const MULTICAST_TTL: Limit<u64> = Limit {
    section: Network,
    key: "multicast_ttl",
    min: 0,
    max: 255,
    default: Some(1),
    why: "IP time-to-live of multicast broadcasts (1: this subnet)",
};
pub(crate) const REPORT_RATE: Limit<f64> = Limit {
    section: Ros2,
    key: "report_rate",
    min: 1.0,
    max: 100.0,
    default: Some(30.0),
    why: "ROS 2 vehicle reports a second (Autoware's control wants them fresh)",
};
pub(crate) const SUPERVISOR_PERIOD: Limit<Duration> = Limit {
    section: Supervisor,
    key: "period",
    min: ms(10),
    max: s(1),
    default: Some(ms(100)),
    why: "how often the supervisor looks (the paper's was 1 s)",
};
pub(crate) const ERROR_RATE: Limit<f64> = Limit {
    section: Supervisor,
    key: "error_rate",
    min: 0.01,
    max: 0.99,
    default: Some(0.5),
    why: "failed transactions above this fraction are a fault; 1 or more never would be",
};
pub(crate) const ERROR_WINDOW: Limit<Duration> = Limit {
    section: Supervisor,
    key: "error_window",
    min: ms(100),
    max: s(60),
    default: Some(s(2)),
    why: "the window `error_rate` is measured over",
};
pub(crate) const FOLLOW_TOLERANCE: Limit<f64> = Limit {
    section: Supervisor,
    key: "follow_tolerance",
    min: 0.01,
    max: 0.5,
    default: Some(0.1),
    why: "a device without a declared response, measured further than this fraction of its range from its command …",
};
pub(crate) const FOLLOW_TIME: Limit<Duration> = Limit {
    section: Supervisor,
    key: "follow_time",
    min: ms(100),
    max: s(10),
    default: Some(ms(2500)),
    why: "… for longer than this is `not_following`",
};
pub(crate) const STALL_TIME: Limit<Duration> = Limit {
    section: Supervisor,
    key: "stall_time",
    min: ms(100),
    max: s(10),
    default: Some(ms(500)),
    why: "a device with a declared response that makes no headway toward its command this long is `not_following`",
};
pub(crate) const RANGE_MARGIN: Limit<f64> = Limit {
    section: Supervisor,
    key: "range_margin",
    min: 0.0,
    max: 0.5,
    default: Some(0.05),
    why: "reported positions may stray this fraction of the range outside it",
};
pub(crate) const ATTEMPTS: Limit<u64> = Limit {
    section: Supervisor,
    key: "attempts",
    min: 1,
    max: 10,
    default: Some(3),
    why: "tries of a recovery procedure before it gives up",
};
pub(crate) const STEP_TIMEOUT: Limit<Duration> = Limit {
    section: Supervisor,
    key: "step_timeout",
    min: ms(100),
    max: s(30),
    default: Some(s(4)),
    why: "the time a recovery step may take",
};
pub(crate) const GIVE_UP_AFTER: Limit<Duration> = Limit {
    section: Supervisor,
    key: "give_up_after",
    min: s(1),
    max: s(86_400),
    default: None,
    why: "off: adrive never ends the run because of a device. Set (or `--give-up-after`): a device gone this long, or a recovery that gave up after trying this long, ends the run (status 4, after the safe state)",
};
pub(crate) const TELEOP_GAS: Limit<f64> = Limit {
    section: Teleop,
    key: "gas",
    min: 0.01,
    max: 0.5,
    default: Some(0.2),
    why: "`↑` held: the throttle at this fraction of its range; a keyboard holds at most half",
};
pub(crate) const TELEOP_BRAKE: Limit<f64> = Limit {
    section: Teleop,
    key: "brake",
    min: 0.05,
    max: 1.0,
    default: Some(0.6),
    why: "`↓` held: the brake at this fraction of its range",
};
pub(crate) const TELEOP_HOLD: Limit<f64> = Limit {
    section: Teleop,
    key: "hold",
    min: 0.0,
    max: 1.0,
    default: Some(0.3),
    why: "no pedal key held: the brake at this (enough to hold the vehicle still; 0 lets it coast), never gas",
};
pub(crate) const TELEOP_STEER_RATE: Limit<f64> = Limit {
    section: Teleop,
    key: "steer_rate",
    min: 0.05,
    max: 2.0,
    default: Some(0.5),
    why: "`←`/`→` held: the steering command moves this much of its range a second (−1 … 1: its left end … its right)",
};
pub const DEADMAN: Limit<Duration> = Limit {
    section: CommandLine,
    key: "deadman",
    min: ms(100),
    max: s(5),
    default: Some(s(1)),
    why: "teleop: no teleop key this long, gas 0 and brake full",
};
/// The teleop deadman when `--deadman` is not given: [`DEADMAN`]'s default. Longer than
/// a terminal's key-repeat delay (typically 250–660 ms), so holding a key never trips it.
pub const DEADMAN_DEFAULT: Duration = DEADMAN.default.unwrap();

/// A rule between keys of one section.
#[derive(Debug)]
pub(crate) struct Rule {
    /// Where the guide's table lists it (read by its test).
    #[cfg_attr(not(test), allow(dead_code))]
    pub section: Section,
    /// The rule as the guide and the error say it.
    pub text: &'static str,
}

impl Rule {
    /// The rule broken by `facts` (`status_max_age 250ms, status_period 1500ms`), about
    /// `paths`, the one to blame first.
    pub(crate) fn violation(&self, paths: &[&str], facts: String) -> Violation {
        Violation {
            paths: paths.iter().map(|p| p.to_string()).collect(),
            message: format!("{facts}: expected {}", self.text),
        }
    }
}

pub(crate) const MAX_AGE_COVERS_PERIOD: Rule = Rule {
    section: Device,
    text: "`status_max_age` at least `status_period`",
};
pub(crate) const REPLY_WITHIN_MAX_AGE: Rule = Rule {
    section: Device,
    text: "`reply_timeout` at most `status_max_age` (a device is not judged silent while a reply may still come)",
};
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) const RANGE_FORM: Rule = Rule {
    section: Device,
    text: "`range` on every setpoint device, as `[min, max]`: two finite numbers, min < max; a throttle's and a brake's start at 0 (released)",
};
pub(crate) const RESPONSE_IN_UNITS: Rule = Rule {
    section: DeviceResponse,
    text: "`rate`, `noise`, `tolerance`, `deadband` and `override_threshold` (by default a tenth of the range) in the device's units, above 0: `rate` at most 1000 ranges a second, the others below the width of its range, `tolerance` above `noise`",
};
pub(crate) const RESPONSE_ON_SETPOINTS: Rule = Rule {
    section: Device,
    text: "`[device.response]` only on setpoint devices; `polling = \"adaptive\"` only with a `[device.response]` (the estimate it polls by)",
};
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) const PORT_NAMED: Rule = Rule {
    section: Device,
    text: "a `port` path on every device, unless it is simulated (`--sim`, `adrive sim`)",
};
pub(crate) const HOLD_BELOW_BRAKE: Rule = Rule {
    section: Teleop,
    text: "`hold` at most `brake` (`↓` brakes at least as hard as letting go)",
};
pub(crate) const SIM_IN_UNITS: Rule = Rule {
    section: DeviceSim,
    text: "`rate`, `deadband` and `backlash` in the device's units, on setpoint devices only: `rate` above 0 and at most 1000 ranges a second, `deadband` and `backlash` from 0 to a tenth of its range; a reading's `noise` (`readings = { NAME = { noise = … } }`) a finite number from 0",
};
pub(crate) const WATCHDOG_OUTLASTS_RESEND: Rule = Rule {
    section: DeviceSim,
    text: "`watchdog` longer than the device's `command_timeout` (which keeps a live adrive resending)",
};

/// One limit, whatever its type: a row of the guide's table (docs/vehicles.md).
pub trait Row: Sync {
    fn section(&self) -> Section;
    fn key(&self) -> &'static str;
    /// The key as a message names it.
    fn name(&self) -> String;
    /// `a duration from 1ms to 10s`.
    fn expected(&self) -> String;
    fn cells(&self) -> [String; 5];
}

impl<T: Bounded + Sync> Row for Limit<T> {
    fn section(&self) -> Section {
        self.section
    }
    fn key(&self) -> &'static str {
        self.key
    }
    fn name(&self) -> String {
        Limit::name(self)
    }
    fn expected(&self) -> String {
        Limit::expected(self)
    }
    fn cells(&self) -> [String; 5] {
        let key = match self.section {
            CommandLine => format!("`--{}`", self.key),
            _ => format!("`{}`", self.key),
        };
        [
            format!("`{}`", self.section.header()),
            key,
            format!("{} … {}", self.min.show(), self.max.show()),
            self.default.map_or_else(|| "—".to_string(), |d| d.show()),
            self.why.to_string(),
        ]
    }
}

/// Every limit, in the guide's order.
pub static ALL: &[&dyn Row] = &[
    &BAUD,
    &STATUS_PERIOD,
    &STATUS_MAX_AGE,
    &COMMAND_TIMEOUT,
    &REPLY_TIMEOUT,
    &MIN_COMMAND_INTERVAL,
    &SIM_TURNAROUND,
    &SIM_POLL_DELAY,
    &SIM_COMMAND_DELAY,
    &SIM_WATCHDOG,
    &SIM_LAG,
    &SIM_DELAY,
    &SIM_SETTLE,
    &MODBUS_SLAVE,
    &RESPONSE_LAG,
    &OVERRIDE_TIME,
    &WATCHDOG_TIMEOUT,
    &BROADCAST_RATE,
    &MULTICAST_TTL,
    &TERMINAL_TIMEOUT,
    &REPORT_RATE,
    &SUPERVISOR_PERIOD,
    &ERROR_RATE,
    &ERROR_WINDOW,
    &FOLLOW_TOLERANCE,
    &FOLLOW_TIME,
    &STALL_TIME,
    &RANGE_MARGIN,
    &ATTEMPTS,
    &STEP_TIMEOUT,
    &GIVE_UP_AFTER,
    &TELEOP_GAS,
    &TELEOP_BRAKE,
    &TELEOP_HOLD,
    &TELEOP_STEER_RATE,
    &DEADMAN,
];

/// The limit of `key` in `section`, if it has one.
pub fn find(section: Section, key: &str) -> Option<&'static dyn Row> {
    ALL.iter()
        .copied()
        .find(|r| r.section() == section && r.key() == key)
}

/// Every rule, in the guide's order.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) static RULES: &[&Rule] = &[
    &MAX_AGE_COVERS_PERIOD,
    &REPLY_WITHIN_MAX_AGE,
    &RANGE_FORM,
    &RESPONSE_ON_SETPOINTS,
    &PORT_NAMED,
    &WATCHDOG_OUTLASTS_RESEND,
    &SIM_IN_UNITS,
    &RESPONSE_IN_UNITS,
    &HOLD_BELOW_BRAKE,
];

/// The guide's table (docs/vehicles.md) of limits and list of rules, as Markdown.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn markdown() -> String {
    let mut out = String::from("| section | key | accepted | default | |\n|---|---|---|---|---|\n");
    for row in ALL {
        out.push_str(&format!("| {} |\n", row.cells().join(" | ")));
    }
    out.push('\n');
    for rule in RULES {
        out.push_str(&format!("- `{}`: {}\n", rule.section.header(), rule.text));
    }
    out
}

/// `--give-up-after DURATION`: a duration within [`GIVE_UP_AFTER`] (clap names the
/// option).
pub(crate) fn parse_give_up_after(text: &str) -> Result<Duration, String> {
    parse_within(&GIVE_UP_AFTER, text)
}

/// A command-line duration held to `limit` (clap names the option).
fn parse_within(limit: &Limit<Duration>, text: &str) -> Result<Duration, String> {
    let d = crate::config::parse_duration(text)?;
    if limit.check(d).is_err() {
        return Err(format!(
            "expected {}, got {}",
            limit.expected(),
            fmt_duration(d)
        ));
    }
    Ok(d)
}

/// `--terminal-timeout DURATION`: a duration within [`TERMINAL_TIMEOUT`] (clap names
/// the option).
pub(crate) fn parse_terminal_timeout(text: &str) -> Result<Duration, String> {
    parse_within(&TERMINAL_TIMEOUT, text)
}

/// `--deadman DURATION`: a duration within [`DEADMAN`] (clap names the option).
pub(crate) fn parse_deadman(text: &str) -> Result<Duration, String> {
    parse_within(&DEADMAN, text)
}

impl fmt::Display for Section {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.header())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_are_written_the_way_a_vehicle_file_writes_them() {
        assert_eq!(fmt_duration(ms(250)), "250ms");
        assert_eq!(fmt_duration(ms(1500)), "1500ms");
        assert_eq!(fmt_duration(s(2)), "2s");
        assert_eq!(fmt_duration(Duration::ZERO), "0s");
        assert_eq!(fmt_duration(Duration::from_micros(10)), "10µs");
        assert_eq!(
            crate::config::parse_duration(&fmt_duration(Duration::from_nanos(7))).unwrap(),
            Duration::from_nanos(7)
        );
    }

    #[test]
    fn a_violation_names_the_key_the_range_and_the_value() {
        let e = REPLY_TIMEOUT.check(s(3_600_000_000)).unwrap_err();
        assert_eq!(
            e.message,
            "reply_timeout: expected a duration (\"250ms\", \"2s\") from 1ms to 5s, got 3600000000s"
        );
        assert_eq!(e.paths, ["reply_timeout"]);
        let e = SIM_WATCHDOG.check(ms(0)).unwrap_err();
        assert!(e.message.starts_with("sim.watchdog: "), "{e}");
        assert_eq!(e.paths, ["sim.watchdog"]);
        assert!(ATTEMPTS.check(1).is_ok() && ATTEMPTS.check(10).is_ok());
    }

    #[test]
    fn every_default_lies_in_its_own_range() {
        fn ok<T: Bounded + fmt::Debug>(l: &Limit<T>) {
            if let Some(d) = l.default {
                assert!(l.check(d).is_ok(), "{l:?}");
            }
            assert!(l.min <= l.max, "{l:?}");
        }
        ok(&BAUD);
        ok(&MODBUS_SLAVE);
        ok(&MULTICAST_TTL);
        ok(&ATTEMPTS);
        for l in [
            &STATUS_PERIOD,
            &STATUS_MAX_AGE,
            &COMMAND_TIMEOUT,
            &REPLY_TIMEOUT,
            &MIN_COMMAND_INTERVAL,
            &SIM_TURNAROUND,
            &SIM_POLL_DELAY,
            &SIM_COMMAND_DELAY,
            &SIM_WATCHDOG,
            &SIM_LAG,
            &SIM_DELAY,
            &SIM_SETTLE,
            &WATCHDOG_TIMEOUT,
            &SUPERVISOR_PERIOD,
            &ERROR_WINDOW,
            &FOLLOW_TIME,
            &STALL_TIME,
            &RESPONSE_LAG,
            &OVERRIDE_TIME,
            &STEP_TIMEOUT,
            &GIVE_UP_AFTER,
            &DEADMAN,
        ] {
            ok(l);
        }
        for l in [
            &BROADCAST_RATE,
            &REPORT_RATE,
            &ERROR_RATE,
            &FOLLOW_TOLERANCE,
            &RANGE_MARGIN,
            &TELEOP_GAS,
            &TELEOP_BRAKE,
            &TELEOP_HOLD,
            &TELEOP_STEER_RATE,
        ] {
            ok(l);
        }
    }

    #[test]
    fn deadman_zero_is_refused_with_its_range() {
        let e = parse_deadman("0s").unwrap_err();
        assert_eq!(
            e,
            "expected a duration (\"250ms\", \"2s\") from 100ms to 5s, got 0s"
        );
        assert!(DEADMAN_DEFAULT > ms(660), "longer than a key-repeat delay");
        assert_eq!(parse_deadman("1500ms"), Ok(ms(1500)));
        assert!(parse_deadman("1h").is_err());
        assert!(parse_deadman("soon").unwrap_err().contains("250ms"));
    }

    #[test]
    fn give_up_after_on_the_command_line_is_held_to_its_limit() {
        assert_eq!(parse_give_up_after("30s"), Ok(s(30)));
        assert_eq!(
            parse_give_up_after("500ms").unwrap_err(),
            "expected a duration (\"250ms\", \"2s\") from 1s to 86400s, got 500ms"
        );
        assert!(parse_give_up_after("2days").is_err());
    }

    /// The guide's table (docs/vehicles.md) is this module's, so the documented ranges cannot drift.
    #[test]
    fn the_guide_shows_the_limits_table() {
        let readme = include_str!("../../docs/vehicles.md");
        let table = markdown();
        crate::testkit::assert_guide_holds("docs/vehicles.md", readme, "limits", &table);
    }
}
