//! Reading a recording back, for `record info`, `export`, `repair` and replay: what
//! recorded it, its channels, and its messages in the order they were written. A file
//! ends one of three ways ([`Ending`]): finished, with its summary and index; at a
//! checkpoint, with a footer and no summary (adrive ends every chunk so while it
//! writes: the file of a run that is still recording, or that was killed); or inside a
//! chunk, cut while it was written (a power loss, a file from before adrive ended
//! each chunk, a copy taken mid-write). Each reads up to its last whole chunk.

use mcap::read::Options as ReadOptions;
use mcap::records::Record;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// How a recording's file ends.
#[derive(Clone, Debug, PartialEq)]
pub enum Ending {
    /// Finished: its summary and index are there.
    Finished,
    /// At a checkpoint: whole, with no summary; every MCAP reader reads it from the
    /// start. Still being written, or its writer stopped without finishing it.
    Checkpoint,
    /// Inside a chunk, after `chunks` whole ones: why it cannot be read further.
    Cut(String),
}

/// A recording, in memory.
pub struct Recording {
    pub path: PathBuf,
    bytes: Vec<u8>,
    /// The `adrive` metadata record: vehicle, config, adrive's version, start time.
    pub metadata: BTreeMap<String, String>,
    /// Whole chunks in the file.
    pub chunks: usize,
    pub ending: Ending,
    /// The file was finished (its summary and footer are there).
    pub complete: bool,
    /// Where the readable part ends early, and why (a file cut inside a chunk).
    pub cut: Option<String>,
    /// A running adrive is writing it (it holds the file's lock). Only a process on
    /// this machine can be seen so: a file written by another machine (a network
    /// file system, a copy) is not.
    pub writing: bool,
}

/// One message.
pub struct Message<'a> {
    pub topic: &'a str,
    pub schema: &'a str,
    /// Wall-clock nanoseconds since the Unix epoch.
    pub(crate) log_time: u64,
    pub data: &'a [u8],
}

/// An error reading a recording: the file and what is wrong.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {message}")]
pub struct ReadError {
    pub path: String,
    pub message: String,
}

impl Recording {
    /// Read the file at `path`. Only a file that is not MCAP at all is an error; a
    /// damaged end is reported in [`Recording::cut`].
    pub fn open(path: &Path) -> Result<Recording, ReadError> {
        let fail = |message: String| ReadError {
            path: path.display().to_string(),
            message,
        };
        let file = std::fs::File::open(path).map_err(|e| fail(format!("cannot read: {e}")))?;
        let writing = matches!(
            rustix::fs::flock(&file, rustix::fs::FlockOperation::NonBlockingLockShared),
            Err(e) if e == rustix::io::Errno::WOULDBLOCK
        );
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut &file, &mut bytes)
            .map_err(|e| fail(format!("cannot read: {e}")))?;
        drop(file);
        if !bytes.starts_with(mcap::MAGIC) {
            return Err(fail("not an MCAP file (no MCAP magic at its start)".into()));
        }
        let records =
            mcap::read::LinearReader::new_with_options(&bytes, ReadOptions::IgnoreEndMagic.into())
                .map_err(|e| fail(e.to_string()))?;
        let mut metadata = BTreeMap::new();
        let (mut chunks, mut ending) = (0, None);
        for record in records {
            match record {
                Ok(Record::Chunk { .. }) => chunks += 1,
                Ok(Record::Metadata(m)) if m.name == super::message::METADATA => {
                    metadata = m.metadata
                }
                Ok(Record::Footer(f)) => {
                    ending = Some(match f.summary_start {
                        0 => Ending::Checkpoint,
                        _ => Ending::Finished,
                    })
                }
                Ok(_) => {}
                Err(e) => {
                    ending = Some(Ending::Cut(format!(
                        "ends inside chunk {}: {e}",
                        chunks + 1
                    )));
                    break;
                }
            }
        }
        let ending = ending.unwrap_or_else(|| {
            Ending::Cut(format!("ends after chunk {chunks} without its footer"))
        });
        Ok(Recording {
            path: path.to_path_buf(),
            bytes,
            metadata,
            chunks,
            complete: ending == Ending::Finished,
            cut: match &ending {
                Ending::Cut(why) => Some(why.clone()),
                _ => None,
            },
            ending,
            writing,
        })
    }

    /// The file's bytes.
    pub(crate) fn data(&self) -> &[u8] {
        &self.bytes
    }

    /// Bytes in the file.
    pub fn size(&self) -> u64 {
        self.bytes.len() as u64
    }

    /// Every readable message, in the order written, to `each`. A chunk that cannot be
    /// read ends the walk (it can only be the last one, cut off); the reason is
    /// returned.
    pub fn for_each(&self, mut each: impl FnMut(Message<'_>)) -> Option<String> {
        let stream = match mcap::MessageStream::new_with_options(
            &self.bytes,
            ReadOptions::IgnoreEndMagic.into(),
        ) {
            Ok(s) => s,
            Err(e) => return Some(e.to_string()),
        };
        for m in stream {
            match m {
                Ok(m) => each(Message {
                    topic: &m.channel.topic,
                    schema: m.channel.schema.as_ref().map_or("", |s| s.name.as_str()),
                    log_time: m.log_time,
                    data: &m.data,
                }),
                // A complete file's stream ends at its data end; anything else ends a
                // cut-off file.
                Err(e) => return Some(e.to_string()),
            }
        }
        None
    }

    /// Every message, parsed as JSON, with its topic and time.
    pub fn json(&self) -> (Vec<(String, u64, serde_json::Value)>, Option<String>) {
        let mut out = Vec::new();
        let why = self.for_each(|m| {
            if let Ok(v) = serde_json::from_slice(m.data) {
                out.push((m.topic.to_string(), m.log_time, v));
            }
        });
        (out, why)
    }
}
