//! The recording tap: where the engine, the gate, the network intake, the console and
//! the supervisor hand what happens to the recorder ([`crate::record`]) without ever
//! waiting for it.
//!
//! Off (no recording), a hook costs one atomic load. On, it builds a plain [`Event`] —
//! `Copy` data on the command path, no heap — and `try_send`s it into a bounded
//! channel that the recorder's thread drains on its own schedule (it polls; it never
//! parks on the channel, so a send never has to wake it). A full channel drops the
//! event and counts the drop: the recording may lose an event, the vehicle never waits
//! for a disk. Once the recorder stops (its file could not be written), the tap turns
//! itself off.

use super::trace::TraceEntry;
use crate::snapshot::{FaultKind, RecordView};
use crate::value::{Command, DeviceId, Reading};
use crossbeam_channel::{Receiver, Sender, TrySendError};
use parking_lot::Mutex;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::OnceLock;
use std::time::{Instant, SystemTime};

/// Events the channel holds before it drops: a second of a busy vehicle at 20 ms per
/// drain is a few hundred; this leaves room for a recorder held up by a slow disk.
pub const CAPACITY: usize = 8 * 1024;

pub use crate::value::Source;

/// What a source asked for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Asked {
    Device(DeviceId, Command),
    /// The virtual `accel` command (−1 … 1).
    Accel(f64),
}

/// What the gate did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GateChange {
    Engaged,
    Disengaged,
    EngageRefused,
}

/// One thing that happened, stamped where it happened.
// A reading travels inline (some 300 bytes, as the vehicle's caches hold it): boxing it
// would allocate on every poll; the channel's 8 Ki slots take 2.5 MB, allocated once.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
pub enum Event {
    /// A command reached intake: accepted, or refused with the reason's code.
    Received {
        at: Instant,
        source: Source,
        asked: Asked,
        refused: Option<&'static str>,
    },
    /// A datagram refused whole (grammar, key, counter, allow-list), by reason code.
    Refused {
        at: Instant,
        from: SocketAddr,
        reason: &'static str,
    },
    /// A command transaction: the command written (after the wire check), when it was
    /// received, when its first byte went out, when the device answered; `error` is
    /// the paper's code (0 good).
    Written {
        device: DeviceId,
        command: Command,
        received: Instant,
        first: Option<Instant>,
        done: Instant,
        /// A new command, not a resend.
        fresh: bool,
        error: u32,
    },
    /// A status transaction: the reading, or the error code.
    Polled {
        device: DeviceId,
        first: Option<Instant>,
        done: Instant,
        reading: Option<Reading>,
        error: u32,
    },
    /// Raw bytes on a device's port (only when raw traffic is asked for).
    Raw { device: DeviceId, entry: TraceEntry },
    Gate {
        at: Instant,
        change: GateChange,
        reason: String,
    },
    Fault {
        at: Instant,
        raised: bool,
        kind: FaultKind,
        device: Option<String>,
        cause: String,
    },
    /// A line of the supervisor's history: a recovery step, an outcome.
    Note { at: Instant, text: String },
    Log {
        at: SystemTime,
        level: tracing::Level,
        target: &'static str,
        file: Option<&'static str>,
        line: Option<u32>,
        text: String,
    },
    /// The state snapshot as broadcast, JSON.
    Snapshot { at: Instant, json: Vec<u8> },
}

/// The tap of one vehicle.
#[derive(Default)]
pub struct Tap {
    tx: OnceLock<Sender<Event>>,
    on: AtomicBool,
    raw: AtomicBool,
    dropped: AtomicU64,
    /// What the recorder says of itself, for the snapshot.
    status: Mutex<Option<RecordView>>,
}

impl Tap {
    /// Start tapping: events go into the returned receiver from now on. `raw`: raw
    /// serial traffic too. A tap opens once.
    pub fn open(&self, raw: bool) -> Option<Receiver<Event>> {
        let (tx, rx) = crossbeam_channel::bounded(CAPACITY);
        self.tx.set(tx).ok()?;
        self.raw.store(raw, Relaxed);
        self.on.store(true, Relaxed);
        Some(rx)
    }

    /// Stop tapping (the recorder stopped); hooks cost one load again.
    pub fn close(&self) {
        self.on.store(false, Relaxed);
        self.raw.store(false, Relaxed);
    }

    pub fn is_on(&self) -> bool {
        self.on.load(Relaxed)
    }

    /// Raw serial traffic is asked for.
    pub fn wants_raw(&self) -> bool {
        self.raw.load(Relaxed)
    }

    /// Hand an event over, built only while tapping; never blocks.
    #[inline]
    pub fn send(&self, event: impl FnOnce() -> Event) {
        if !self.is_on() {
            return;
        }
        let Some(tx) = self.tx.get() else { return };
        match tx.try_send(event()) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => {
                self.dropped.fetch_add(1, Relaxed);
            }
            Err(TrySendError::Disconnected(_)) => self.close(),
        }
    }

    /// Events dropped because the channel was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Relaxed)
    }

    /// The recorder's own account, for the snapshot.
    pub fn set_status(&self, view: Option<RecordView>) {
        *self.status.lock() = view;
    }

    pub fn status(&self) -> Option<RecordView> {
        self.status.lock().clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn note() -> Event {
        Event::Note {
            at: Instant::now(),
            text: "x".into(),
        }
    }

    #[test]
    fn a_closed_tap_builds_nothing() {
        let tap = Tap::default();
        tap.send(|| panic!("built while off"));
        let rx = tap.open(false).unwrap();
        tap.send(note);
        assert_eq!(rx.len(), 1);
        tap.close();
        tap.send(|| panic!("built after close"));
    }

    #[test]
    fn a_full_tap_drops_and_counts_instead_of_waiting() {
        let tap = Tap::default();
        let rx = tap.open(false).unwrap();
        for _ in 0..CAPACITY + 5 {
            tap.send(note);
        }
        assert_eq!(rx.len(), CAPACITY);
        assert_eq!(tap.dropped(), 5);
    }
}
