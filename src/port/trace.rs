//! The raw traffic trace of one device: every chunk of bytes written to or read from
//! its port, with a timestamp, in a bounded ring that the console's bench view reads.
//! Recording copies at most [`CHUNK`] bytes into a preallocated slot under a lock held
//! for that copy only; nothing allocates. At `RUST_LOG=adrive=trace` each chunk is also
//! logged as hex and ASCII, and when a recording asks for raw traffic, tapped for it.

use parking_lot::Mutex;
use std::fmt::Write as _;
use std::sync::Arc;
use std::time::Instant;

/// Entries kept per device.
pub(crate) const CAPACITY: usize = 256;
/// Bytes kept per entry; longer chunks are cut (and marked so).
pub(crate) const CHUNK: usize = 64;

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Dir {
    /// Host to device.
    Out,
    /// Device to host.
    In,
}

impl Dir {
    pub(crate) fn arrow(self) -> &'static str {
        match self {
            Dir::Out => "->",
            Dir::In => "<-",
        }
    }
}

/// One chunk on the wire.
#[derive(Clone, Copy, Debug)]
pub struct TraceEntry {
    pub at: Instant,
    pub dir: Dir,
    len: u16,
    /// The chunk was longer than [`CHUNK`] bytes.
    pub cut: bool,
    data: [u8; CHUNK],
}

impl TraceEntry {
    pub fn new(at: Instant, dir: Dir, bytes: &[u8]) -> TraceEntry {
        let n = bytes.len().min(CHUNK);
        let mut data = [0; CHUNK];
        data[..n].copy_from_slice(&bytes[..n]);
        TraceEntry {
            at,
            dir,
            len: n as u16,
            cut: bytes.len() > CHUNK,
            data,
        }
    }

    pub fn bytes(&self) -> &[u8] {
        &self.data[..self.len as usize]
    }

    /// `01 03 00 00` …
    pub fn hex(&self) -> String {
        let mut s = String::with_capacity(self.bytes().len() * 3);
        for (i, b) in self.bytes().iter().enumerate() {
            if i > 0 {
                s.push(' ');
            }
            let _ = write!(s, "{b:02x}");
        }
        if self.cut {
            s.push_str(" …");
        }
        s
    }

    /// Printable ASCII, other bytes as `.`.
    pub fn ascii(&self) -> String {
        self.bytes()
            .iter()
            .map(|&b| {
                if (0x20..0x7f).contains(&b) {
                    b as char
                } else {
                    '.'
                }
            })
            .collect()
    }
}

/// Where a trace also hands its chunks while a recording asks for raw traffic: the
/// vehicle's tap (`crate::vehicle::tap`), which sits above this layer and sees its own
/// readers.
pub trait RawSink: Send + Sync {
    /// A recording asks for raw traffic now (a cheap check, made for every chunk).
    fn wants(&self) -> bool;
    /// One chunk of this device's traffic.
    fn chunk(&self, entry: TraceEntry);
}

struct Ring {
    entries: Vec<TraceEntry>,
    next: usize,
    total: u64,
}

/// The bounded trace of one device.
pub struct Trace {
    device: String,
    ring: Mutex<Ring>,
    tap: Option<Arc<dyn RawSink>>,
}

impl Trace {
    pub fn new(device: &str) -> Trace {
        Trace {
            device: device.to_string(),
            ring: Mutex::new(Ring {
                entries: Vec::with_capacity(CAPACITY),
                next: 0,
                total: 0,
            }),
            tap: None,
        }
    }

    /// Hand every chunk to `sink` too, while it asks for raw traffic.
    pub(crate) fn tapped(mut self, sink: Arc<dyn RawSink>) -> Trace {
        self.tap = Some(sink);
        self
    }

    pub fn device(&self) -> &str {
        &self.device
    }

    pub fn record(&self, dir: Dir, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        let e = TraceEntry::new(Instant::now(), dir, bytes);
        {
            let mut r = self.ring.lock();
            r.total += 1;
            if r.entries.len() < CAPACITY {
                r.entries.push(e);
            } else {
                let i = r.next;
                r.entries[i] = e;
            }
            r.next = (r.next + 1) % CAPACITY;
        }
        if let Some(sink) = self.tap.as_ref().filter(|t| t.wants()) {
            sink.chunk(e);
        }
        tracing::trace!(
            device = %self.device,
            "{} {}  |{}|",
            dir.arrow(),
            e.hex(),
            e.ascii()
        );
    }

    /// The kept entries, oldest first.
    pub fn entries(&self) -> Vec<TraceEntry> {
        let r = self.ring.lock();
        if r.entries.len() < CAPACITY {
            r.entries.clone()
        } else {
            let mut v = r.entries[r.next..].to_vec();
            v.extend_from_slice(&r.entries[..r.next]);
            v
        }
    }

    /// Chunks recorded since start (including those no longer kept).
    pub fn total(&self) -> u64 {
        self.ring.lock().total
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ring_keeps_the_newest_entries_in_order() {
        let t = Trace::new("steer");
        for i in 0..(CAPACITY + 10) {
            t.record(Dir::Out, &(i as u32).to_le_bytes());
        }
        let e = t.entries();
        assert_eq!(e.len(), CAPACITY);
        assert_eq!(e[0].bytes(), &10u32.to_le_bytes());
        assert_eq!(
            e.last().unwrap().bytes(),
            &((CAPACITY + 9) as u32).to_le_bytes()
        );
        assert_eq!(t.total(), (CAPACITY + 10) as u64);
    }

    #[test]
    fn entries_render_as_hex_and_ascii_and_long_chunks_are_cut() {
        let e = TraceEntry::new(Instant::now(), Dir::In, b"ok\r\n");
        assert_eq!(e.hex(), "6f 6b 0d 0a");
        assert_eq!(e.ascii(), "ok..");
        let long = TraceEntry::new(Instant::now(), Dir::In, &[0x41; 100]);
        assert!(long.cut && long.hex().ends_with(" …"));
        assert_eq!(long.bytes().len(), CHUNK);
    }
}
