//! The part of a simulated device that is its firmware rather than its port: the
//! communication-loss watchdog that drive-by-wire gas and brake actuators carry.
//!
//! A real actuator's microcontroller keeps running when its USB link drops, so its
//! watchdog does too: with no command frame for the configured time, the gas goes to 0
//! and the brake on, whether the port is up, vanished or back. The simulator's device
//! thread asks [`Watchdog::expired`] on every turn of its loop, link up or down, and
//! feeds it each time the device applies a command.

use std::time::{Duration, Instant};

/// One device's communication-loss watchdog.
#[derive(Debug)]
pub struct Watchdog {
    limit: Option<Duration>,
    last_command: Instant,
    tripped: bool,
}

impl Watchdog {
    /// A watchdog that trips `limit` after the last command (none: never), armed from
    /// `now` (the device powering up).
    pub fn new(limit: Option<Duration>, now: Instant) -> Watchdog {
        Watchdog {
            limit,
            last_command: now,
            tripped: false,
        }
    }

    pub fn limit(&self) -> Option<Duration> {
        self.limit
    }

    /// A command frame arrived at `now`: start counting again.
    pub fn feed(&mut self, now: Instant) {
        self.last_command = now;
        self.tripped = false;
    }

    /// True once, when `now` is past the limit since the last command; the device then
    /// goes to its safe state. It trips again only after being fed.
    pub(crate) fn expired(&mut self, now: Instant) -> bool {
        let Some(limit) = self.limit else {
            return false;
        };
        if self.tripped || now.saturating_duration_since(self.last_command) <= limit {
            return false;
        }
        self.tripped = true;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trips_once_after_the_limit_and_again_only_after_a_command() {
        let t = Instant::now();
        let ms = Duration::from_millis;
        let mut w = Watchdog::new(Some(ms(100)), t);
        assert!(!w.expired(t + ms(100)));
        assert!(w.expired(t + ms(101)));
        assert!(!w.expired(t + ms(500)), "once");
        w.feed(t + ms(600));
        assert!(!w.expired(t + ms(650)));
        assert!(w.expired(t + ms(701)));
    }

    #[test]
    fn without_a_limit_it_never_trips() {
        let t = Instant::now();
        let mut w = Watchdog::new(None, t);
        assert!(!w.expired(t + Duration::from_secs(3600)));
    }
}
