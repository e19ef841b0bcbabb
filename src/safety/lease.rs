//! A held pedal: gas only while its key is held, enforced by the engine.
//!
//! Hold-to-drive teleop gives gas while `↑` is held and takes it away when the key comes
//! up — or when its repeats stop arriving (a stalled SSH link, a lid closed, a terminal
//! that stopped sending). The console knows when a key was last seen, but the end of a
//! hold must not depend on the console's loop turning in time: a console busy drawing,
//! swapped out or stuck would leave the gas on. So gas from a held key carries a
//! **lease** ([`Ask::Held`](super::Ask::Held)): the intake stores it beside who
//! commands, each repeat renews it ([`Ask::Renew`](super::Ask::Renew)), and the gate's
//! monitor (`gate/monitor`, every 10 ms) ends it when it runs out — throttle 0 and the
//! brake at the level the lease names, through the same accel rule as every accel —
//! whatever the console does. A lease that ran out is never renewed: only a new press
//! gives gas again.
//!
//! The deadman stays the console's watchdog over all of teleop (no teleop key for its
//! bound: the safe state and disengage); the lease bounds the gas of one held key.

use crate::value::Source;
use std::time::{Duration, Instant};

/// The longest lease the intake grants: the longest learned key-repeat delay and more.
/// A console asking more gets this.
pub(crate) const LONGEST: Duration = Duration::from_secs(2);

/// Gas held on a lease.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Lease {
    /// Who holds it: the commander when it was granted.
    pub source: Source,
    /// When it runs out.
    pub until: Instant,
    /// The accel when it runs out: never gas (−1 … 0: the brake at its hold level).
    pub release: f64,
}

impl Lease {
    /// A lease of `source` for `length` from `from` (at most [`LONGEST`]), ending in
    /// `release` made safe: no gas, a number.
    pub(crate) fn new(source: Source, from: Instant, length: Duration, release: f64) -> Lease {
        Lease {
            source,
            until: from + length.min(LONGEST),
            release: if release.is_finite() {
                release.clamp(-1.0, 0.0)
            } else {
                0.0
            },
        }
    }

    /// Still running at `now`.
    pub(crate) fn runs(&self, now: Instant) -> bool {
        now < self.until
    }

    /// Renewed by `source` at `now` for `length`: only a running lease of its own, and
    /// never past [`LONGEST`] from `now`. Returns whether it was renewed.
    pub(crate) fn renew(&mut self, source: Source, now: Instant, length: Duration) -> bool {
        if source != self.source || !self.runs(now) {
            return false;
        }
        self.until = now + length.min(LONGEST);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lease_never_ends_in_gas_nor_outlasts_the_longest() {
        let t = Instant::now();
        let l = Lease::new(Source::Console, t, Duration::from_secs(3600), 0.7);
        assert_eq!(l.release, 0.0);
        assert_eq!(l.until, t + LONGEST);
        assert_eq!(
            Lease::new(Source::Console, t, LONGEST, f64::NAN).release,
            0.0
        );
        assert_eq!(Lease::new(Source::Console, t, LONGEST, -3.0).release, -1.0);
    }

    #[test]
    fn only_a_running_lease_of_its_own_source_is_renewed() {
        let t = Instant::now();
        let ms = Duration::from_millis;
        let mut l = Lease::new(Source::Console, t, ms(60), -0.3);
        assert!(!l.renew(Source::Attached(1), t + ms(30), ms(60)));
        assert!(l.renew(Source::Console, t + ms(30), ms(60)));
        assert_eq!(l.until, t + ms(90));
        assert!(!l.runs(t + ms(90)));
        assert!(
            !l.renew(Source::Console, t + ms(90), ms(60)),
            "a lease that ran out gives no gas again"
        );
    }
}
