//! What a recording holds: its channels (topics), the JSON message of each and the
//! JSON Schema that describes it, so that Foxglove and any MCAP reader know every
//! field's type without being told. Device channels are `/DEVICE/command` (each
//! command written, `value` a number) and `/DEVICE/reading` (each reading taken, by
//! reading name), so a plot of `/steer/command.value` against
//! `/steer/reading.position` needs no configuration.

use super::schema::{self, schema_of};
use crate::config::{DeviceConfig, ReadingKind, VehicleConfig};
use crate::port::trace::{Dir, TraceEntry};
use crate::snapshot::{FaultKind, Snapshot};
use crate::value::{Command, DeviceId, Reading};
use crate::vehicle::seen::Seen;
use crate::vehicle::tap::{Asked, Event, GateChange, Source};
use crate::vehicle::Vehicle;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use serde_json::{json, Map, Value};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// The MCAP profile: none of the well-known ones (JSON messages need none).
pub(crate) const PROFILE: &str = "";
/// The schema encoding and message encoding of every channel.
pub(crate) const SCHEMA_ENCODING: &str = "jsonschema";
pub(crate) const MESSAGE_ENCODING: &str = "json";
/// The name of the metadata record that says what recorded the file.
pub(crate) const METADATA: &str = "adrive";

/// One channel of a recording.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(crate) enum Topic {
    /// `/snapshot`: the state snapshot, as broadcast.
    Snapshot,
    /// `/commands`: every command received (network, console, supervisor) and every
    /// datagram refused whole, with its outcome.
    Commands,
    /// `/gate`: engaged, disengaged, engage refused.
    Gate,
    /// `/faults`: each fault raised and cleared.
    Faults,
    /// `/supervisor`: the supervisor's history (recovery steps and outcomes).
    Supervisor,
    /// `/log`: log lines, as Foxglove's `foxglove.Log`.
    Log,
    /// `/record`: the recorder's own figures, once a second.
    Record,
    /// `/DEVICE/command`: each command written to a device.
    Command(DeviceId),
    /// `/DEVICE/reading`: each reading taken (or the poll's error).
    Reading(DeviceId),
    /// `/DEVICE/raw`: raw serial traffic, when asked for.
    Raw(DeviceId),
}

impl Topic {
    /// The MCAP topic, with device names from `devices`.
    pub(crate) fn name(self, devices: &[DeviceConfig]) -> String {
        let dev = |id: DeviceId| devices[id.index()].name.as_str();
        match self {
            Topic::Snapshot => "/snapshot".into(),
            Topic::Commands => "/commands".into(),
            Topic::Gate => "/gate".into(),
            Topic::Faults => "/faults".into(),
            Topic::Supervisor => "/supervisor".into(),
            Topic::Log => "/log".into(),
            Topic::Record => "/record".into(),
            Topic::Command(id) => format!("/{}/command", dev(id)),
            Topic::Reading(id) => format!("/{}/reading", dev(id)),
            Topic::Raw(id) => format!("/{}/raw", dev(id)),
        }
    }

    /// Every channel a run of `devices` can have, in the order a viewer lists them: the
    /// vehicle's, then each device's (a command channel for an actuator only), then
    /// raw traffic when it is taken. `/record` is the recorder's own and not here.
    pub(crate) fn channels(devices: &[DeviceConfig], raw: bool) -> Vec<Topic> {
        let mut all = vec![
            Topic::Snapshot,
            Topic::Commands,
            Topic::Gate,
            Topic::Faults,
            Topic::Supervisor,
            Topic::Log,
        ];
        for (i, d) in devices.iter().enumerate() {
            let id = DeviceId(i as u16);
            if d.is_actuator() {
                all.push(Topic::Command(id));
            }
            all.push(Topic::Reading(id));
            if raw {
                all.push(Topic::Raw(id));
            }
        }
        all
    }

    /// The schema's name and its JSON Schema text, as the viewers read it
    /// ([`schema::readable`]): the one schema of this channel, recorded or live.
    pub(crate) fn schema(self, config: &VehicleConfig) -> (String, Vec<u8>) {
        let s = schema::readable(&self.generated(config), &schema::Keys::of(config));
        (
            self.schema_name(&config.devices),
            serde_json::to_vec(&s).expect("a schema serializes"),
        )
    }

    /// The schema's name.
    pub(crate) fn schema_name(self, devices: &[DeviceConfig]) -> String {
        match self {
            Topic::Snapshot => "adrive.Snapshot".into(),
            Topic::Commands => "adrive.Received".into(),
            Topic::Gate => "adrive.Gate".into(),
            Topic::Faults => "adrive.Fault".into(),
            Topic::Supervisor => "adrive.Note".into(),
            Topic::Log => "foxglove.Log".into(),
            Topic::Record => "adrive.RecordStatus".into(),
            Topic::Command(_) => "adrive.Written".into(),
            Topic::Reading(id) => format!("adrive.{}.Reading", devices[id.index()].name),
            Topic::Raw(_) => "adrive.Raw".into(),
        }
    }

    /// The JSON Schema of the channel's type as generated, before [`schema::readable`].
    pub(crate) fn generated(self, config: &VehicleConfig) -> Value {
        match self {
            Topic::Snapshot => schema_of::<Snapshot>(),
            Topic::Commands => schema_of::<Received>(),
            Topic::Gate => schema_of::<GateMsg>(),
            Topic::Faults => schema_of::<FaultMsg>(),
            Topic::Supervisor => schema_of::<NoteMsg>(),
            Topic::Log => foxglove_log_schema(),
            Topic::Record => schema_of::<RecordMsg>(),
            Topic::Command(_) => schema_of::<Written>(),
            Topic::Reading(id) => reading_schema(&config.devices[id.index()]),
            Topic::Raw(_) => schema_of::<RawMsg>(),
        }
    }
}

/// `/commands`: a command received, or a datagram refused whole.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub(crate) struct Received {
    /// `network 127.0.0.1:40001`, `console`, `supervisor`.
    pub source: String,
    /// The device (or `accel`); null for a datagram refused whole.
    pub device: Option<String>,
    /// The command in words (`0.250`, `drive`, `home`).
    pub command: Option<String>,
    /// The command as a number, for plots (a state by its index).
    pub value: Option<f64>,
    pub accepted: bool,
    /// Why it was refused (`gas_while_braking`, `bad_tag`…).
    pub reason: Option<String>,
    /// What the decision saw of the vehicle: the gate's state and the interlocks'
    /// facts, for `adrive replay --check`. Absent where no rule decided: a command
    /// refused because another source commands, the supervisor's own, a datagram
    /// refused whole.
    #[serde(default)]
    pub seen: Option<Seen>,
}

impl Received {
    /// The source as the intake names it (`console`, `network 127.0.0.1:5555`).
    pub(crate) fn source_text(source: Source) -> String {
        crate::safety::owner::Commander(source).to_string()
    }
}

/// `/DEVICE/command`: one command transaction.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub(crate) struct Written {
    /// The command written, as a number (a set point; a state by its index); null for
    /// a drive-control command.
    pub value: Option<f64>,
    /// The command in words.
    pub command: String,
    /// A new command (false: sent again after `command_timeout`).
    pub fresh: bool,
    /// The device acknowledged it.
    pub ok: bool,
    /// What went wrong (`timeout`, `garbled`, `refused`, `unsupported`, `io`).
    pub error: Option<String>,
    /// Receipt to first byte written, µs (new commands only).
    pub delay_us: Option<f64>,
    /// First byte to the device's answer, µs.
    pub(crate) txn_us: Option<f64>,
}

impl Written {
    pub(crate) fn of(d: &DeviceConfig, command: Command) -> (Option<f64>, String) {
        let v = command.as_f64();
        (v.is_finite().then_some(v), d.command_text(command))
    }
}

/// `/gate`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub(crate) struct GateMsg {
    /// `engaged`, `disengaged` or `engage_refused`.
    pub event: String,
    /// Engaged after this.
    pub engaged: bool,
    pub reason: String,
}

/// `/faults`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub(crate) struct FaultMsg {
    /// `raised` or `cleared`.
    pub event: String,
    pub kind: FaultKind,
    pub device: Option<String>,
    pub cause: String,
}

/// `/supervisor`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub(crate) struct NoteMsg {
    pub text: String,
}

/// `/DEVICE/raw`: one chunk of bytes on the port.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub(crate) struct RawMsg {
    /// `out` (to the device) or `in`.
    pub dir: String,
    /// The bytes in hex, `01 03 00 00`.
    pub hex: String,
    /// Printable ASCII, other bytes as `.`.
    pub text: String,
    /// The chunk was longer than what was kept (64 bytes).
    pub cut: bool,
}

impl RawMsg {
    pub(crate) fn of(e: &TraceEntry) -> RawMsg {
        RawMsg {
            dir: match e.dir {
                Dir::Out => "out".into(),
                Dir::In => "in".into(),
            },
            hex: e.hex().trim_end_matches(" …").to_string(),
            text: e.ascii(),
            cut: e.cut,
        }
    }

    /// The bytes back from the hex.
    pub(crate) fn bytes(&self) -> Vec<u8> {
        self.hex
            .split_whitespace()
            .filter_map(|h| u8::from_str_radix(h, 16).ok())
            .collect()
    }
}

/// `/record`: the recorder's figures.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub(crate) struct RecordMsg {
    /// Messages written so far, every file of this run.
    pub messages: u64,
    /// Events left out so far because the recorder fell behind.
    pub dropped: u64,
    /// Bytes of this file so far.
    pub bytes: u64,
}

/// `/log`, in Foxglove's `foxglove.Log` form, so its Log panel shows it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct LogMsg {
    pub(crate) timestamp: Time,
    /// 1 debug, 2 info, 3 warning, 4 error (Foxglove's `LogLevel`).
    pub level: u8,
    pub message: String,
    /// Where it was logged (the module).
    pub name: String,
    pub file: String,
    pub line: u32,
}

/// Foxglove's `time`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct Time {
    pub sec: u64,
    pub(crate) nsec: u32,
}

impl Time {
    pub(crate) fn of_ns(ns: u64) -> Time {
        Time {
            sec: ns / 1_000_000_000,
            nsec: (ns % 1_000_000_000) as u32,
        }
    }
}

impl LogMsg {
    pub(crate) fn level_of(level: tracing::Level) -> u8 {
        match level {
            tracing::Level::TRACE | tracing::Level::DEBUG => 1,
            tracing::Level::INFO => 2,
            tracing::Level::WARN => 3,
            tracing::Level::ERROR => 4,
        }
    }
}

/// `foxglove.Log`'s JSON Schema, as Foxglove publishes it.
fn foxglove_log_schema() -> Value {
    json!({
        "title": "foxglove.Log",
        "description": "A log message",
        "type": "object",
        "properties": {
            "timestamp": {
                "type": "object",
                "title": "time",
                "properties": {
                    "sec": { "type": "integer", "minimum": 0 },
                    "nsec": { "type": "integer", "minimum": 0, "maximum": 999_999_999 }
                },
                "description": "Timestamp of log message"
            },
            "level": {
                "title": "foxglove.LogLevel",
                "description": "Log level",
                "oneOf": [
                    { "title": "UNKNOWN", "const": 0 },
                    { "title": "DEBUG", "const": 1 },
                    { "title": "INFO", "const": 2 },
                    { "title": "WARNING", "const": 3 },
                    { "title": "ERROR", "const": 4 },
                    { "title": "FATAL", "const": 5 }
                ]
            },
            "message": { "type": "string", "description": "Log message" },
            "name": { "type": "string", "description": "Process or node name" },
            "file": { "type": "string", "description": "Filename" },
            "line": { "type": "integer", "minimum": 0, "description": "Line number in the file" }
        }
    })
}

/// The figures every reading message carries beside the readings.
const READING_FIELDS: [&str; 4] = ["ok", "error", "fault", "txn_us"];

/// `/DEVICE/reading`'s schema: the device's readings by name, with their types and
/// units, then whether the poll succeeded. A reading not reported is absent.
pub(crate) fn reading_schema(d: &DeviceConfig) -> Value {
    let mut props = Map::new();
    props.insert(
        "ok".into(),
        json!({ "type": "boolean", "description": "the poll succeeded" }),
    );
    props.insert(
        "error".into(),
        json!({ "type": "string", "description": "timeout, garbled, refused, unsupported or io; absent when it succeeded" }),
    );
    props.insert(
        "fault".into(),
        json!({ "type": "integer", "description": "device-reported fault bits; 0 is good" }),
    );
    props.insert(
        "txn_us".into(),
        json!({ "type": "number", "description": "the status transaction, µs" }),
    );
    for r in &d.readings {
        let mut s = json!({ "type": schema::reading_type(&r.kind) });
        if let ReadingKind::States(states) = &r.kind {
            s["description"] = json!(format!("one of {}", states.join(", ")));
        }
        if !r.units.is_empty() {
            s["description"] = json!(r.units);
        }
        props.insert(r.name.clone(), s);
    }
    json!({
        "title": format!("adrive.{}.Reading", d.name),
        "description": format!("A reading of {}, by reading name", d.name),
        "type": "object",
        "properties": props,
        "required": ["ok"],
    })
}

/// One reading message: each of the device's readings by name (null when not
/// reported), and the poll's outcome.
pub(crate) fn reading_message(
    d: &DeviceConfig,
    reading: Option<&Reading>,
    error: Option<&str>,
    txn_us: Option<f64>,
) -> Value {
    let mut m = Map::new();
    m.insert("ok".into(), json!(reading.is_some()));
    m.insert("error".into(), json!(error));
    m.insert("fault".into(), json!(reading.map(|r| r.fault)));
    m.insert("txn_us".into(), json!(txn_us));
    for (i, r) in d.readings.iter().enumerate() {
        if READING_FIELDS.contains(&r.name.as_str()) {
            continue;
        }
        // A state by its name; one the device has no name for, by its number in words.
        let v = reading
            .and_then(|x| x.get(i))
            .map(|v| match (&r.kind, r.value(v)) {
                (ReadingKind::States(_), crate::value::Value::Number(n)) => json!(n.to_string()),
                (_, v) => json!(v),
            });
        m.insert(r.name.clone(), json!(v));
    }
    Value::Object(m)
}

/// A recorded `/snapshot` message back as the snapshot it was: a recording leaves null
/// members out ([`schema::without_nulls`]), so a reading not reported yet comes back
/// as null, every device's readings in the order of its `reading_units`, as broadcast.
pub(crate) fn recorded_snapshot(json: &[u8]) -> serde_json::Result<Snapshot> {
    let mut s: Snapshot = serde_json::from_slice(json)?;
    for d in &mut s.devices {
        let mut readings = std::mem::take(&mut d.readings).0;
        let mut all: Vec<(String, Option<crate::value::Value>)> = Vec::new();
        for (name, _) in d.reading_units.iter() {
            let i = readings.iter().position(|(n, _)| n == name);
            all.push((name.to_string(), i.and_then(|i| readings.remove(i).1)));
        }
        all.extend(readings);
        d.readings = crate::snapshot::Pairs(all);
    }
    Ok(s)
}

/// The paper's error codes in words.
pub(crate) fn error_word(code: u32) -> &'static str {
    match code {
        1 => "timeout",
        2 => "garbled",
        3 => "refused",
        4 => "unsupported",
        5 => "io",
        _ => "error",
    }
}

/// The channel an event of the tap goes to.
pub(crate) fn topic(ev: &Event) -> Topic {
    match ev {
        Event::Snapshot { .. } => Topic::Snapshot,
        Event::Received { .. } | Event::Refused { .. } => Topic::Commands,
        Event::Written { device, .. } => Topic::Command(*device),
        Event::Polled { device, .. } => Topic::Reading(*device),
        Event::Raw { device, .. } => Topic::Raw(*device),
        Event::Gate { .. } => Topic::Gate,
        Event::Fault { .. } => Topic::Faults,
        Event::Note { .. } => Topic::Supervisor,
        Event::Log { .. } => Topic::Log,
    }
}

/// One event of the tap as its channel, its time (wall-clock ns) and its JSON message:
/// what the recorder writes and the live view sends, made in this one place.
pub(crate) fn encode(v: &Vehicle, c: &Clock, ev: Event) -> (Topic, u64, Vec<u8>) {
    match ev {
        Event::Snapshot { at, json } => (Topic::Snapshot, c.ns(at), schema::without_nulls(&json)),
        Event::Received {
            at,
            source,
            asked,
            refused,
            seen,
        } => {
            let (device, command, value) = match asked {
                Asked::Device(id, cmd) => {
                    let d = &v.device(id).config();
                    let (value, text) = Written::of(d, cmd);
                    (d.name.clone(), text, value)
                }
                Asked::Accel(a) => ("accel".to_string(), format!("{a:.3}"), Some(a)),
            };
            let m = Received {
                source: Received::source_text(source),
                device: Some(device),
                command: Some(command),
                value,
                accepted: refused.is_none(),
                reason: refused.map(str::to_string),
                seen,
            };
            json(Topic::Commands, c.ns(at), &m)
        }
        Event::Refused { at, from, reason } => {
            let m = Received {
                source: format!("network {from}"),
                device: None,
                command: None,
                value: None,
                accepted: false,
                reason: Some(reason.to_string()),
                seen: None,
            };
            json(Topic::Commands, c.ns(at), &m)
        }
        Event::Written {
            device,
            command,
            received,
            first,
            done,
            fresh,
            error,
        } => {
            let (value, text) = Written::of(v.device(device).config(), command);
            let m = Written {
                value,
                command: text,
                fresh,
                ok: error == 0,
                error: (error != 0).then(|| error_word(error).to_string()),
                delay_us: first
                    .filter(|_| fresh)
                    .map(|f| us(f.saturating_duration_since(received))),
                txn_us: first.map(|f| us(done.saturating_duration_since(f))),
            };
            json(Topic::Command(device), c.ns(first.unwrap_or(done)), &m)
        }
        Event::Polled {
            device,
            first,
            done,
            reading,
            error,
        } => {
            let m = reading_message(
                v.device(device).config(),
                reading.as_ref(),
                (error != 0).then(|| error_word(error)),
                first.map(|f| us(done.saturating_duration_since(f))),
            );
            json(Topic::Reading(device), c.ns(done), &m)
        }
        Event::Raw { device, entry } => {
            json(Topic::Raw(device), c.ns(entry.at), &RawMsg::of(&entry))
        }
        Event::Gate { at, change, reason } => {
            let m = GateMsg {
                event: match change {
                    GateChange::Engaged => "engaged",
                    GateChange::Disengaged => "disengaged",
                    GateChange::EngageRefused => "engage_refused",
                }
                .into(),
                engaged: change == GateChange::Engaged,
                reason,
            };
            json(Topic::Gate, c.ns(at), &m)
        }
        Event::Fault {
            at,
            raised,
            kind,
            device,
            cause,
        } => {
            let m = FaultMsg {
                event: if raised { "raised" } else { "cleared" }.into(),
                kind,
                device,
                cause,
            };
            json(Topic::Faults, c.ns(at), &m)
        }
        Event::Note { at, text } => json(Topic::Supervisor, c.ns(at), &NoteMsg { text }),
        Event::Log {
            at,
            level,
            target,
            file,
            line,
            text,
        } => {
            let ns = wall_ns(at);
            let m = LogMsg {
                timestamp: Time::of_ns(ns),
                level: LogMsg::level_of(level),
                message: text,
                name: target.to_string(),
                file: file.unwrap_or_default().to_string(),
                line: line.unwrap_or_default(),
            };
            json(Topic::Log, ns, &m)
        }
    }
}

fn json(topic: Topic, at: u64, value: &impl Serialize) -> (Topic, u64, Vec<u8>) {
    let data = serde_json::to_vec(value).expect("a message of plain fields serializes");
    (topic, at, schema::without_nulls(&data))
}

/// Wall-clock nanoseconds of the instants events carry, from one reading of both clocks.
#[derive(Clone, Copy)]
pub(crate) struct Clock {
    at: Instant,
    wall_ns: u64,
}

impl Clock {
    pub(crate) fn now() -> Clock {
        Clock {
            at: Instant::now(),
            wall_ns: wall_ns(SystemTime::now()),
        }
    }

    pub(crate) fn ns(&self, t: Instant) -> u64 {
        match t.checked_duration_since(self.at) {
            Some(d) => self.wall_ns + d.as_nanos() as u64,
            None => self
                .wall_ns
                .saturating_sub(self.at.duration_since(t).as_nanos() as u64),
        }
    }
}

pub(crate) fn wall_ns(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

fn us(d: Duration) -> f64 {
    d.as_secs_f64() * 1e6
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schemas_are_inlined_objects() {
        let alice = crate::config::VehicleConfig::alice();
        for t in [
            Topic::Snapshot,
            Topic::Commands,
            Topic::Command(DeviceId(0)),
        ] {
            let (_, bytes) = t.schema(&alice);
            let text = String::from_utf8(bytes).unwrap();
            assert!(!text.contains("$ref"), "{text}");
            let v: Value = serde_json::from_str(&text).unwrap();
            assert_eq!(v["type"], "object", "{text}");
        }
    }

    /// A recording leaves nulls out, for the viewers; replay gets back the snapshot
    /// as broadcast, readings not reported yet included, in their order.
    #[test]
    fn a_recorded_snapshot_reads_back_as_broadcast() {
        let mut snap = crate::testkit::gate(Instant::now()).snapshot(3);
        let d = &mut snap.devices[0];
        d.readings = [
            ("position", None),
            ("velocity", Some(crate::value::Value::Number(0.5))),
        ]
        .into_iter()
        .map(|(n, v)| (n.to_string(), v))
        .collect();
        d.reading_units = [("position", "rad"), ("velocity", "rad/s")]
            .into_iter()
            .map(|(n, u)| (n.to_string(), u.to_string()))
            .collect();
        let json = serde_json::to_vec(&snap).unwrap();
        let recorded = schema::without_nulls(&json);
        assert!(!String::from_utf8_lossy(&recorded).contains("null"));
        let sent: Snapshot = serde_json::from_slice(&json).unwrap();
        let back = recorded_snapshot(&recorded).unwrap();
        assert!(
            back == sent,
            "{}\n{}",
            serde_json::to_string(&back).unwrap(),
            serde_json::to_string(&sent).unwrap()
        );
    }

    #[test]
    fn a_reading_message_names_each_reading() {
        let alice = crate::config::VehicleConfig::alice();
        let steer = alice.device("steer").unwrap();
        let mut r = Reading::default();
        r.set(0, 0.25);
        let m = reading_message(steer, Some(&r), None, Some(10.0));
        assert_eq!(m["position"], json!(0.25));
        assert_eq!(m["ok"], json!(true));
        let schema = reading_schema(steer);
        assert!(schema["properties"]["position"].is_object());
        let failed = reading_message(steer, None, Some("timeout"), None);
        assert_eq!(failed["ok"], json!(false));
        assert_eq!(failed["position"], Value::Null);
    }
}
