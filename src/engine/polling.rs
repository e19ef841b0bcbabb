//! When a status thread polls: the paper's fixed period, or — answering the paper's
//! open problem — by the estimate's confidence (`polling = "adaptive"`), leaving the
//! serial line to commands while the estimate is good enough.
//!
//! The status thread wakes every `status_period` (the fastest period); an adaptive
//! device is polled at a wake-up only when one of these holds:
//!
//! - it was never read;
//! - its command changed (beyond the tolerance) since the last poll;
//! - the last reading was a surprise (far outside its prediction);
//! - the estimate's σ passes the tolerance before the next wake-up;
//! - its reading would otherwise grow older than `status_max_age` (the slowest period:
//!   the poll is started a reply timeout early, so its answer still comes in time).
//!
//! So it returns to the fastest period within one period of a change or a surprise,
//! and stretches toward the slowest under a steady command.

use crate::config::Polling;
use crate::vehicle::Device;
use std::time::Instant;

/// What an adaptive status thread remembers of its last poll.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Schedule {
    /// When the last poll started.
    last: Option<Instant>,
    /// The command the estimator moved to when the last poll ended.
    command: Option<f64>,
    /// The last reading was a surprise.
    surprised: bool,
}

impl Schedule {
    /// Whether the status thread of `d` polls at this wake-up, at `now`.
    pub(crate) fn due(&self, d: &Device, now: Instant) -> bool {
        if d.config().polling == Polling::Fixed {
            return true;
        }
        let (Some(last), Some(e)) = (self.last, d.estimator()) else {
            return true;
        };
        let period = d.settings().status_period();
        let tolerance = e.response().tolerance;
        let changed = match (self.command, e.commanded()) {
            (Some(a), Some(b)) => (a - b).abs() > tolerance,
            (a, b) => a.is_some() != b.is_some(),
        };
        let oldest = d
            .config()
            .status_max_age
            .saturating_sub(d.config().reply_timeout);
        let too_old = now.saturating_duration_since(last) + period > oldest;
        let unsure = e.at(now + period).is_none_or(|x| x.sigma > tolerance);
        self.surprised || changed || too_old || unsure
    }

    /// A poll of `d` starts at `at` (a command acknowledged while it runs counts as a
    /// change after it).
    pub(crate) fn start(&mut self, d: &Device, at: Instant) {
        self.last = Some(at);
        self.command = d.estimator().and_then(|e| e.commanded());
    }

    /// The poll ended; `surprised`: its reading was far outside the prediction.
    pub(crate) fn finish(&mut self, surprised: bool) {
        self.surprised = surprised;
    }
}
