//! Reading a recording back, for `record info`, `export` and replay: what recorded
//! it, its channels, and its messages in the order they were written. A recording
//! cut off by `kill -9` or a power loss has no summary and may end inside a chunk;
//! it reads up to its last whole chunk and says where and why it ends.

use mcap::read::Options as ReadOptions;
use mcap::records::Record;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A recording, in memory.
pub struct Recording {
    pub path: PathBuf,
    bytes: Vec<u8>,
    /// The `adrive` metadata record: vehicle, config, adrive's version, start time.
    pub metadata: BTreeMap<String, String>,
    /// Whole chunks in the file.
    pub chunks: usize,
    /// The file was finished (its summary and footer are there).
    pub complete: bool,
    /// Where the readable part ends early, and why (a cut-off recording).
    pub cut: Option<String>,
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
        let bytes = std::fs::read(path).map_err(|e| fail(format!("cannot read: {e}")))?;
        if !bytes.starts_with(mcap::MAGIC) {
            return Err(fail("not an MCAP file (no MCAP magic at its start)".into()));
        }
        let mut r = Recording {
            path: path.to_path_buf(),
            bytes,
            metadata: BTreeMap::new(),
            chunks: 0,
            complete: false,
            cut: None,
        };
        let records = mcap::read::LinearReader::new_with_options(
            &r.bytes,
            ReadOptions::IgnoreEndMagic.into(),
        )
        .map_err(|e| fail(e.to_string()))?;
        let mut metadata = BTreeMap::new();
        let (mut chunks, mut complete, mut cut) = (0, false, None);
        for record in records {
            match record {
                Ok(Record::Chunk { .. }) => chunks += 1,
                Ok(Record::Metadata(m)) if m.name == super::message::METADATA => {
                    metadata = m.metadata
                }
                Ok(Record::Footer(_)) => complete = true,
                Ok(_) => {}
                Err(e) => {
                    cut = Some(format!("ends after chunk {chunks}: {e}"));
                    break;
                }
            }
        }
        if !complete && cut.is_none() {
            cut = Some(format!("ends after chunk {chunks} without its summary"));
        }
        (r.metadata, r.chunks, r.complete, r.cut) = (metadata, chunks, complete, cut);
        Ok(r)
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
