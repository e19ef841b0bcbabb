//! The recorder's thread and its files: events from the tap turned into MCAP messages,
//! a chunk closed, written and synced every [`CHUNK_EVERY`], a new file when the
//! current one is big or old enough (rolling), the oldest beyond `keep` deleted. Any
//! write error stops recording — logged once, kept in the snapshot — and never
//! reaches the vehicle.
//!
//! **Every MCAP reader reads a file at every instant.** A reader opens an MCAP file at
//! its end: the footer says where the summary (the index) is, and a reader that finds
//! no footer gives up (Python `mcap`'s `make_reader`, Foxglove's indexed reader) or
//! reads what it can and fails at the end. The specification lets a file have no
//! summary: a footer whose `summary_start` is 0 tells a reader to read the data section
//! from the start. So each chunk is written with such an ending after it — a Data End
//! record, that footer and the closing magic ([`TAIL`]) — in one write, at the end of
//! the data, and the next chunk's write starts over that ending. A run killed by
//! `kill -9` or a power loss leaves a whole file without an index, which every reader
//! reads to its last chunk; the finished file has its summary and index as usual.
//! While a file is written its recorder holds an exclusive lock on it (`flock`), which
//! the system drops when the process ends however it ends: `adrive record info` tells a
//! file being written from one cut off by it.

use super::message::{self, Clock, RecordMsg, Topic};
use super::{Target, CHUNK_EVERY, DRAIN};
use crate::snapshot::RecordView;
use crate::threads::StopSignal;
use crate::vehicle::tap::{Event, ReaderId, CAPACITY};
use crate::vehicle::Vehicle;
use crossbeam_channel::Receiver;
use mcap::records::MessageHeader;
use mcap::write::{Metadata, NoSeek};
use parking_lot::Mutex;
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{self, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Instant, SystemTime};

type McapWriter = mcap::Writer<NoSeek<Pending>>;

/// What ends the file after each chunk (MCAP specification, "Data End", "Footer"): a
/// Data End record (opcode 0x0F, its length 4, a data section CRC of 0: not computed),
/// a Footer (opcode 0x02, its length 20, `summary_start` 0: no summary, so a reader
/// reads the data section from the start; `summary_offset_start` 0; `summary_crc` 0)
/// and the closing magic.
pub(crate) const TAIL: [u8; 50] = tail();

const fn tail() -> [u8; 50] {
    let mut t = [0u8; 50];
    t[0] = mcap::records::op::DATA_END;
    t[1] = 4;
    t[13] = mcap::records::op::FOOTER;
    t[14] = 20;
    let mut i = 0;
    while i < 8 {
        t[42 + i] = mcap::MAGIC[i];
        i += 1;
    }
    t
}

/// What the MCAP writer has written and the file not yet: handed to the file in one
/// write at each checkpoint.
#[derive(Clone, Default)]
struct Pending(Arc<Mutex<Vec<u8>>>);

impl Write for Pending {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0.lock().extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// One open file.
struct File1 {
    path: PathBuf,
    writer: McapWriter,
    pending: Pending,
    /// The file, written at offsets; locked while it is written.
    file: File,
    /// Bytes of data in the file: where its ending ([`TAIL`]) starts.
    end: u64,
    /// Channel ids in this file.
    channels: HashMap<Topic, u16>,
    opened: Instant,
}

impl File1 {
    /// Write what the MCAP writer has written, with the ending after it, in one write.
    fn commit(&mut self) -> io::Result<()> {
        let mut buf = std::mem::take(&mut *self.pending.0.lock());
        let data = buf.len() as u64;
        buf.extend_from_slice(&TAIL);
        self.file.write_all_at(&buf, self.end)?;
        self.end += data;
        Ok(())
    }

    /// After a failed write: the file back to its data up to the last commit and the
    /// ending, so that it reads as it did then.
    fn restore(&self) -> io::Result<()> {
        self.file.set_len(self.end + TAIL.len() as u64)?;
        self.file.write_all_at(&TAIL, self.end)?;
        self.file.sync_data()
    }
}

/// Where the recording goes now.
pub(super) struct Output {
    vehicle: Arc<Vehicle>,
    target: Target,
    file: Option<File1>,
    /// The last file's path, and its size once finished (for the status).
    last: PathBuf,
    last_bytes: u64,
    clock: Clock,
    /// Messages handed to the MCAP writer, in every file of this recording.
    messages: u64,
    /// Of those, the messages in what the files hold: up to the last chunk written.
    /// What a failed write leaves is the recording's account.
    written: u64,
    sequence: u32,
    /// The drops already said.
    dropped_said: u64,
    /// The recorder's reader of the vehicle's tap, once it is tapped.
    reader: Option<ReaderId>,
}

impl Output {
    /// Open the first file.
    pub(super) fn open(vehicle: Arc<Vehicle>, target: Target) -> io::Result<Output> {
        let mut out = Output {
            vehicle,
            target,
            file: None,
            last: PathBuf::new(),
            last_bytes: 0,
            clock: Clock::now(),
            messages: 0,
            written: 0,
            sequence: 0,
            dropped_said: 0,
            reader: None,
        };
        out.next_file()?;
        out.publish(None);
        Ok(out)
    }

    /// Reading the tap as `reader` from now on.
    pub(super) fn tapped(&mut self, reader: ReaderId) {
        self.reader = Some(reader);
    }

    /// Events the tap left out of this recording.
    fn dropped(&self) -> u64 {
        self.reader.map_or(0, |r| self.vehicle.tap().dropped(r))
    }

    /// Stop tapping for this recording.
    fn untap(&self) {
        if let Some(r) = self.reader {
            self.vehicle.tap().close(r);
        }
    }

    pub(super) fn path(&self) -> &Path {
        &self.last
    }

    /// Finish the current file (if any) and start the next.
    fn next_file(&mut self) -> io::Result<()> {
        self.finish_file()?;
        let path = match &self.target {
            Target::File(p) => p.clone(),
            Target::Dir { dir, .. } => {
                std::fs::create_dir_all(dir).map_err(|e| with_path(dir, e))?;
                fresh_name(dir, self.vehicle.name())
            }
        };
        let file = File::create(&path).map_err(|e| with_path(&path, e))?;
        rustix::fs::flock(&file, rustix::fs::FlockOperation::NonBlockingLockExclusive)
            .map_err(|e| with_path(&path, io::Error::from(e)))?;
        let opts = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_threads(0)
            // A chunk is closed at each checkpoint only, and written whole there.
            .chunk_size(None)
            .profile(message::PROFILE)
            .library(format!("adrive {}", env!("CARGO_PKG_VERSION")))
            .disable_seeking(true);
        let pending = Pending::default();
        let mut writer = opts
            .create(NoSeek::new(pending.clone()))
            .map_err(|e| with_path(&path, mcap_io(e)))?;
        let started = humantime::format_rfc3339_millis(SystemTime::now()).to_string();
        let metadata = BTreeMap::from([
            ("vehicle".to_string(), self.vehicle.name().to_string()),
            ("config".to_string(), self.vehicle.config().source.clone()),
            ("adrive".to_string(), env!("CARGO_PKG_VERSION").to_string()),
            ("started".to_string(), started),
        ]);
        writer
            .write_metadata(&Metadata {
                name: message::METADATA.into(),
                metadata,
            })
            .map_err(|e| with_path(&path, mcap_io(e)))?;
        let mut f = File1 {
            path: path.clone(),
            writer,
            pending,
            file,
            end: 0,
            channels: HashMap::new(),
            opened: Instant::now(),
        };
        // Readable from its first instant: the header, what recorded it, the ending.
        f.commit().map_err(|e| with_path(&path, e))?;
        self.last = path;
        self.file = Some(f);
        if let Target::Dir { dir, keep, .. } = &self.target {
            prune(dir, self.vehicle.name(), *keep, &self.last);
        }
        Ok(())
    }

    /// Write one message on `topic` at `at` (wall-clock ns).
    fn write(&mut self, topic: Topic, at: u64, data: &[u8]) -> io::Result<()> {
        let config = self.vehicle.config();
        let f = self.file.as_mut().expect("a file is open while recording");
        let id = match f.channels.get(&topic) {
            Some(id) => *id,
            None => {
                let (name, schema) = topic.schema(config);
                let schema_id = f
                    .writer
                    .add_schema(&name, message::SCHEMA_ENCODING, &schema)
                    .map_err(mcap_io)?;
                let id = f
                    .writer
                    .add_channel(
                        schema_id,
                        &topic.name(&config.devices),
                        message::MESSAGE_ENCODING,
                        &BTreeMap::new(),
                    )
                    .map_err(mcap_io)?;
                f.channels.insert(topic, id);
                id
            }
        };
        self.sequence = self.sequence.wrapping_add(1);
        let header = MessageHeader {
            channel_id: id,
            sequence: self.sequence,
            log_time: at,
            publish_time: at,
        };
        f.writer
            .write_to_known_channel(&header, data)
            .map_err(mcap_io)?;
        self.messages += 1;
        Ok(())
    }

    fn json(&mut self, topic: Topic, at: u64, value: &impl serde::Serialize) -> io::Result<()> {
        let data = serde_json::to_vec(value).map_err(io::Error::other)?;
        self.write(topic, at, &data)
    }

    /// Write one event as its message.
    fn event(&mut self, ev: Event) -> io::Result<()> {
        let (topic, at, data) = message::encode(&self.vehicle, &self.clock, ev);
        self.write(topic, at, &data)
    }

    /// Close the chunk, flush it to the disk, say how it goes, and roll to a new file
    /// when this one is big or old enough.
    fn checkpoint(&mut self) -> io::Result<()> {
        let dropped = self.dropped();
        let bytes = self.bytes();
        let m = RecordMsg {
            messages: self.messages,
            dropped,
            bytes,
        };
        let now = self.clock.ns(Instant::now());
        self.json(Topic::Record, now, &m)?;
        let f = self.file.as_mut().expect("open");
        f.writer.flush().map_err(mcap_io)?;
        f.commit()?;
        f.file.sync_data()?;
        self.written = self.messages;
        if dropped > self.dropped_said {
            tracing::warn!(
                "recording: {} events left out, the recorder fell behind (the vehicle did not wait)",
                dropped - self.dropped_said
            );
            self.dropped_said = dropped;
        }
        self.publish(None);
        if let Target::Dir {
            roll_size,
            roll_age,
            ..
        } = self.target
        {
            let f = self.file.as_ref().expect("open");
            if self.bytes() >= roll_size || f.opened.elapsed() >= roll_age {
                self.next_file()?;
                tracing::info!(file = %self.last.display(), "recording: next file");
            }
        }
        Ok(())
    }

    /// The size of the file being written (or of the last, once finished).
    fn bytes(&self) -> u64 {
        match &self.file {
            Some(f) => f.file.metadata().map_or(0, |m| m.len()),
            None => self.last_bytes,
        }
    }

    /// Put the recorder's account in the snapshot.
    fn publish(&self, error: Option<String>) {
        self.vehicle.tap().set_status(Some(RecordView {
            file: self.last.display().to_string(),
            bytes: self.bytes(),
            messages: self.messages,
            dropped: self.dropped(),
            error,
        }));
    }

    /// Finish the last file: its index, summary and footer.
    fn close(&mut self) -> io::Result<()> {
        self.finish_file()
    }

    /// Finish the file being written, if any: its index, summary and footer. One that
    /// fails is left at its last checkpoint ([`finish`]), and its size is that.
    fn finish_file(&mut self) -> io::Result<()> {
        if let Some(f) = self.file.take() {
            self.last_bytes = f.end + TAIL.len() as u64;
            self.last_bytes = finish(f)?;
            self.written = self.messages;
        }
        Ok(())
    }

    /// Recording failed: leave the file as it was at its last checkpoint, which every
    /// reader reads (it is not finished: its index would name the chunk that failed),
    /// and count what it holds, not what was handed to the writer after that.
    fn abandon(&mut self) {
        if let Some(f) = self.file.take() {
            match f.restore() {
                Ok(()) => self.last_bytes = f.end + TAIL.len() as u64,
                Err(e) => {
                    self.last_bytes = f.file.metadata().map_or(0, |m| m.len());
                    tracing::warn!(
                        "recording: {}: cannot end it at its last chunk: {e}",
                        f.path.display()
                    );
                }
            }
        }
        self.messages = self.written;
    }
}

/// Write a file's index, summary and footer; its final size. The lock goes with the
/// file. A write that fails leaves the file as it was at its last checkpoint.
fn finish(mut f: File1) -> io::Result<u64> {
    f.writer
        .finish()
        .map_err(|e| with_path(&f.path, mcap_io(e)))?;
    let rest = std::mem::take(&mut *f.pending.0.lock());
    let size = f.end + rest.len() as u64;
    let written = f
        .file
        .write_all_at(&rest, f.end)
        .and_then(|()| f.file.set_len(size))
        .and_then(|()| f.file.sync_data());
    if let Err(e) = written {
        let _ = f.restore();
        return Err(with_path(&f.path, e));
    }
    Ok(size)
}

fn mcap_io(e: mcap::McapError) -> io::Error {
    match e {
        mcap::McapError::Io(e) => e,
        other => io::Error::other(other),
    }
}

fn with_path(path: &Path, e: io::Error) -> io::Error {
    io::Error::new(e.kind(), format!("{}: {e}", path.display()))
}

/// A file name for `vehicle` in `dir` that does not exist yet:
/// `alice-2026-11-23T00-28-47Z.mcap` (UTC; `-2`, `-3`… when taken).
fn fresh_name(dir: &Path, vehicle: &str) -> PathBuf {
    let stem = format!(
        "{}-{}",
        prefix(vehicle),
        humantime::format_rfc3339_seconds(SystemTime::now())
            .to_string()
            .replace(':', "-")
    );
    let mut path = dir.join(format!("{stem}.mcap"));
    let mut n = 1;
    while path.exists() {
        n += 1;
        path = dir.join(format!("{stem}-{n}.mcap"));
    }
    path
}

/// The vehicle's name as a file name prefix: letters, digits, `-` and `_`.
fn prefix(vehicle: &str) -> String {
    let p: String = vehicle
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c.to_ascii_lowercase()
            } else {
                '_'
            }
        })
        .collect();
    if p.is_empty() {
        "adrive".into()
    } else {
        p
    }
}

/// Delete this vehicle's oldest recordings in `dir` beyond `keep` (0: keep all); never
/// `current`. The names sort by time.
fn prune(dir: &Path, vehicle: &str, keep: usize, current: &Path) {
    if keep == 0 {
        return;
    }
    let start = format!("{}-", prefix(vehicle));
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension().is_some_and(|x| x == "mcap")
                && p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with(&start))
        })
        .collect();
    files.sort();
    let excess = files.len().saturating_sub(keep);
    for old in files.into_iter().take(excess).filter(|p| p != current) {
        match std::fs::remove_file(&old) {
            Ok(()) => {
                tracing::info!(file = %old.display(), "recording: deleted the oldest (keep {keep})")
            }
            Err(e) => tracing::warn!(file = %old.display(), "recording: cannot delete: {e}"),
        }
    }
}

/// The recorder's thread: drain, write, checkpoint every [`CHUNK_EVERY`], until told
/// to stop; then what is left, and the file is finished.
pub(super) fn run(mut out: Output, rx: &Receiver<Event>, stop: &StopSignal) {
    let mut checkpoint = Instant::now() + CHUNK_EVERY;
    loop {
        let go_on = stop.sleep_until(Instant::now() + DRAIN);
        // At most a channel's worth a turn, so a flood cannot keep the checkpoint away.
        let mut result = Ok(());
        for ev in rx.try_iter().take(CAPACITY) {
            result = out.event(ev);
            if result.is_err() {
                break;
            }
        }
        if result.is_ok() && (!go_on || Instant::now() >= checkpoint) {
            checkpoint = Instant::now() + CHUNK_EVERY;
            result = out.checkpoint();
        }
        if let Err(e) = result {
            return fail(&mut out, &e);
        }
        if !go_on {
            break;
        }
    }
    match out.close() {
        Ok(()) => {
            out.publish(None);
            tracing::info!(
            file = %out.last.display(),
            messages = out.messages,
            dropped = out.dropped(),
            "recording finished"
            )
        }
        Err(e) => fail(&mut out, &e),
    }
    out.untap();
}

/// Writing failed: stop recording, loudly; the vehicle runs on.
fn fail(out: &mut Output, e: &io::Error) {
    out.untap();
    let file = out.last.display().to_string();
    let what = if e.to_string().starts_with(&file) {
        e.to_string()
    } else {
        format!("{file}: {e}")
    };
    let msg = format!("recording stopped: {what}; the vehicle runs on");
    tracing::error!("{msg}");
    // What was written up to the last chunk stays readable, to every reader; the
    // account says what that is.
    out.abandon();
    out.publish(Some(msg));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_names_sort_by_time_and_never_collide() {
        let dir = tempfile::Builder::new()
            .prefix("adrive-names-")
            .tempdir()
            .unwrap();
        let a = fresh_name(dir.path(), "Alice 2");
        std::fs::write(&a, b"").unwrap();
        let b = fresh_name(dir.path(), "Alice 2");
        assert_ne!(a, b);
        let name = a.file_name().unwrap().to_string_lossy().to_string();
        assert!(
            name.starts_with("alice_2-") && name.ends_with("Z.mcap"),
            "{name}"
        );
    }

    #[test]
    fn prune_keeps_the_newest_of_this_vehicle_only() {
        let dir = tempfile::Builder::new()
            .prefix("adrive-prune-")
            .tempdir()
            .unwrap();
        for n in [
            "alice-1.mcap",
            "alice-2.mcap",
            "alice-3.mcap",
            "bob-1.mcap",
            "alice.txt",
        ] {
            std::fs::write(dir.path().join(n), b"").unwrap();
        }
        prune(dir.path(), "Alice", 2, &dir.path().join("alice-3.mcap"));
        let mut left: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .collect();
        left.sort();
        assert_eq!(
            left,
            ["alice-2.mcap", "alice-3.mcap", "alice.txt", "bob-1.mcap"]
        );
    }
}
