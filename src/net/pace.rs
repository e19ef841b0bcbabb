//! How often `net/listen` looks at its socket under a flood.
//!
//! Each wake of a thread blocked on a socket costs this machine about as much as a
//! datagram's whole parse and intake (a bare receiver thread doing one `recv` per
//! datagram spends ~13 µs of CPU on each). Planners — one at a few hundred datagrams
//! a second, or sixty-four independent controllers at 100 Hz each — must wake the
//! listener at once with every datagram: that wake is the start of the command's way
//! to the wire. A flood is different: one device commanded [`FLOOD_PER_DEVICE`] times
//! a second or more (faster than any serial line executes commands, so its slot
//! replaces most of them unsent), or thousands of datagrams a second that command
//! nothing. Then a wake per datagram only burns CPU, so the listener pauses
//! [`FLOOD_GAP`] after a read that emptied its socket, taking everything queued
//! meanwhile in one `recvmmsg` (a read that did not empty it is followed at once by the
//! next: pacing never lets the socket fall behind). The flooded device loses nothing it
//! could use; the others lose at most the gap.
//!
//! Datagrams found queued after such a pause are stamped as received when the previous
//! read returned, the earliest they can have arrived, so the delay figures count the
//! pause.

use super::counters::NetStatus;
use std::time::{Duration, Instant};

/// Commands a second to one device from which the listener paces its reads.
pub(crate) const FLOOD_PER_DEVICE: u64 = 500;
/// Datagrams a second that command no device (rejected, refused, replies to nothing)
/// from which the listener paces its reads.
pub(crate) const FLOOD_IDLE: u64 = 2000;
/// The shortest time between two reads while flooded.
pub const FLOOD_GAP: Duration = Duration::from_millis(2);
/// The window over which the rates are counted.
const WINDOW: Duration = Duration::from_millis(20);

/// The listener's pacing state: the intake's counters at the start of the window.
#[derive(Debug)]
pub(crate) struct Pace {
    window_start: Instant,
    /// Datagrams, and commands to each device (accel last), so far.
    datagrams: u64,
    commands: Vec<u64>,
    flooded: bool,
}

impl Pace {
    pub(crate) fn new(now: Instant, status: &NetStatus) -> Pace {
        let mut commands = Vec::new();
        status.each_command_count(|_, c| commands.push(c));
        Pace {
            window_start: now,
            datagrams: status.datagrams(),
            commands,
            flooded: false,
        }
    }

    /// A read returned at `now`, its datagrams handled. Returns when the next read may
    /// start (`None`: at once).
    pub(crate) fn read(&mut self, now: Instant, status: &NetStatus) -> Option<Instant> {
        let elapsed = now.saturating_duration_since(self.window_start);
        if elapsed >= WINDOW {
            let (mut busiest, mut commands) = (0, 0);
            status.each_command_count(|i, c| {
                if let Some(last) = self.commands.get_mut(i) {
                    let n = c.saturating_sub(*last);
                    busiest = busiest.max(n);
                    commands += n;
                    *last = c;
                }
            });
            let datagrams = status.datagrams();
            let idle = datagrams
                .saturating_sub(self.datagrams)
                .saturating_sub(commands);
            self.datagrams = datagrams;
            let per_s = |n: u64| n * 1_000_000 / (elapsed.as_micros() as u64).max(1);
            self.flooded = per_s(busiest) >= FLOOD_PER_DEVICE || per_s(idle) >= FLOOD_IDLE;
            self.window_start = now;
        }
        self.flooded.then(|| now + FLOOD_GAP)
    }

    /// Whether reads are paced now.
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn flooded(&self) -> bool {
        self.flooded
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::value::DeviceId;

    fn status(devices: usize) -> NetStatus {
        NetStatus::new(
            "127.0.0.1:0".parse().unwrap(),
            Duration::from_millis(500),
            (0..devices).map(|i| format!("a{i}")).collect(),
        )
    }

    /// Feed `rounds` rounds `every` apart, each one datagram per listed device (or,
    /// for `None`, a datagram that commands nothing), read one at a time; returns the
    /// time of the last read and whether any read was paced.
    fn feed(
        p: &mut Pace,
        st: &NetStatus,
        start: Instant,
        every: Duration,
        rounds: u32,
        to: &[Option<usize>],
    ) -> (Instant, bool) {
        let (mut t, mut paced) = (start, false);
        for _ in 0..rounds {
            t += every;
            for d in to {
                st.count_datagram();
                if let Some(i) = d {
                    st.count_command(DeviceId(*i as u16));
                }
                paced |= p.read(t, st).is_some();
            }
        }
        (t, paced)
    }

    #[test]
    fn planners_are_never_paced_however_many_devices_they_command() {
        let t0 = Instant::now();
        // One planner: four actuators in four datagrams every 10 ms.
        let st = status(4);
        let mut p = Pace::new(t0, &st);
        let four: Vec<_> = (0..4).map(Some).collect();
        let (_, paced) = feed(&mut p, &st, t0, Duration::from_millis(10), 100, &four);
        assert!(!paced && !p.flooded());
        // Sixty-four independent controllers at 100 Hz: 6,400 datagrams a second.
        let st = status(64);
        let mut p = Pace::new(t0, &st);
        let all: Vec<_> = (0..64).map(Some).collect();
        let (_, paced) = feed(&mut p, &st, t0, Duration::from_millis(10), 100, &all);
        assert!(!paced && !p.flooded(), "6,400 a second to 64 devices");
    }

    #[test]
    fn a_flood_to_one_device_is_read_once_per_gap() {
        let t0 = Instant::now();
        let st = status(4);
        let mut p = Pace::new(t0, &st);
        let (t, _) = feed(&mut p, &st, t0, Duration::from_micros(400), 100, &[Some(2)]);
        assert!(p.flooded(), "2,500 commands a second to one device");
        assert_eq!(p.read(t, &st), Some(t + FLOOD_GAP));
    }

    #[test]
    fn a_flood_of_datagrams_that_command_nothing_is_paced() {
        let t0 = Instant::now();
        let st = status(4);
        let mut p = Pace::new(t0, &st);
        feed(&mut p, &st, t0, Duration::from_micros(100), 400, &[None]);
        assert!(p.flooded(), "10,000 junk datagrams a second");
    }

    #[test]
    fn pacing_ends_within_a_window_of_the_flood_ending() {
        let t0 = Instant::now();
        let st = status(4);
        let mut p = Pace::new(t0, &st);
        let (t, _) = feed(&mut p, &st, t0, Duration::from_micros(100), 400, &[Some(0)]);
        assert!(p.flooded());
        // Back to 100 Hz: the first read after a full window of it is not paced.
        let (t, _) = feed(&mut p, &st, t, Duration::from_millis(10), 3, &[Some(0)]);
        assert!(!p.flooded());
        assert_eq!(p.read(t + Duration::from_millis(10), &st), None);
    }
}
