//! Headless mode: the engine without a console, for a service manager. It logs a
//! line of figures per device now and then, waits for a way out, and on the way out
//! prints a per-device summary.

use crate::engine::Gate;
use crate::exit::Exit;
use crate::net::NetRefusal;
use crate::snapshot::{NetView, RecordView, Snapshot};
use crate::vehicle::Vehicle;
use crossbeam_channel::Receiver;
use std::fmt::Write;
use std::time::Duration;

/// How often the figures are logged.
pub(crate) const REPORT_EVERY: Duration = Duration::from_secs(10);

/// Run until an exit arrives; returns it.
pub(crate) fn wait(gate: &Gate, exits: &Receiver<Exit>) -> Exit {
    tracing::info!(
        vehicle = %gate.vehicle().name(),
        devices = gate.vehicle().devices().len(),
        "running headless; SIGINT or SIGTERM stops safely"
    );
    let tick = crossbeam_channel::tick(REPORT_EVERY);
    loop {
        crossbeam_channel::select! {
            recv(exits) -> why => return why.unwrap_or(Exit::Quit),
            recv(tick) -> _ => {
                for d in gate.snapshot(0).devices {
                    tracing::info!(
                        device = %d.name,
                        polls = d.counters.polls,
                        status_errors = d.counters.status_errors,
                        received = d.counters.received,
                        executed = d.counters.executed,
                        delay_p99_us = d.delay_us.p99_us.unwrap_or(0.0),
                        faulty = d.health.faulty,
                        "figures"
                    );
                }
            }
        }
    }
}

/// The safe state in words, for the log: `gas 0.000, brake 1.000`.
pub(crate) fn safe_state_words(vehicle: &Vehicle) -> String {
    let words: Vec<String> = crate::safety::safe::state(vehicle.config())
        .into_iter()
        .map(|(id, c)| {
            let d = vehicle.device(id);
            format!("{} {}", d.name(), d.config().command_text(c))
        })
        .collect();
    if words.is_empty() {
        "nothing to command (no throttle or brake bound)".into()
    } else {
        words.join(", ")
    }
}

fn fmt_us(v: Option<f64>) -> String {
    match v {
        None => "-".into(),
        Some(us) if us < 1000.0 => format!("{us:.1}µs"),
        Some(us) => format!("{:.2}ms", us / 1000.0),
    }
}

/// The width of the device column: the longest name, at least six.
fn name_width(snap: &Snapshot) -> usize {
    snap.devices
        .iter()
        .map(|d| d.name.len())
        .max()
        .unwrap_or(6)
        .max(6)
}

/// The per-device summary printed on exit.
pub(crate) fn summary(snap: &Snapshot) -> String {
    let w = name_width(snap);
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<w$} {:>8} {:>8} {:>8} {:>6} {:>8} {:>6} {:>7} {:>6}   {:>9} {:>9} {:>9}   {:>9}",
        "device",
        "received",
        "executed",
        "supersed",
        "resent",
        "rejected",
        "errors",
        "polls",
        "st_err",
        "delay p50",
        "delay p99",
        "delay max",
        "txn p50"
    );
    for d in &snap.devices {
        let s = &d.counters;
        let _ = writeln!(
            out,
            "{:<w$} {:>8} {:>8} {:>8} {:>6} {:>8} {:>6} {:>7} {:>6}   {:>9} {:>9} {:>9}   {:>9}",
            d.name,
            s.received,
            s.executed,
            s.superseded,
            s.resent,
            s.rejected,
            s.command_errors,
            s.polls,
            s.status_errors,
            fmt_us(d.delay_us.p50_us),
            fmt_us(d.delay_us.p99_us),
            fmt_us(d.delay_us.max_us),
            fmt_us(if d.is_actuator() {
                d.command_txn_us.p50_us
            } else {
                d.status_txn_us.p50_us
            }),
        );
    }
    out
}

/// One line of network figures for the summary printed on exit: datagrams, those
/// accepted and those refused whole (every datagram is one or the other), then the
/// commands refused within accepted ones, each by reason.
pub(crate) fn net_summary(n: &NetView, gate: &crate::snapshot::GateView) -> String {
    let mut out = format!(
        "network {}: {} datagrams, {} accepted",
        n.listen, n.datagrams, n.accepted
    );
    let whole = n.rejected.datagram.iter().chain(
        n.rejected
            .refused
            .iter()
            .filter(|(r, _)| NetRefusal::named(r).is_some_and(NetRefusal::refuses_datagram)),
    );
    let commands = n.rejected.intake.iter().chain(
        n.rejected
            .refused
            .iter()
            .filter(|(r, _)| !NetRefusal::named(r).is_some_and(NetRefusal::refuses_datagram)),
    );
    for (label, reasons) in [
        (", refused whole: ", whole.collect::<Vec<_>>()),
        ("; commands refused: ", commands.collect()),
    ] {
        let nonzero: Vec<String> = reasons
            .into_iter()
            .filter(|(_, c)| **c > 0)
            .map(|(r, c)| format!("{r} {c}"))
            .collect();
        if !nonzero.is_empty() {
            let _ = write!(out, "{label}{}", nonzero.join(", "));
        }
    }
    if let Some(why) = gate.watchdog.as_ref().and_then(|w| w.last_trip.as_ref()) {
        let _ = write!(out, "; watchdog tripped: {why}");
    }
    out
}

/// The recording in one line: `recorded 1234 messages (2.1 MB) to FILE`, the events
/// left out, or why recording stopped.
pub(crate) fn record_summary(r: &RecordView) -> String {
    let mut s = format!(
        "recorded {} messages ({}) to {}",
        r.messages,
        bytesize::ByteSize::b(r.bytes).display().si(),
        r.file
    );
    if r.dropped > 0 {
        let _ = write!(
            s,
            "; {} events left out (the recorder fell behind)",
            r.dropped
        );
    }
    if let Some(e) = &r.error {
        let _ = write!(s, "\n{e}");
    }
    s
}

/// The vehicle in a few lines, for `adrive ctl status`: the gate and who commands,
/// the faults, then a line per device (its command, what it reports, its health).
pub(crate) fn status_table(snap: &Snapshot) -> String {
    let g = &snap.gate;
    let mut out = String::new();
    let gate = match (&g.engaged, &g.commander) {
        (true, Some(c)) => format!("ENGAGED by {c}"),
        (true, None) => "ENGAGED, nobody commands (handed over)".into(),
        (false, _) => format!("DISENGAGED ({})", g.cause.why()),
    };
    let _ = writeln!(
        out,
        "{} · {gate} · interlocks {} · up {:.0} s",
        snap.vehicle,
        if g.interlocks { "on" } else { "OFF" },
        snap.uptime_s
    );
    if !g.engaged && !g.blockers.is_empty() {
        let _ = writeln!(out, "engaging is blocked: {}", g.blockers.join("; "));
    }
    for f in &snap.supervisor.faults {
        let who = f
            .device
            .as_deref()
            .map(|d| format!("{d} "))
            .unwrap_or_default();
        let _ = writeln!(out, "fault: {who}{} {}", f.kind, f.cause);
    }
    let w = name_width(snap);
    let _ = writeln!(
        out,
        "{:<w$} {:>10} {:>10}  {:<8} reports",
        "device", "commanded", "executed", "health"
    );
    let v = |x: &Option<crate::value::Value>| x.as_ref().map_or("-".into(), |v| v.to_string());
    for d in &snap.devices {
        let health = if d.health.missing {
            "missing"
        } else if d.health.faulty {
            "FAULTY"
        } else if d.stale {
            "stale"
        } else {
            "ok"
        };
        let reports: Vec<String> = d
            .readings
            .iter()
            .map(|(k, x)| format!("{k} {}", v(x)))
            .collect();
        let _ = writeln!(
            out,
            "{:<w$} {:>10} {:>10}  {:<8} {}",
            d.name,
            v(&d.commanded),
            v(&d.executed),
            health,
            reports.join(", ")
        );
    }
    out.trim_end().to_string()
}
