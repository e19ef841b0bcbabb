//! `adrive record info FILE`: what a recording holds — who recorded it, when and for
//! how long, each channel with its message count, the commands received and refused,
//! engage and disengage, every fault, what the recorder left out — and whether the
//! file was finished, is being written, or was cut off ([`state`]).

use super::message::{FaultMsg, GateMsg, Received, RecordMsg};
use super::read::{Ending, Recording};
use std::collections::BTreeMap;
use std::fmt::Write;
use std::time::{Duration, UNIX_EPOCH};

/// What [`report`] found, for tests and the report itself.
#[derive(Debug, Default)]
pub(crate) struct Info {
    /// Topic → (schema, messages), in the order first seen.
    pub channels: Vec<(String, String, u64)>,
    pub(crate) first_ns: Option<u64>,
    pub(crate) last_ns: Option<u64>,
    pub received: u64,
    /// Refused commands by reason.
    pub refused: BTreeMap<String, u64>,
    /// Datagrams refused whole (no command in them was looked at), by reason.
    pub refused_whole: BTreeMap<String, u64>,
    /// (seconds from the start, line) of gate events and faults.
    pub events: Vec<(f64, String)>,
    pub faults: u64,
    pub dropped: u64,
    /// Why the readable part ends early, if it does.
    pub cut: Option<String>,
}

/// Read every message of `rec` and sum it up.
pub(crate) fn gather(rec: &Recording) -> Info {
    let mut i = Info::default();
    let mut timeline: Vec<(u64, String)> = Vec::new();
    let why = rec.for_each(|m| {
        i.first_ns = Some(i.first_ns.map_or(m.log_time, |t| t.min(m.log_time)));
        i.last_ns = Some(i.last_ns.map_or(m.log_time, |t| t.max(m.log_time)));
        match i.channels.iter_mut().find(|(t, _, _)| t == m.topic) {
            Some(c) => c.2 += 1,
            None => i
                .channels
                .push((m.topic.to_string(), m.schema.to_string(), 1)),
        }
        match m.topic {
            "/commands" => {
                if let Ok(r) = serde_json::from_slice::<Received>(m.data) {
                    let why = r.reason.filter(|_| !r.accepted);
                    match (r.device, why) {
                        // No device: a datagram refused whole, not a command.
                        (None, Some(why)) => *i.refused_whole.entry(why).or_default() += 1,
                        (_, why) => {
                            i.received += 1;
                            if let Some(why) = why {
                                *i.refused.entry(why).or_default() += 1;
                            }
                        }
                    }
                }
            }
            "/gate" => {
                if let Ok(g) = serde_json::from_slice::<GateMsg>(m.data) {
                    timeline.push((m.log_time, g.reason));
                }
            }
            "/faults" => {
                if let Ok(f) = serde_json::from_slice::<FaultMsg>(m.data) {
                    if f.event == "raised" {
                        i.faults += 1;
                    }
                    let dev = f.device.map(|d| format!("{d} ")).unwrap_or_default();
                    timeline.push((
                        m.log_time,
                        format!("fault {} {dev}{}: {}", f.event, f.kind, f.cause),
                    ));
                }
            }
            "/record" => {
                if let Ok(r) = serde_json::from_slice::<RecordMsg>(m.data) {
                    i.dropped = i.dropped.max(r.dropped);
                }
            }
            _ => {}
        }
    });
    let start = i.first_ns.unwrap_or(0);
    i.events = timeline
        .into_iter()
        .map(|(t, s)| (t.saturating_sub(start) as f64 / 1e9, s))
        .collect();
    i.cut = rec.cut.clone().or(why);
    i
}

fn rfc3339(ns: u64) -> String {
    humantime::format_rfc3339_millis(UNIX_EPOCH + Duration::from_nanos(ns)).to_string()
}

/// The report `adrive record info` prints.
pub(crate) fn report(rec: &Recording) -> String {
    let i = gather(rec);
    let mut s = String::new();
    let state = state(rec, i.cut.as_deref());
    let _ = writeln!(
        s,
        "{}: {}, {state}",
        rec.path.display(),
        bytesize::ByteSize::b(rec.size()).display().si()
    );
    let m = &rec.metadata;
    if let Some(v) = m.get("vehicle") {
        let _ = writeln!(
            s,
            "vehicle {v}, from {}, recorded by adrive {}",
            m.get("config").map_or("?", String::as_str),
            m.get("adrive").map_or("?", String::as_str)
        );
    }
    match (i.first_ns, i.last_ns) {
        (Some(a), Some(b)) => {
            let _ = writeln!(
                s,
                "{} → {} ({:.1} s)",
                rfc3339(a),
                rfc3339(b),
                (b - a) as f64 / 1e9
            );
        }
        _ => s.push_str("no messages\n"),
    }
    let _ = writeln!(s, "\n{:<24} {:>9}  schema", "channel", "messages");
    for (topic, schema, n) in &i.channels {
        let _ = writeln!(s, "{topic:<24} {n:>9}  {schema}");
    }
    let refused: u64 = i.refused.values().sum();
    let _ = write!(
        s,
        "\ncommands received {}, accepted {}, refused {refused}",
        i.received,
        i.received - refused
    );
    let by = |m: &BTreeMap<String, u64>| {
        m.iter()
            .map(|(k, n)| format!("{k} {n}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if !i.refused.is_empty() {
        let _ = write!(s, " ({})", by(&i.refused));
    }
    if !i.refused_whole.is_empty() {
        let whole: u64 = i.refused_whole.values().sum();
        let _ = write!(
            s,
            "; datagrams refused whole {whole} ({})",
            by(&i.refused_whole)
        );
    }
    let _ = writeln!(
        s,
        "\nfaults {}, events left out by the recorder {}",
        i.faults, i.dropped
    );
    if !i.events.is_empty() {
        s.push('\n');
        for line in timeline(&i.events) {
            let _ = writeln!(s, "{line}");
        }
    }
    s
}

/// How the file ends, in words: finished, being written, stopped without being
/// finished, or cut inside a chunk — with what reads it.
pub(crate) fn state(rec: &Recording, cut: Option<&str>) -> String {
    let n = rec.chunks;
    let repair = format!("`adrive record repair {}`", rec.path.display());
    if rec.writing {
        return format!(
            "being written by a running adrive (it holds the file's lock), {n} chunks so far"
        );
    }
    let cut = cut.or(match &rec.ending {
        Ending::Cut(why) => Some(why.as_str()),
        _ => None,
    });
    match cut {
        None if rec.ending == Ending::Finished => format!("complete, {n} chunks"),
        None => format!(
            "NOT FINISHED, {n} chunks: no summary (adrive stopped without finishing it: \
             kill -9, a power loss, a full disk; or another machine is writing it); every MCAP reader \
             reads it; {repair} adds the index"
        ),
        Some(why) => format!(
            "CUT OFF ({why}); readable up to its last whole chunk by adrive and by \
             readers that read from the start; {repair} writes a whole copy"
        ),
    }
}

/// The events one a line, a run of the same event (an engage refused ten times a
/// second while a device has not reported) on one line with its count and its end.
pub(crate) fn timeline(events: &[(f64, String)]) -> Vec<String> {
    events
        .chunk_by(|a, b| a.1 == b.1)
        .map(|run| {
            let (t, line) = &run[0];
            match run {
                [_] => format!("{t:>9.1} s  {line}"),
                [.., (end, _)] => format!("{t:>9.1} s  {line} (×{}, to {end:.1} s)", run.len()),
                [] => unreachable!("chunk_by yields no empty run"),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refused_engage_repeated_by_a_planner_is_one_line() {
        let refused = "engage refused: obd has not reported yet".to_string();
        let mut events = vec![(0.1, refused.clone())];
        events.extend((2..=14).map(|k| (k as f64 / 10.0, refused.clone())));
        events.push((1.5, "engaged by network".into()));
        events.push((9.0, refused.clone()));
        assert_eq!(
            timeline(&events),
            [
                "      0.1 s  engage refused: obd has not reported yet (×14, to 1.4 s)",
                "      1.5 s  engaged by network",
                "      9.0 s  engage refused: obd has not reported yet",
            ]
        );
    }
}
