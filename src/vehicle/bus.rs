//! The bus monitor: each CAN bus as the snapshot carries it ([`BusView`]) — its
//! adapter's state and counters, and the last frame of every identifier seen, sent or
//! received, decoded by the bus's DBC into words the way `cantools monitor` shows them.
//! The console's bench view draws it for a device on the bus; the broadcast, recordings
//! and attached consoles carry it like the rest of the snapshot.
//!
//! It is built with every snapshot, so it stays small and cheap: at most
//! [`BusView::MAX_FRAMES`] identifiers a bus (the most recent), and a kit's constant
//! signals (its magic bytes) left out while they hold their value.

use crate::can::dbc::{Kind, Message, Signal};
use crate::can::{Frame, Id};
use crate::config::protocol_map::Wire;
use crate::driver::slcan::{Bus, Seen};
use crate::snapshot::{BusCounters, BusView, FrameView, Pairs};
use std::fmt::Write as _;
use std::sync::atomic::Ordering::Relaxed;
use std::time::Instant;

/// A signal that holds a device's fault codes, named by the bits of its value table.
type FaultSignal<'a> = (Id, &'a str);

/// One bus, ages as of `now`. `faults`: the signals that carry a device's fault codes
/// on this bus (a bitfield whatever its value table looks like).
pub(crate) fn bus_view(bus: &Bus, faults: &[FaultSignal], now: Instant) -> BusView {
    let c = bus.config();
    let s = &bus.stats;
    let mut seen = bus.seen();
    let left_out = seen.len().saturating_sub(BusView::MAX_FRAMES);
    if left_out > 0 {
        // The most recent ones, back in identifier order.
        seen.sort_by_key(|e| std::cmp::Reverse(e.at));
        seen.truncate(BusView::MAX_FRAMES);
        seen.sort_by_key(|e| e.frame.id());
    }
    BusView {
        name: c.name.clone(),
        port: c.port.clone(),
        bitrate: c.bitrate.bits_per_second(),
        down: bus.down_reason(),
        bus_error: bus.bus_error(),
        counters: BusCounters {
            received: s.received.load(Relaxed),
            sent: s.sent.load(Relaxed),
            acked: s.acked.load(Relaxed),
            refused: s.refused.load(Relaxed),
            garbled: s.garbled.load(Relaxed),
            opens: s.opens.load(Relaxed),
        },
        frames: seen
            .iter()
            .map(|e| frame_view(c.dbc.by_id(e.frame.id()), e, faults, now))
            .collect(),
        left_out: left_out as u64,
    }
}

/// Every bus of the vehicle, with the fault signals of the devices on it.
pub(crate) fn bus_views(v: &super::Vehicle, now: Instant) -> Vec<BusView> {
    v.buses()
        .iter()
        .enumerate()
        .map(|(i, bus)| {
            let faults: Vec<FaultSignal> = v
                .devices()
                .iter()
                .filter_map(|d| match &d.config().wire {
                    Wire::Can(m) if m.bus == i => m.faults.as_ref(),
                    _ => None,
                })
                .map(|f| (f.message, f.signal.as_str()))
                .collect();
            bus_view(bus, &faults, now)
        })
        .collect()
}

/// One identifier's last frame, decoded by `message` (`None`: the DBC does not know it).
fn frame_view(
    message: Option<&Message>,
    e: &Seen,
    faults: &[FaultSignal],
    now: Instant,
) -> FrameView {
    let f = &e.frame;
    let signals = match message {
        Some(m) if !f.is_remote() => m
            .decode(f)
            .filter_map(|(s, v)| {
                let raw = s.raw(f.data())?;
                let bitfield = faults.contains(&(m.id(), s.name())) || is_bitfield(s);
                signal_text(s, raw, v, bitfield).map(|t| (s.name().to_string(), t))
            })
            .collect(),
        _ => Pairs::default(),
    };
    FrameView {
        id: f.id().to_string(),
        message: message.map(|m| m.name().to_string()),
        sent: e.sent,
        count: e.count,
        age_ms: now.saturating_duration_since(e.at).as_secs_f64() * 1e3,
        data: hex(f),
        signals,
    }
}

/// A frame's data bytes in hex, `05 CC 01`; `remote [2]` for a remote request.
fn hex(f: &Frame) -> String {
    if f.is_remote() {
        return format!("remote [{}]", f.len());
    }
    let mut out = String::with_capacity(3 * f.len());
    for (i, b) in f.data().iter().enumerate() {
        if i > 0 {
            out.push(' ');
        }
        let _ = write!(out, "{b:02X}");
    }
    out
}

/// A value table of single bits only, two or more (a kit's fault codes): its raw value
/// is a set of flags.
fn is_bitfield(s: &Signal) -> bool {
    s.values().len() >= 2
        && s.values()
            .iter()
            .all(|&(v, _)| v > 0 && (v as u64).is_power_of_two())
}

/// One signal in words: the value table's name of its raw value; a bitfield's names
/// of the bits set; else the value with its unit. `None` for a constant (its range is
/// one value) that holds it: a kit's magic bytes say nothing while they are right.
fn signal_text(s: &Signal, raw: u64, value: f64, bitfield: bool) -> Option<String> {
    if let Some((lo, hi)) = s.range() {
        if lo == hi && value == lo {
            return None;
        }
    }
    let signed = match s.kind() {
        Kind::Integer { signed: true } => s.raw_number(raw) as i64,
        _ => raw as i64,
    };
    if let Some(name) = s.value_name(signed) {
        return Some(name.to_string());
    }
    if bitfield && raw != 0 {
        return Some(s.flag_names(raw).join("|"));
    }
    let number = number(s, value);
    Some(if s.unit().is_empty() {
        number
    } else {
        format!("{number} {}", s.unit())
    })
}

/// A physical value with the decimals its scaling gives (an integer as one; a float
/// signal to four), trailing zeros dropped.
fn number(s: &Signal, value: f64) -> String {
    let decimals = match s.kind() {
        Kind::Float32 | Kind::Float64 => 4,
        Kind::Integer { .. } => {
            let f = s.factor().abs();
            if f >= 1.0 || f == 0.0 {
                0
            } else {
                (-f.log10()).ceil().clamp(0.0, 6.0) as usize
            }
        }
    };
    let mut t = format!("{value:.decimals$}");
    if t.contains('.') {
        while t.ends_with('0') {
            t.pop();
        }
        if t.ends_with('.') {
            t.pop();
        }
    }
    if t == "-0" {
        t = "0".into();
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::driver::slcan::decode_into;
    use crate::snapshot::{GateView, Snapshot};
    use crate::vehicle::{Cached, Vehicle};
    use std::time::Duration;

    /// The OSCC vehicle, every reading 0.
    fn oscc() -> Vehicle {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/vehicles/oscc.toml");
        let config = crate::config::load(std::path::Path::new(path)).unwrap();
        crate::testkit::vehicle_zeroed(config)
    }

    fn frame(v: &Vehicle, name: &str, values: &[(&str, f64)]) -> Frame {
        let dbc = &v.buses()[0].config().dbc;
        dbc.message(name).unwrap().encode(values).unwrap()
    }

    fn capture(v: &Vehicle, now: Instant) -> Snapshot {
        super::super::capture::snapshot(v, 1, now, GateView::default(), Pairs::default())
    }

    /// What the bus carried, as the snapshot says it: sorted by identifier, each
    /// identifier's last frame with who sent it, how many, how long ago and its
    /// signals in words — table names, units, a fault bitfield by its flags' names, an
    /// unknown identifier by its bytes alone — and the magic bytes only when wrong.
    #[test]
    fn the_snapshot_carries_the_bus_frames_decoded_by_the_dbc() {
        let now = Instant::now();
        let v = oscc();
        let bus = &v.buses()[0];
        let ago = |ms| now - Duration::from_millis(ms);
        let report = frame(
            &v,
            "STEERING_REPORT",
            &[("enabled", 1.0), ("operator_override", 0.0), ("dtcs", 0.0)],
        );
        for _ in 0..3 {
            bus.note(&report, ago(12), false);
        }
        // Both fault bits set: no one name in the table, the two flags' names.
        let brake = frame(&v, "BRAKE_REPORT", &[("enabled", 0.0), ("dtcs", 3.0)]);
        bus.note(&brake, ago(5), false);
        let cmd = frame(&v, "STEERING_COMMAND", &[("torque_command", 0.25)]);
        bus.note(&cmd, ago(1), true);
        let speed = frame(
            &v,
            "KIA_SOUL_WHEEL_SPEED",
            &[("wheel_speed_rear_left", 36.5)],
        );
        bus.note(&speed, ago(2), false);
        // The magic bytes are wrong: shown.
        let mut bad = frame(&v, "THROTTLE_REPORT", &[]);
        bad.data_mut()[0] = 0x06;
        bus.note(&bad, ago(3), false);
        let unknown = Frame::new(Id::Standard(0x123), &[1, 2, 0xAB]).unwrap();
        bus.note(&unknown, ago(40), false);
        let extended = Frame::new(Id::Extended(0x18DA_F110), &[]).unwrap();
        bus.note(&extended, ago(7), false);

        let snap = capture(&v, now);
        let b = &snap.buses[0];
        assert_eq!((b.name.as_str(), b.bitrate), ("kit", 500_000));
        assert_eq!(b.left_out, 0);
        let ids: Vec<&str> = b.frames.iter().map(|f| f.id.as_str()).collect();
        assert_eq!(
            ids,
            [
                "0x073",
                "0x082",
                "0x083",
                "0x093",
                "0x123",
                "0x4B0",
                "0x18DAF110x"
            ]
        );
        let by = |id: &str| b.frames.iter().find(|f| f.id == id).unwrap();
        let signals = |id: &str| -> Vec<(String, String)> { by(id).signals.0.clone() };
        let pairs = |p: &[(&str, &str)]| -> Vec<(String, String)> {
            p.iter()
                .map(|(a, b)| (a.to_string(), b.to_string()))
                .collect()
        };

        let steer = by("0x083");
        assert_eq!(steer.message.as_deref(), Some("STEERING_REPORT"));
        assert_eq!((steer.sent, steer.count), (false, 3));
        assert!((steer.age_ms - 12.0).abs() < 0.5, "{}", steer.age_ms);
        assert_eq!(steer.data, "05 CC 01 00 00 00 00 00");
        assert_eq!(
            signals("0x083"),
            pairs(&[
                ("enabled", "ENABLED"),
                ("operator_override", "NONE"),
                ("dtcs", "0")
            ])
        );
        assert_eq!(
            signals("0x073"),
            pairs(&[
                ("enabled", "DISABLED"),
                ("operator_override", "NONE"),
                ("dtcs", "INVALID_SENSOR_VAL|OPERATOR_OVERRIDE")
            ])
        );
        assert!(by("0x082").sent, "the command is adrive's");
        assert_eq!(signals("0x082"), pairs(&[("torque_command", "0.25")]));
        assert_eq!(signals("0x093")[0], ("magic_0".into(), "6".into()));
        assert_eq!(
            signals("0x4B0")[2],
            ("wheel_speed_rear_left".into(), "36.5 km/h".into())
        );
        let u = by("0x123");
        assert_eq!((u.message.as_ref(), u.data.as_str()), (None, "01 02 AB"));
        assert!(u.signals.is_empty());
        assert_eq!(by("0x18DAF110x").data, "");

        // Through JSON and back, as a broadcast carries it, and valid under the
        // broadcast's schema.
        let back: Snapshot = serde_json::from_slice(&serde_json::to_vec(&snap).unwrap()).unwrap();
        assert_eq!(back.buses, snap.buses);
        let schema: serde_json::Value = serde_json::from_str(include_str!(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/schemas/snapshot-4.json"
        )))
        .unwrap();
        let json = serde_json::to_value(&snap).unwrap();
        let errors: Vec<String> = jsonschema::validator_for(&schema)
            .unwrap()
            .iter_errors(&json)
            .map(|e| format!("{e} at {}", e.instance_path()))
            .collect();
        assert!(errors.is_empty(), "{}", errors.join("\n"));
    }

    /// A device's kit fault codes by the DBC's names; none for a device without them.
    #[test]
    fn a_kit_device_names_its_fault_codes() {
        let now = Instant::now();
        let v = oscc();
        let brake = v.find("brake").unwrap();
        let map = match &brake.config().wire {
            Wire::Can(m) => m.clone(),
            _ => unreachable!("a CAN device"),
        };
        let mut reading = brake.cached().reading;
        let f = frame(&v, "BRAKE_REPORT", &[("enabled", 0.0), ("dtcs", 2.0)]);
        assert!(decode_into(&map, &f, &mut reading));
        brake.store(Cached {
            reading,
            at: Some(now),
            asked: None,
        });
        let snap = capture(&v, now);
        let d = snap.device("brake").unwrap();
        assert_eq!(d.fault, 2);
        assert_eq!(d.faults, ["OPERATOR_OVERRIDE"]);
        assert_eq!(d.bus.as_deref(), Some("kit"));
        let steer = snap.device("steer").unwrap();
        assert!(steer.faults.is_empty());
        let json = serde_json::to_string(d).unwrap();
        assert!(json.contains(r#""faults":["OPERATOR_OVERRIDE"]"#), "{json}");
        // Not on a bus: no names, no bus, and nothing more in its JSON.
        let alice = capture(&crate::testkit::vehicle(now), now);
        assert!(alice
            .devices
            .iter()
            .all(|d| d.faults.is_empty() && d.bus.is_none()));
        assert!(alice.buses.is_empty());
        let json = serde_json::to_string(&alice.devices).unwrap();
        assert!(!json.contains("\"faults\"") && !json.contains("\"bus\""));
        assert!(!serde_json::to_string(&alice).unwrap().contains("\"buses\""));
    }

    /// A busy bus keeps the snapshot small: the most recent identifiers, the rest
    /// counted.
    #[test]
    fn a_bus_carries_at_most_its_cap_of_identifiers() {
        let now = Instant::now();
        let v = oscc();
        let bus = &v.buses()[0];
        let n = BusView::MAX_FRAMES + 6;
        for i in 0..n {
            let f = Frame::new(Id::Standard(0x500 + i as u16), &[i as u8]).unwrap();
            // The lowest identifiers are the oldest.
            bus.note(&f, now - Duration::from_millis((n - i) as u64), false);
        }
        let b = &capture(&v, now).buses[0];
        assert_eq!(b.frames.len(), BusView::MAX_FRAMES);
        assert_eq!(b.left_out, 6);
        assert_eq!(b.frames[0].id, "0x506");
        assert!(b.frames.windows(2).all(|w| w[0].id < w[1].id));
    }
}
