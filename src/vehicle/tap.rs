//! The tap: where the engine, the gate, the network intake, the console and the
//! supervisor hand what happens to its readers — the recorder ([`crate::record`]) and
//! the live view ([`crate::foxglove`]) — without ever waiting for them.
//!
//! Off (no reader), a hook costs one atomic load. On, it builds a plain [`Event`] —
//! `Copy` data on the command path, no heap — and `try_send`s it into each reader's
//! bounded channel, which that reader's thread drains on its own schedule (it polls; it
//! never parks on the channel, so a send never has to wake it). A second reader gets a
//! clone: a copy for the command path's events, which own no heap. A full channel
//! drops the event for that reader and counts the drop: a reader may lose an event,
//! the vehicle never waits for a disk or a viewer. A reader that stops (the recorder's
//! file could not be written) closes its own channel; the tap turns itself off when no
//! reader is left.

use crate::port::trace::{RawSink, TraceEntry};
use crate::snapshot::{FaultKind, LiveView, RecordView};
use crate::value::{Command, DeviceId, Reading};
use crossbeam_channel::{Receiver, Sender, TrySendError};
use parking_lot::Mutex;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering::Relaxed};
use std::sync::OnceLock;
use std::time::{Instant, SystemTime};

/// Events a reader's channel holds before it drops: a second of a busy vehicle at 20 ms
/// per drain is a few hundred; this leaves room for a recorder held up by a slow disk.
pub(crate) const CAPACITY: usize = 8 * 1024;

/// Readers a tap takes: the recorder and the live view, and room for one more.
pub(crate) const READERS: usize = 3;

pub(crate) use crate::value::Source;

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
    /// A command reached intake: accepted, or refused with the reason's code; and what
    /// the decision saw (`None`: ownership refused it, or the supervisor's own).
    Received {
        at: Instant,
        source: Source,
        asked: Asked,
        refused: Option<&'static str>,
        seen: Option<super::seen::Seen>,
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

/// One device's raw traffic, from its trace ([`crate::port::trace`]) to the tap.
pub(crate) struct RawOf {
    pub device: DeviceId,
    pub tap: std::sync::Arc<Tap>,
}

impl RawSink for RawOf {
    fn wants(&self) -> bool {
        self.tap.wants_raw()
    }

    fn chunk(&self, entry: TraceEntry) {
        self.tap.send(|| Event::Raw {
            device: self.device,
            entry,
        });
    }
}

/// One reader's channel, its own switch and its own drops.
struct Reader {
    tx: Sender<Event>,
    on: AtomicBool,
    raw: bool,
    dropped: AtomicU64,
}

/// A reader of the tap: its events, and its handle to close it and count its drops.
pub struct Tapped {
    pub rx: Receiver<Event>,
    pub reader: ReaderId,
}

/// Which of a tap's readers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReaderId(usize);

/// The tap of one vehicle.
#[derive(Default)]
pub struct Tap {
    readers: [OnceLock<Reader>; READERS],
    /// Readers open, and those of them that take raw traffic.
    open: AtomicUsize,
    raw: AtomicUsize,
    /// What the recorder says of itself, for the snapshot.
    status: Mutex<Option<RecordView>>,
    /// What the live view says of itself, for the snapshot.
    live: Mutex<Option<LiveView>>,
}

impl Tap {
    /// Add a reader: events go into its channel from now on. `raw`: raw serial traffic
    /// too. `None` when the tap has all the readers it takes.
    pub fn open(&self, raw: bool) -> Option<Tapped> {
        let (tx, rx) = crossbeam_channel::bounded(CAPACITY);
        let mut reader = Reader {
            tx,
            on: AtomicBool::new(true),
            raw,
            dropped: AtomicU64::new(0),
        };
        let mut at = None;
        for (i, slot) in self.readers.iter().enumerate() {
            match slot.set(reader) {
                Ok(()) => {
                    at = Some(i);
                    break;
                }
                Err(r) => reader = r,
            }
        }
        let i = at?;
        if raw {
            self.raw.fetch_add(1, Relaxed);
        }
        self.open.fetch_add(1, Relaxed);
        Some(Tapped {
            rx,
            reader: ReaderId(i),
        })
    }

    /// Stop one reader (the recorder stopped); with none left, hooks cost one load again.
    pub fn close(&self, reader: ReaderId) {
        let Some(r) = self.readers[reader.0].get() else {
            return;
        };
        if r.on.swap(false, Relaxed) {
            if r.raw {
                self.raw.fetch_sub(1, Relaxed);
            }
            self.open.fetch_sub(1, Relaxed);
        }
    }

    pub(crate) fn is_on(&self) -> bool {
        self.open.load(Relaxed) > 0
    }

    /// Raw serial traffic is asked for.
    pub(crate) fn wants_raw(&self) -> bool {
        self.raw.load(Relaxed) > 0
    }

    /// Hand an event over to every reader, built only while tapping; never blocks.
    #[inline]
    pub fn send(&self, event: impl FnOnce() -> Event) {
        if !self.is_on() {
            return;
        }
        let event = event();
        let raw = matches!(event, Event::Raw { .. });
        let mut to = self
            .readers
            .iter()
            .enumerate()
            .filter_map(|(i, slot)| Some((i, slot.get()?)))
            .filter(|(_, r)| r.on.load(Relaxed) && (r.raw || !raw));
        let mut next = to.next();
        let mut event = Some(event);
        while let Some((i, r)) = next {
            next = to.next();
            let e = match next {
                Some(_) => event.clone(),
                None => event.take(),
            };
            match r.tx.try_send(e.expect("an event for each reader")) {
                Ok(()) => {}
                Err(TrySendError::Full(_)) => {
                    r.dropped.fetch_add(1, Relaxed);
                }
                Err(TrySendError::Disconnected(_)) => self.close(ReaderId(i)),
            }
        }
    }

    /// Events dropped for `reader` because its channel was full.
    pub fn dropped(&self, reader: ReaderId) -> u64 {
        self.readers[reader.0]
            .get()
            .map_or(0, |r| r.dropped.load(Relaxed))
    }

    /// The recorder's own account, for the snapshot.
    pub(crate) fn set_status(&self, view: Option<RecordView>) {
        *self.status.lock() = view;
    }

    pub fn status(&self) -> Option<RecordView> {
        self.status.lock().clone()
    }

    /// The live view's own account, for the snapshot's network part.
    pub(crate) fn set_live(&self, view: Option<LiveView>) {
        *self.live.lock() = view;
    }

    pub fn live(&self) -> Option<LiveView> {
        self.live.lock().clone()
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
        let t = tap.open(false).unwrap();
        tap.send(note);
        assert_eq!(t.rx.len(), 1);
        tap.close(t.reader);
        tap.send(|| panic!("built after close"));
    }

    #[test]
    fn a_full_tap_drops_and_counts_instead_of_waiting() {
        let tap = Tap::default();
        let t = tap.open(false).unwrap();
        for _ in 0..CAPACITY + 5 {
            tap.send(note);
        }
        assert_eq!(t.rx.len(), CAPACITY);
        assert_eq!(tap.dropped(t.reader), 5);
    }

    #[test]
    fn each_reader_gets_every_event_and_drops_on_its_own() {
        let tap = Tap::default();
        let slow = tap.open(false).unwrap();
        let fast = tap.open(true).unwrap();
        for _ in 0..CAPACITY + 5 {
            tap.send(note);
            let _ = fast.rx.try_recv().expect("the other reader's event");
        }
        assert_eq!(slow.rx.len(), CAPACITY);
        assert_eq!(tap.dropped(slow.reader), 5);
        assert_eq!(tap.dropped(fast.reader), 0);
        // Raw traffic goes to the reader that asked for it only.
        assert!(tap.wants_raw());
        let raw = || Event::Raw {
            device: DeviceId(0),
            entry: TraceEntry::new(Instant::now(), crate::port::trace::Dir::Out, b"x"),
        };
        let _ = slow.rx.try_iter().count();
        tap.send(raw);
        assert!(slow.rx.is_empty());
        assert_eq!(fast.rx.len(), 1);
        // One reader stopping leaves the other tapped.
        tap.close(fast.reader);
        assert!(!tap.wants_raw());
        tap.send(note);
        assert_eq!(slow.rx.len(), 1);
        tap.close(slow.reader);
        assert!(!tap.is_on());
    }
}
