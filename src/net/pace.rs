//! How often `net/listen` looks at its socket under a flood.
//!
//! Each wake of a thread blocked on a socket costs this machine about as much as a
//! datagram's whole parse and intake (a bare receiver thread doing one `recv` per
//! datagram spends ~13 µs of CPU on each). At a planner's rate — a few hundred
//! datagrams a second — every datagram should wake the listener at once: that wake is
//! the start of the command's way to the wire. Under a flood (thousands a second, far
//! more than any serial line can execute) a wake per datagram only burns CPU, so the
//! listener then pauses [`FLOOD_GAP`] after a read that emptied its socket, taking
//! everything queued meanwhile in one `recvmmsg` (a read that did not empty it is
//! followed at once by the next: pacing never lets the socket fall behind). The commands lose nothing they could use: a slot keeps only
//! the newest command anyway.
//!
//! Datagrams found queued after such a pause are stamped as received when the previous
//! read returned, the earliest they can have arrived, so the delay figures count the
//! pause.

use std::time::{Duration, Instant};

/// Datagrams a second from which the listener paces its reads.
pub const FLOOD_RATE: u32 = 2000;
/// The shortest time between two reads while flooded.
pub const FLOOD_GAP: Duration = Duration::from_millis(2);
/// The window over which the rate is counted.
const WINDOW: Duration = Duration::from_millis(20);

/// The listener's pacing state: a count of datagrams over the current window.
#[derive(Debug)]
pub struct Pace {
    window_start: Instant,
    count: u32,
    flooded: bool,
}

impl Pace {
    pub fn new(now: Instant) -> Pace {
        Pace {
            window_start: now,
            count: 0,
            flooded: false,
        }
    }

    /// A read returned `n` datagrams at `now`. Returns when the next read may start
    /// (`None`: at once).
    pub fn read(&mut self, n: usize, now: Instant) -> Option<Instant> {
        self.count = self.count.saturating_add(n as u32);
        let elapsed = now.saturating_duration_since(self.window_start);
        if elapsed >= WINDOW {
            let per_window = u64::from(FLOOD_RATE) * WINDOW.as_micros() as u64 / 1_000_000;
            let rate_in_window = u64::from(self.count) * WINDOW.as_micros() as u64
                / elapsed.as_micros().max(1) as u64;
            self.flooded = rate_in_window >= per_window;
            self.window_start = now;
            self.count = 0;
        }
        self.flooded.then(|| now + FLOOD_GAP)
    }

    /// Whether reads are paced now.
    pub fn flooded(&self) -> bool {
        self.flooded
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn feed(p: &mut Pace, start: Instant, every: Duration, count: u32) -> Instant {
        let mut t = start;
        for _ in 0..count {
            t += every;
            p.read(1, t);
        }
        t
    }

    #[test]
    fn a_planner_at_a_few_hundred_datagrams_a_second_is_never_paced() {
        let t0 = Instant::now();
        let mut p = Pace::new(t0);
        // Four datagrams at once every 10 ms (one per actuator), for a second.
        let mut t = t0;
        for _ in 0..100 {
            t += Duration::from_millis(10);
            for _ in 0..4 {
                assert_eq!(p.read(1, t), None);
            }
        }
        assert!(!p.flooded());
    }

    #[test]
    fn a_flood_is_read_once_per_gap() {
        let t0 = Instant::now();
        let mut p = Pace::new(t0);
        let t = feed(&mut p, t0, Duration::from_micros(100), 400);
        assert!(p.flooded(), "10,000 datagrams a second is a flood");
        assert_eq!(p.read(1, t), Some(t + FLOOD_GAP));
        let later = t + FLOOD_GAP;
        assert_eq!(p.read(10, later), Some(later + FLOOD_GAP));
    }

    #[test]
    fn pacing_ends_within_a_window_of_the_flood_ending() {
        let t0 = Instant::now();
        let mut p = Pace::new(t0);
        let t = feed(&mut p, t0, Duration::from_micros(100), 400);
        assert!(p.flooded());
        // Back to 100 Hz: the first read after a full window of it is not paced.
        let t = feed(&mut p, t, Duration::from_millis(10), 3);
        assert!(!p.flooded());
        assert_eq!(p.read(1, t + Duration::from_millis(10)), None);
    }
}
