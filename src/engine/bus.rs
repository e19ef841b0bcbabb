//! A CAN bus's reader: the status thread of every device on the bus at once. On a bus
//! the devices do not wait to be polled — a kit's modules report at their own rate —
//! so one thread per bus (`bus/<name>`) opens the adapter, brings it onto the bus
//! ([`proto::bring_up`]), reads every frame and stores each device's readings from the
//! frames that carry them, by identifier. While the adapter is up it lends its write
//! half to the devices' command threads ([`Bus::up`]); they write under adrive's port
//! rule, as for any device.
//!
//! The adapter's answers come here too: `z`/`Z` (a frame taken for transmission) are
//! counted; a BEL (a frame refused) and status flags that say the bus is in error (asked
//! for every [`STATUS_EVERY`]) are an error of every device on the bus, which then
//! hears nothing and is silent to the supervisor, with the adapter's words as the
//! cause. A port that fails is closed and reopened with backoff, as any device's.
//!
//! At every turn it proves its progress ([`Beat`]): a read turn within
//! [`STATUS_EVERY`] and a write, an open and bring-up within the adapter's answers, a
//! backoff within itself.

use crate::config::protocol_map::Wire;
use crate::driver::slcan::proto::{self, Decoder, Event, FromAdapter, StatusFlags};
use crate::driver::slcan::{decode_into, Bus, BusPort, ANSWER_WITHIN};
use crate::driver::{read_some, Deadline, DriverError, Link};
use crate::threads::{Beat, StopSignal};
use crate::value::Reading;
use crate::vehicle::{Cached, Device, Vehicle};
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

/// How often the adapter is asked for its status flags.
pub(crate) const STATUS_EVERY: Duration = Duration::from_millis(500);
const BACKOFF_MIN: Duration = Duration::from_millis(100);
pub(crate) const BACKOFF_MAX: Duration = crate::snapshot::RETRY_AT_MOST;
/// The reader's first turn is due within this (it turns at once, then says its own
/// bound for each open, backoff and read).
pub(crate) const TURN: Duration = Duration::from_secs(10);
/// A read turn: a status request written, then a read until the next is due.
const READ_TURN: Duration = STATUS_EVERY.saturating_add(ANSWER_WITHIN);

/// The devices on bus `index`, by their index in the vehicle.
fn devices_on(v: &Vehicle, index: usize) -> Vec<usize> {
    v.devices()
        .iter()
        .enumerate()
        .filter(|(_, d)| matches!(&d.config().wire, Wire::Can(m) if m.bus == index))
        .map(|(i, _)| i)
        .collect()
}

/// Run bus `index` of the vehicle until stopped.
pub(crate) fn reader_loop(v: &Vehicle, index: usize, stop: &StopSignal, beat: &Beat) {
    let bus = &v.buses()[index];
    let on = devices_on(v, index);
    let mut backoff = BACKOFF_MIN;
    let mut readings: Vec<Reading> = vec![Reading::default(); on.len()];
    // An open and the bring-up: a write and an answer per command, the kits' disables.
    let opening =
        ANSWER_WITHIN * (proto::bring_up(bus.bitrate(), false).len() + on.len() + 2) as u32;
    loop {
        beat.turn(opening);
        if stop.is_stopped() {
            bus.go_down("stopped".into());
            return;
        }
        let path = bus.config().port.clone();
        let opened = crate::driver::slcan::open_serial_pair(&path, ANSWER_WITHIN)
            .and_then(|port| bring_up(bus, port));
        let mut reader = match opened {
            Ok(r) => {
                backoff = BACKOFF_MIN;
                for &i in &on {
                    v.devices()[i].port_health().missing.store(false, Relaxed);
                }
                tracing::info!(bus = bus.name(), port = %path, "adapter on the bus at {} bit/s", bus.bitrate().bits_per_second());
                if !bus.kits_enabled() {
                    disable_kits(v, bus, &on);
                }
                r
            }
            Err(e) => {
                let why = e.to_string();
                bus.go_down(why.clone());
                for &i in &on {
                    let d = &v.devices()[i];
                    d.port_health().missing.store(true, Relaxed);
                    d.port_health()
                        .retry_ms
                        .store(backoff.as_millis() as u64, Relaxed);
                    d.record_error(
                        &DriverError::Io(std::io::Error::new(e.kind(), why.clone())),
                        false,
                    );
                }
                beat.turn(backoff);
                if !stop.sleep_until(Instant::now() + backoff) {
                    return;
                }
                backoff = (backoff * 2).min(BACKOFF_MAX);
                continue;
            }
        };
        let why = read(v, bus, &on, &mut readings, reader.as_mut(), stop, beat);
        bus.go_down(why.clone());
        if stop.is_stopped() {
            return;
        }
        tracing::warn!(bus = bus.name(), "adapter lost: {why}");
        for &i in &on {
            let e = std::io::Error::new(
                std::io::ErrorKind::BrokenPipe,
                format!("bus {}: {why}", bus.name()),
            );
            v.devices()[i].record_error(&DriverError::Io(e), false);
        }
    }
}

/// Bring the adapter onto the bus; its write half goes to the bus, its read half is
/// returned.
fn bring_up(bus: &Bus, (mut reader, mut writer): BusPort) -> std::io::Result<Box<dyn Link>> {
    drain(reader.as_mut());
    let mut decoder = Decoder::<FromAdapter>::new();
    for (n, c) in proto::bring_up(bus.bitrate(), false).iter().enumerate() {
        writer.write_all(&proto::encode_command(c))?;
        let deadline = Deadline::after(ANSWER_WITHIN);
        let answer = loop {
            if let Some(e) = decoder.next() {
                match e {
                    // A frame from a bus already open: not the answer.
                    Event::Received { .. } | Event::Sent { .. } => continue,
                    e => break e,
                }
            }
            let mut buf = [0u8; 64];
            match read_some(reader.as_mut(), &mut buf, &deadline) {
                Ok(k) => decoder.push(&buf[..k]),
                Err(DriverError::Io(e)) => return Err(e),
                Err(e) => {
                    return Err(std::io::Error::new(
                        std::io::ErrorKind::TimedOut,
                        format!("adapter did not answer {c:?}: {e}"),
                    ))
                }
            }
        };
        // Closing an adapter that was closed is refused; anything else must be done.
        if answer != Event::Ok && n > 0 {
            return Err(std::io::Error::other(format!(
                "adapter refused {c:?} ({answer:?}): not an SLCAN adapter, or not at this bitrate"
            )));
        }
    }
    bus.up(writer);
    Ok(reader)
}

/// How long the adapter's line must be quiet before the bring-up's first command.
const QUIET: Duration = Duration::from_millis(50);

/// Before the bring-up asks anything: read and drop what the adapter sends unasked — the
/// late answer of an earlier try (never to be taken for an answer of this one), the
/// frames of a bus left open — until the line has been quiet for [`QUIET`], at most
/// [`ANSWER_WITHIN`] (a bus left open is never quiet; its frames are no answer, and the
/// decoder skips them).
fn drain(reader: &mut dyn Link) {
    let end = Instant::now() + ANSWER_WITHIN;
    let mut buf = [0u8; 256];
    loop {
        let quiet = Deadline::after(QUIET.min(end.saturating_duration_since(Instant::now())));
        match read_some(reader, &mut buf, &quiet) {
            Ok(_) if Instant::now() < end => {}
            _ => return,
        }
    }
}

/// A kit a previous run left enabled (adrive killed, the adapter unplugged while
/// engaged) is disabled as soon as the adapter is on the bus again and the vehicle is
/// not engaged: its disable messages go out before anything else.
fn disable_kits(v: &Vehicle, bus: &Bus, on: &[usize]) {
    for &i in on {
        let d = &v.devices()[i];
        let Some(id) = d.config().kit().and_then(|k| k.disable) else {
            continue;
        };
        let frame = bus
            .config()
            .dbc
            .by_id(id)
            .expect("checked at load")
            .encode(&[])
            .expect("start values fit");
        if let Err(e) = bus.send(&frame) {
            tracing::warn!(device = d.name(), "disable at bring-up: {e}");
        }
    }
}

/// Read the bus until the port fails or the thread is stopped; returns why it ended.
fn read(
    v: &Vehicle,
    bus: &Bus,
    on: &[usize],
    readings: &mut [Reading],
    reader: &mut dyn Link,
    stop: &StopSignal,
    beat: &Beat,
) -> String {
    let mut decoder = Decoder::<FromAdapter>::new();
    let mut buf = [0u8; 256];
    let mut next_status = Instant::now() + STATUS_EVERY;
    let each = |f: &dyn Fn(&Device)| {
        for &i in on {
            f(&v.devices()[i]);
        }
    };
    loop {
        beat.turn(READ_TURN);
        if stop.is_stopped() {
            return "stopped".into();
        }
        let now = Instant::now();
        if now >= next_status {
            next_status = now + STATUS_EVERY;
            if let Err(e) = bus.ask(proto::Command::Status) {
                return e.to_string();
            }
        }
        let deadline = Deadline::after(
            next_status
                .saturating_duration_since(now)
                .max(Duration::from_millis(1)),
        );
        match read_some(reader, &mut buf, &deadline) {
            Ok(k) => decoder.push(&buf[..k]),
            Err(DriverError::Timeout(_)) => continue,
            Err(e) => return e.to_string(),
        }
        let at = Instant::now();
        while let Some(event) = decoder.next() {
            match event {
                Event::Received { frame, .. } => {
                    bus.stats.received.fetch_add(1, Relaxed);
                    bus.note(&frame, at, false);
                    for (k, &i) in on.iter().enumerate() {
                        let d = &v.devices()[i];
                        let Wire::Can(map) = &d.config().wire else {
                            continue;
                        };
                        if decode_into(map, &frame, &mut readings[k]) {
                            store(d, readings[k], at);
                        }
                    }
                }
                Event::Sent { .. } => {
                    bus.stats.acked.fetch_add(1, Relaxed);
                    bus.set_refusing(false);
                }
                Event::Refused => {
                    bus.stats.refused.fetch_add(1, Relaxed);
                    bus.set_refusing(true);
                    let why = bus
                        .bus_error()
                        .unwrap_or_else(|| "the adapter refused a frame (BEL)".into());
                    each(&|d| d.record_error(&DriverError::Refused(why.clone()), true));
                }
                Event::Status(flags) => {
                    if let Some(why) = status(bus, flags) {
                        each(&|d| d.record_error(&DriverError::Refused(why.clone()), false));
                    }
                }
                Event::Garbled(_) => {
                    bus.stats.garbled.fetch_add(1, Relaxed);
                }
                Event::Ok | Event::Version(_) | Event::Serial(_) => {}
            }
        }
    }
}

/// The adapter's status flags: a bus in error is an error of every device on it (the
/// words returned).
fn status(bus: &Bus, flags: StatusFlags) -> Option<String> {
    let serious = StatusFlags(
        flags.0
            & (StatusFlags::BUS_ERROR
                | StatusFlags::ERROR_PASSIVE
                | StatusFlags::ARBITRATION_LOST
                | StatusFlags::DATA_OVERRUN),
    );
    if serious.any() {
        let why = format!(
            "bus {}: adapter reports {}",
            bus.name(),
            serious.names().collect::<Vec<_>>().join(", ")
        );
        if bus.bus_error().as_deref() != Some(why.as_str()) {
            tracing::warn!("{why}");
        }
        bus.set_bus_error(Some(why.clone()));
        return Some(why);
    }
    if bus.bus_error().is_some() {
        tracing::info!(bus = bus.name(), "bus error cleared");
        bus.set_bus_error(None);
    }
    None
}

/// What a device's frames said, as its status thread would store a poll.
fn store(d: &Device, reading: Reading, at: Instant) {
    crate::vehicle::stats::Stats::bump(&d.stats().polls);
    d.store(Cached {
        reading,
        at: Some(at),
        asked: None,
    });
    d.estimate_reading(&reading, at);
    d.health().status_error.store(0, Relaxed);
    d.record_ok(at);
    d.tap_polled(Some(at), at, Ok(&reading));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::driver::serial::SerialLink;
    use serialport::TTYPort;
    use std::io::{Read, Write};

    /// The class of a late reply taken for the next request's: the late answer of an
    /// earlier try at bringing the adapter up (a `\r`, "done") waits on the line. Taken
    /// for the answer to `C`, it would shift every answer by one — `C`'s own `\r` read as
    /// "the bitrate is set" — and the adapter's refusal of the bitrate would be blamed
    /// on the next command. Drained first, the refusal is the bitrate's.
    #[test]
    fn a_late_answer_of_an_earlier_try_is_no_answer_of_the_bring_up() {
        let v = crate::config::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("vehicles/oscc.toml"),
        )
        .unwrap();
        let bus = Bus::new(v.buses[0].clone(), std::sync::Arc::default());
        let (mut adapter, host) = TTYPort::pair().expect("a pseudo-terminal pair");
        adapter.set_timeout(Duration::from_millis(20)).unwrap();
        // The late answer, there before anything is asked.
        adapter.write_all(b"\r").unwrap();
        let served = std::thread::spawn(move || {
            // `C` is done; the bitrate is refused (BEL).
            let mut answered = 0;
            let mut b = [0u8; 1];
            let end = Instant::now() + Duration::from_secs(20);
            while answered < 2 && Instant::now() < end {
                if let Ok(1) = adapter.read(&mut b) {
                    if b[0] == b'\r' {
                        let answer: &[u8] = if answered == 0 { b"\r" } else { b"\x07" };
                        adapter.write_all(answer).unwrap();
                        answered += 1;
                    }
                }
            }
            adapter
        });
        let reader = SerialLink::new(host, ANSWER_WITHIN).unwrap();
        let writer = reader.try_clone().unwrap();
        let e = bring_up(&bus, (Box::new(reader), Box::new(writer)))
            .err()
            .expect("the adapter refuses the bitrate");
        assert!(e.to_string().contains("adapter refused Bitrate"), "{e}");
        drop(served.join().unwrap());
    }
}
