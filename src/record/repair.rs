//! `adrive record repair FILE [--out OUT]`: a finished copy of a recording that was
//! not finished — every message that can be read, in order, with its channels, the
//! metadata that says what recorded it and where the copy comes from, then the
//! summary and index — for a tool that insists on an index, or a file cut inside a
//! chunk that a reader looking at its end refuses. The copy goes next to the file
//! (`drive.mcap` → `drive.repaired.mcap`) or to `--out`; an existing file is never
//! overwritten.

use super::read::{ReadError, Recording};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// What a repair wrote.
#[derive(Debug)]
pub(crate) struct Repaired {
    pub out: PathBuf,
    pub messages: u64,
    pub channels: usize,
}

/// Where the copy of `file` goes without `--out`: beside it, `NAME.repaired.mcap`.
pub(crate) fn beside(file: &Path) -> PathBuf {
    let stem = file
        .file_stem()
        .map_or_else(|| "recording".into(), |s| s.to_string_lossy().to_string());
    file.with_file_name(format!("{stem}.repaired.mcap"))
}

/// Write the finished copy of `rec` to `out`, which must not exist. Returns what it
/// wrote; a copy that cannot be written whole is removed.
pub(crate) fn repair(rec: &Recording, out: &Path, why: &str) -> Result<Repaired, ReadError> {
    let fail = |p: &Path, message: String| ReadError {
        path: p.display().to_string(),
        message,
    };
    let file = File::create_new(out).map_err(|e| match e.kind() {
        std::io::ErrorKind::AlreadyExists => fail(
            out,
            "exists, and is not overwritten: remove it, or name another file with --out".into(),
        ),
        _ => fail(out, format!("cannot create: {e}")),
    })?;
    let written = write(rec, BufWriter::new(file), why);
    match written {
        Ok(r) => Ok(Repaired {
            out: out.to_path_buf(),
            ..r
        }),
        Err(e) => {
            let _ = std::fs::remove_file(out);
            Err(fail(out, e.to_string()))
        }
    }
}

fn write(rec: &Recording, w: BufWriter<File>, why: &str) -> anyhow::Result<Repaired> {
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile(super::message::PROFILE)
        .library(format!("adrive {}", env!("CARGO_PKG_VERSION")))
        .create(w)?;
    let mut metadata: BTreeMap<String, String> = rec.metadata.clone();
    metadata.insert(
        "repaired_from".into(),
        format!("{}: {why}", rec.path.display()),
    );
    writer.write_metadata(&mcap::write::Metadata {
        name: super::message::METADATA.into(),
        metadata,
    })?;
    let mut messages = 0;
    let mut topics = std::collections::HashSet::new();
    let stream = mcap::MessageStream::new_with_options(
        rec.data(),
        mcap::read::Options::IgnoreEndMagic.into(),
    )?;
    // A stream that cannot be read further ends at the last whole chunk.
    for m in stream.map_while(Result::ok) {
        topics.insert(m.channel.topic.clone());
        writer.write(&m)?;
        messages += 1;
    }
    writer.finish()?;
    let mut w = writer.into_inner();
    w.flush()?;
    w.get_ref().sync_all()?;
    Ok(Repaired {
        out: PathBuf::new(),
        messages,
        channels: topics.len(),
    })
}
