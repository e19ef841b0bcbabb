//! Logging through `tracing`: to stderr in headless mode (coloured on a terminal,
//! plain text elsewhere), and always to a daily rolling file, plain text, through
//! `tracing-appender`'s non-blocking writer. The returned guard flushes
//! the file when dropped, so every exit path keeps it alive until the very end.

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
pub const LOG_QUEUE: usize = 4096;

/// Keeps the log file writer alive; dropping it flushes the file.
pub struct LogGuard {
    _file: Option<WorkerGuard>,
}

/// Start logging. `stderr`: also log to standard error (headless, subcommands).
/// `dir`: where the rolling log file `adrive.log.YYYY-MM-DD` goes.
pub fn init(stderr: bool, dir: Option<&Path>) -> std::io::Result<LogGuard> {
    init_with(stderr, dir, Vec::new())
}

/// A layer added beside the file and stderr layers (e.g. the console's log pane).
pub type ExtraLayer = Box<dyn Layer<Registry> + Send + Sync>;

/// [`init`] with extra layers (the console's log pane, a recording) that see every
/// event, unfiltered.
pub fn init_with(
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
        .try_init();
    Ok(LogGuard { _file: guard })
}

/// Log at most `per_second` lines a second; count the rest and say how many were left
/// out when the next second opens.
pub struct RateLimit {
    per_second: u32,
    window: Instant,
    logged: u32,
    suppressed: u64,
}

impl RateLimit {
    pub fn new(per_second: u32) -> RateLimit {
        RateLimit {
            per_second,
            window: Instant::now(),
            logged: 0,
            suppressed: 0,
        }
    }

    /// May a line be logged now?
    pub fn allow(&mut self, now: Instant) -> bool {
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
