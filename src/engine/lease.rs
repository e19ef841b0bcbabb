//! The end of a held pedal's lease ([`crate::safety::lease`]): the intake grants and
//! renews it ([`super::admit`]); the gate's monitor ([`super::monitor`]) calls
//! [`Gate::end_lease`] every turn, which ends a lease that ran out — throttle 0 and the
//! brake at the lease's release level, through [`Gate::submit_accel`] (the accel rule,
//! in its one place) — under the intake's lock, so a renewal either lands before the
//! end or finds nothing to renew.

use super::Gate;
use crate::safety::owner::{Commander, LeaseTurn};
use crate::value::{Command, DeviceId};
use crate::vehicle::tap::Asked;
use std::time::Instant;

impl Gate {
    /// The device is the throttle or the brake.
    pub(crate) fn is_pedal(&self, id: DeviceId) -> bool {
        let b = self.vehicle().bindings();
        b.throttle == Some(id) || b.brake == Some(id)
    }

    /// One turn (from `gate/monitor`): a lease that ran out by `now` ends — the
    /// throttle at 0 and the brake at its release level. A lease whose holder no longer
    /// commands the engaged vehicle is dropped (the stop that ended its command
    /// commanded the safe state). Returns whether a lease ended.
    pub fn end_lease(&self, now: Instant) -> bool {
        let mut o = self.state().owner();
        let LeaseTurn::Ended(lease) = o.lease_turn(self.is_engaged(), now) else {
            return false;
        };
        let (done, seen) = self.submit_accel_seen(lease.release, now);
        self.tap_received(lease.source, Asked::Accel(lease.release), now, done, seen);
        if let Err(why) = done {
            // The brake's level refused (a recovery holds the pedals, a rule): the
            // throttle goes to 0 regardless, as in the safe state.
            if let Some(t) = self.vehicle().bindings().throttle {
                let t = self.vehicle().device(t);
                self.store(t, Command::Set(t.config().range[0]), now);
            }
            tracing::warn!(
                "{}'s held gas ran out: throttle 0 (the brake at {:.2} refused: {why})",
                Commander(lease.source),
                -lease.release
            );
        }
        drop(o);
        tracing::debug!(
            "{}'s held gas ran out: throttle 0, brake {:.2}",
            Commander(lease.source),
            -lease.release
        );
        true
    }
}

#[cfg(test)]
mod tests {
    use crate::safety::{Ask, Done, Held};
    use crate::testkit as sample;
    use crate::value::{Command, Source};
    use std::time::{Duration, Instant};

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    /// The latest command of the throttle and the brake.
    fn pedals(g: &crate::engine::Gate) -> (Option<Command>, Option<Command>) {
        let v = g.vehicle();
        let at = |n: &str| v.find(n).unwrap().slot().wire().latest();
        (at("gas"), at("brake"))
    }

    /// Alice engaged by `source`, her interlocks off so that gas is taken in the
    /// sample's park.
    fn engaged(source: Source) -> (std::sync::Arc<crate::engine::Gate>, Instant) {
        let t = Instant::now();
        let g = sample::gate(t);
        g.admit(source, Ask::Engage, t).unwrap();
        g.set_interlocks(source, false).unwrap();
        (g, t)
    }

    fn held(accel: f64, lease: Duration) -> Ask {
        Ask::Held(Held {
            accel,
            lease,
            release: -0.3,
        })
    }

    /// The console holds `↑` and then its loop stops (stuck, swapped out, its terminal
    /// stalled): the engine ends the gas when the lease runs out, and brakes at the
    /// hold level, without a word from the console.
    #[test]
    fn held_gas_ends_when_its_lease_runs_out_whatever_the_console_does() {
        let (g, t) = engaged(Source::Console);
        assert_eq!(
            g.admit(Source::Console, held(0.2, ms(60)), t),
            Ok(Done::Commanded)
        );
        assert_eq!(
            pedals(&g),
            (Some(Command::Set(0.2)), Some(Command::Set(0.0)))
        );
        assert!(!g.end_lease(t + ms(59)));
        assert_eq!(pedals(&g).0, Some(Command::Set(0.2)));
        assert!(g.end_lease(t + ms(60)));
        assert_eq!(
            pedals(&g),
            (Some(Command::Set(0.0)), Some(Command::Set(0.3)))
        );
        assert!(g.is_engaged(), "the hold ends; the deadman disengages");
        assert!(!g.end_lease(t + ms(70)), "ended once");
    }

    /// Each repeat renews the lease from its receipt; a lease that ran out is not
    /// renewed, even before the monitor's turn: only a new press gives gas again.
    #[test]
    fn a_repeat_renews_a_running_lease_and_never_one_that_ran_out() {
        let (g, t) = engaged(Source::Console);
        g.admit(Source::Console, held(0.2, ms(60)), t).unwrap();
        assert_eq!(
            g.admit(Source::Console, Ask::Renew(ms(60)), t + ms(40)),
            Ok(Done::Commanded)
        );
        assert!(!g.end_lease(t + ms(99)));
        assert_eq!(
            g.admit(Source::Console, Ask::Renew(ms(60)), t + ms(100)),
            Ok(Done::Same),
            "ran out at 100 ms"
        );
        assert!(g.end_lease(t + ms(101)));
        assert_eq!(pedals(&g).0, Some(Command::Set(0.0)));
        assert_eq!(
            g.admit(Source::Console, Ask::Renew(ms(60)), t + ms(102)),
            Ok(Done::Same)
        );
    }

    /// A lease asked for an hour lasts the longest the intake grants.
    #[test]
    fn a_lease_lasts_at_most_the_longest() {
        let (g, t) = engaged(Source::Attached(1));
        g.admit(Source::Attached(1), held(0.2, ms(3_600_000)), t)
            .unwrap();
        assert!(!g.end_lease(t + crate::safety::lease::LONGEST - ms(1)));
        assert!(g.end_lease(t + crate::safety::lease::LONGEST));
    }

    /// An accel or a pedal's command outright ends the lease's hold on the pedals: it
    /// is what the commander asked last, and no lease undoes it later.
    #[test]
    fn a_later_accel_or_pedal_command_drops_the_lease() {
        let (g, t) = engaged(Source::Console);
        g.admit(Source::Console, held(0.2, ms(60)), t).unwrap();
        g.admit(Source::Console, Ask::Accel(0.1), t + ms(10))
            .unwrap();
        assert!(!g.end_lease(t + ms(200)));
        assert_eq!(pedals(&g).0, Some(Command::Set(0.1)));
        g.admit(Source::Console, held(0.2, ms(60)), t + ms(300))
            .unwrap();
        let gas = g.vehicle().find("gas").unwrap().id();
        g.admit(
            Source::Console,
            Ask::Set(gas, Command::Set(0.05)),
            t + ms(310),
        )
        .unwrap();
        assert!(!g.end_lease(t + ms(400)));
        // Steering while the gas is held keeps the lease.
        g.admit(Source::Console, held(0.2, ms(60)), t + ms(500))
            .unwrap();
        let steer = g.vehicle().find("steer").unwrap().id();
        g.admit(
            Source::Console,
            Ask::Set(steer, Command::Set(0.1)),
            t + ms(510),
        )
        .unwrap();
        assert!(g.end_lease(t + ms(560)));
    }

    /// A held accel that is not gas needs no lease: a brake held stays until the next
    /// ask; the hold, a stop and another commander end a lease.
    #[test]
    fn no_gas_no_lease_and_a_change_of_hands_ends_one() {
        let (g, t) = engaged(Source::Console);
        g.admit(Source::Console, held(-0.6, ms(60)), t).unwrap();
        assert!(!g.end_lease(t + ms(100)));
        assert_eq!(pedals(&g).1, Some(Command::Set(0.6)));
        g.admit(Source::Console, held(0.2, ms(60)), t).unwrap();
        g.admit(Source::Console, Ask::Hold, t + ms(10)).unwrap();
        assert!(!g.end_lease(t + ms(100)));
        assert_eq!(
            pedals(&g),
            (Some(Command::Set(0.0)), Some(Command::Set(1.0)))
        );
        g.admit(Source::Console, held(0.2, ms(60)), t + ms(200))
            .unwrap();
        g.admit(Source::Console, Ask::Stop, t + ms(210)).unwrap();
        assert!(!g.end_lease(t + ms(300)), "the stop's safe state stands");
        assert_eq!(
            pedals(&g),
            (Some(Command::Set(0.0)), Some(Command::Set(1.0)))
        );
    }

    #[derive(Clone, Copy, Debug)]
    enum Step {
        Ask(Ask),
        /// This many milliseconds pass, then a monitor turn.
        Wait(u16),
    }

    fn step() -> impl proptest::strategy::Strategy<Value = Step> {
        use proptest::prelude::*;
        let ask = prop_oneof![
            (-1.0f64..1.0, 0u64..300).prop_map(|(a, l)| held(a, ms(l))),
            (0u64..300).prop_map(|l| Ask::Renew(ms(l))),
            (-1.0f64..1.0).prop_map(Ask::Accel),
            Just(Ask::Hold),
        ];
        prop_oneof![
            3 => ask.prop_map(Step::Ask),
            2 => (0u16..200).prop_map(Step::Wait),
        ]
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(256))]
        /// Whatever the console asks and however late, after every monitor turn the
        /// throttle has gas only while a lease runs that was granted or renewed within
        /// its length, or when the last accel was an outright one (a supervisory
        /// `accel`, not a held key).
        #[test]
        fn held_gas_never_outlives_its_lease(steps in proptest::collection::vec(step(), 1..80)) {
            let (g, mut now) = engaged(Source::Console);
            // When the gas of a held key must be gone by, or None when the last gas
            // asked was outright.
            let mut gone_by: Option<Instant> = Some(now);
            for s in steps {
                match s {
                    Step::Ask(ask) => {
                        let done = g.admit(Source::Console, ask, now);
                        match (ask, done) {
                            (Ask::Held(h), Ok(_)) => gone_by = Some(now + h.lease.min(crate::safety::lease::LONGEST)),
                            (Ask::Renew(l), Ok(Done::Commanded)) => gone_by = Some(now + l),
                            (Ask::Accel(a), Ok(_)) => gone_by = (a <= 0.0).then_some(now),
                            (Ask::Hold, Ok(_)) => gone_by = Some(now),
                            _ => {}
                        }
                    }
                    Step::Wait(n) => {
                        now += ms(n.into());
                        g.end_lease(now);
                        let gas = match pedals(&g).0 {
                            Some(Command::Set(v)) => v,
                            _ => 0.0,
                        };
                        if let Some(by) = gone_by {
                            proptest::prop_assert!(
                                gas == 0.0 || now < by,
                                "gas {gas} at {:?} past its lease ({:?})",
                                now - by, by
                            );
                        }
                    }
                }
            }
        }
    }
}
