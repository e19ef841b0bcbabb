//! Timestamps along the command path, for the benchmark that measures it from outside
//! (section 11 of `cargo bench --bench paper`, docs/performance.md).
//!
//! adrive's own figure, receipt → first byte, starts when the listener's read has
//! returned and ends at the write. A planner sees more: the kernel's delivery and the
//! listener's wake before, the pseudo-terminal's (or the serial driver's) delivery
//! after. To say where each microsecond of the whole way goes, the listener and the
//! command path stamp each datagram's steps here, in `CLOCK_MONOTONIC` nanoseconds —
//! the clock the planner's and the device's ends read in another process — and the
//! benchmark reads them back beside its own `sendto` and first-byte times.
//!
//! Off unless the environment names a file (`ADRIVE_PROBE=FILE`, read once when the
//! network starts): then every stamp is a few relaxed stores into that file, mapped
//! shared, which the benchmark reads while adrive runs. Off, a stamp is one load of a
//! pointer that is null. Nothing here allocates, locks or makes a system call on the
//! path. The listener's datagram is the record a stamp lands on: a command another
//! source (a console, ROS 2) admits meanwhile stamps the same record, so figures are
//! taken with the planner the only source, as the benchmark does.

// The probe reads the monotonic clock and maps its file shared: system calls with no
// safe wrapper here, each block with its SAFETY reason.
#![allow(unsafe_code)]

use std::sync::atomic::{AtomicPtr, AtomicU64, AtomicUsize, Ordering::Relaxed};
use std::sync::OnceLock;
use std::time::Instant;

/// The environment variable that turns the probe on: the file to write to.
pub const ENV: &str = "ADRIVE_PROBE";

/// Records the file holds (a ring: the newest overwrite the oldest).
pub(crate) const RECORDS: usize = 8192;
/// Stamps per record.
pub(crate) const STAMPS: usize = 8;
/// The file's size: a header record (its first word: records started), then the ring.
pub(crate) const BYTES: usize = (RECORDS + 1) * STAMPS * 8;

/// A step of one datagram's way, the index of its stamp in a record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(usize)]
pub enum Step {
    /// The listener's read returned (the `received` every delay figure starts at).
    Received = 0,
    /// The network's own checks done: sender table, grammar, key, rolling counter.
    Parsed = 1,
    /// The one intake's checks done for a set point: ownership, value, interlocks;
    /// next, the fast path's wire check and write, or the slot.
    Checked = 2,
    /// The fast path's send returned (the listener wrote the request itself), the raw
    /// trace of its bytes recorded.
    FastWritten = 3,
    /// The first byte of the command's request was written, on either path (the
    /// stamp adrive's own delay figure ends at), taken from the command's bookkeeping.
    FirstByte = 4,
    /// The listener is done with the datagram (reply included) and reads again.
    Handled = 5,
}

struct Probe {
    words: &'static [AtomicU64],
    /// The record of the datagram the listener is on.
    current: AtomicUsize,
    base: Instant,
    base_ns: u64,
}

static PROBE: AtomicPtr<Probe> = AtomicPtr::new(std::ptr::null_mut());
static INIT: OnceLock<()> = OnceLock::new();

/// `CLOCK_MONOTONIC` now, in nanoseconds: the clock `Instant` reads, as a number other
/// processes can compare.
pub fn mono_ns() -> u64 {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes the timespec it is given.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut t) };
    t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64
}

/// Turn the probe on if [`ENV`] names a file (once; later calls do nothing). A file
/// that cannot be mapped leaves it off, with a warning.
pub(crate) fn init() {
    INIT.get_or_init(|| {
        if let Some(path) = std::env::var_os(ENV) {
            start(std::path::Path::new(&path));
        }
    });
}

/// Turn the probe on, stamping into `path` (created, or reused as it is). Once on, it
/// stays on with its first file.
pub fn start(path: &std::path::Path) {
    if probe().is_some() {
        return;
    }
    match map(path) {
        Ok(words) => {
            let probe = Box::new(Probe {
                words,
                current: AtomicUsize::new(0),
                base: Instant::now(),
                base_ns: mono_ns(),
            });
            let p = Box::into_raw(probe);
            if PROBE
                .compare_exchange(std::ptr::null_mut(), p, Relaxed, Relaxed)
                .is_err()
            {
                // SAFETY: `p` came from Box::into_raw above and was never shared.
                drop(unsafe { Box::from_raw(p) });
                return;
            }
            tracing::info!(file = %path.display(), "command path probe on");
        }
        Err(e) => tracing::warn!("{ENV}={}: {e}; the probe stays off", path.display()),
    }
}

fn map(path: &std::path::Path) -> std::io::Result<&'static [AtomicU64]> {
    use std::os::fd::AsRawFd;
    let f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)?;
    f.set_len(BYTES as u64)?;
    // SAFETY: a fresh shared mapping of a file of BYTES bytes; never unmapped, so the
    // slice lives as long as the process. AtomicU64 has u64's layout, and the mapping
    // is page-aligned.
    let p = unsafe {
        libc::mmap(
            std::ptr::null_mut(),
            BYTES,
            libc::PROT_READ | libc::PROT_WRITE,
            libc::MAP_SHARED,
            f.as_raw_fd(),
            0,
        )
    };
    if p == libc::MAP_FAILED {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: see above.
    Ok(unsafe { std::slice::from_raw_parts(p.cast::<AtomicU64>(), BYTES / 8) })
}

fn probe() -> Option<&'static Probe> {
    // SAFETY: null, or a Probe leaked by `init` that lives as long as the process.
    unsafe { PROBE.load(Relaxed).as_ref() }
}

impl Probe {
    fn ns(&self, at: Instant) -> u64 {
        match at.checked_duration_since(self.base) {
            Some(d) => self.base_ns + d.as_nanos() as u64,
            None => self
                .base_ns
                .saturating_sub(self.base.duration_since(at).as_nanos() as u64),
        }
    }

    fn word(&self, record: usize, step: usize) -> &AtomicU64 {
        &self.words[(1 + record % RECORDS) * STAMPS + step]
    }
}

/// The listener read a datagram at `received`: a new record.
#[inline]
pub fn datagram(received: Instant) {
    if let Some(p) = probe() {
        let r = p.words[0].fetch_add(1, Relaxed) as usize;
        p.current.store(r, Relaxed);
        for s in 0..STAMPS {
            p.word(r, s).store(0, Relaxed);
        }
        p.word(r, Step::Received as usize)
            .store(p.ns(received), Relaxed);
    }
}

/// The datagram the listener is on reached `step`, now.
#[inline]
pub fn stamp(step: Step) {
    if let Some(p) = probe() {
        p.word(p.current.load(Relaxed), step as usize)
            .store(mono_ns(), Relaxed);
    }
}

/// A command received at `received` had its first byte written at `first` (from the
/// command's bookkeeping, on whichever thread): stamped on its datagram's record.
#[inline]
pub(crate) fn first_byte(received: Instant, first: Instant) {
    if let Some(p) = probe() {
        let at = p.ns(received);
        let newest = p.current.load(Relaxed);
        // The datagram is among the last few the listener read.
        for r in (newest.saturating_sub(63)..=newest).rev() {
            let w = p.word(r, Step::FirstByte as usize);
            if p.word(r, Step::Received as usize).load(Relaxed) == at {
                if w.load(Relaxed) == 0 {
                    w.store(p.ns(first), Relaxed);
                }
                return;
            }
        }
    }
}

/// One datagram's stamps read back from a probe file (0: not reached).
pub fn read(path: &std::path::Path) -> std::io::Result<Vec<[u64; STAMPS]>> {
    let bytes = std::fs::read(path)?;
    let word = |i: usize| {
        bytes
            .get(i * 8..i * 8 + 8)
            .map_or(0, |b| u64::from_ne_bytes(b.try_into().unwrap_or([0; 8])))
    };
    let started = word(0) as usize;
    let first = started.saturating_sub(RECORDS);
    Ok((first..started)
        .map(|r| std::array::from_fn(|s| word((1 + r % RECORDS) * STAMPS + s)))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A datagram's steps come back from the file as the benchmark reads them: its
    /// read, its checks, and its first byte (stamped from the command's bookkeeping,
    /// by its `received`), in order, in the clock the benchmark's own stamps use.
    #[test]
    fn a_datagrams_steps_are_read_back_from_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("probe");
        start(&file);
        // Other tests' listeners in this process stamp too once the probe is on: a
        // datagram of theirs between two stamps of this one moves the current record.
        // One clean pass of the steps is what is asserted.
        let order = [
            Step::Received,
            Step::Parsed,
            Step::Checked,
            Step::FirstByte,
            Step::Handled,
        ];
        let clean = (0..50).find_map(|_| {
            let before = mono_ns();
            let received = Instant::now();
            datagram(received);
            stamp(Step::Parsed);
            stamp(Step::Checked);
            first_byte(received, Instant::now());
            stamp(Step::Handled);
            let after = mono_ns();
            let at = probe().unwrap().ns(received);
            let r = *read(&file)
                .unwrap()
                .iter()
                .find(|r| r[Step::Received as usize] == at)?;
            let ordered = order
                .windows(2)
                .all(|w| r[w[0] as usize] <= r[w[1] as usize]);
            (ordered && before <= r[0] && r[Step::Handled as usize] <= after).then_some(r)
        });
        assert!(clean.is_some(), "no datagram's steps read back in order");
    }

    /// An `Instant` and the nanoseconds it is stamped as agree with the clock another
    /// process reads (the benchmark compares them with its own `sendto` times).
    ///
    /// Each pair of clock reads is bracketed, so no preemption between them can fail
    /// it: the base's true time lies between the reads around it, and so does the
    /// converted instant's.
    #[test]
    fn instants_convert_to_the_monotonic_clock() {
        let early = mono_ns();
        let base = Instant::now();
        let p = Probe {
            words: Box::leak(Box::new([])),
            current: AtomicUsize::new(0),
            base,
            base_ns: mono_ns(),
        };
        // The base is stamped late by at most this much.
        let late = p.base_ns - early;
        std::thread::sleep(std::time::Duration::from_millis(2));
        let before = mono_ns();
        let b = p.ns(Instant::now());
        let after = mono_ns();
        assert!(
            before <= b && b <= after + late,
            "{b} converted, read between {before} and {after} (base late by up to {late} ns)"
        );
    }
}
