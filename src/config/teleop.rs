//! The `[teleop]` section of a vehicle file: what hold-to-drive teleop commands while a
//! key is held — the throttle while `↑` is held, the brake while `↓` is, the brake when
//! no pedal key is held (enough to hold the vehicle still; 0 lets it coast), and how fast
//! `←`/`→` move the steering. Every key has a default and a range in [`limits`]; the
//! console starts from these and the operator changes them with keys in teleop, within
//! the same ranges.

use super::limits::{self, Violation};
use serde::{Deserialize, Serialize};

/// `[teleop]`: levels as a fraction of the pedal's range, the steering rate in units of
/// the −1 … 1 steering command a second.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TeleopConfig {
    /// `↑` held: the throttle at this.
    pub gas: f64,
    /// `↓` held: the brake at this.
    pub brake: f64,
    /// No pedal key held: the brake at this (0: the vehicle coasts). Never gas.
    pub hold: f64,
    /// `←`/`→` held: the steering moves this much a second.
    pub steer_rate: f64,
}

impl Default for TeleopConfig {
    fn default() -> Self {
        TeleopConfig {
            gas: limits::TELEOP_GAS.default_value(),
            brake: limits::TELEOP_BRAKE.default_value(),
            hold: limits::TELEOP_HOLD.default_value(),
            steer_rate: limits::TELEOP_STEER_RATE.default_value(),
        }
    }
}

impl TeleopConfig {
    /// Every value within its limit, and the hold no harder than the brake.
    pub fn check(&self) -> Result<(), Violation> {
        limits::TELEOP_GAS.check(self.gas)?;
        limits::TELEOP_BRAKE.check(self.brake)?;
        limits::TELEOP_HOLD.check(self.hold)?;
        limits::TELEOP_STEER_RATE.check(self.steer_rate)?;
        if self.hold > self.brake {
            return Err(limits::HOLD_BELOW_BRAKE.violation(
                &["hold", "brake"],
                format!("hold {}, brake {}", self.hold, self.brake),
            ));
        }
        Ok(())
    }
}
