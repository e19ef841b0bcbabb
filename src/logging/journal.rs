//! The journal's native protocol (`sd_journal_send(3)`, `systemd.journal-fields(7)`):
//! each event one datagram to journald's socket, its fields as journal fields
//! (`device=steer` as `DEVICE=steer`, for `journalctl -u adrive DEVICE=steer`), its
//! level as the priority, and the thread that logged it (`THREAD_NAME=steer/status`).
//!
//! Written here rather than taken from `tracing-journald`, which keeps the fields only
//! as fields: its `MESSAGE` holds the message alone, so `journalctl -u adrive` showed
//! `figures`, `network up` and `engine started` with none of their figures, address or
//! threads. Here `MESSAGE` is the line the log file has (`figures device=steer
//! polls=400 …`), and the fields are there too.

use std::fmt::Write as _;
use std::io;
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::layer::Context;

/// Where journald listens for native messages.
pub(crate) const SOCKET: &str = "/run/systemd/journal/socket";

/// A `tracing` layer writing each event to the journal.
pub(crate) struct Journal {
    socket: UnixDatagram,
    to: PathBuf,
}

impl Journal {
    /// The journal at `path` (journald's is [`SOCKET`]), if something listens there.
    pub(crate) fn at(path: &Path) -> io::Result<Journal> {
        let socket = UnixDatagram::unbound()?;
        // journald drops an empty datagram; sending one tells whether it listens.
        socket.send_to(&[], path)?;
        Ok(Journal {
            socket,
            to: path.to_path_buf(),
        })
    }

    /// One event's datagram.
    fn entry(event: &Event<'_>) -> Vec<u8> {
        let meta = event.metadata();
        let mut fields = Fields::default();
        event.record(&mut fields);
        let mut buf = Vec::with_capacity(256);
        let mut message = fields.message;
        message.push_str(&fields.text);
        put(&mut buf, "MESSAGE", &message);
        put(&mut buf, "PRIORITY", priority(*meta.level()));
        put(&mut buf, "SYSLOG_IDENTIFIER", "adrive");
        put(&mut buf, "TARGET", meta.target());
        if let Some(file) = meta.file() {
            put(&mut buf, "CODE_FILE", file);
        }
        if let Some(line) = meta.line() {
            put(&mut buf, "CODE_LINE", &line.to_string());
        }
        if let Some(name) = std::thread::current().name() {
            put(&mut buf, "THREAD_NAME", name);
        }
        for (name, value) in &fields.pairs {
            put(&mut buf, name, value);
        }
        buf
    }
}

impl<S: Subscriber> tracing_subscriber::Layer<S> for Journal {
    fn on_event(&self, event: &Event<'_>, _: Context<'_, S>) {
        // A line that cannot be sent (journald restarting, a datagram too large) is
        // lost to the journal only: the log file has it.
        let _ = self.socket.send_to(&Journal::entry(event), &self.to);
    }
}

/// syslog's priorities, as `journalctl -p` filters them.
fn priority(level: Level) -> &'static str {
    match level {
        Level::ERROR => "3",
        Level::WARN => "4",
        Level::INFO => "6",
        Level::DEBUG | Level::TRACE => "7",
    }
}

/// `KEY=value\n`; a value with a newline in the binary form: `KEY\n`, its length as
/// a little-endian u64, the value, `\n`.
fn put(buf: &mut Vec<u8>, key: &str, value: &str) {
    buf.extend_from_slice(key.as_bytes());
    if value.contains('\n') {
        buf.push(b'\n');
        buf.extend_from_slice(&(value.len() as u64).to_le_bytes());
    } else {
        buf.push(b'=');
    }
    buf.extend_from_slice(value.as_bytes());
    buf.push(b'\n');
}

/// The names journald keeps for what this module writes itself.
const OWN: [&str; 7] = [
    "MESSAGE",
    "PRIORITY",
    "SYSLOG_IDENTIFIER",
    "TARGET",
    "CODE_FILE",
    "CODE_LINE",
    "THREAD_NAME",
];

/// A tracing field's name as a journal field's: upper case, letters, digits and `_`,
/// starting with a letter (a leading `_` would claim to be journald's own), at most 64
/// bytes; one that would collide with a field written here gets `F_` in front.
fn field_name(name: &str) -> String {
    let mut s: String = name
        .chars()
        .map(|c| match c {
            'a'..='z' => c.to_ascii_uppercase(),
            'A'..='Z' | '0'..='9' => c,
            _ => '_',
        })
        .collect::<String>()
        .trim_start_matches(|c: char| c == '_' || c.is_ascii_digit())
        .to_string();
    if s.is_empty() || OWN.contains(&s.as_str()) {
        s.insert_str(0, "F_");
    }
    s.truncate(64);
    s
}

/// An event's message, its other fields as text (` key=value`, as in the log file)
/// and as journal fields.
#[derive(Default)]
struct Fields {
    message: String,
    text: String,
    pairs: Vec<(String, String)>,
}

impl Visit for Fields {
    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "message" {
            self.message.push_str(value);
        } else {
            let _ = write!(self.text, " {}={value}", field.name());
            self.pairs
                .push((field_name(field.name()), value.to_string()));
        }
    }

    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        let value = format!("{value:?}");
        if field.name() == "message" {
            self.message.push_str(&value);
        } else {
            let _ = write!(self.text, " {}={value}", field.name());
            self.pairs.push((field_name(field.name()), value));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracing_subscriber::layer::SubscriberExt;

    /// The journal's datagram, parsed back: each field's values in order.
    fn parse(mut d: &[u8]) -> Vec<(String, String)> {
        let mut out = Vec::new();
        while !d.is_empty() {
            let nl = d.iter().position(|&b| b == b'\n').unwrap();
            let line = &d[..nl];
            if let Some(eq) = line.iter().position(|&b| b == b'=') {
                let (k, v) = (&line[..eq], &line[eq + 1..]);
                out.push((
                    String::from_utf8(k.to_vec()).unwrap(),
                    String::from_utf8(v.to_vec()).unwrap(),
                ));
                d = &d[nl + 1..];
            } else {
                let key = String::from_utf8(line.to_vec()).unwrap();
                let len = u64::from_le_bytes(d[nl + 1..nl + 9].try_into().unwrap()) as usize;
                let value = String::from_utf8(d[nl + 9..nl + 9 + len].to_vec()).unwrap();
                assert_eq!(d[nl + 9 + len], b'\n');
                out.push((key, value));
                d = &d[nl + 10 + len..];
            }
        }
        out
    }

    fn get<'a>(fields: &'a [(String, String)], key: &str) -> Vec<&'a str> {
        fields
            .iter()
            .filter(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
            .collect()
    }

    /// `journalctl -u adrive` shows the whole line, `DEVICE=steer` selects it, `-p
    /// warning` keeps it, and the thread that logged it is named.
    #[test]
    fn an_event_reaches_the_journal_as_its_line_and_its_fields() {
        let dir = tempfile::Builder::new()
            .prefix("adrive-journal-")
            .tempdir()
            .unwrap();
        let path = dir.path().join("socket");
        let journald = UnixDatagram::bind(&path).unwrap();
        journald
            .set_read_timeout(Some(std::time::Duration::from_secs(10)))
            .unwrap();
        let journal = Journal::at(&path).unwrap();
        let mut buf = vec![0; 65536];
        assert_eq!(journald.recv(&mut buf).unwrap(), 0, "the probe is empty");
        let subscriber = tracing_subscriber::registry().with(journal);
        std::thread::Builder::new()
            .name("steer/status".into())
            .spawn(move || {
                tracing::subscriber::with_default(subscriber, || {
                    let name = "steer";
                    tracing::warn!(device = %name, polls = 400, priority = "high", "figures");
                    tracing::error!("two\nlines");
                })
            })
            .unwrap()
            .join()
            .unwrap();
        let n = journald.recv(&mut buf).unwrap();
        let f = parse(&buf[..n]);
        assert_eq!(
            get(&f, "MESSAGE"),
            ["figures device=steer polls=400 priority=high"]
        );
        assert_eq!(get(&f, "DEVICE"), ["steer"]);
        assert_eq!(get(&f, "POLLS"), ["400"]);
        assert_eq!(get(&f, "PRIORITY"), ["4"], "a warning");
        assert_eq!(get(&f, "F_PRIORITY"), ["high"], "a field named like ours");
        assert_eq!(get(&f, "SYSLOG_IDENTIFIER"), ["adrive"]);
        assert_eq!(get(&f, "THREAD_NAME"), ["steer/status"]);
        assert_eq!(get(&f, "CODE_FILE"), [file!()]);
        let n = journald.recv(&mut buf).unwrap();
        let f = parse(&buf[..n]);
        assert_eq!(get(&f, "MESSAGE"), ["two\nlines"]);
        assert_eq!(get(&f, "PRIORITY"), ["3"]);
    }

    #[test]
    fn field_names_become_journal_field_names() {
        assert_eq!(field_name("device"), "DEVICE");
        assert_eq!(field_name("delay_p99_us"), "DELAY_P99_US");
        assert_eq!(field_name("r#type"), "R_TYPE");
        assert_eq!(field_name("_private"), "PRIVATE");
        assert_eq!(field_name("9lives"), "LIVES");
        assert_eq!(field_name("message_id"), "MESSAGE_ID");
        assert_eq!(field_name("target"), "F_TARGET");
        assert_eq!(field_name("_"), "F_");
        assert_eq!(field_name(&"x".repeat(80)).len(), 64);
    }

    #[test]
    fn nothing_listening_is_an_error_at_the_start() {
        let dir = tempfile::Builder::new()
            .prefix("adrive-journal-")
            .tempdir()
            .unwrap();
        assert!(Journal::at(&dir.path().join("none")).is_err());
    }
}
