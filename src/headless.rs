//! Headless mode: the engine without a console, for a service manager. It logs a
//! line of figures per device now and then, waits for a way out, and on the way out
//! prints a per-device summary.

use crate::exit::Exit;
use crate::vehicle::Vehicle;
use crossbeam_channel::Receiver;
use std::fmt::Write;
use std::time::Duration;

/// How often the figures are logged.
pub const REPORT_EVERY: Duration = Duration::from_secs(10);

/// Run until an exit arrives; returns it.
pub fn wait(vehicle: &Vehicle, exits: &Receiver<Exit>) -> Exit {
    tracing::info!(
        vehicle = %vehicle.name,
        devices = vehicle.devices.len(),
        "running headless; SIGINT or SIGTERM stops safely"
    );
    let tick = crossbeam_channel::tick(REPORT_EVERY);
    loop {
        crossbeam_channel::select! {
            recv(exits) -> why => return why.unwrap_or(Exit::Quit),
            recv(tick) -> _ => {
                for d in &vehicle.devices {
                    let s = d.stats.snapshot();
                    tracing::info!(
                        device = %d.role,
                        polls = s.polls,
                        status_errors = s.status_errors,
                        received = s.received,
                        executed = s.executed,
                        delay_p99_us = s.command_delay.p99_us.unwrap_or(0.0),
                        faulty = d.is_faulty(),
                        "figures"
                    );
                }
            }
        }
    }
}

fn fmt_us(v: Option<f64>) -> String {
    match v {
        None => "-".into(),
        Some(us) if us < 1000.0 => format!("{us:.1}µs"),
        Some(us) => format!("{:.2}ms", us / 1000.0),
    }
}

/// The per-device summary printed on exit.
pub fn summary(vehicle: &Vehicle) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<6} {:>8} {:>8} {:>8} {:>6} {:>8} {:>6} {:>7} {:>6}   {:>9} {:>9} {:>9}   {:>9}",
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
    for d in &vehicle.devices {
        let s = d.stats.snapshot();
        let _ = writeln!(
            out,
            "{:<6} {:>8} {:>8} {:>8} {:>6} {:>8} {:>6} {:>7} {:>6}   {:>9} {:>9} {:>9}   {:>9}",
            d.role.as_str(),
            s.received,
            s.executed,
            s.superseded,
            s.resent,
            s.rejected,
            s.command_errors,
            s.polls,
            s.status_errors,
            fmt_us(s.command_delay.p50_us),
            fmt_us(s.command_delay.p99_us),
            fmt_us(s.command_delay.max_us),
            fmt_us(if d.is_actuator() {
                s.command_txn.p50_us
            } else {
                s.status_txn.p50_us
            }),
        );
    }
    out
}

/// One line of network figures for the summary printed on exit.
pub fn net_summary(n: &crate::net::NetSnapshot) -> String {
    let mut out = format!(
        "network {}: {} datagrams, {} accepted",
        n.listen, n.datagrams, n.accepted
    );
    let rejected = [
        &n.rejected.datagram,
        &n.rejected.intake,
        &n.rejected.refused,
    ];
    let nonzero: Vec<String> = rejected
        .into_iter()
        .flatten()
        .filter(|(_, c)| *c > 0)
        .map(|(r, c)| format!("{r} {c}"))
        .collect();
    if !nonzero.is_empty() {
        let _ = write!(out, "; rejected: {}", nonzero.join(", "));
    }
    if let Some(why) = &n.watchdog.last_trip {
        let _ = write!(out, "; watchdog tripped: {why}");
    }
    out
}
