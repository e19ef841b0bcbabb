//! The part of a simulated device that is its firmware rather than its port: the
//! communication-loss watchdog that drive-by-wire gas and brake actuators carry.
//!
//! A real actuator's microcontroller keeps running when its USB link drops, so its
//! watchdog does too: with no command frame for the configured time, the gas goes to 0
//! and the brake on, whether the port is up, vanished or back. The simulator's device
//! thread asks [`Watchdog::expired`] on every turn of its loop, link up or down, and
//! feeds it each time the device applies a command. It is armed by the first command:
//! a device that never heard one has lost no commander, and sits where it powered up.

use std::time::{Duration, Instant};

/// One device's communication-loss watchdog.
#[derive(Debug)]
pub(crate) struct Watchdog {
    limit: Option<Duration>,
    /// The last command (`None`: none yet, the watchdog is not armed).
    last_command: Option<Instant>,
    tripped: bool,
}

impl Watchdog {
    /// A watchdog that trips `limit` after the last command (none: never), armed by the
    /// first command.
    pub(crate) fn new(limit: Option<Duration>) -> Watchdog {
        Watchdog {
            limit,
            last_command: None,
            tripped: false,
        }
    }

    pub(crate) fn limit(&self) -> Option<Duration> {
        self.limit
    }

    /// A command frame arrived at `now`: start counting again.
    pub(crate) fn feed(&mut self, now: Instant) {
        self.last_command = Some(now);
        self.tripped = false;
    }

    /// True once, when `now` is past the limit since the last command; the device then
    /// goes to its safe state. It trips again only after being fed.
    pub(crate) fn expired(&mut self, now: Instant) -> bool {
        let (Some(limit), Some(last)) = (self.limit, self.last_command) else {
            return false;
        };
        if self.tripped || now.saturating_duration_since(last) <= limit {
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
        let mut w = Watchdog::new(Some(ms(100)));
        w.feed(t);
        assert!(!w.expired(t + ms(100)));
        assert!(w.expired(t + ms(101)));
        assert!(!w.expired(t + ms(500)), "once");
        w.feed(t + ms(600));
        assert!(!w.expired(t + ms(650)));
        assert!(w.expired(t + ms(701)));
    }

    /// The incident: every `adrive sim` printed `gas <- 0.000  device watchdog: no
    /// command for 1s` a second after its start, as if a command had arrived, and a
    /// headless run logged "going safe": the watchdog counted from power-up.
    #[test]
    fn a_device_that_never_heard_a_command_never_trips() {
        let t = Instant::now();
        let mut w = Watchdog::new(Some(Duration::from_millis(100)));
        // Asked every turn, it still never trips: nothing armed it.
        assert!(!w.expired(t + Duration::from_secs(3600)));
        assert!(!w.expired(t + Duration::from_secs(3601)));
        w.feed(t + Duration::from_secs(3600));
        assert!(w.expired(t + Duration::from_millis(3_600_101)));
    }

    #[test]
    fn without_a_limit_it_never_trips() {
        let t = Instant::now();
        let mut w = Watchdog::new(None);
        assert!(!w.expired(t + Duration::from_secs(3600)));
    }
}
