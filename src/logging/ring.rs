//! The log pane's source: a `tracing` layer that keeps the last warnings and errors in
//! a small ring the console (and an attached console, through the socket) reads each
//! tick; it lives with the logging, below the console, so that core tests can read
//! what a user would see logged. It sits beside the file and stderr layers
//! (see [`crate::logging::init_with`]) and never blocks for long: one short lock per
//! warning.

use crate::logging::EventText;
use parking_lot::Mutex;
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Instant;
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::layer::Context;
use tracing_subscriber::Layer;

/// How many lines the ring keeps.
pub(crate) const KEEP: usize = 200;

/// One warning or error.
#[derive(Clone, Debug, PartialEq)]
pub struct LogLine {
    /// Seconds since the ring was made (the console's start).
    pub secs: f64,
    pub level: Level,
    pub text: String,
}

/// The shared ring; clone it to hand out.
#[derive(Clone)]
pub struct LogRing {
    /// The lines kept, and how many were ever pushed.
    inner: Arc<Mutex<(VecDeque<LogLine>, u64)>>,
    start: Instant,
}

impl Default for LogRing {
    fn default() -> Self {
        LogRing {
            inner: Arc::new(Mutex::new((VecDeque::with_capacity(KEEP), 0))),
            start: Instant::now(),
        }
    }
}

impl LogRing {
    /// The layer that fills this ring.
    pub fn layer(&self) -> RingLayer {
        RingLayer { ring: self.clone() }
    }

    pub fn push(&self, level: Level, text: String) {
        let mut g = self.inner.lock();
        g.1 += 1;
        let q = &mut g.0;
        if q.len() == KEEP {
            q.pop_front();
        }
        q.push_back(LogLine {
            secs: self.start.elapsed().as_secs_f64(),
            level,
            text,
        });
    }

    /// The lines kept, oldest first.
    pub(crate) fn recent(&self) -> Vec<LogLine> {
        self.inner.lock().0.iter().cloned().collect()
    }

    /// The lines pushed after the first `seen` (those still kept), and how many were
    /// pushed in all: what an attached console has not been sent yet.
    pub fn since(&self, seen: u64) -> (Vec<LogLine>, u64) {
        let g = self.inner.lock();
        let new = g.1.saturating_sub(seen).min(g.0.len() as u64) as usize;
        (g.0.iter().skip(g.0.len() - new).cloned().collect(), g.1)
    }
}

/// A `tracing` layer keeping WARN and ERROR events in a [`LogRing`].
pub struct RingLayer {
    ring: LogRing,
}

impl<S: Subscriber> Layer<S> for RingLayer {
    fn on_event(&self, event: &Event<'_>, _ctx: Context<'_, S>) {
        let level = *event.metadata().level();
        if level > Level::WARN {
            return;
        }
        self.ring.push(level, EventText::of(event).line());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracing_subscriber::layer::SubscriberExt;

    #[test]
    fn keeps_warnings_and_errors_only() {
        let ring = LogRing::default();
        let sub = tracing_subscriber::registry().with(ring.layer());
        tracing::subscriber::with_default(sub, || {
            tracing::info!("fine");
            tracing::warn!(device = "steer", "status: timeout");
            tracing::error!("boom");
        });
        let lines = ring.recent();
        assert_eq!(lines.len(), 2);
        assert_eq!(lines[0].text, "status: timeout device=steer");
        assert_eq!(lines[1].level, Level::ERROR);
    }

    #[test]
    fn since_gives_only_the_lines_not_seen_yet() {
        let ring = LogRing::default();
        ring.push(Level::WARN, "a".into());
        let (lines, seen) = ring.since(0);
        assert_eq!((lines.len(), seen), (1, 1));
        ring.push(Level::WARN, "b".into());
        ring.push(Level::ERROR, "c".into());
        let (lines, seen) = ring.since(seen);
        let texts: Vec<_> = lines.iter().map(|l| l.text.as_str()).collect();
        assert_eq!((texts, seen), (vec!["b", "c"], 3));
        assert!(ring.since(seen).0.is_empty());
        for i in 0..KEEP + 5 {
            ring.push(Level::WARN, i.to_string());
        }
        // More than the ring keeps: what it still has.
        assert_eq!(ring.since(seen).0.len(), KEEP);
    }

    #[test]
    fn the_ring_forgets_the_oldest() {
        let ring = LogRing::default();
        for i in 0..KEEP + 5 {
            ring.push(Level::WARN, i.to_string());
        }
        let lines = ring.recent();
        assert_eq!(lines.len(), KEEP);
        assert_eq!(lines[0].text, "5");
    }
}
