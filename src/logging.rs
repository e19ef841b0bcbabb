//! Logging through `tracing`: to stderr in headless mode (coloured on a terminal,
//! plain text elsewhere), and always to a daily rolling file, plain text, through
//! `tracing-appender`'s non-blocking writer. The returned guard flushes
//! the file when dropped, so every exit path keeps it alive until the very end.
//!
//! Run by systemd (its `JOURNAL_STREAM` names the stderr adrive has), the stderr lines
//! go to the journal instead ([`journal`](mod@journal)), each event with its fields as journal
//! fields (`device=steer` as `DEVICE=steer`, so `journalctl -u adrive DEVICE=steer`
//! finds a device's lines) and its level as the journal's priority.

pub(crate) mod journal;
pub mod ring;

use std::fmt::Write as _;
use std::io::IsTerminal;
use std::path::Path;
use std::time::{Duration, Instant};
use tracing::field::{Field, Visit};
use tracing_appender::non_blocking::WorkerGuard;
use tracing_subscriber::filter::LevelFilter;
use tracing_subscriber::layer::Filter;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{fmt, EnvFilter, Layer, Registry};

/// What is logged: `RUST_LOG` when set (`debug`, `adrive=trace`, any `EnvFilter`
/// directive), else `info`. Without `RUST_LOG` no filter is parsed: `EnvFilter`
/// compiles regular expressions at start, half a megabyte of code and heap that a
/// plain level does without.
fn filter<S>() -> Box<dyn Filter<S> + Send + Sync>
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
{
    match std::env::var("RUST_LOG") {
        Ok(v) if !v.trim().is_empty() => {
            Box::new(EnvFilter::try_new(v).unwrap_or_else(|_| EnvFilter::new("info")))
        }
        _ => Box::new(LevelFilter::INFO),
    }
}

/// Log lines queued for the file writer at most.
pub(crate) const LOG_QUEUE: usize = 4096;

/// Keeps the log file writer alive; dropping it flushes the file.
pub(crate) struct LogGuard {
    _file: Option<WorkerGuard>,
}

/// Start logging. `stderr`: also log to standard error (headless, subcommands).
/// `dir`: where the rolling log file `adrive.log.YYYY-MM-DD` goes.
pub(crate) fn init(stderr: bool, dir: Option<&Path>) -> std::io::Result<LogGuard> {
    init_with(stderr, dir, Vec::new())
}

/// A layer added beside the file and stderr layers (e.g. the console's log pane).
pub(crate) type ExtraLayer = Box<dyn Layer<Registry> + Send + Sync>;

/// [`init`] with extra layers (the console's log pane, a recording) that see every
/// event, unfiltered.
pub(crate) fn init_with(
    stderr: bool,
    dir: Option<&Path>,
    extra: Vec<ExtraLayer>,
) -> std::io::Result<LogGuard> {
    // An empty list of layers is a layer that enables nothing, which would silence the
    // file and stderr layers beside it: no list, then.
    let extra = (!extra.is_empty()).then_some(extra);
    let (file_layer, guard) = match dir {
        Some(dir) => {
            std::fs::create_dir_all(dir)?;
            let appender = tracing_appender::rolling::daily(dir, "adrive.log");
            // The writer's queue is allocated whole up front: 128,000 lines by default,
            // 4 MB resident from the start. Lines are rate-limited where they could
            // flood, so a few thousand are plenty; past that they are dropped (counted
            // by tracing-appender), never waited for.
            let (writer, guard) = tracing_appender::non_blocking::NonBlockingBuilder::default()
                .buffered_lines_limit(LOG_QUEUE)
                .lossy(true)
                .finish(appender);
            let layer = fmt::layer()
                .with_writer(writer)
                .with_ansi(false)
                .with_thread_names(true)
                .with_filter(filter());
            (Some(layer), Some(guard))
        }
        None => (None, None),
    };
    let journal_layer = stderr.then(journal).flatten();
    let stderr = stderr && journal_layer.is_none();
    let journal_layer = journal_layer.map(|l| l.with_filter(filter()));
    let stderr_layer = stderr.then(|| {
        let mut layer = fmt::layer()
            .with_writer(std::io::stderr)
            .with_thread_names(true);
        // Colour (unless NO_COLOR, tracing-subscriber's default) on a terminal only:
        // a file, a pipe or a journal gets plain text.
        if !std::io::stderr().is_terminal() {
            layer.set_ansi(false);
        }
        layer.with_filter(filter())
    });
    let _ = tracing_subscriber::registry()
        .with(extra)
        .with(file_layer)
        .with(stderr_layer)
        .with(journal_layer)
        .try_init();
    Ok(LogGuard { _file: guard })
}

/// The journal, when standard error is the stream systemd connected to it; `None`
/// elsewhere, or when journald cannot be reached (then stderr it is).
fn journal() -> Option<journal::Journal> {
    let stream = std::env::var("JOURNAL_STREAM").ok()?;
    let stat = rustix::fs::fstat(std::io::stderr()).ok()?;
    if !is_stream(&stream, stat.st_dev, stat.st_ino) {
        return None;
    }
    journal::Journal::at(Path::new(journal::SOCKET)).ok()
}

/// `JOURNAL_STREAM` (`DEVICE:INODE`, in decimal) names this device and inode: the
/// documented check (`systemd.exec(5)`) that stderr still is the stream systemd
/// connected to the journal, and not a file or terminal a child was given since.
fn is_stream(var: &str, dev: u64, ino: u64) -> bool {
    let Some((d, i)) = var.trim().split_once(':') else {
        return false;
    };
    d.parse() == Ok(dev) && i.parse() == Ok(ino)
}

/// Log at most `per_second` lines a second; count the rest and say how many were left
/// out when the next second opens.
pub(crate) struct RateLimit {
    per_second: u32,
    window: Instant,
    logged: u32,
    suppressed: u64,
}

impl RateLimit {
    pub(crate) fn new(per_second: u32) -> RateLimit {
        RateLimit {
            per_second,
            window: Instant::now(),
            logged: 0,
            suppressed: 0,
        }
    }

    /// May a line be logged now?
    pub(crate) fn allow(&mut self, now: Instant) -> bool {
        if now.saturating_duration_since(self.window) >= Duration::from_secs(1) {
            if self.suppressed > 0 {
                tracing::warn!(
                    "{} more similar lines not logged in the last second",
                    self.suppressed
                );
            }
            self.window = now;
            self.logged = 0;
            self.suppressed = 0;
        }
        if self.logged < self.per_second {
            self.logged += 1;
            true
        } else {
            self.suppressed += 1;
            false
        }
    }
}

/// How often a condition that lasts is logged again.
pub(crate) const REPEAT_EVERY: Duration = Duration::from_secs(60);

/// A condition that repeats — a device failing every poll, a port reopened again and
/// again, a broadcast that cannot be sent — logged once when it starts or changes, then
/// at most once every [`REPEAT_EVERY`] with how many times it came meanwhile
/// (`… (repeated 120 times in the last minute)`). [`RateLimit`] is for events that
/// differ (each rejected command); this is for the same words again. The same words
/// with other figures are the same condition (`it came 30.8 ms later`, then `28.4 ms
/// later`: a late reply logged at every poll, once): what changes it is its words.
#[derive(Debug, Default)]
pub struct Repeats {
    /// The shape of what was logged last ([`shape`]), and when.
    last: Option<(String, Instant)>,
    /// Times it came since it was last logged.
    unlogged: u64,
}

impl Repeats {
    /// `what` happened at `now`: `Some(suffix)` when it is to be logged — an empty
    /// suffix when it starts or changes, else how many times it repeated — `None`
    /// when it is only counted.
    pub fn note(&mut self, what: &str, now: Instant) -> Option<String> {
        let what = shape(what);
        match &mut self.last {
            Some((said, at)) if *said == what => {
                self.unlogged += 1;
                let since = now.saturating_duration_since(*at);
                if since < REPEAT_EVERY {
                    return None;
                }
                *at = now;
                let n = std::mem::take(&mut self.unlogged);
                let times = match n {
                    1 => "once".to_string(),
                    n => format!("{n} times"),
                };
                Some(match since.as_secs() / 60 {
                    0 | 1 => format!(" (repeated {times} in the last minute)"),
                    m => format!(" (repeated {times} in the last {m} minutes)"),
                })
            }
            _ => {
                self.last = Some((what, now));
                self.unlogged = 0;
                Some(String::new())
            }
        }
    }

    /// The condition is over: the next time it comes, it starts again (logged at once).
    pub fn clear(&mut self) {
        self.last = None;
        self.unlogged = 0;
    }
}

/// `what` with each figure (a run of digits, with its decimal point) as `#`: the
/// words that say which condition it is.
fn shape(what: &str) -> String {
    let mut out = String::with_capacity(what.len());
    let mut chars = what.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            while chars
                .peek()
                .is_some_and(|n| n.is_ascii_digit() || *n == '.')
            {
                chars.next();
            }
            out.push('#');
        } else {
            out.push(c);
        }
    }
    out
}

/// An event's words, for the layers that keep them (the console's log pane, a
/// recording): its message, then its other fields as ` key=value`.
#[derive(Default)]
pub struct EventText {
    pub message: String,
    pub fields: String,
}

impl EventText {
    pub fn of(event: &tracing::Event<'_>) -> EventText {
        let mut t = EventText::default();
        event.record(&mut t);
        t
    }

    /// `status: timeout device=steer`
    pub fn line(self) -> String {
        let mut s = self.message;
        s.push_str(&self.fields);
        s
    }
}

impl Visit for EventText {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            let _ = write!(self.message, "{value:?}");
        } else {
            let _ = write!(self.fields, " {}={value:?}", field.name());
        }
    }
    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "message" {
            self.message.push_str(value);
        } else {
            let _ = write!(self.fields, " {}={value}", field.name());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_journal_stream_is_stderr_only_when_device_and_inode_match() {
        assert!(is_stream("25:123456", 25, 123456));
        assert!(is_stream("25:123456\n", 25, 123456));
        assert!(!is_stream("25:123457", 25, 123456));
        assert!(!is_stream("26:123456", 25, 123456));
        for bad in ["", "25", "25:", ":123456", "x:y", "25:123456:7"] {
            assert!(!is_stream(bad, 25, 123456), "{bad:?}");
        }
    }

    /// A device failing twice a second for two minutes: logged when it starts, then
    /// once a minute with the count of the minute; a change of words is logged at once;
    /// after it cleared, the same words start again.
    #[test]
    fn a_repeating_condition_is_logged_once_then_once_a_minute_with_a_count() {
        let t0 = Instant::now();
        let mut r = Repeats::default();
        let logged: Vec<(u64, String)> = (0..240u64)
            .filter_map(|k| {
                let ms = 500 * k;
                r.note("timeout", t0 + Duration::from_millis(ms))
                    .map(|s| (ms, s))
            })
            .collect();
        assert_eq!(
            logged,
            [
                (0, String::new()),
                (60_000, " (repeated 120 times in the last minute)".into()),
            ]
        );
        let t = t0 + Duration::from_secs(120);
        assert_eq!(r.note("garbled", t), Some(String::new()), "a change");
        assert_eq!(r.note("garbled", t + Duration::from_secs(1)), None);
        r.clear();
        assert_eq!(
            r.note("garbled", t + Duration::from_secs(2)),
            Some(String::new())
        );
        // Rare: the count says over how long.
        assert_eq!(
            r.note("garbled", t + Duration::from_secs(302)),
            Some(" (repeated once in the last 5 minutes)".into())
        );
    }

    /// A late reply names how late it came, a different figure each poll: one
    /// condition, logged once (it was logged at every poll, 14 lines in 3 s); other
    /// words are another.
    #[test]
    fn the_same_words_with_other_figures_are_the_same_condition() {
        let t0 = Instant::now();
        let mut r = Repeats::default();
        let late = |ms: f64| format!("status: no reply within 100ms: it came {ms}ms later");
        assert_eq!(r.note(&late(30.796228), t0), Some(String::new()));
        assert_eq!(
            r.note(&late(28.397225), t0 + Duration::from_millis(50)),
            None
        );
        assert_eq!(r.note(&late(1033.5), t0 + Duration::from_millis(100)), None);
        assert_eq!(
            r.note("status: garbled reply", t0 + Duration::from_millis(150)),
            Some(String::new())
        );
        assert_eq!(shape("steer 0.25 in 12 ms, v1.2.3"), "steer # in # ms, v#");
    }
}
