//! What one decision of the intake saw of the vehicle: the gate's state and the
//! interlocks' facts ([`Seen`], [`Facts`]). Safety gathers the facts
//! (`crate::safety::facts`) and decides over them (`crate::safety::gate_state::decide`); the
//! types are plain data defined here, beside the tap that carries them to a recording
//! with every command received, so that every layer from the vehicle up can hold them.

use crate::value::EstopState;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// What the intake's decision on one ask saw of the vehicle, besides the vehicle file:
/// the gate's state and, where the interlocks looked, their facts. With the vehicle
/// file it is all a decision needs ([`crate::safety::gate_state::decide`],
/// [`crate::safety::gate_state::decide_accel`]): a recording keeps it with every command
/// received, and `adrive replay --check` decides each again, under another vehicle
/// file's rules and limits, over what was seen then.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Seen {
    /// The vehicle was engaged.
    pub engaged: bool,
    /// A recovery procedure had the device (for `accel`: either pedal).
    pub recovering: bool,
    /// The interlock rules were on.
    pub interlocks: bool,
    /// What the interlocks knew of the vehicle; absent where they did not look (the
    /// vehicle disengaged, a device no rule looks at). Throttle and brake as fractions
    /// of their range's top.
    pub facts: Option<Facts>,
}

/// What the interlocks know of the vehicle, at intake (`safety::facts::gather`) or at
/// the wire (`safety::facts::gather_wire`): one type, so that both checks ask the same
/// rule functions (`safety::rules::breaks`). Throttle and brake values are fractions
/// of their range's top (0 released … 1 full), whatever the devices' units. A recording keeps
/// the intake's facts with each command received (`/commands`), so that
/// `adrive replay --check` decides it again over the very facts it was decided on.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Facts {
    /// Highest brake value pending, in flight, sent or acknowledged (None: unknown);
    /// at the wire, pending, in flight or last sent.
    pub(crate) brake_high: Option<f64>,
    /// Lowest brake value pending, in flight, sent or acknowledged.
    pub(crate) brake_low: Option<f64>,
    /// The brake's newest command releases it: throttle may follow, held back at the
    /// wire until the release has reached the brake ([`crate::safety::wire::Wait::BrakeReleased`]).
    pub(crate) brake_releasing: bool,
    /// The gear reported, as a state of the gear device.
    pub gear: Option<u8>,
    /// The reported gear drives the wheels.
    pub(crate) in_gear: bool,
    pub running: Option<bool>,
    pub speed: Option<f64>,
    pub estop: Option<EstopState>,
    /// A shift is commanded and the gearbox does not report that gear yet.
    pub(crate) shifting: bool,
    /// At the wire: the throttle has nothing above released pending, in flight or
    /// last sent.
    #[serde(skip, default = "released")]
    pub(crate) throttle_released: bool,
    /// At the wire: a gear command is pending or in flight for the gearbox that is not
    /// the last one sent.
    #[serde(skip)]
    pub(crate) shift_on_its_way: bool,
}

/// What [`Facts::default`] says of the throttle at the wire: released.
fn released() -> bool {
    true
}

impl Default for Facts {
    fn default() -> Facts {
        Facts {
            brake_high: None,
            brake_low: None,
            brake_releasing: false,
            gear: None,
            in_gear: false,
            running: None,
            speed: None,
            estop: None,
            shifting: false,
            throttle_released: released(),
            shift_on_its_way: false,
        }
    }
}
