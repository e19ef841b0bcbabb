//! The `[record]` section of a vehicle file: record every run into a directory of
//! MCAP files, a new file when the current one reaches `roll_size` or `roll_age`,
//! keeping the newest `keep`. Without the section nothing is recorded unless
//! `--record` asks. These settings are not safety-relevant (a recording never holds the
//! vehicle up), so they are checked here for sense, not in the limits table.

use super::limits::Violation;
use serde::{Deserialize, Deserializer};
use std::path::PathBuf;
use std::time::Duration;

/// The smallest file worth rolling to: a few seconds of a busy vehicle.
pub(crate) const MIN_ROLL_SIZE: u64 = 1_000_000;
/// The shortest age worth rolling at.
pub(crate) const MIN_ROLL_AGE: Duration = Duration::from_secs(10);

/// `[record]`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordConfig {
    /// Where the files go; relative to the vehicle file's directory.
    pub dir: PathBuf,
    /// Start a new file once this one holds this many bytes.
    #[serde(default = "default_roll_size", deserialize_with = "size")]
    pub(crate) roll_size: u64,
    /// Start a new file once this one is this old.
    #[serde(default = "default_roll_age", deserialize_with = "super::duration")]
    pub(crate) roll_age: Duration,
    /// Keep at most this many files of this vehicle in `dir`, deleting the oldest
    /// (0: keep every file).
    #[serde(default)]
    pub keep: usize,
    /// Record the raw serial traffic of every device too.
    #[serde(default)]
    pub raw: bool,
}

fn default_roll_size() -> u64 {
    100_000_000
}

fn default_roll_age() -> Duration {
    Duration::from_secs(600)
}

impl RecordConfig {
    /// Every value makes sense.
    pub fn check(&self) -> Result<(), Violation> {
        let bad = |key: &str, message: String| {
            Err(Violation {
                paths: vec![key.into()],
                message,
            })
        };
        if self.dir.as_os_str().is_empty() {
            return bad(
                "dir",
                "dir: expected a directory for the recordings (\"recordings\")".into(),
            );
        }
        if self.roll_size < MIN_ROLL_SIZE {
            return bad(
                "roll_size",
                format!(
                    "roll_size: expected a size of at least 1 MB (\"100 MB\", \"1 GiB\"), got {} bytes",
                    self.roll_size
                ),
            );
        }
        if self.roll_age < MIN_ROLL_AGE {
            return bad(
                "roll_age",
                format!(
                    "roll_age: expected a duration of at least 10s (\"10m\", \"1h\"), got {}",
                    super::fmt_duration(self.roll_age)
                ),
            );
        }
        Ok(())
    }
}

/// A size written as `"100 MB"`, `"512KiB"`, `"1 GiB"` (or a number of bytes).
pub(crate) fn parse_size(s: &str) -> Result<u64, String> {
    s.trim()
        .parse::<bytesize::ByteSize>()
        .map(|b| b.as_u64())
        .map_err(|_| format!("expected a size such as \"100 MB\" or \"1 GiB\", got {s:?}"))
}

fn size<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Size {
        Bytes(u64),
        Text(String),
    }
    match Size::deserialize(d)? {
        Size::Bytes(n) => Ok(n),
        Size::Text(s) => parse_size(&s).map_err(serde::de::Error::custom),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(extra: &str) -> Result<crate::config::VehicleConfig, String> {
        crate::config::parse(
            &format!("[vehicle]\nname = \"x\"\n\n[record]\n{extra}"),
            "v.toml",
        )
        .map_err(|e| e.to_string())
    }

    #[test]
    fn a_record_table_with_defaults() {
        let c = parse("dir = \"rec\"\n").unwrap();
        let r = c.record.unwrap();
        assert_eq!(r.dir, PathBuf::from("rec"));
        assert_eq!(r.roll_size, 100_000_000);
        assert_eq!(r.roll_age, Duration::from_secs(600));
        assert_eq!((r.keep, r.raw), (0, false));
        assert!(crate::config::VehicleConfig::alice().record.is_none());
    }

    #[test]
    fn sizes_and_ages_are_read_in_units() {
        let r = parse(
            "dir = \"rec\"\nroll_size = \"5 MiB\"\nroll_age = \"1h\"\nkeep = 3\nraw = true\n",
        )
        .unwrap()
        .record
        .unwrap();
        assert_eq!(r.roll_size, 5 * 1024 * 1024);
        assert_eq!(r.roll_age, Duration::from_secs(3600));
        assert_eq!((r.keep, r.raw), (3, true));
    }

    #[test]
    fn record_errors_name_file_line_and_form() {
        let e = parse("dir = \"rec\"\nroll_size = \"lots\"\n").unwrap_err();
        assert!(
            e.starts_with("v.toml:6: ") && e.contains("expected a size such as"),
            "{e}"
        );
        let e = parse("dir = \"rec\"\nroll_size = \"10 kB\"\n").unwrap_err();
        assert!(
            e.starts_with("v.toml:6: [record] roll_size: expected a size of at least 1 MB"),
            "{e}"
        );
        let e = parse("dir = \"rec\"\nroll_age = \"1s\"\n").unwrap_err();
        assert!(
            e.starts_with("v.toml:6: [record] roll_age: expected a duration of at least 10s"),
            "{e}"
        );
        let e = parse("roll_age = \"1m\"\n").unwrap_err();
        assert!(e.starts_with("v.toml:4: ") && e.contains("dir"), "{e}");
        let e = parse("dri = \"rec\"\n").unwrap_err();
        assert!(e.starts_with("v.toml:5: ") && e.contains("dri"), "{e}");
        let e = crate::config::parse("[vehicle]\nname = \"x\"\n[recrod]\ndir = \"r\"\n", "v.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("did you mean [record]"), "{e}");
    }
}
