//! Recording: every run can be kept in an MCAP file — the state snapshot at its
//! broadcast rate, every command received with its outcome, every command written and
//! every reading taken with their times, faults, recovery steps, engage and disengage,
//! log lines and, when asked, the raw serial traffic — as JSON messages with JSON
//! Schemas ([`message`]), which Foxglove and every MCAP reader open.
//!
//! The vehicle's [`Tap`](crate::vehicle::tap::Tap) feeds the recorder without locks
//! and never waits for it; the recorder's thread (`record/write`) drains it every
//! [`DRAIN`], writes, and closes a
//! compressed chunk every [`CHUNK_EVERY`], written and synced to the disk with an
//! ending after it that makes the file whole at every instant: a recording cut off by
//! `kill -9` or a power loss reads up to its last chunk with every MCAP reader. When the
//! file cannot be written (a full disk), recording stops with an error in the log and
//! in the snapshot; the vehicle runs on.
//!
//! [`read`] reads a recording back (a cut-off one too); [`info`], [`repair`] and
//! [`export`] are `adrive record info`, `adrive record repair` and `adrive export`; the
//! console replays it (`crate::console::replay`), and [`check`] decides every command
//! it received again under another vehicle file (`adrive replay --check`).

pub(crate) mod check;
pub(crate) mod export;
pub(crate) mod info;
pub(crate) mod log;
pub(crate) mod message;
pub mod read;
pub(crate) mod repair;
pub(crate) mod schema;
mod writer;

use crate::config::VehicleConfig;
use crate::threads::Group;
use crate::vehicle::Vehicle;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How often the recorder takes what the tap holds.
pub(crate) const DRAIN: Duration = Duration::from_millis(20);
/// How often a chunk is closed, flushed and synced: what a cut-off recording loses.
pub(crate) const CHUNK_EVERY: Duration = Duration::from_secs(1);

/// Where a recording goes.
#[derive(Clone, Debug, PartialEq)]
pub enum Target {
    /// One file (`--record FILE.mcap`).
    File(PathBuf),
    /// Rolling files in a directory (`[record]`, or `--record DIR/`).
    Dir {
        dir: PathBuf,
        roll_size: u64,
        roll_age: Duration,
        /// Files of this vehicle kept (0: all).
        keep: usize,
    },
}

/// What to record, where.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Options {
    pub target: Target,
    /// The raw serial traffic too.
    pub raw: bool,
}

impl Options {
    /// From `--record PATH` (a file, or an existing directory or one written with a
    /// trailing `/` for rolling files) and `--record-raw`, else the vehicle file's
    /// `[record]`; `None`: nothing to record.
    pub(crate) fn of(path: Option<&Path>, raw: bool, config: &VehicleConfig) -> Option<Options> {
        let table = config.record.as_ref();
        let rolling = |dir: PathBuf| Target::Dir {
            dir,
            roll_size: table.map_or(100_000_000, |r| r.roll_size),
            roll_age: table.map_or(Duration::from_secs(600), |r| r.roll_age),
            keep: table.map_or(0, |r| r.keep),
        };
        let target = match path {
            Some(p) if p.is_dir() || p.as_os_str().to_string_lossy().ends_with('/') => {
                rolling(p.to_path_buf())
            }
            Some(p) => Target::File(p.to_path_buf()),
            None => rolling(config.relative(&table?.dir)),
        };
        Some(Options {
            target,
            raw: raw || table.is_some_and(|r| r.raw),
        })
    }
}

/// The running recorder.
pub(crate) struct Recorder {
    /// Dropped without [`Recorder::shutdown`] (a panic unwinding): told to finish the
    /// file, not waited for.
    threads: Group,
}

impl Recorder {
    /// Open the first file and start recording what `vehicle`'s tap sees. A file that
    /// cannot be created is an error here, before anything runs.
    pub(crate) fn start(vehicle: &Arc<Vehicle>, opts: Options) -> std::io::Result<Recorder> {
        #[allow(unsafe_code)]
        // A file size limit (`ulimit -f`, a service's LimitFSIZE) must fail a write
        // like a full disk does, not kill the process that drives the vehicle.
        // SAFETY: setting a signal's disposition to "ignore".
        unsafe {
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN)
        };
        let mut out = writer::Output::open(vehicle.clone(), opts.target)?;
        let tapped = vehicle.tap().open(opts.raw).ok_or_else(|| {
            std::io::Error::other("this vehicle's tap has no room for a recorder")
        })?;
        out.tapped(tapped.reader);
        let rx = tapped.rx;
        tracing::info!(file = %out.path().display(), raw = opts.raw, "recording");
        let mut threads = Group::default();
        threads.spawn("record/write", move |stop| writer::run(out, &rx, stop))?;
        Ok(Recorder { threads })
    }
}

impl crate::threads::Shutdown for Recorder {
    /// Write what is left, finish the file (its index and summary) and stop. Returns
    /// the names of threads that did not stop.
    fn shutdown(mut self, deadline: Duration) -> Vec<String> {
        self.threads.stop(Instant::now() + deadline)
    }
}
