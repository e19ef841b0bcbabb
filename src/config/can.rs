//! CAN buses and the devices on them. A `[[bus]]` is one serial-line CAN adapter (its
//! port, the bus bitrate) and the DBC file that describes the messages on that bus; a
//! device with `driver = "can"` names its bus and, in `[device.can]`, the DBC messages
//! and signals that command it, enable and disable it, and carry each of its readings.
//! Everything is looked up in the DBC here, once: a misspelt message or signal is a
//! vehicle-file error at its line, never a silent frame on the bus.

use super::device::{DeviceConfig, Mistake, ReadingKind};
use crate::can::dbc::{Checksum, Database, Message, Sequence};
use crate::can::{Bitrate, Id};
use crate::value::Kind;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;
use toml::Spanned;

/// The reading a kit reports itself enabled by (a flag): while engaged, 0 is a fault.
pub(crate) const ENABLED: &str = "enabled";
/// The reading a kit reports its operator override by (a flag): adrive's driver
/// override, beside the estimator's.
pub(crate) const OVERRIDE: &str = "override";

/// One CAN bus, checked.
#[derive(Clone, Debug)]
pub struct BusConfig {
    /// Its free name (devices name it in `bus = "…"`).
    pub name: String,
    /// The adapter's serial port.
    pub port: String,
    pub bitrate: Bitrate,
    /// The messages on the bus.
    pub dbc: Arc<Database>,
    /// The simulated kit behind the adapter under `--sim`.
    pub sim: BusSim,
}

impl PartialEq for BusConfig {
    fn eq(&self, o: &BusConfig) -> bool {
        self.name == o.name
            && self.port == o.port
            && self.bitrate == o.bitrate
            && self.dbc.path() == o.dbc.path()
            && self.sim == o.sim
    }
}

/// `[bus.sim]`: the simulated kit.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusSim {
    /// The modules' firmware watchdog: a module that hears no command this long
    /// disables itself. None: the module never times out (OSCC v1.2.4).
    #[serde(default, deserialize_with = "super::opt_duration")]
    pub watchdog: Option<Duration>,
}

/// `[[bus]]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawBus {
    name: Spanned<String>,
    #[serde(default)]
    port: String,
    #[serde(default = "default_bitrate")]
    bitrate: Spanned<u32>,
    dbc: Spanned<String>,
    #[serde(default)]
    sim: BusSim,
}

fn default_bitrate() -> Spanned<u32> {
    Spanned::new(0..0, 500_000)
}

impl RawBus {
    /// Check the bus and load its DBC, relative to the vehicle file at `source`.
    pub(super) fn check(self, source: &str) -> Result<BusConfig, Mistake> {
        let at = self.name.span().start;
        let name = self.name.into_inner();
        super::device::check_name("bus", &name).map_err(|m| (at, m))?;
        let bps = *self.bitrate.get_ref();
        let bitrate = Bitrate::from_bits_per_second(bps).ok_or_else(|| {
            let rates: Vec<String> = Bitrate::ALL
                .iter()
                .map(|b| b.bits_per_second().to_string())
                .collect();
            (
                self.bitrate.span().start.max(at),
                format!(
                    "bus {name}: bitrate {bps}: expected one of the adapter's rates ({})",
                    rates.join(", ")
                ),
            )
        })?;
        let at_dbc = self.dbc.span().start;
        let written = self.dbc.into_inner();
        let path = Path::new(source)
            .parent()
            .unwrap_or(Path::new(""))
            .join(&written);
        let dbc = Database::load(&path).map_err(|e| (at_dbc, format!("bus {name}: dbc: {e}")))?;
        check_texts(&dbc).map_err(|e| (at_dbc, format!("bus {name}: dbc: {e}")))?;
        Ok(BusConfig {
            name,
            port: self.port,
            bitrate,
            dbc: Arc::new(dbc),
            sim: self.sim,
        })
    }
}

/// The texts of a DBC file that adrive shows (the console's bus monitor, the snapshot,
/// the logs): each signal's unit and the names of its value table are free text, held
/// to the rule every name a person wrote is held to ([`super::device::check_text`]).
fn check_texts(dbc: &Database) -> Result<(), String> {
    for m in dbc.messages() {
        for s in m.signals() {
            let at = |line: usize, what: String| {
                format!(
                    "{}:{line}: signal {}.{}: {what}",
                    dbc.path(),
                    m.name(),
                    s.name()
                )
            };
            super::device::check_text("unit", s.unit(), true).map_err(|e| at(s.line(), e))?;
            for (raw, value) in s.values() {
                super::device::check_text(&format!("value {raw}"), value, false)
                    .map_err(|e| at(s.values_line(), e))?;
            }
        }
    }
    Ok(())
}

/// One signal of one message, and how a reading is made of it (value × scale).
#[derive(Clone, Debug, PartialEq)]
pub struct SignalRef {
    pub message: Id,
    pub signal: String,
    pub scale: f64,
}

/// A device's place on its bus, checked against the DBC.
#[derive(Clone, Debug)]
pub struct CanMap {
    /// Its bus, by index in the vehicle's buses.
    pub bus: usize,
    pub dbc: Arc<Database>,
    /// The message and signal that carry its command (actuators).
    pub command: Option<SignalRef>,
    /// The rolling counter and checksum adrive fills in, in the command message.
    pub sequence: Option<Sequence>,
    /// Sent to enable the device when the vehicle is engaged (after the safe command).
    pub enable: Option<Id>,
    /// Sent after the safe command whenever the vehicle is not engaged.
    pub disable: Option<Id>,
    /// Each reading's signal, by reading index.
    pub readings: Vec<SignalRef>,
    /// The signal of its fault codes (named by the DBC's value table).
    pub faults: Option<SignalRef>,
}

impl PartialEq for CanMap {
    fn eq(&self, o: &CanMap) -> bool {
        self.bus == o.bus
            && self.dbc.path() == o.dbc.path()
            && self.command == o.command
            && self.enable == o.enable
            && self.disable == o.disable
            && self.readings == o.readings
            && self.faults == o.faults
    }
}

impl CanMap {
    /// Every identifier this device listens to (its readings' and faults' messages).
    pub fn listens(&self) -> impl Iterator<Item = Id> + '_ {
        self.readings
            .iter()
            .chain(self.faults.as_ref())
            .map(|s| s.message)
    }

    /// Whether the device follows the gate (it has enable or disable messages).
    pub fn is_kit(&self) -> bool {
        self.enable.is_some() || self.disable.is_some()
    }

    /// The message the command signal is in.
    pub fn command_message(&self) -> Option<&Message> {
        self.command
            .as_ref()
            .and_then(|c| self.dbc.by_id(c.message))
    }

    /// The names of the fault codes set in `raw` (by the DBC's value table, as bits).
    pub fn fault_names(&self, raw: u16) -> Vec<String> {
        let Some(f) = &self.faults else {
            return Vec::new();
        };
        self.dbc
            .by_id(f.message)
            .and_then(|m| m.signal(&f.signal))
            .map(|s| s.flag_names(u64::from(raw)))
            .unwrap_or_default()
    }
}

/// A reading's signal as written: `"MESSAGE.signal"` or `{ signal = "…", scale = … }`.
#[derive(Deserialize)]
#[serde(untagged)]
pub(super) enum RawSignal {
    Name(String),
    Scaled {
        signal: String,
        #[serde(default = "one")]
        scale: f64,
    },
}

fn one() -> f64 {
    1.0
}

/// `[device.sequence]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawSequence {
    #[serde(default)]
    counter: Option<String>,
    #[serde(default)]
    checksum: Option<String>,
    /// `xor8` or `sum8`.
    #[serde(default)]
    checksum_kind: Option<String>,
}

/// `[device.can]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCan {
    #[serde(default)]
    command: Option<Spanned<String>>,
    #[serde(default)]
    enable: Option<Spanned<String>>,
    #[serde(default)]
    disable: Option<Spanned<String>>,
    #[serde(default)]
    faults: Option<Spanned<String>>,
    #[serde(default)]
    readings: BTreeMap<String, Spanned<RawSignal>>,
    #[serde(default)]
    sequence: Option<RawSequence>,
}

/// Resolve a CAN device's `[device.can]` against its bus's DBC.
pub(super) fn resolve(
    d: &DeviceConfig,
    at: usize,
    bus: Option<Spanned<String>>,
    can: Option<Spanned<RawCan>>,
    buses: &[BusConfig],
) -> Result<CanMap, Mistake> {
    let name = &d.name;
    let Some(bus) = bus else {
        return Err((
            at,
            format!("{name}: a CAN device names its bus (`bus = \"…\"`, a [[bus]] of the file)"),
        ));
    };
    let at_bus = bus.span().start;
    let Some(index) = buses.iter().position(|b| &b.name == bus.get_ref()) else {
        let known: Vec<&str> = buses.iter().map(|b| b.name.as_str()).collect();
        return Err((
            at_bus,
            format!(
                "{name}: bus {:?} is not a [[bus]] of the file (buses: {})",
                bus.get_ref(),
                if known.is_empty() {
                    "none".to_string()
                } else {
                    known.join(", ")
                }
            ),
        ));
    };
    let Some(can) = can else {
        return Err((at, format!("{name}: a CAN device needs [device.can]: its command, readings and enable/disable messages")));
    };
    let at_can = can.span().start;
    let raw = can.into_inner();
    let db = &buses[index].dbc;
    let refuse_at = |at: usize, m: String| (at.max(at_can), format!("{name}: can: {m}"));
    let refuse = |m: String| refuse_at(at_can, m);
    let signal = |what: &str, at: usize, text: &str, scale: f64| -> Result<SignalRef, Mistake> {
        let refuse = |m: String| refuse_at(at, m);
        let Some((m, s)) = text.split_once('.') else {
            return Err(refuse(format!(
                "{what} = {text:?}: expected \"MESSAGE.signal\""
            )));
        };
        let message = db
            .message_named(m)
            .map_err(|e| refuse(format!("{what}: {}", e.message)))?;
        let sig = message
            .signal_named(s)
            .map_err(|e| refuse(format!("{what}: {e}")))?;
        if !(scale.is_finite() && scale != 0.0) {
            return Err(refuse(format!(
                "{what}: scale: expected a finite number other than 0"
            )));
        }
        let _ = sig;
        Ok(SignalRef {
            message: message.id(),
            signal: s.to_string(),
            scale,
        })
    };
    let message = |what: &str, text: &Spanned<String>| -> Result<Id, Mistake> {
        db.message_named(text.get_ref())
            .map(|m| m.id())
            .map_err(|e| refuse_at(text.span().start, format!("{what}: {}", e.message)))
    };
    let command = match (&raw.command, d.kind) {
        (Some(spanned), Kind::Setpoint | Kind::State) => {
            let c = spanned.get_ref();
            let r = signal("command", spanned.span().start, c, 1.0)?;
            let sig = db
                .by_id(r.message)
                .and_then(|m| m.signal(&r.signal))
                .expect("found");
            if let (Kind::Setpoint, Some((lo, hi))) = (d.kind, sig.range()) {
                if d.range[0] < lo || d.range[1] > hi {
                    return Err(refuse_at(spanned.span().start, format!(
                        "command = {c:?}: the device's range [{}, {}] is outside the signal's [{lo}, {hi}]",
                        d.range[0], d.range[1]
                    )));
                }
            }
            Some(r)
        }
        (None, Kind::Setpoint | Kind::State) => {
            return Err(refuse(
                "an actuator needs `command = \"MESSAGE.signal\"`".into(),
            ))
        }
        (Some(_), Kind::Sensor) => return Err(refuse("a sensor takes no command".into())),
        (None, Kind::Sensor) => None,
    };
    let sequence = match (&raw.sequence, &command) {
        (None, _) => None,
        (Some(_), None) => return Err(refuse("sequence: only a command message has one".into())),
        (Some(s), Some(c)) => {
            let m = db.by_id(c.message).expect("found");
            let kind = match s.checksum_kind.as_deref() {
                None | Some("xor8") => Checksum::Xor8,
                Some("sum8") => Checksum::Sum8,
                Some(k) => {
                    return Err(refuse(format!(
                        "sequence.checksum_kind = {k:?}: expected \"xor8\" or \"sum8\""
                    )))
                }
            };
            Some(
                Sequence::new(
                    m,
                    s.counter.as_deref(),
                    s.checksum.as_deref().map(|n| (n, kind)),
                )
                .map_err(|e| refuse(format!("sequence: {e}")))?,
            )
        }
    };
    let enable = raw
        .enable
        .as_ref()
        .map(|m| message("enable", m))
        .transpose()?;
    let disable = raw
        .disable
        .as_ref()
        .map(|m| message("disable", m))
        .transpose()?;
    if (enable.is_some() || disable.is_some()) && d.kind == Kind::Sensor {
        return Err(refuse("enable/disable: a sensor is not enabled".into()));
    }
    let faults = raw
        .faults
        .as_ref()
        .map(|f| signal("faults", f.span().start, f.get_ref(), 1.0))
        .transpose()?;
    let mut readings = Vec::new();
    for spec in &d.readings {
        let Some(w) = raw.readings.get(&spec.name) else {
            return Err(refuse(format!(
                "readings: {} has no signal (write `{} = \"MESSAGE.signal\"`)",
                spec.name, spec.name
            )));
        };
        let at = w.span().start;
        let (text, scale) = match w.get_ref() {
            RawSignal::Name(t) => (t.as_str(), 1.0),
            RawSignal::Scaled { signal, scale } => (signal.as_str(), *scale),
        };
        readings.push(signal(&format!("readings.{}", spec.name), at, text, scale)?);
        if matches!(spec.name.as_str(), ENABLED | OVERRIDE) && spec.kind != ReadingKind::Flag {
            return Err(refuse(format!(
                "readings: {} is the kit's flag: declare it as a flag",
                spec.name
            )));
        }
    }
    if let Some(extra) = raw.readings.keys().find(|k| d.reading(k).is_none()) {
        return Err(refuse(format!(
            "readings: {extra} is not one of the device's readings ({})",
            d.readings
                .iter()
                .map(|r| r.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    Ok(CanMap {
        bus: index,
        dbc: db.clone(),
        command,
        sequence,
        enable,
        disable,
        readings,
        faults,
    })
}

#[cfg(test)]
mod tests {
    use crate::config::protocol_map::Wire;
    use crate::config::{load, parse};
    use std::path::Path;

    /// A vehicle file beside vehicles/oscc.dbc (the DBC is found relative to it).
    fn path() -> String {
        format!("{}/vehicles/test.toml", env!("CARGO_MANIFEST_DIR"))
    }

    const HEAD: &str = r#"[vehicle]
name = "kit"
[[bus]]
name = "kit"
port = "/dev/ttyACM0"
dbc = "oscc.dbc"
"#;

    fn steer(can: &str) -> String {
        format!(
            r#"{HEAD}
[[device]]
name = "steer"
kind = "setpoint"
range = [-1.0, 1.0]
driver = "can"
bus = "kit"
readings = ["enabled", "override"]
reply_timeout = "50ms"
[device.can]
{can}
"#
        )
    }

    const GOOD: &str = r#"command = "STEERING_COMMAND.torque_command"
enable = "STEERING_ENABLE"
disable = "STEERING_DISABLE"
faults = "STEERING_REPORT.dtcs"
readings = { enabled = "STEERING_REPORT.enabled", override = "STEERING_REPORT.operator_override" }"#;

    fn error(text: &str) -> String {
        parse(text, &path()).unwrap_err().to_string()
    }

    #[test]
    fn the_oscc_vehicle_loads_with_its_bus_and_four_devices_on_it() {
        let v = load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("vehicles/oscc.toml")).unwrap();
        assert_eq!(v.buses.len(), 1);
        assert_eq!(v.buses[0].bitrate.bits_per_second(), 500_000);
        let names: Vec<&str> = v.devices.iter().map(|d| d.name.as_str()).collect();
        assert_eq!(names, ["steer", "gas", "brake", "car"]);
        for d in &v.devices {
            assert_eq!(d.port, v.buses[0].port, "{}: the bus's port", d.name);
            assert!(matches!(d.wire, Wire::Can(_)));
        }
        let kits: Vec<&str> = v
            .devices
            .iter()
            .filter(|d| d.kit().is_some())
            .map(|d| d.name.as_str())
            .collect();
        assert_eq!(kits, ["steer", "gas", "brake"]);
        let brake = v.device("brake").unwrap().kit().unwrap();
        assert_eq!(brake.command.as_ref().unwrap().message.raw(), 0x72);
        assert_eq!(brake.enable.unwrap().raw(), 0x70);
        assert_eq!(brake.disable.unwrap().raw(), 0x71);
        assert_eq!(
            brake.fault_names(0b11),
            ["INVALID_SENSOR_VAL", "OPERATOR_OVERRIDE"]
        );
        // Road speed in m/s from km/h on the bus.
        let Wire::Can(car) = &v.device("car").unwrap().wire else {
            unreachable!()
        };
        assert!((car.readings[0].scale - 1.0 / 3.6).abs() < 1e-6);
        assert!(v.roles.speed.is_some());
    }

    #[test]
    fn a_good_kit_device_parses() {
        parse(&steer(GOOD), &path()).unwrap();
    }

    #[test]
    fn a_misspelt_message_is_refused_at_its_device_with_the_messages_there_are() {
        let e = error(&steer(&GOOD.replace("STEERING_ENABLE", "STEERING_ENABEL")));
        assert!(e.contains("test.toml:18:"), "{e}");
        assert!(e.contains("enable: no message \"STEERING_ENABEL\""), "{e}");
        assert!(e.contains("STEERING_ENABLE"), "names the messages: {e}");
    }

    #[test]
    fn a_misspelt_signal_is_refused() {
        let e = error(&steer(&GOOD.replace("torque_command", "torque")));
        assert!(e.contains("command:") && e.contains("torque"), "{e}");
    }

    #[test]
    fn a_reading_without_its_signal_is_refused_with_the_form_expected() {
        let e = error(&steer(
            &GOOD.replace(", override = \"STEERING_REPORT.operator_override\"", ""),
        ));
        assert!(
            e.contains("readings: override has no signal (write `override = \"MESSAGE.signal\"`)"),
            "{e}"
        );
    }

    #[test]
    fn a_range_wider_than_the_signal_is_refused_never_clamped() {
        let e = error(&steer(GOOD).replace("range = [-1.0, 1.0]", "range = [-2.0, 2.0]"));
        assert!(e.contains("outside the signal's [-1, 1]"), "{e}");
    }

    #[test]
    fn an_unknown_bus_is_refused_with_the_buses_there_are() {
        let e = error(&steer(GOOD).replace("bus = \"kit\"", "bus = \"kitt\""));
        assert!(
            e.contains("bus \"kitt\" is not a [[bus]] of the file (buses: kit)"),
            "{e}"
        );
        assert!(e.contains("test.toml:13:"), "at the bus key: {e}");
    }

    #[test]
    fn a_bitrate_the_adapter_cannot_do_is_refused_with_those_it_can() {
        let e = error(
            &steer(GOOD).replace("dbc = \"oscc.dbc\"", "dbc = \"oscc.dbc\"\nbitrate = 400000"),
        );
        assert!(
            e.contains("bitrate 400000: expected one of the adapter's rates"),
            "{e}"
        );
        assert!(e.contains("500000"), "{e}");
    }

    #[test]
    fn a_dbc_that_is_missing_or_broken_is_named_with_its_own_line() {
        let e = error(&steer(GOOD).replace("oscc.dbc", "nowhere.dbc"));
        assert!(
            e.contains("test.toml:6:") && e.contains("nowhere.dbc"),
            "{e}"
        );
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("bad.dbc"),
            "VERSION \"\"\n\nBO_ 112 X: 8 A\n SG_ a : 0|8@1+ (1,0 [0|1] \"\" B\n",
        )
        .unwrap();
        let at = dir.path().join("v.toml");
        let e = parse(
            &steer(GOOD).replace("oscc.dbc", "bad.dbc"),
            at.to_str().unwrap(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("bad.dbc:4:"), "the DBC's file and line: {e}");
    }

    /// A DBC's units and value names are shown (the bus monitor, the snapshot, the
    /// logs) as a vehicle file's names are: a control character in one (an escape
    /// sequence, a newline) is refused at the DBC's line, as a vehicle name is.
    #[test]
    fn a_dbc_s_texts_with_a_control_character_are_refused_at_their_line() {
        let oscc = include_str!("../../vehicles/oscc.dbc");
        let dir = tempfile::tempdir().unwrap();
        let at = dir.path().join("v.toml");
        let refused = |dbc: String| {
            std::fs::write(dir.path().join("kit.dbc"), dbc).unwrap();
            parse(
                &steer(GOOD).replace("oscc.dbc", "kit.dbc"),
                at.to_str().unwrap(),
            )
            .unwrap_err()
            .to_string()
        };
        let line_of = |needle: &str| oscc.lines().position(|l| l.contains(needle)).unwrap() + 1;
        let table = "VAL_ 131 enabled 0 \"DISABLED\"";
        let e = refused(oscc.replace(table, "VAL_ 131 enabled 0 \"DIS\u{1b}[2JABLED\""));
        assert!(
            e.contains(&format!(
                "kit.dbc:{}: signal STEERING_REPORT.enabled: value 0 \"DIS\\u{{1b}}[2JABLED\": expected printable text on one line",
                line_of(table)
            )),
            "{e}"
        );
        let unit = "\"km/h\"";
        let e = refused(oscc.replacen(unit, "\"km\nh\"", 1));
        assert!(
            e.contains(&format!(
                "kit.dbc:{}: signal KIA_SOUL_WHEEL_SPEED.wheel_speed_front_left: unit \"km\\nh\"",
                line_of(unit)
            )),
            "{e}"
        );
        assert!(!e.contains('\n') && !e.contains('\x1b'), "{e:?}");
    }

    #[test]
    fn a_sensor_takes_no_command_and_an_actuator_needs_one() {
        let e = error(&steer(
            &GOOD.replace("command = \"STEERING_COMMAND.torque_command\"\n", ""),
        ));
        assert!(
            e.contains("an actuator needs `command = \"MESSAGE.signal\"`"),
            "{e}"
        );
    }

    #[test]
    fn can_keys_on_a_serial_device_are_refused() {
        let e = error(&format!(
            "{HEAD}\n[[device]]\nname = \"x\"\nkind = \"sensor\"\ndriver = \"line\"\nport = \"/dev/x\"\nbus = \"kit\"\nreadings = [\"speed\"]\n"
        ));
        assert!(e.contains("`bus` goes with driver = \"can\" only"), "{e}");
    }
}
