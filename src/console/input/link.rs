//! The console's half of the liveness check: when to ask the terminal for a round trip,
//! and which answers count.
//!
//! A terminal answers a device status request by itself (`CSI 6 n` → the cursor
//! position), so an answer proves the whole way from adrive to the operator's screen
//! and back: the request was written after the frame before it, so the terminal had
//! read (and drawn) that frame. While the console commands, it asks every [`EVERY`]
//! and hands every answer to its controls as a proof ([`Controls::answered`]); the
//! engine's gate monitor, not the console, holds the bound from the last proof (the
//! console's loop may itself be what is stuck). It asks too while a characterization it
//! started from the bench runs, whose own thread holds the same bound
//! (`characterize/background.rs`). A console that only watches does not ask. An answer counts only against a request the console made: the same bytes
//! are Shift+F3 on a legacy terminal.
//!
//! [`Controls::answered`]: crate::controls::Controls::answered

use std::time::{Duration, Instant};

/// How often a commanding console asks.
pub(crate) const EVERY: Duration = Duration::from_millis(250);
/// The request: a device status report of the cursor position.
pub(crate) const ASK: &[u8] = b"\x1b[6n";

/// Requests made and not answered yet, and when the next is due.
#[derive(Debug, Default)]
pub(crate) struct RoundTrips {
    /// When the next request is due (`None`: not commanding).
    next: Option<Instant>,
    waiting: u32,
}

impl RoundTrips {
    /// Ask now? Only while the console commands (`commanding`), every [`EVERY`] from the
    /// first. A console that starts commanding again starts afresh.
    pub(crate) fn due(&mut self, commanding: bool, now: Instant) -> bool {
        if !commanding {
            self.next = None;
            return false;
        }
        let next = *self.next.get_or_insert_with(|| {
            self.waiting = 0;
            now
        });
        if now < next {
            return false;
        }
        self.waiting = self.waiting.saturating_add(1);
        // On schedule; after a late turn, a period from now.
        let after = next + EVERY;
        self.next = Some(if after > now { after } else { now + EVERY });
        true
    }

    /// A cursor position report came: does it answer a request of ours?
    pub(crate) fn answered(&mut self) -> bool {
        if self.waiting == 0 {
            return false;
        }
        self.waiting -= 1;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn asks_every_period_while_commanding_only() {
        let t = Instant::now();
        let mut r = RoundTrips::default();
        assert!(!r.due(false, t));
        assert!(r.due(true, t), "at once when it starts commanding");
        assert!(!r.due(true, t + EVERY / 2));
        assert!(r.due(true, t + EVERY));
        assert!(r.answered() && r.answered());
        assert!(!r.answered(), "a report nobody asked for is no proof");
        assert!(!r.due(false, t + EVERY * 2));
        assert!(!r.due(false, t + EVERY * 3), "never while watching");
    }

    /// A loop that was busy asks once when it comes back, not once per period missed.
    #[test]
    fn a_late_turn_asks_once() {
        let t = Instant::now();
        let mut r = RoundTrips::default();
        assert!(r.due(true, t));
        assert!(r.due(true, t + EVERY * 10));
        assert!(!r.due(true, t + EVERY * 10 + EVERY / 2));
        assert!(r.due(true, t + EVERY * 11));
    }

    #[test]
    fn commanding_again_forgets_requests_never_answered() {
        let t = Instant::now();
        let mut r = RoundTrips::default();
        for i in 0..5 {
            assert!(r.due(true, t + EVERY * i));
        }
        r.due(false, t + EVERY * 6);
        assert!(r.due(true, t + EVERY * 7));
        assert!(r.answered());
        assert!(!r.answered());
    }
}
