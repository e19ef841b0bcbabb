//! The simulated vehicle behind every simulated device. Each device has its own
//! simulated state from the vehicle file: a setpoint actuator moves toward its command
//! at its `[device.sim] rate` and with its `lag`, after its transport `delay`, ignoring
//! a change within its `deadband`, and with its `backlash` between its drive and what
//! its position reading sees; a state actuator settles into a new
//! state after `settle` (reporting `transit` meanwhile); a sensor's readings are
//! constants, ramps or noise. The vehicle itself — speed, engine, rpm, coolant, the
//! e-stop — works through the role bindings: the throttle's position drives, the
//! brake's stops, the gear's state picks the direction, the starter cranks. So Alice
//! behaves as she always did, and any other vehicle file gets a plausible vehicle.
//!
//! State advances with wall time on every access, so no extra thread is needed.

use crate::config::{Bindings, ReadingKind, Role, SimReading, VehicleConfig};
use crate::value::{flush_subnormal, Command, Control, DeviceId, EstopState, Kind, Reading};
use std::collections::VecDeque;
use std::time::{Duration, Instant};

const IDLE_RPM: f64 = 700.0;
/// Full-throttle acceleration, m/s².
const GAS_ACCEL: f64 = 3.0;
/// Full-brake deceleration, m/s².
const BRAKE_DECEL: f64 = 8.0;
/// How long the starter cranks before the engine catches.
pub(crate) const CRANK_TIME: Duration = Duration::from_millis(800);
/// A drive's status bits: its fault latch, and its power stage off (informational).
pub(crate) const DRIVE_FAULT: u16 = 0x0001;
pub(crate) const DRIVE_DISABLED: u16 = 0x0100;

/// What a device's readings may show of the simulated vehicle ([`Model::shows`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Shown {
    /// The e-stop's state.
    Estop,
    /// The engine: its rpm, or whether it runs.
    Engine,
    /// The device's own position.
    Position,
}

/// Where a simulated reading comes from.
#[derive(Clone, Debug, PartialEq)]
enum Source {
    Position,
    Velocity,
    State,
    Speed,
    Rpm,
    Coolant,
    Running,
    /// The e-stop, as state indices of disable, pause, run.
    Estop([u8; 3]),
    Configured(SimReading),
}

/// One simulated device.
#[derive(Clone, Debug)]
pub struct SimDevice {
    pub name: String,
    pub kind: Kind,
    pub range: [f64; 2],
    /// A setpoint actuator's position (what its reading sees, past the backlash), the
    /// command its drive follows, and how fast it moved last step.
    pub position: f64,
    pub command: f64,
    pub velocity: f64,
    /// Where its drive is: the position is this, give or take half the backlash.
    drive: f64,
    rate: Option<f64>,
    lag: Option<f64>,
    deadband: f64,
    backlash: f64,
    /// Transport delay, seconds.
    delay: f64,
    /// Set points received and not yet acted on, with the model time they take effect.
    delayed: VecDeque<(f64, f64)>,
    /// A state actuator's state, and the state it is settling into (and when).
    pub state: u8,
    target: Option<(u8, Instant)>,
    settle: Duration,
    /// A state actuator's states by name, and their other words (aliases).
    states: Vec<String>,
    aliases: Vec<(String, u8)>,
    transit: Option<u8>,
    /// A drive's power stage is on.
    pub enabled: bool,
    /// The drive latched a fault: it holds still until disabled and enabled.
    pub fault_latched: bool,
    /// Fault injection: the motor does not move, and the drive does not notice.
    pub stuck: bool,
    /// Fault injection: an offset added to the position it reports (a slipped sensor).
    pub bias: f64,
    /// Fault injection: a driver's hand pushes the device toward this position,
    /// stronger than its drive.
    pub hand: Option<f64>,
    /// What the device's own watchdog commands.
    pub safe: Option<Command>,
    sources: Vec<Source>,
}

impl SimDevice {
    fn step(&mut self, h: f64) {
        if self.kind != Kind::Setpoint {
            return;
        }
        let before = self.position;
        if let Some(to) = self.hand {
            // Twice as fast as the drive, and never slower than a range a second; the
            // hand moves the whole linkage.
            let [lo, hi] = self.range;
            let r = self.rate.unwrap_or(0.0).max(hi - lo) * 2.0;
            self.position += (to.clamp(lo, hi) - self.position).clamp(-r * h, r * h);
            self.drive = self.position;
        } else if self.enabled && !self.fault_latched && !self.stuck {
            let err = self.command - self.drive;
            self.drive += match (self.rate, self.lag) {
                (r, Some(tau)) if tau > 0.0 => {
                    let s = err * (1.0 - (-h / tau).exp());
                    r.map_or(s, |r| s.clamp(-r * h, r * h))
                }
                (Some(r), _) => err.clamp(-r * h, r * h),
                _ => err,
            };
            // The reading follows the drive once the play is taken up.
            let half = self.backlash / 2.0;
            if self.drive - self.position > half {
                self.position = self.drive - half;
            } else if self.position - self.drive > half {
                self.position = self.drive + half;
            }
        }
        // A lag closing on 0 would walk down the subnormal numbers.
        self.position = flush_subnormal(self.position);
        self.drive = flush_subnormal(self.drive);
        self.velocity = flush_subnormal((self.position - before) / h);
    }

    /// A set point reaches the drive: it follows it unless it is within its deadband
    /// of the one it follows.
    fn take(&mut self, v: f64) {
        if (v - self.command).abs() >= self.deadband {
            self.command = v;
        }
    }

    /// A set point arrives at model time `now`: taken at once, or after the delay.
    fn receive(&mut self, v: f64, now: f64) {
        if self.delay > 0.0 {
            self.delayed.push_back((now + self.delay, v));
        } else {
            self.take(v);
        }
    }

    /// The set points whose delay is over at model time `now` reach the drive.
    fn arrive(&mut self, now: f64) {
        while let Some(&(due, v)) = self.delayed.front() {
            if due > now + 1e-9 {
                break;
            }
            self.delayed.pop_front();
            self.take(v);
        }
    }

    /// The state it reports now: mid-shift, its transit state (if it has one) or the
    /// one it left.
    fn reported_state(&self) -> u8 {
        self.state
    }

    /// The fraction of its range (0 at the bottom, 1 at the top).
    fn fraction(&self) -> f64 {
        let [lo, hi] = self.range;
        if hi > lo {
            ((self.position - lo) / (hi - lo)).clamp(0.0, 1.0)
        } else {
            0.0
        }
    }
}

/// The simulated vehicle.
#[derive(Clone, Debug)]
pub struct Model {
    pub devices: Vec<SimDevice>,
    roles: Bindings,
    pub running: bool,
    pub rpm: f64,
    /// Signed: positive forward.
    pub velocity: f64,
    pub coolant: f64,
    pub estop: EstopState,
    cranking: Option<Instant>,
    /// Fault injection: the starter turns but the engine never catches.
    pub(crate) start_fails: bool,
    /// A small deterministic noise source.
    noise: u64,
    started: Instant,
    last: Instant,
    /// Seconds of model time advanced since it started (the clock of delayed commands).
    clock: f64,
}

impl Model {
    /// The vehicle of `config` at rest: engine idling, brake on, e-stop in run, every
    /// actuator at its safe value (or the bottom of its range, or its first state).
    pub fn new(config: &VehicleConfig) -> Model {
        let b = &config.roles;
        let safe = crate::safety::safe::state(config);
        let devices = config
            .devices
            .iter()
            .enumerate()
            .map(|(i, d)| {
                let id = DeviceId(i as u16);
                let own_safe = safe.iter().find(|(x, _)| *x == id).map(|(_, c)| *c);
                let start = match own_safe {
                    Some(Command::Set(v)) => v,
                    _ => 0.0f64.clamp(d.range[0], d.range[1]),
                };
                let state = match own_safe {
                    Some(Command::State(s)) => s,
                    _ => b
                        .gear
                        .as_ref()
                        .filter(|g| g.device == id)
                        .and_then(|g| g.park)
                        .unwrap_or(0),
                };
                let sources = d
                    .readings
                    .iter()
                    .enumerate()
                    .map(|(r, spec)| {
                        let at = crate::config::roles::ReadingRef {
                            device: id,
                            reading: r,
                        };
                        if let Some(c) = d.sim.readings.get(&spec.name) {
                            return Source::Configured(c.clone());
                        }
                        if b.estop.is_some_and(|e| e.at == at) {
                            return Source::Estop(b.estop.expect("checked").states);
                        }
                        if b.speed == Some(at) {
                            return Source::Speed;
                        }
                        if b.engine_running == Some(at) {
                            return Source::Running;
                        }
                        match (spec.name.as_str(), &spec.kind) {
                            ("position", _) if d.kind == Kind::Setpoint => Source::Position,
                            ("velocity", _) if d.kind == Kind::Setpoint => Source::Velocity,
                            ("state", _) if d.kind == Kind::State => Source::State,
                            ("speed", _) => Source::Speed,
                            ("rpm", _) => Source::Rpm,
                            ("coolant", _) => Source::Coolant,
                            ("running", _) => Source::Running,
                            (_, ReadingKind::States(s)) if s.iter().any(|x| x == "run") => {
                                let idx =
                                    |n: &str| s.iter().position(|x| x == n).unwrap_or(0) as u8;
                                Source::Estop([idx("disable"), idx("pause"), idx("run")])
                            }
                            _ => Source::Configured(SimReading {
                                value: 0.0,
                                noise: 0.0,
                                ramp_to: None,
                                ramp_time: Duration::from_secs(60),
                                per_position: None,
                            }),
                        }
                    })
                    .collect();
                SimDevice {
                    name: d.name.clone(),
                    kind: d.kind,
                    range: d.range,
                    position: start,
                    command: start,
                    velocity: 0.0,
                    drive: start,
                    rate: d.sim.rate,
                    lag: d.sim.lag.map(|l| l.as_secs_f64()),
                    deadband: d.sim.deadband,
                    backlash: d.sim.backlash,
                    delay: d.sim.delay.as_secs_f64(),
                    delayed: VecDeque::new(),
                    state,
                    target: None,
                    settle: d.sim.settle,
                    states: d.states.clone(),
                    aliases: d.aliases.clone(),
                    transit: d.sim.transit.as_deref().and_then(|t| d.state_index(t)),
                    enabled: true,
                    fault_latched: false,
                    stuck: false,
                    bias: 0.0,
                    hand: None,
                    safe: own_safe,
                    sources,
                }
            })
            .collect();
        let now = Instant::now();
        Model {
            devices,
            roles: b.clone(),
            running: true,
            rpm: IDLE_RPM,
            velocity: 0.0,
            coolant: 85.0,
            estop: EstopState::Run,
            cranking: None,
            start_fails: false,
            noise: 0x2545_f491_4f6c_dd1d,
            started: now,
            last: now,
            clock: 0.0,
        }
    }

    /// A device by name.
    pub fn find(&self, name: &str) -> Option<DeviceId> {
        self.devices
            .iter()
            .position(|d| d.name == name)
            .map(|i| DeviceId(i as u16))
    }

    pub fn device(&self, id: DeviceId) -> &SimDevice {
        &self.devices[id.index()]
    }

    pub(crate) fn device_mut(&mut self, id: DeviceId) -> &mut SimDevice {
        &mut self.devices[id.index()]
    }

    /// Whether device `id`'s readings, as the model serves them on its own port, show
    /// `what`: what a simulated fault needs to be seen at all.
    pub(crate) fn shows(&self, id: DeviceId, what: Shown) -> bool {
        self.device(id).sources.iter().any(|s| match what {
            Shown::Estop => matches!(s, Source::Estop(_)),
            Shown::Engine => matches!(s, Source::Rpm | Source::Running),
            Shown::Position => matches!(s, Source::Position),
        })
    }

    /// The device bound to the starter role.
    pub(crate) fn starter(&self) -> Option<DeviceId> {
        self.roles.starter
    }

    /// The device bound to a role.
    pub fn bound(&self, role: Role) -> Option<&SimDevice> {
        self.roles.device(role).map(|id| self.device(id))
    }

    /// The gear state reported now drives the wheels (no gearbox: always forward).
    fn drive_direction(&self) -> f64 {
        let Some(g) = &self.roles.gear else {
            return 1.0;
        };
        let d = self.device(g.device);
        if d.target.is_some() {
            return 0.0;
        }
        if g.forward.contains(&d.state) {
            1.0
        } else if g.reverse.contains(&d.state) {
            -1.0
        } else {
            0.0
        }
    }

    fn parked(&self) -> bool {
        self.roles
            .gear
            .as_ref()
            .is_some_and(|g| g.park == Some(self.device(g.device).reported_state()))
    }

    /// Advance the model to now.
    pub fn step(&mut self) {
        let now = Instant::now();
        let dt = (now - self.last).as_secs_f64();
        self.last = now;
        if dt <= 0.0 {
            return;
        }
        // Integrate in small steps so large gaps stay stable, and end a step where a
        // delayed command takes effect, so it acts at its time to the microsecond.
        let mut left = dt;
        while left > 0.0 {
            let due = self
                .devices
                .iter()
                .filter_map(|d| d.delayed.front().map(|x| x.0 - self.clock))
                .fold(f64::INFINITY, f64::min);
            let h = left.min(0.01).min(due.max(1e-6));
            self.advance(h);
            self.clock += h;
            left -= h;
            let now = self.clock;
            for d in &mut self.devices {
                d.arrive(now);
            }
        }
        for d in &mut self.devices {
            if let Some((s, at)) = d.target {
                if now >= at {
                    d.state = s;
                    d.target = None;
                }
            }
        }
        if let Some(at) = self.cranking {
            if now >= at {
                self.cranking = None;
                if !self.start_fails {
                    self.running = true;
                }
            }
        }
    }

    fn advance(&mut self, h: f64) {
        for d in &mut self.devices {
            d.step(h);
        }
        let throttle = self.bound(Role::Throttle).map_or(0.0, SimDevice::fraction);
        let brake = self.bound(Role::Brake).map_or(0.0, SimDevice::fraction);
        let dir = self.drive_direction();
        let in_gear = dir != 0.0 && self.running;
        let drive = if in_gear {
            throttle * GAS_ACCEL * dir
        } else {
            0.0
        };
        let stop = brake * BRAKE_DECEL + 0.3 + 0.02 * self.velocity.abs();
        let v = self.velocity + drive * h;
        // Braking and drag only slow the vehicle; they never reverse it.
        let slowed = v.abs() - stop * h;
        self.velocity = if self.parked() || slowed <= 0.0 {
            0.0
        } else {
            slowed * v.signum()
        };
        let target = if !self.running {
            0.0
        } else if in_gear {
            IDLE_RPM + throttle * 2500.0 + self.velocity.abs() * 80.0
        } else {
            IDLE_RPM + throttle * 4500.0
        };
        self.rpm += (target - self.rpm) * (1.0 - (-h / 0.3).exp());
        let warm = if self.running { 90.0 } else { 20.0 };
        self.coolant += (warm - self.coolant) * (1.0 - (-h / 600.0).exp());
        // An engine winding down decays toward 0 rpm (as the velocity would).
        self.rpm = flush_subnormal(self.rpm);
        self.velocity = flush_subnormal(self.velocity);
    }

    /// Fault injection: a drive latches a fault (it stops following).
    pub fn jam(&mut self, id: DeviceId) {
        self.step();
        self.device_mut(id).fault_latched = true;
    }

    /// Fault injection: a driver's hand pushes a drive toward `to` (`None`: lets go).
    pub(crate) fn set_override(&mut self, id: DeviceId, to: Option<f64>) {
        self.step();
        self.device_mut(id).hand = to;
    }

    /// Fault injection: a driver's hand moves state device `id`'s lever to the state
    /// named `word` (a name or an alias): it is in that state at once, any shift under
    /// way abandoned. The state's name, or what the device's states are.
    pub(crate) fn lever(&mut self, id: DeviceId, word: &str) -> Result<String, String> {
        self.step();
        let d = self.device_mut(id);
        let named = d
            .states
            .iter()
            .position(|n| n.eq_ignore_ascii_case(word))
            .map(|i| i as u8)
            .or_else(|| {
                d.aliases
                    .iter()
                    .find(|(a, _)| a.eq_ignore_ascii_case(word))
                    .map(|a| a.1)
            });
        let Some(s) = named.filter(|&s| usize::from(s) < d.states.len()) else {
            return Err(format!(
                "lever: {word:?} is not a state of {} ({})",
                d.name,
                d.states.join(", ")
            ));
        };
        d.state = s;
        d.target = None;
        Ok(d.states[usize::from(s)].clone())
    }

    /// The device's own watchdog tripped: no command frame for too long. It goes to
    /// its safe value by itself.
    pub(crate) fn watchdog_trip(&mut self, id: DeviceId) -> Option<Command> {
        self.step();
        let safe = self.device(id).safe?;
        let d = self.device_mut(id);
        match safe {
            Command::Set(v) => {
                d.delayed.clear();
                d.command = v;
            }
            Command::State(s) => d.state = s,
            Command::Control(_) => {}
        }
        Some(safe)
    }

    /// The engine dies (a stall): rpm falls to zero until the starter runs.
    pub fn stall(&mut self) {
        self.step();
        self.running = false;
    }

    fn gaussian(&mut self) -> f64 {
        // xorshift64*, then the sum of four uniforms: a bell shape, σ ≈ 0.58.
        let mut sum = 0.0;
        for _ in 0..4 {
            self.noise ^= self.noise >> 12;
            self.noise ^= self.noise << 25;
            self.noise ^= self.noise >> 27;
            let u =
                (self.noise.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64;
            sum += u - 0.5;
        }
        sum / 0.577
    }

    /// What a device reports now.
    pub fn reading(&mut self, id: DeviceId) -> Reading {
        self.step();
        let elapsed = self.started.elapsed().as_secs_f64();
        let mut r = Reading::default();
        let sources = self.devices[id.index()].sources.clone();
        for (i, src) in sources.iter().enumerate() {
            let d = &self.devices[id.index()];
            let v = match src {
                Source::Position => d.position + d.bias,
                Source::Velocity => d.velocity,
                Source::State => d.reported_state() as f64,
                Source::Speed => self.velocity.abs(),
                Source::Rpm => self.rpm,
                Source::Coolant => self.coolant,
                Source::Running => f64::from(u8::from(self.running)),
                Source::Estop([disable, pause, run]) => f64::from(match self.estop {
                    EstopState::Disable => *disable,
                    EstopState::Pause => *pause,
                    EstopState::Run => *run,
                }),
                Source::Configured(c) => {
                    let base = match (c.per_position, c.ramp_to) {
                        (Some(k), _) => d.position * k,
                        (None, Some(to)) => {
                            let t = (elapsed / c.ramp_time.as_secs_f64().max(1e-3)).min(1.0);
                            c.value + (to - c.value) * t
                        }
                        (None, None) => c.value,
                    };
                    if c.noise > 0.0 {
                        base + c.noise * self.gaussian()
                    } else {
                        base
                    }
                }
            };
            r.set(i, v);
        }
        let d = &self.devices[id.index()];
        if d.fault_latched {
            r.fault |= DRIVE_FAULT;
        }
        if !d.enabled {
            r.fault |= DRIVE_DISABLED;
        }
        r
    }

    /// Apply a command that a device received. Devices clamp set points to their
    /// travel; they do not enforce adrive's interlocks.
    pub fn command(&mut self, id: DeviceId, command: Command) -> Result<(), String> {
        self.step();
        let is_starter = self.roles.starter == Some(id);
        let gear_drives = self.drive_direction() != 0.0
            || self
                .roles
                .gear
                .as_ref()
                .is_some_and(|g| self.device(g.device).target.is_some());
        let d = &mut self.devices[id.index()];
        match (d.kind, command) {
            (Kind::Sensor, _) => return Err("a sensor takes no commands".into()),
            (Kind::Setpoint, Command::Set(v)) => {
                d.receive(v.clamp(d.range[0], d.range[1]), self.clock)
            }
            (Kind::State, Command::State(s)) => {
                // Where it is heading: a new state starts a new shift (through its
                // transit state, if it has one); the state it is in ends one early.
                let heading = d.target.map_or(d.state, |t| t.0);
                if s != heading {
                    if let Some(t) = d.transit.filter(|_| !d.settle.is_zero()) {
                        d.state = t;
                    }
                    d.target = (d.state != s && !d.settle.is_zero())
                        .then(|| (s, Instant::now() + d.settle));
                    if d.target.is_none() {
                        d.state = s;
                    }
                }
            }
            (_, Command::Control(Control::Start)) if is_starter => {
                if gear_drives {
                    return Err("the starter runs only out of gear".into());
                }
                if !self.running && self.cranking.is_none() {
                    self.cranking = Some(Instant::now() + CRANK_TIME);
                }
            }
            (_, Command::Control(Control::Start)) => return Err("no starter here".into()),
            (_, Command::Control(Control::Disable)) => d.enabled = false,
            (_, Command::Control(Control::Enable)) => {
                // A latched fault clears on a disable → enable cycle.
                if !d.enabled {
                    d.fault_latched = false;
                }
                d.enabled = true;
            }
            (_, Command::Control(Control::Home)) => {
                if d.fault_latched && d.enabled {
                    return Err("drive fault latched: disable and enable first".into());
                }
                d.fault_latched = false;
                d.enabled = true;
                d.delayed.clear();
                d.command = d.drive;
            }
            (kind, other) => return Err(format!("a {kind} device cannot take {other:?}")),
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alice() -> (Model, impl Fn(&str) -> DeviceId) {
        let cfg = VehicleConfig::alice();
        let names: Vec<String> = cfg.devices.iter().map(|d| d.name.clone()).collect();
        (Model::new(&cfg), move |n: &str| {
            DeviceId(names.iter().position(|x| x == n).unwrap() as u16)
        })
    }

    fn run_for(m: &mut Model, secs: f64) {
        // Move the model's clock back instead of sleeping.
        m.last -= Duration::from_secs_f64(secs);
        m.step();
    }

    fn settle(m: &mut Model) {
        for d in &mut m.devices {
            if let Some((_, at)) = d.target.as_mut() {
                *at = Instant::now();
            }
        }
        m.step();
    }

    const DRIVE: u8 = 3;

    /// The incident: the simulated gas and brake (first-order lags) closing on 0, and
    /// the engine winding down to 0 rpm, walked down the subnormal numbers within a
    /// minute; they reached the readings of a 100 s recording. Ten idle minutes, every
    /// number the model holds checked at each step.
    #[test]
    fn ten_idle_minutes_leave_no_subnormal_number_in_the_model() {
        let (mut m, id) = alice();
        m.command(id("gas"), Command::Set(0.7)).unwrap();
        m.command(id("brake"), Command::Set(0.0)).unwrap();
        for _ in 0..100 {
            m.advance(0.01);
        }
        m.command(id("gas"), Command::Set(0.0)).unwrap();
        m.running = false;
        for step in 0..60_000 {
            m.advance(0.01);
            let numbers = m
                .devices
                .iter()
                .flat_map(|d| [d.position, d.velocity])
                .chain([m.rpm, m.velocity, m.coolant]);
            for x in numbers {
                assert!(!x.is_subnormal(), "{x:e} after {} s", step / 100);
            }
        }
        assert_eq!(m.device(id("gas")).position, 0.0);
        assert_eq!(m.rpm, 0.0);
    }

    #[test]
    fn steering_moves_at_a_limited_rate() {
        let (mut m, id) = alice();
        m.command(id("steer"), Command::Set(1.0)).unwrap();
        run_for(&mut m, 0.5);
        let s = m.device(id("steer")).position;
        assert!((s - 0.5).abs() < 0.02, "{s}");
        run_for(&mut m, 1.0);
        assert_eq!(m.device(id("steer")).position, 1.0);
    }

    /// Alice's steering with `[device.sim]` edited by `edit`.
    fn steering(edit: impl Fn(&mut crate::config::SimConfig)) -> (Model, DeviceId) {
        let mut cfg = VehicleConfig::alice();
        let i = cfg.devices.iter().position(|d| d.name == "steer").unwrap();
        edit(&mut cfg.devices[i].sim);
        cfg.devices[i].check_limits().unwrap();
        (Model::new(&cfg), DeviceId(i as u16))
    }

    fn at(m: &Model, s: DeviceId) -> f64 {
        m.device(s).position
    }

    #[test]
    fn a_change_within_the_deadband_does_not_move_it() {
        let (mut m, s) = steering(|c| c.deadband = 0.1);
        m.command(s, Command::Set(0.099)).unwrap();
        run_for(&mut m, 1.0);
        assert_eq!(at(&m, s), 0.0, "a step smaller than the deadband");
        m.command(s, Command::Set(0.1)).unwrap();
        run_for(&mut m, 1.0);
        assert_eq!(at(&m, s), 0.1, "a step of the deadband moves it");
        m.command(s, Command::Set(0.05)).unwrap();
        run_for(&mut m, 1.0);
        assert_eq!(at(&m, s), 0.1, "measured from the command it follows");
        m.command(s, Command::Set(-0.3)).unwrap();
        run_for(&mut m, 1.0);
        assert_eq!(at(&m, s), -0.3);
    }

    #[test]
    fn approached_from_below_and_from_above_it_settles_a_backlash_apart() {
        let (mut m, s) = steering(|c| c.backlash = 0.04);
        let settle_at = |m: &mut Model, via: f64| {
            m.command(s, Command::Set(via)).unwrap();
            run_for(m, 2.0);
            m.command(s, Command::Set(0.2)).unwrap();
            run_for(m, 2.0);
            at(m, s)
        };
        let below = settle_at(&mut m, -0.5);
        let above = settle_at(&mut m, 0.9);
        assert!((below - 0.18).abs() < 1e-9, "{below}");
        assert!((above - 0.22).abs() < 1e-9, "{above}");
        // Reversing, the reading stays put until the play is taken up.
        m.command(s, Command::Set(0.25)).unwrap();
        run_for(&mut m, 0.035);
        assert!((at(&m, s) - 0.22).abs() < 1e-9, "{}", at(&m, s));
    }

    #[test]
    fn nothing_moves_before_the_transport_delay() {
        let (mut m, s) = steering(|c| c.delay = Duration::from_millis(100));
        m.command(s, Command::Set(1.0)).unwrap();
        run_for(&mut m, 0.0995);
        assert_eq!(at(&m, s), 0.0, "within the delay");
        run_for(&mut m, 0.1005);
        // A range a second for the 100 ms since the delay ran out.
        assert!((at(&m, s) - 0.1).abs() < 1e-4, "{}", at(&m, s));
        // Commands keep their order and their own delays.
        m.command(s, Command::Set(-1.0)).unwrap();
        run_for(&mut m, 0.05);
        m.command(s, Command::Set(0.5)).unwrap();
        run_for(&mut m, 0.06);
        assert_eq!(m.device(s).command, -1.0);
        run_for(&mut m, 0.05);
        assert_eq!(m.device(s).command, 0.5);
    }

    #[test]
    fn with_a_rate_and_a_lag_it_follows_the_lag_no_faster_than_the_rate() {
        let (mut m, s) = steering(|c| c.lag = Some(Duration::from_millis(100)));
        m.command(s, Command::Set(1.0)).unwrap();
        run_for(&mut m, 0.2);
        // Far from its command the rate holds it: a range a second.
        assert!((at(&m, s) - 0.2).abs() < 1e-3, "{}", at(&m, s));
        run_for(&mut m, 2.0);
        // Close to it the lag: 0.1 away at 1/s is where the lag takes over, then e^-t/τ.
        let left = 1.0 - at(&m, s);
        assert!(left > 0.0 && left < 1e-6, "{left}");
    }

    #[test]
    fn a_hand_pushes_a_drive_past_its_command_and_lets_go() {
        let (mut m, id) = alice();
        let s = id("steer");
        m.command(s, Command::Set(0.0)).unwrap();
        m.set_override(s, Some(-0.6));
        run_for(&mut m, 1.0);
        assert_eq!(
            m.device(s).position,
            -0.6,
            "the hand is stronger than the drive"
        );
        m.set_override(s, None);
        run_for(&mut m, 1.0);
        assert_eq!(m.device(s).position, 0.0, "let go, the drive takes it back");
    }

    #[test]
    fn gas_in_drive_moves_the_vehicle_and_brake_stops_it() {
        let (mut m, id) = alice();
        m.command(id("trans"), Command::State(DRIVE)).unwrap();
        settle(&mut m);
        m.command(id("brake"), Command::Set(0.0)).unwrap();
        m.command(id("gas"), Command::Set(0.5)).unwrap();
        run_for(&mut m, 3.0);
        assert!(m.velocity > 2.0, "{}", m.velocity);
        assert!(m.rpm > IDLE_RPM + 500.0);
        m.command(id("gas"), Command::Set(0.0)).unwrap();
        m.command(id("brake"), Command::Set(1.0)).unwrap();
        run_for(&mut m, 3.0);
        assert_eq!(m.velocity, 0.0);
    }

    #[test]
    fn gas_in_park_does_not_move_the_vehicle() {
        let (mut m, id) = alice();
        m.command(id("brake"), Command::Set(0.0)).unwrap();
        m.command(id("gas"), Command::Set(1.0)).unwrap();
        run_for(&mut m, 2.0);
        assert_eq!(m.velocity, 0.0);
        assert!(m.rpm > 3000.0);
    }

    #[test]
    fn a_shift_passes_through_neutral_and_takes_time() {
        let (mut m, id) = alice();
        let trans = id("trans");
        m.command(trans, Command::State(DRIVE)).unwrap();
        assert_eq!(m.reading(trans).get(0), Some(2.0), "neutral while shifting");
        settle(&mut m);
        assert_eq!(m.reading(trans).get(0), Some(DRIVE as f64));
        // Neutral commanded mid-shift: it stays there.
        m.command(trans, Command::State(0)).unwrap();
        assert_eq!(m.reading(trans).get(0), Some(2.0));
        m.command(trans, Command::State(2)).unwrap();
        settle(&mut m);
        assert_eq!(m.reading(trans).get(0), Some(2.0), "stopped in neutral");
    }

    #[test]
    fn a_hand_on_the_lever_shifts_at_once_without_a_command() {
        let (mut m, id) = alice();
        let trans = id("trans");
        m.command(trans, Command::State(DRIVE)).unwrap();
        assert_eq!(m.lever(trans, "P"), Ok("park".into()), "an alias");
        assert_eq!(m.reading(trans).get(0), Some(0.0), "the shift abandoned");
        assert_eq!(m.lever(trans, "drive"), Ok("drive".into()));
        assert_eq!(m.reading(trans).get(0), Some(DRIVE as f64), "at once");
        let e = m.lever(trans, "low").unwrap_err();
        assert!(e.contains("park, reverse, neutral, drive"), "{e}");
    }

    #[test]
    fn a_latched_drive_fault_clears_only_on_disable_then_enable() {
        let (mut m, id) = alice();
        let s = id("steer");
        m.jam(s);
        m.command(s, Command::Set(1.0)).unwrap();
        run_for(&mut m, 0.5);
        assert_eq!(m.device(s).position, 0.0, "a faulted drive holds still");
        assert_eq!(m.reading(s).fault & DRIVE_FAULT, DRIVE_FAULT);
        assert!(m.command(s, Command::Control(Control::Home)).is_err());
        m.command(s, Command::Control(Control::Enable)).unwrap();
        assert!(
            m.device(s).fault_latched,
            "enable alone does not clear the latch"
        );
        m.command(s, Command::Control(Control::Disable)).unwrap();
        m.command(s, Command::Control(Control::Enable)).unwrap();
        m.command(s, Command::Control(Control::Home)).unwrap();
        assert_eq!(m.reading(s).fault, 0);
        assert_eq!(
            m.device(s).command,
            m.device(s).position,
            "homing holds where it is"
        );
    }

    #[test]
    fn the_starter_restarts_a_stalled_engine_only_out_of_gear() {
        let (mut m, id) = alice();
        let (trans, obd) = (id("trans"), id("obd"));
        m.command(trans, Command::State(DRIVE)).unwrap();
        settle(&mut m);
        m.stall();
        run_for(&mut m, 2.0);
        let r = m.reading(obd);
        assert_eq!(r.get(3), Some(0.0), "not running");
        assert!(r.get(0).unwrap() < 50.0, "rpm");
        assert!(m.command(trans, Command::Control(Control::Start)).is_err());
        m.command(trans, Command::State(0)).unwrap();
        settle(&mut m);
        m.command(trans, Command::Control(Control::Start)).unwrap();
        if let Some(at) = m.cranking.as_mut() {
            *at = Instant::now();
        }
        m.step();
        assert!(m.running);
    }

    #[test]
    fn the_device_watchdog_releases_gas_and_applies_the_brake() {
        let (mut m, id) = alice();
        m.command(id("gas"), Command::Set(0.6)).unwrap();
        m.command(id("brake"), Command::Set(0.0)).unwrap();
        m.watchdog_trip(id("gas"));
        m.watchdog_trip(id("brake"));
        assert_eq!(
            (m.device(id("gas")).command, m.device(id("brake")).command),
            (0.0, 1.0)
        );
        assert_eq!(
            m.watchdog_trip(id("steer")),
            None,
            "steering has no safe value"
        );
    }

    #[test]
    fn sensors_refuse_commands() {
        let (mut m, id) = alice();
        assert!(m.command(id("obd"), Command::Set(1.0)).is_err());
        assert!(m.command(id("steer"), Command::State(1)).is_err());
    }

    #[test]
    fn a_configured_reading_ramps_and_a_brake_reports_pressure() {
        let (mut m, id) = alice();
        let r = m.reading(id("brake"));
        assert_eq!(r.get(1), Some(80.0), "full brake: 80 bar");
        assert_eq!(m.reading(id("estop")).get(0), Some(2.0), "run");
    }
}
