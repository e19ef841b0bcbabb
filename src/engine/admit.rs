//! Admission: the one intake below every front end. The console, attached consoles, the network
//! listener, ROS 2 and `adrive ctl` turn what they receive into an [`Ask`] tagged with
//! its [`Source`] and hand it to [`Gate::admit`]; what comes back is the outcome each
//! turns into its reply, log line or message. No front end decides who commands, and
//! none formats text for another.
//!
//! `admit` applies, in order and under one lock (safety's [`Owner`]):
//! 1. **ownership** ([`owner::decide`]): at most one source commands the engaged
//!    vehicle; command changes hands only explicitly (engage, release, a console's
//!    take); stopping is never refused. A command from a source that does not command
//!    is refused naming the commander, logged at WARN, counted and shown;
//! 2. **the commander's watchdog**: every admitted ask of the commander feeds it;
//!    [`Gate::watch`] (on `gate/monitor`: [`super::monitor`]) brings the vehicle to the
//!    safe state and disengages it when it goes quiet — the network's
//!    `watchdog_timeout` for a network sender or ROS 2, the teleop deadman for a console
//!    while it teleoperates. One rule, one timeout per source. A commanding console
//!    also proves its operator is there: its terminal's answers to round trips
//!    ([`Gate::answered`]) must not stop for `[console] terminal_timeout`;
//! 3. **the interlocks and the engage gate**: [`Gate::submit`] and [`Gate::submit_accel`],
//!    which admit a command (a compound one as a whole) and send it on its way
//!    ([`super::dispatch`]), or change nothing. Gas from a held key ([`Ask::Held`]) is granted a lease beside who
//!    commands, renewed by [`Ask::Renew`] and ended by the monitor ([`super::lease`]);
//!    any other accel or pedal command, a hold, a stop or a change of hands drops it.
//!
//! The lock is held across the store, so no command of a previous commander lands after
//! command changed hands. The accepted path does not touch the heap.

use super::Gate;
use crate::safety::accel::{Pedal, Plan};
use crate::safety::lease::Lease;
use crate::safety::owner::{self, Act, Bounds, CommandView, Commander, Outcome, Owner, Trip};
use crate::safety::{Ask, Done, Held, Refused, Reject, Seen};
use crate::snapshot::{DisengageCause, WatchdogView};
use crate::value::{Command, DeviceId, Source};
use crate::vehicle::tap::{Asked, Event};
use std::time::{Duration, Instant};

impl Gate {
    /// The one intake: `ask` from `source`, received at `received` (socket read, key
    /// press). Ownership, the commander's watchdog, then the interlocks and the engage
    /// gate; a refused ask changes nothing.
    pub fn admit(&self, source: Source, ask: Ask, received: Instant) -> Result<Done, Refused> {
        let mut o = self.state().owner();
        let engaged = self.is_engaged();
        if !engaged {
            o.nobody();
        }
        let outcome = match ask.act() {
            None => Outcome::Same,
            Some(act) => match o.decide(engaged, source, act) {
                Ok(x) => x,
                Err(r) => {
                    o.refuse(source, ask, r);
                    drop(o);
                    self.refused_by_owner(source, ask, r, received);
                    // A recording keeps it with its reason, as every refused command.
                    let asked = match ask {
                        Ask::Set(id, c) => Some(Asked::Device(id, c)),
                        Ask::Accel(a) | Ask::Held(Held { accel: a, .. }) => Some(Asked::Accel(a)),
                        _ => None,
                    };
                    if let Some(asked) = asked {
                        self.vehicle().tap().send(|| Event::Received {
                            at: received,
                            source,
                            asked,
                            refused: Some("other_commander"),
                            seen: None,
                        });
                    }
                    return Err(Refused::Owner(r));
                }
            },
        };
        let mine = o.is(source);
        let done = match ask {
            Ask::Set(id, c) => {
                let (done, seen) = self.submit_seen(id, c, received);
                self.tap_received(source, Asked::Device(id, c), received, done, seen);
                if done.is_ok() && self.is_pedal(id) {
                    // A pedal commanded outright: no lease ends it later.
                    o.lease(None);
                }
                done.map(|()| Done::Commanded).map_err(Refused::Rule)
            }
            Ask::Accel(a) => {
                let (done, seen) = self.submit_accel_seen(a, received);
                self.tap_received(source, Asked::Accel(a), received, done, seen);
                if done.is_ok() {
                    o.lease(None);
                }
                done.map(|()| Done::Commanded).map_err(Refused::Rule)
            }
            Ask::Held(h) => {
                let (done, seen) = self.submit_accel_seen(h.accel, received);
                self.tap_received(source, Asked::Accel(h.accel), received, done, seen);
                if done.is_ok() {
                    o.lease(
                        (h.accel > 0.0).then(|| Lease::new(source, received, h.lease, h.release)),
                    );
                }
                done.map(|()| Done::Commanded).map_err(Refused::Rule)
            }
            Ask::Renew(d) => Ok(match o.renew(source, received, d) {
                true => Done::Commanded,
                false => Done::Same,
            }),
            // Taken by a console, or picked up after a release.
            Ask::Engage | Ask::Take if outcome == Outcome::Commands => {
                let from = o.commands(source, received);
                tracing::warn!(
                    "{} takes command from {}",
                    Commander(source),
                    from.map_or("nobody".into(), |s| Commander(s).to_string())
                );
                Ok(Done::Commanding)
            }
            Ask::Engage if outcome == Outcome::Engages => {
                let by = Commander(source).to_string();
                self.engage(&by).map_err(Refused::Blocked)?;
                o.engages(source, received);
                Ok(Done::Engaged)
            }
            Ask::Engage | Ask::Take => Ok(Done::Same),
            Ask::Release => {
                let handover = self.vehicle().config().network.watchdog_timeout;
                o.releases(source, received, handover);
                tracing::warn!(
                    "{} released command: the vehicle is stopped unless a source engages within {} ms",
                    Commander(source),
                    handover.as_millis()
                );
                Ok(Done::Released)
            }
            Ask::Disengage | Ask::Stop => {
                o.nobody();
                let by = Commander(source).to_string();
                Ok(Done::Disengaged(if ask == Ask::Stop {
                    self.stop(DisengageCause::Stop { by })
                } else {
                    self.disengage(DisengageCause::Disengage { by })
                }))
            }
            Ask::Hold if engaged => {
                o.lease(None);
                self.command_safe_state();
                Ok(Done::Commanded)
            }
            Ask::Hold => Err(Refused::Rule(Reject::Disengaged)),
            Ask::Clear => self
                .clear_overrides()
                .map(Done::Cleared)
                .map_err(Refused::Clear),
        };
        if mine && done.is_ok() {
            // A sign of life from the commander, whatever it asked.
            o.alive(received);
        }
        done
    }

    /// Command intake for one device, past ownership: the gate and the interlocks
    /// ([`crate::safety::GateState::check`]), then on its way. `received` is when the
    /// command was born (socket read, key press). A rejected command never reaches the
    /// slot.
    pub fn submit(&self, id: DeviceId, command: Command, received: Instant) -> Result<(), Reject> {
        self.submit_seen(id, command, received).0
    }

    /// [`Gate::submit`], and what its decision saw (for the recording).
    pub(crate) fn submit_seen(
        &self,
        id: DeviceId,
        command: Command,
        received: Instant,
    ) -> (Result<(), Reject>, Option<Seen>) {
        let Some(d) = self.vehicle().devices().get(id.index()) else {
            return (
                Err(self.reject(None, Some(command), Reject::NoSuchDevice)),
                None,
            );
        };
        let (done, seen) = self.state().decided(self.vehicle(), d, command);
        if let Err(why) = done {
            return (Err(self.reject(Some(d), Some(command), why)), Some(seen));
        }
        self.dispatch(d, command, received);
        // A disengage that raced this command (it checks the gate, then stores): the
        // safe state must be the last word.
        if !self.is_engaged() {
            self.command_safe_state();
        }
        (Ok(()), Some(seen))
    }

    /// The follower's virtual `accel` command, −1…1 of the pedals' ranges: positive is
    /// throttle, negative is brake; it never applies both. Safety decides it as a whole
    /// ([`crate::safety::accel`]): refused, both slots stay exactly as they were;
    /// admitted, its plan goes out, the brake's release first when throttle follows it.
    /// Needs throttle and brake bound.
    pub fn submit_accel(&self, a: f64, received: Instant) -> Result<(), Reject> {
        self.submit_accel_seen(a, received).0
    }

    /// [`Gate::submit_accel`], and what its decision saw (for the recording).
    pub(crate) fn submit_accel_seen(
        &self,
        a: f64,
        received: Instant,
    ) -> (Result<(), Reject>, Option<Seen>) {
        let v = self.vehicle();
        let Some((done, seen)) = self.state().decided_accel(v, a) else {
            return (
                Err(self.reject_accel(None, a, None, Reject::NoSuchDevice)),
                None,
            );
        };
        let b = v.bindings();
        let pedal = |p: Pedal| match p {
            Pedal::Throttle => b.throttle.map(|id| v.device(id)),
            Pedal::Brake => b.brake.map(|id| v.device(id)),
        };
        let plan = match done {
            Ok(plan) => plan,
            Err(r) => {
                return (
                    Err(self.reject_accel(pedal(r.at), a, r.command, r.why)),
                    Some(seen),
                )
            }
        };
        for (p, share) in plan.order() {
            if let Some(d) = pedal(p) {
                self.dispatch(d, Plan::command(d.config(), share), received);
            }
        }
        if !self.is_engaged() {
            self.command_safe_state();
        }
        (Ok(()), Some(seen))
    }

    /// The source commanding the engaged vehicle, if any.
    pub fn commander(&self) -> Option<Source> {
        self.state().owner().commander(self.is_engaged())
    }

    /// The commander's stream is alive but frozen (a rolling counter that stopped
    /// advancing): nothing it sends is valid, and its watchdog keeps counting; the
    /// trip then says why.
    pub fn frozen(&self, source: Source) {
        self.state().owner().freeze(source);
    }

    /// Arm (`Some`) or disarm the commanding console's deadman — its watchdog while it
    /// teleoperates. Arming also feeds it: a teleop key is a sign of life. A console
    /// that does not command has no deadman to arm (its teleop keys are refused).
    pub fn deadman(&self, source: Source, armed: Option<Duration>, now: Instant) {
        self.state().owner().deadman(source, armed, now);
    }

    /// A console's terminal answered a round trip of its liveness check at `at` (read
    /// then by the embedded console; arrived then over the control socket from an
    /// attached one). A commanding console's link's watchdog is fed
    /// ([`owner::terminal_silent`]); a watcher's answers change nothing.
    pub fn answered(&self, source: Source, at: Instant) {
        self.state().owner().answered(source, at);
    }

    /// A source went away for good (an attached console's connection closed: its
    /// terminal closed, its SSH session dropped, its process killed; or it was
    /// dropped). If it commands the engaged vehicle, that is its watchdog: the safe
    /// state and disengage, now, the reason its name and `cause`, what it did (`went
    /// away (its connection closed)`, `stopped reading for 4.1 s: dropped`). Interlocks it switched off come back on: nobody who
    /// stays chose to drive without them. A watcher changes nothing. Returns whether
    /// the watchdog tripped.
    pub fn gone(&self, source: Source, cause: &str) -> bool {
        let mut o = self.state().owner();
        let gone = o.gone(source, self.is_engaged());
        if gone.interlocks_on {
            self.state().set_interlocks(true);
            tracing::warn!(
                "interlocks switched on again: {} that switched them off {cause}",
                Commander(source)
            );
        }
        if gone.trips {
            self.trip(
                o,
                Trip::Gone {
                    commander: source,
                    how: cause.to_string(),
                },
            );
        }
        gone.trips
    }

    /// The commander's watchdog trips for `cause`: nobody commands, the safe state, and
    /// disengaged — under the intake lock, so no command slips in between the decision
    /// and the safe state.
    fn trip(&self, mut o: parking_lot::MutexGuard<'_, Owner>, cause: Trip) {
        let words = cause.to_string();
        let why = DisengageCause::Watchdog {
            trip: cause.kind(),
            what: words.clone(),
        };
        o.trip(cause);
        self.disengage_engaged(why);
        drop(o);
        tracing::warn!("watchdog: {words}; safe state commanded");
    }

    /// The bounds of the commander's watchdog, from the vehicle file.
    fn bounds(&self) -> Bounds {
        let c = self.vehicle().config();
        Bounds {
            watchdog: c.network.watchdog_timeout,
            terminal: c.console.terminal_timeout,
        }
    }

    /// One watchdog turn (from `gate/monitor`): a bound that ran out
    /// ([`Owner::expired`]) brings the vehicle to the safe state and disengages it.
    /// Returns the cause when it did.
    pub fn watch(&self, now: Instant) -> Option<Trip> {
        let mut o = self.state().owner();
        if !self.is_engaged() {
            o.nobody();
            return None;
        }
        let cause = o.expired(now, self.bounds())?;
        self.trip(o, cause.clone());
        Some(cause)
    }

    /// Switch the interlocks — only from a console that commands the vehicle or may
    /// (nobody else commands), after its confirmation.
    pub(crate) fn set_interlocks(&self, source: Source, on: bool) -> Result<(), Refused> {
        let mut o = self.state().owner();
        let engaged = self.is_engaged();
        o.decide(engaged, source, Act::Interlocks)
            .map_err(Refused::Owner)?;
        self.state().set_interlocks(on);
        o.interlocks(source, on);
        tracing::warn!(
            "interlocks switched {} from the {}",
            if on { "on" } else { "off" },
            Commander(source)
        );
        Ok(())
    }

    /// May `source` tune a device now (its delays, threads, a wake, a simulated
    /// fault)? A console, when it commands or nobody does.
    pub(crate) fn tune(&self, source: Source) -> Result<(), Refused> {
        let o = self.state().owner();
        o.decide(self.is_engaged(), source, Act::Tune)
            .map(drop)
            .map_err(Refused::Owner)
    }

    /// Who commands, for the snapshot.
    pub(crate) fn command_view(&self, now: Instant) -> CommandView {
        let o = self.state().owner();
        let engaged = self.is_engaged();
        let commander = o.commander(engaged);
        let (refused, last_refused) = o.refused();
        let name = |s: Source| match s {
            Source::Ros2 => format!("ros2 {}", self.vehicle().config().ros2.namespace),
            other => Commander(other).to_string(),
        };
        let timeout = commander.and_then(|c| o.timeout(c, self.bounds()));
        let state = o.watchdog_state(engaged, timeout);
        let shown_timeout = timeout.unwrap_or(self.vehicle().config().network.watchdog_timeout);
        CommandView {
            commander: commander.map(name),
            watchdog: Some(WatchdogView {
                state,
                timeout_ms: shown_timeout.as_secs_f64() * 1e3,
                last_command_age_ms: commander.map(|_| o.quiet(now).as_secs_f64() * 1e3),
                last_trip: o.last_trip().map(Trip::to_string),
                trip: o.last_trip().map(Trip::kind),
            }),
            refused,
            last_refused: last_refused
                .map(|(s, ask, r)| format!("refused {} from {}: {r}", self.ask_text(ask), name(s))),
        }
    }

    /// An ask in words: `steer 0.500`, `accel 0.3`, `engage`.
    pub(crate) fn ask_text(&self, ask: Ask) -> String {
        match ask {
            Ask::Set(id, c) => match self.vehicle().devices().get(id.index()) {
                Some(d) => format!("{} {}", d.name(), d.config().command_text(c)),
                None => format!("{c:?}"),
            },
            Ask::Accel(a) => format!("accel {a}"),
            Ask::Held(h) => format!("accel {} (held {} ms)", h.accel, h.lease.as_millis()),
            Ask::Renew(d) => format!("held for {} ms more", d.as_millis()),
            other => format!("{other:?}").to_lowercase(),
        }
    }

    fn refused_by_owner(&self, source: Source, ask: Ask, r: owner::Refusal, at: Instant) {
        if self.state().log_allowed(at) {
            tracing::warn!(
                "refused {} from {}: {r}",
                self.ask_text(ask),
                Commander(source)
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::port::slot::WireState;
    use crate::snapshot::WatchdogState;
    use crate::testkit as sample;
    use crate::value::{Command, DeviceId};
    use proptest::prelude::*;
    use std::net::{Ipv4Addr, SocketAddr};

    fn net(port: u16) -> Source {
        Source::Network(SocketAddr::from((Ipv4Addr::LOCALHOST, port)))
    }

    fn slots(g: &Gate) -> Vec<WireState> {
        g.vehicle()
            .devices()
            .iter()
            .map(|d| d.slot().wire())
            .collect()
    }

    fn id(g: &Gate, name: &str) -> DeviceId {
        g.vehicle().find(name).unwrap().id()
    }

    /// The incident of the walk: engage at the console, then one `steer 0.5` from the
    /// network. It is refused naming the console, nothing reaches the slot, and the
    /// attempt is counted and worded for the console.
    #[test]
    fn a_network_steer_on_a_console_engaged_vehicle_is_refused_and_changes_nothing() {
        let g = sample::gate(Instant::now());
        let t = Instant::now();
        assert_eq!(g.admit(Source::Console, Ask::Engage, t), Ok(Done::Engaged));
        let before = slots(&g);
        let steer = Ask::Set(id(&g, "steer"), Command::Set(0.5));
        assert_eq!(
            g.admit(net(5555), steer, t),
            Err(Refused::Owner(owner::Refusal::Commander(Source::Console)))
        );
        assert_eq!(slots(&g), before);
        assert_eq!(g.commander(), Some(Source::Console));
        let v = g.view(t);
        assert_eq!(v.commander.as_deref(), Some("console"));
        assert_eq!(v.refused, 1);
        let said = v.last_refused.unwrap();
        assert!(
            said.contains("steer 0.500") && said.contains("network 127.0.0.1:5555"),
            "{said}"
        );
        // Handed over with the console's release, the sender engages and commands.
        assert_eq!(
            g.admit(Source::Console, Ask::Release, t),
            Ok(Done::Released)
        );
        assert_eq!(g.admit(net(5555), Ask::Engage, t), Ok(Done::Commanding));
        assert_eq!(g.admit(net(5555), steer, t), Ok(Done::Commanded));
    }

    /// What who commands refuses is recorded with its reason — a set point as its
    /// device's, an accel as an accel (a recording keeps every refused command); an
    /// engage of a vehicle one already commands is the same engagement, not a new one;
    /// a hold asks for nothing on a disengaged vehicle and is refused.
    #[test]
    fn refusals_of_who_commands_are_recorded_and_a_repeat_changes_nothing() {
        let t = Instant::now();
        let g = sample::gate(t);
        let tapped = g.vehicle().tap().open(false).expect("a reader");
        assert_eq!(
            g.admit(Source::Console, Ask::Hold, t),
            Err(Refused::Rule(Reject::Disengaged))
        );
        assert_eq!(g.admit(Source::Console, Ask::Engage, t), Ok(Done::Engaged));
        assert_eq!(g.admit(Source::Console, Ask::Engage, t), Ok(Done::Same));
        let steer = id(&g, "steer");
        assert!(g
            .admit(net(5555), Ask::Set(steer, Command::Set(0.5)), t)
            .is_err());
        assert!(g.admit(net(5555), Ask::Accel(0.2), t).is_err());
        let refused: Vec<Asked> = tapped
            .rx
            .try_iter()
            .filter_map(|e| match e {
                Event::Received {
                    source,
                    asked,
                    refused: Some(_),
                    ..
                } if source == net(5555) => Some(asked),
                _ => None,
            })
            .collect();
        assert!(
            matches!(
                refused.as_slice(),
                [Asked::Device(d, Command::Set(v)), Asked::Accel(a)]
                    if *d == steer && *v == 0.5 && *a == 0.2
            ),
            "{refused:?}"
        );
    }

    /// The other incident: in neutral with the brake on, `accel 0.3` was rejected
    /// (`gas_not_in_gear`) yet released the brake. A refused accel leaves both slots
    /// as they were.
    #[test]
    fn a_rejected_accel_in_neutral_leaves_the_brake_applied() {
        let g = sample::gate(Instant::now());
        let t = Instant::now();
        g.admit(Source::Console, Ask::Engage, t).unwrap();
        let brake = g.vehicle().find("brake").unwrap();
        assert_eq!(brake.slot().wire().latest(), Some(Command::Set(1.0)));
        let before = slots(&g);
        assert_eq!(
            g.admit(Source::Console, Ask::Accel(0.3), t),
            Err(Refused::Rule(Reject::GasNotInGear))
        );
        assert_eq!(slots(&g), before, "a refused accel changed a slot");
    }

    /// A refused accel is logged as the accel asked, with the part refused where
    /// that is what was (it was logged `command=""`).
    #[test]
    fn a_refused_accel_is_logged_as_asked() {
        let g = sample::gate(Instant::now());
        let t = Instant::now();
        g.admit(Source::Console, Ask::Engage, t).unwrap();
        let lines = sample::logged(|| {
            let _ = g.admit(Source::Console, Ask::Accel(0.3), t);
        });
        let line = lines.iter().find(|l| l.starts_with("rejected: ")).unwrap();
        assert!(line.contains("device=gas command=accel 0.300"), "{line}");
        g.state().set_interlocks(false);
        let lines = sample::logged(|| {
            let _ = g.admit(
                Source::Console,
                Ask::Accel(-7.0),
                t + Duration::from_secs(1),
            );
        });
        let line = lines.iter().find(|l| l.starts_with("rejected: ")).unwrap();
        assert!(line.contains("command=accel -7.000"), "{line}");
    }

    /// The commander's watchdog, over a clock of our own: a network commander quiet
    /// for `watchdog_timeout` disengages; the console's deadman only while armed; a
    /// release nobody picks up ends in the safe state too.
    /// An attached console that commands and goes away (its SSH session dropped) is
    /// its watchdog; the interlocks it switched off come back on; a watcher that goes
    /// away changes nothing.
    #[test]
    fn a_commanding_console_that_goes_away_stops_the_vehicle_and_restores_the_interlocks() {
        let t = Instant::now();
        let g = sample::gate(t);
        let (driver, watcher) = (Source::Attached(1), Source::Attached(2));
        g.admit(driver, Ask::Engage, t).unwrap();
        g.set_interlocks(driver, false).unwrap();
        assert_eq!(
            g.set_interlocks(watcher, true),
            Err(Refused::Owner(owner::Refusal::Commander(driver)))
        );
        assert!(!g.gone(watcher, "went away (its connection closed)"));
        assert!(g.is_engaged() && !g.interlocks_on());
        assert!(g.gone(driver, "went away (its connection closed)"));
        assert!(!g.is_engaged());
        assert!(g.interlocks_on());
        let why = g.command_view(t).watchdog.unwrap().last_trip.unwrap();
        assert_eq!(why, "console #1 went away (its connection closed)");
    }

    #[test]
    fn the_watchdog_is_the_commanders_with_its_own_timeout() {
        let g = sample::gate(Instant::now());
        let t0 = Instant::now();
        let timeout = g.vehicle().config().network.watchdog_timeout;
        g.admit(net(1), Ask::Engage, t0).unwrap();
        assert_eq!(g.watch(t0 + timeout / 2), None);
        let why = g.watch(t0 + timeout).expect("tripped");
        assert_eq!(
            why,
            Trip::Silent {
                commander: net(1),
                quiet: timeout
            }
        );
        assert!(
            why.to_string().starts_with("no valid command from network"),
            "{why}"
        );
        assert!(!g.is_engaged());
        assert_eq!(g.view(t0).watchdog.unwrap().state, WatchdogState::Tripped);
        // The console outside teleop has no deadman, only its terminal's answers to
        // watch; its deadman too, once armed.
        let t1 = t0 + timeout * 2;
        let alive = |t: Instant| g.answered(Source::Console, t);
        g.admit(Source::Console, Ask::Engage, t1).unwrap();
        for s in 1..=60 {
            alive(t1 + Duration::from_secs(s) - Duration::from_millis(100));
            assert_eq!(g.watch(t1 + Duration::from_secs(s)), None);
        }
        let deadman = Duration::from_millis(1000);
        let t2 = t1 + Duration::from_secs(60);
        g.deadman(Source::Console, Some(deadman), t2);
        alive(t2 + deadman / 2);
        assert_eq!(g.watch(t2 + deadman / 2), None);
        g.deadman(Source::Console, Some(deadman), t2 + deadman / 2);
        alive(t2 + deadman);
        assert_eq!(g.watch(t2 + deadman), None, "a key fed it");
        alive(t2 + deadman * 2);
        let why = g.watch(t2 + deadman * 2).expect("tripped");
        assert_eq!(why, Trip::Deadman { bound: deadman });
        assert_eq!(why.to_string(), "deadman: no teleop key for 1.0s");
        assert!(!g.is_engaged());
        // Engaged again, the deadman waits for the next teleop key.
        let t4 = t2 + deadman * 2;
        g.admit(Source::Console, Ask::Engage, t4).unwrap();
        alive(t4 + deadman * 2);
        assert_eq!(g.watch(t4 + deadman * 2), None, "idle until a key");
        g.admit(Source::Console, Ask::Disengage, t4).unwrap();
        // A release nobody picks up.
        g.deadman(Source::Console, None, t2);
        let t3 = t2 + deadman * 3;
        g.admit(Source::Console, Ask::Engage, t3).unwrap();
        g.admit(Source::Console, Ask::Release, t3).unwrap();
        assert!(g.is_engaged());
        let why = g.watch(t3 + timeout).expect("ended");
        assert_eq!(
            why,
            Trip::Handover {
                from: Source::Console
            }
        );
        assert_eq!(
            why.to_string(),
            "released by console and nobody took command"
        );
        assert!(!g.is_engaged());
    }

    /// A sign of life is the commander's own ask that held: a refused one (a steer out
    /// of range, sent again and again by a planner gone wrong) does not keep the
    /// vehicle engaged past the watchdog's bound.
    #[test]
    fn a_refused_ask_of_the_commander_is_no_sign_of_life() {
        let g = sample::gate(Instant::now());
        let t0 = Instant::now();
        let timeout = g.vehicle().config().network.watchdog_timeout;
        g.admit(net(1), Ask::Engage, t0).unwrap();
        let wild = Ask::Set(id(&g, "steer"), Command::Set(5.0));
        assert!(g.admit(net(1), wild, t0 + timeout * 4 / 5).is_err());
        assert_eq!(
            g.watch(t0 + timeout),
            Some(Trip::Silent {
                commander: net(1),
                quiet: timeout
            })
        );
        // One that held is.
        let t1 = t0 + timeout * 2;
        g.admit(net(1), Ask::Engage, t1).unwrap();
        let steer = Ask::Set(id(&g, "steer"), Command::Set(0.5));
        assert_eq!(
            g.admit(net(1), steer, t1 + timeout * 4 / 5),
            Ok(Done::Commanded)
        );
        assert_eq!(g.watch(t1 + timeout), None);
    }

    /// An admitted command is what the device gets next: nothing after it takes its
    /// place while the vehicle stays engaged.
    #[test]
    fn an_admitted_command_is_the_devices_next() {
        let g = sample::gate(Instant::now());
        let t = Instant::now();
        g.admit(net(1), Ask::Engage, t).unwrap();
        for (name, value) in [("steer", 0.5), ("brake", 0.4)] {
            let d = id(&g, name);
            g.admit(net(1), Ask::Set(d, Command::Set(value)), t)
                .unwrap();
            assert_eq!(
                slots(&g)[d.index()].latest(),
                Some(Command::Set(value)),
                "{name}: not the safe state"
            );
        }
    }

    /// A commander whose stream froze (its rolling counter stopped) trips the watchdog
    /// as frozen, not as silent: the operator reads which.
    #[test]
    fn a_frozen_stream_trips_the_watchdog_as_frozen() {
        let g = sample::gate(Instant::now());
        let t0 = Instant::now();
        let timeout = g.vehicle().config().network.watchdog_timeout;
        g.admit(net(1), Ask::Engage, t0).unwrap();
        g.frozen(net(2));
        g.frozen(net(1));
        assert_eq!(
            g.watch(t0 + timeout),
            Some(Trip::Frozen {
                commander: net(1),
                quiet: timeout
            })
        );
    }

    /// A console tunes the vehicle (delays, threads, a wake, a simulated fault) when it
    /// commands or nobody does; nobody tunes a vehicle a planner commands, and a
    /// planner never tunes.
    #[test]
    fn tuning_is_a_consoles_while_no_one_else_commands() {
        let g = sample::gate(Instant::now());
        let t = Instant::now();
        assert_eq!(g.tune(Source::Console), Ok(()));
        g.admit(net(1), Ask::Engage, t).unwrap();
        assert!(g.tune(Source::Console).is_err());
        assert!(g.tune(net(1)).is_err());
        g.admit(net(1), Ask::Disengage, t).unwrap();
        g.admit(Source::Console, Ask::Engage, t).unwrap();
        assert_eq!(g.tune(Source::Console), Ok(()));
    }

    /// The watchdog's view in milliseconds: its bound and how long the commander has
    /// been quiet; an owner's refusal is logged with what was refused, from whom.
    #[test]
    fn the_watchdogs_view_is_in_milliseconds_and_a_refusal_is_logged() {
        let g = sample::gate(Instant::now());
        let t0 = Instant::now();
        g.admit(net(1), Ask::Engage, t0).unwrap();
        let w = g
            .command_view(t0 + Duration::from_millis(200))
            .watchdog
            .unwrap();
        assert_eq!(w.timeout_ms, 500.0);
        assert_eq!(w.last_command_age_ms, Some(200.0));
        let steer = Ask::Set(id(&g, "steer"), Command::Set(0.5));
        let lines = crate::testkit::logged(|| {
            let _ = g.admit(net(2), steer, t0);
        });
        assert!(
            lines
                .iter()
                .any(|l| l.starts_with("refused steer 0.500 from network 127.0.0.1:2: ")),
            "{lines:#?}"
        );
    }

    /// A STOP and a disengage end the engagement each under its own cause: the STOP's
    /// is the full safe state, even in a driver's hands.
    #[test]
    fn a_stop_and_a_disengage_are_each_said_as_what_they_were() {
        let g = sample::gate(Instant::now());
        let t = Instant::now();
        g.admit(net(1), Ask::Engage, t).unwrap();
        g.admit(net(1), Ask::Stop, t).unwrap();
        assert_eq!(g.reason(), "disengaged: stop from network 127.0.0.1:1");
        g.admit(net(1), Ask::Engage, t).unwrap();
        g.admit(net(1), Ask::Disengage, t).unwrap();
        assert_eq!(g.reason(), "disengaged: disengage from network 127.0.0.1:1");
    }

    /// A held key is granted a lease only for gas: a hold at accel 0 (coasting, the
    /// brake's hold) leaves nothing to renew or to run out.
    #[test]
    fn only_gas_is_leased() {
        let g = sample::gate(Instant::now());
        let t = Instant::now();
        g.admit(Source::Console, Ask::Engage, t).unwrap();
        let held = |accel: f64| {
            Ask::Held(Held {
                accel,
                lease: Duration::from_millis(300),
                release: -0.3,
            })
        };
        let renew = Ask::Renew(Duration::from_millis(300));
        assert_eq!(g.admit(Source::Console, held(0.0), t), Ok(Done::Commanded));
        assert_eq!(
            g.admit(Source::Console, renew, t),
            Ok(Done::Same),
            "nothing held"
        );
        assert_eq!(g.admit(Source::Console, held(-0.4), t), Ok(Done::Commanded));
        assert_eq!(
            g.admit(Source::Console, renew, t),
            Ok(Done::Same),
            "a brake"
        );
    }

    /// The incident: over SSH, `adrive attach` engaged, then the operator's ssh client
    /// froze; the vehicle stayed engaged, holding its last commands, for the whole 90 s
    /// watched. A commanding console whose terminal stops answering is a watchdog stop
    /// within the bound, said in words; a watcher's silence changes nothing; answers
    /// keep command however long the drive.
    #[test]
    fn a_commanding_console_whose_terminal_stops_answering_stops_the_vehicle() {
        let t = Instant::now();
        let g = sample::gate(t);
        let bound = g.vehicle().config().console.terminal_timeout;
        let (driver, watcher) = (Source::Attached(1), Source::Attached(2));
        g.admit(driver, Ask::Engage, t).unwrap();
        // Live answers 300 ms apart for a minute: command held.
        let mut now = t;
        for _ in 0..200 {
            now += Duration::from_millis(300);
            g.answered(driver, now);
            assert_eq!(g.watch(now + Duration::from_millis(10)), None);
        }
        // A watcher that never answers changes nothing.
        assert_eq!(g.commander(), Some(driver));
        // The driver's terminal stops answering.
        assert_eq!(g.watch(now + bound - Duration::from_millis(10)), None);
        let why = g.watch(now + bound).expect("tripped");
        assert_eq!(
            why.to_string(),
            "console #1: its terminal stopped answering for 1.0 s"
        );
        assert!(!g.is_engaged());
        let v = g.view(now);
        assert_eq!(v.watchdog.as_ref().unwrap().state, WatchdogState::Tripped);
        assert_eq!(
            v.watchdog.unwrap().last_trip.as_deref(),
            Some(why.to_string().as_str())
        );
        // Late answers of the old commander do not engage anything.
        g.answered(driver, now + bound * 2);
        assert_eq!(g.commander(), None);
        // The watcher engages: its clock starts at its engage.
        let t2 = now + bound * 3;
        g.admit(watcher, Ask::Engage, t2).unwrap();
        assert_eq!(g.watch(t2 + bound / 2), None);
        g.answered(driver, t2 + bound / 2);
        assert!(
            g.watch(t2 + bound).is_some(),
            "another console's answers are not its own"
        );
    }

    #[derive(Clone, Copy, Debug)]
    enum Step {
        Ask(u8, Ask),
        /// Time passes: this many milliseconds, then a watchdog turn.
        Wait(u16),
    }

    fn sources() -> [Source; 4] {
        [Source::Console, net(1), net(2), Source::Ros2]
    }

    fn step() -> impl Strategy<Value = Step> {
        let ask = prop_oneof![
            Just(Ask::Engage),
            Just(Ask::Disengage),
            Just(Ask::Stop),
            Just(Ask::Release),
            Just(Ask::Take),
            Just(Ask::Hold),
            (-1.2f64..1.2).prop_map(|v| Ask::Set(DeviceId(0), Command::Set(v))),
            (0.0f64..1.0).prop_map(|v| Ask::Set(DeviceId(2), Command::Set(v))),
            (-1.0f64..1.0).prop_map(Ask::Accel),
            (-1.0f64..1.0, 0u64..800).prop_map(|(a, ms)| Ask::Held(Held {
                accel: a,
                lease: Duration::from_millis(ms),
                release: -0.3,
            })),
            (0u64..800).prop_map(|ms| Ask::Renew(Duration::from_millis(ms))),
            (0u8..4).prop_map(|s| Ask::Set(DeviceId(3), Command::State(s))),
        ];
        prop_oneof![
            4 => (0u8..4, ask).prop_map(|(s, a)| Step::Ask(s, a)),
            1 => (0u16..800).prop_map(Step::Wait),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]
        /// Random interleavings of sources and asks: at every step at most one source
        /// commands (and only while engaged), a refused ask changes no slot, a stop is
        /// never refused, and the network never overrides the console's command.
        #[test]
        fn ownership_holds_over_any_interleaving(steps in prop::collection::vec(step(), 1..60)) {
            let g = sample::gate(Instant::now());
            let mut now = Instant::now();
            for s in steps {
                match s {
                    Step::Wait(ms) => {
                        now += Duration::from_millis(ms.into());
                        g.watch(now);
                    }
                    Step::Ask(who, ask) => {
                        let source = sources()[who as usize];
                        let before = slots(&g);
                        let commander = g.commander();
                        let done = g.admit(source, ask, now);
                        if matches!(ask, Ask::Stop | Ask::Disengage) {
                            prop_assert!(done.is_ok(), "a stop was refused: {done:?}");
                            prop_assert_eq!(g.commander(), None);
                        }
                        if done.is_err() {
                            prop_assert_eq!(slots(&g), before.clone(), "refused {:?} by {:?} changed a slot", ask, source);
                        }
                        if commander == Some(Source::Console) && !source.is_console()
                            && !matches!(ask, Ask::Stop | Ask::Disengage)
                        {
                            prop_assert_eq!(g.commander(), Some(Source::Console));
                            prop_assert_eq!(slots(&g), before, "{:?} by {:?} moved the console's vehicle", ask, source);
                        }
                    }
                }
                let c = g.commander();
                prop_assert!(c.is_none() || g.is_engaged());
            }
        }
    }
}
