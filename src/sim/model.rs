//! A simple model of Alice that ties the simulated devices together: steering moves
//! toward its command at a limited rate, gas and brake follow with a lag, shifting
//! takes time, engine rpm and vehicle speed respond to gas, brake and gear, and the
//! e-stop state can be changed from outside. State advances with wall time on every
//! access, so no extra thread is needed.

use crate::value::{Command, Control, EstopState, Gear, Reading, Role};
use std::time::{Duration, Instant};

/// Steering slew rate, full range per second.
pub const STEER_RATE: f64 = 1.0;
/// Time a shift takes.
pub const SHIFT_TIME: Duration = Duration::from_millis(600);
const PEDAL_TAU: f64 = 0.08;
const IDLE_RPM: f64 = 700.0;
/// Full-gas acceleration, m/s².
const GAS_ACCEL: f64 = 3.0;
/// Full-brake deceleration, m/s².
const BRAKE_DECEL: f64 = 8.0;
/// Brake line pressure at full brake, bar.
const BRAKE_BAR: f64 = 80.0;
/// How long the starter cranks before the engine catches.
pub const CRANK_TIME: Duration = Duration::from_millis(800);
/// Steering status bits: the drive's fault latch, and its power stage off.
pub const STEER_FAULT: u16 = 0x0001;
pub const STEER_DISABLED: u16 = 0x0100;

#[derive(Clone, Debug)]
pub struct Model {
    pub steer: f64,
    pub steer_cmd: f64,
    pub steer_vel: f64,
    pub gas: f64,
    pub gas_cmd: f64,
    pub brake: f64,
    pub brake_cmd: f64,
    pub gear: Gear,
    shifting: Option<(Gear, Instant)>,
    pub running: bool,
    pub rpm: f64,
    /// Signed: positive forward.
    pub velocity: f64,
    pub coolant: f64,
    pub estop: EstopState,
    /// The steering drive's power stage is on.
    pub steer_enabled: bool,
    /// The steering drive latched a fault: it holds still until disabled and enabled.
    pub steer_fault: bool,
    cranking: Option<Instant>,
    /// Fault injection: the starter turns but the engine never catches.
    pub start_fails: bool,
    /// Fault injection: the steering motor does not move, and its drive does not
    /// notice (no fault bits).
    pub steer_stuck: bool,
    /// Fault injection: an offset added to the position each device reports (a
    /// slipped sensor), by role.
    pub bias: [f64; 6],
    last: Instant,
}

impl Default for Model {
    fn default() -> Self {
        Model::new()
    }
}

impl Model {
    /// Alice parked, engine idling, brake on, e-stop in run.
    pub fn new() -> Model {
        Model {
            steer: 0.0,
            steer_cmd: 0.0,
            steer_vel: 0.0,
            gas: 0.0,
            gas_cmd: 0.0,
            brake: 1.0,
            brake_cmd: 1.0,
            gear: Gear::Park,
            shifting: None,
            running: true,
            rpm: IDLE_RPM,
            velocity: 0.0,
            coolant: 85.0,
            estop: EstopState::Run,
            steer_enabled: true,
            steer_fault: false,
            cranking: None,
            start_fails: false,
            steer_stuck: false,
            bias: [0.0; 6],
            last: Instant::now(),
        }
    }

    /// Advance the model to now.
    pub fn step(&mut self) {
        let now = Instant::now();
        let dt = (now - self.last).as_secs_f64();
        self.last = now;
        if dt <= 0.0 {
            return;
        }
        // Integrate in small steps so large gaps stay stable.
        let mut left = dt;
        while left > 0.0 {
            let h = left.min(0.01);
            self.advance(h);
            left -= h;
        }
        if let Some((g, at)) = self.shifting {
            if now >= at {
                self.gear = g;
                self.shifting = None;
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
        let before = self.steer;
        let err = self.steer_cmd - self.steer;
        if self.steer_enabled && !self.steer_fault && !self.steer_stuck {
            self.steer += err.clamp(-STEER_RATE * h, STEER_RATE * h);
        }
        self.steer_vel = (self.steer - before) / h;
        let k = 1.0 - (-h / PEDAL_TAU).exp();
        self.gas += (self.gas_cmd - self.gas) * k;
        self.brake += (self.brake_cmd - self.brake) * k;

        let in_gear = self.shifting.is_none() && self.gear.is_driving() && self.running;
        let dir = if self.gear == Gear::Reverse {
            -1.0
        } else {
            1.0
        };
        let drive = if in_gear {
            self.gas * GAS_ACCEL * dir
        } else {
            0.0
        };
        let stop = self.brake * BRAKE_DECEL + 0.3 + 0.02 * self.velocity.abs();
        let v = self.velocity + drive * h;
        // Braking and drag only slow the vehicle; they never reverse it.
        let slowed = v.abs() - stop * h;
        self.velocity = if self.gear == Gear::Park || slowed <= 0.0 {
            0.0
        } else {
            slowed * v.signum()
        };

        let target = if !self.running {
            0.0
        } else if in_gear {
            IDLE_RPM + self.gas * 2500.0 + self.velocity.abs() * 80.0
        } else {
            IDLE_RPM + self.gas * 4500.0
        };
        self.rpm += (target - self.rpm) * (1.0 - (-h / 0.3).exp());
        let warm = if self.running { 90.0 } else { 20.0 };
        self.coolant += (warm - self.coolant) * (1.0 - (-h / 600.0).exp());
    }

    /// Fault injection: the steering drive latches a fault (it stops following).
    pub fn jam_steering(&mut self) {
        self.step();
        self.steer_fault = true;
    }

    /// The device's own watchdog tripped: no command frame for too long. Gas goes to
    /// zero and the brake comes on, by the device itself.
    pub fn watchdog_trip(&mut self, role: Role) {
        self.step();
        match role {
            Role::Gas => self.gas_cmd = 0.0,
            Role::Brake => self.brake_cmd = 1.0,
            _ => {}
        }
    }

    /// The engine dies (a stall): rpm falls to zero until the starter runs.
    pub fn stall(&mut self) {
        self.step();
        self.running = false;
    }

    /// What `role`'s device reports now.
    pub fn reading(&mut self, role: Role) -> Reading {
        self.step();
        let mut r = Reading::default();
        match role {
            Role::Steer => {
                r.position = Some(self.steer);
                r.velocity = Some(self.steer_vel);
                if self.steer_fault {
                    r.fault |= STEER_FAULT;
                }
                if !self.steer_enabled {
                    r.fault |= STEER_DISABLED;
                }
            }
            Role::Gas => r.position = Some(self.gas),
            Role::Brake => {
                r.position = Some(self.brake);
                r.pressure = Some(self.brake * BRAKE_BAR);
            }
            Role::Trans => r.gear = Some(self.gear),
            Role::Estop => r.estop = Some(self.estop),
            Role::Obd => {
                r.rpm = Some(self.rpm);
                r.speed = Some(self.velocity.abs());
                r.coolant = Some(self.coolant);
                r.running = Some(self.running);
            }
        }
        if let Some(p) = r.position.as_mut() {
            *p += self.bias[role as usize];
        }
        r
    }

    /// Apply a command that `role`'s device received. Devices clamp set points to
    /// their travel; they do not enforce adrive's interlocks.
    pub fn command(&mut self, role: Role, command: Command) -> Result<(), String> {
        self.step();
        match (role, command) {
            (Role::Steer, Command::Set(v)) => self.steer_cmd = v.clamp(-1.0, 1.0),
            (Role::Gas, Command::Set(v)) => self.gas_cmd = v.clamp(0.0, 1.0),
            (Role::Brake, Command::Set(v)) => self.brake_cmd = v.clamp(0.0, 1.0),
            (Role::Trans, Command::Gear(g)) => {
                if g != self.gear && self.shifting.map(|s| s.0) != Some(g) {
                    self.gear = Gear::Neutral;
                    self.shifting = Some((g, Instant::now() + SHIFT_TIME));
                }
            }
            (Role::Steer, Command::Control(c)) => match c {
                Control::Disable => self.steer_enabled = false,
                Control::Enable => {
                    // A latched fault clears on a disable → enable cycle.
                    if !self.steer_enabled {
                        self.steer_fault = false;
                    }
                    self.steer_enabled = true;
                }
                Control::Home => {
                    if self.steer_fault && self.steer_enabled {
                        return Err("drive fault latched: disable and enable first".into());
                    }
                    self.steer_fault = false;
                    self.steer_enabled = true;
                    self.steer_cmd = self.steer;
                }
                Control::Start => return Err("steering has no starter".into()),
            },
            (Role::Trans, Command::Control(Control::Start)) => {
                if self.gear.is_driving() || self.shifting.is_some() {
                    return Err("the starter runs only in park or neutral".into());
                }
                if !self.running && self.cranking.is_none() {
                    self.cranking = Some(Instant::now() + CRANK_TIME);
                }
            }
            (Role::Gas | Role::Brake, Command::Control(_)) => {}
            (Role::Estop | Role::Obd, _) => return Err("sensor".into()),
            _ => return Err(format!("{role} cannot take {command}")),
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_for(m: &mut Model, secs: f64) {
        // Move the model's clock back instead of sleeping.
        m.last -= Duration::from_secs_f64(secs);
        m.step();
    }

    #[test]
    fn steering_moves_at_a_limited_rate() {
        let mut m = Model::new();
        m.command(Role::Steer, Command::Set(1.0)).unwrap();
        run_for(&mut m, 0.5);
        assert!((m.steer - 0.5).abs() < 0.02, "{}", m.steer);
        run_for(&mut m, 1.0);
        assert_eq!(m.steer, 1.0);
    }

    #[test]
    fn gas_in_drive_moves_the_vehicle_and_brake_stops_it() {
        let mut m = Model::new();
        m.gear = Gear::Drive;
        m.command(Role::Brake, Command::Set(0.0)).unwrap();
        m.command(Role::Gas, Command::Set(0.5)).unwrap();
        run_for(&mut m, 3.0);
        assert!(m.velocity > 2.0, "{}", m.velocity);
        assert!(m.rpm > IDLE_RPM + 500.0);
        m.command(Role::Gas, Command::Set(0.0)).unwrap();
        m.command(Role::Brake, Command::Set(1.0)).unwrap();
        run_for(&mut m, 3.0);
        assert_eq!(m.velocity, 0.0);
    }

    #[test]
    fn gas_in_park_does_not_move_the_vehicle() {
        let mut m = Model::new();
        m.command(Role::Brake, Command::Set(0.0)).unwrap();
        m.command(Role::Gas, Command::Set(1.0)).unwrap();
        run_for(&mut m, 2.0);
        assert_eq!(m.velocity, 0.0);
        assert!(m.rpm > 3000.0);
    }

    #[test]
    fn a_shift_passes_through_neutral_and_takes_time() {
        let mut m = Model::new();
        m.command(Role::Trans, Command::Gear(Gear::Drive)).unwrap();
        assert_eq!(m.reading(Role::Trans).gear, Some(Gear::Neutral));
        if let Some((_, at)) = m.shifting.as_mut() {
            *at = Instant::now();
        }
        assert_eq!(m.reading(Role::Trans).gear, Some(Gear::Drive));
    }

    #[test]
    fn a_latched_steering_fault_clears_only_on_disable_then_enable() {
        let mut m = Model::new();
        m.jam_steering();
        m.command(Role::Steer, Command::Set(1.0)).unwrap();
        run_for(&mut m, 0.5);
        assert_eq!(m.steer, 0.0, "a faulted drive holds still");
        assert_eq!(m.reading(Role::Steer).fault & STEER_FAULT, STEER_FAULT);
        assert!(m
            .command(Role::Steer, Command::Control(Control::Home))
            .is_err());
        m.command(Role::Steer, Command::Control(Control::Enable))
            .unwrap();
        assert!(m.steer_fault, "enable alone does not clear the latch");
        m.command(Role::Steer, Command::Control(Control::Disable))
            .unwrap();
        m.command(Role::Steer, Command::Control(Control::Enable))
            .unwrap();
        m.command(Role::Steer, Command::Control(Control::Home))
            .unwrap();
        assert_eq!(m.reading(Role::Steer).fault, 0);
        assert_eq!(m.steer_cmd, m.steer, "homing holds where it is");
    }

    #[test]
    fn the_starter_restarts_a_stalled_engine_only_out_of_gear() {
        let mut m = Model::new();
        m.gear = Gear::Drive;
        m.stall();
        run_for(&mut m, 2.0);
        assert_eq!(m.reading(Role::Obd).running, Some(false));
        assert!(m.reading(Role::Obd).rpm.unwrap() < 50.0);
        assert!(m
            .command(Role::Trans, Command::Control(Control::Start))
            .is_err());
        m.gear = Gear::Park;
        m.command(Role::Trans, Command::Control(Control::Start))
            .unwrap();
        if let Some(at) = m.cranking.as_mut() {
            *at = Instant::now();
        }
        m.step();
        assert!(m.running);
    }

    #[test]
    fn the_device_watchdog_releases_gas_and_applies_the_brake() {
        let mut m = Model::new();
        m.command(Role::Gas, Command::Set(0.6)).unwrap();
        m.command(Role::Brake, Command::Set(0.0)).unwrap();
        m.watchdog_trip(Role::Gas);
        m.watchdog_trip(Role::Brake);
        assert_eq!((m.gas_cmd, m.brake_cmd), (0.0, 1.0));
    }

    #[test]
    fn sensors_refuse_commands() {
        let mut m = Model::new();
        assert!(m.command(Role::Obd, Command::Set(1.0)).is_err());
        assert!(m.command(Role::Steer, Command::Gear(Gear::Drive)).is_err());
    }
}
