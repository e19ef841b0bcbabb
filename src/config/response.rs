//! How a setpoint actuator answers its command, as the vehicle file declares it for the
//! real device (`[device.response]`): it moves toward its command at a `rate`, or
//! follows it with a first-order `lag`; its readings carry `noise`; it counts as at its
//! command within `deadband`; and adaptive polling keeps the estimate within
//! `tolerance`; moved `override_threshold` away from its command for `override_time`, it
//! is in a driver's hands. The estimator ([`crate::vehicle::estimate`]) predicts the device from
//! this between polls; `polling = "adaptive"` (a key of the device) polls by it.
//!
//! `[device.sim]` describes the *simulated* device and is never read here: the two are
//! declared apart, so an estimator tuned to the simulator cannot hide a real device
//! that answers differently.

use super::limits::{self, Violation};
use serde::Deserialize;
use std::time::Duration;

/// How a device's status thread schedules its polls.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Polling {
    /// Every `status_period` (the paper's way).
    #[default]
    Fixed,
    /// By the estimate's confidence: as often as every `status_period` and at least
    /// every `status_max_age` (four fifths of it, so the answer still comes in time).
    Adaptive,
}

impl Polling {
    pub fn as_str(self) -> &'static str {
        match self {
            Polling::Fixed => "fixed",
            Polling::Adaptive => "adaptive",
        }
    }
}

/// How the device moves toward its command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Motion {
    /// At most this fast, in its units a second (a servo drive with a speed limit).
    Rate(f64),
    /// With this first-order lag (a pedal actuator, a hydraulic brake).
    Lag(Duration),
}

/// The declared response of one setpoint actuator, in its units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Response {
    pub(crate) motion: Motion,
    /// One standard deviation of a reading.
    pub noise: f64,
    /// Adaptive polling polls before the estimate's σ passes this; a reading further
    /// than this from its prediction is a surprise.
    pub tolerance: f64,
    /// Within this of its command the device is there (end stops, a drive's own
    /// dead band).
    pub(crate) deadband: f64,
    /// Moved this far in a way its command cannot explain (away from its command) …
    pub override_threshold: f64,
    /// … for longer than this, the device is in a driver's hands: `override`.
    pub override_time: Duration,
}

impl Response {
    /// How far toward its command a device that starts `gap` away gets in `elapsed`,
    /// answering as declared.
    pub(crate) fn progress(&self, gap: f64, elapsed: Duration) -> f64 {
        let gap = gap.abs();
        match self.motion {
            Motion::Rate(r) => (r * elapsed.as_secs_f64()).min(gap),
            Motion::Lag(tau) => gap * (1.0 - (-elapsed.as_secs_f64() / tau.as_secs_f64()).exp()),
        }
    }
}

/// Defaults, as fractions of the range's width.
pub(crate) const NOISE_SHARE: f64 = 0.001;
pub(crate) const TOLERANCE_SHARE: f64 = 0.01;
pub(crate) const DEADBAND_SHARE: f64 = 0.01;
pub(crate) const OVERRIDE_SHARE: f64 = 0.1;

/// `[device.response]` as written.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawResponse {
    #[serde(default)]
    rate: Option<f64>,
    #[serde(default, deserialize_with = "super::opt_duration")]
    lag: Option<Duration>,
    #[serde(default)]
    noise: Option<f64>,
    #[serde(default)]
    tolerance: Option<f64>,
    #[serde(default)]
    deadband: Option<f64>,
    #[serde(default)]
    override_threshold: Option<f64>,
    #[serde(default, deserialize_with = "super::opt_duration")]
    override_time: Option<Duration>,
}

impl RawResponse {
    /// The response of a device whose range is `range`; the message says what was
    /// expected. (Values are checked against their limits by [`check`].)
    pub(super) fn resolve(self, name: &str, range: [f64; 2]) -> Result<Response, String> {
        let motion = match (self.rate, self.lag) {
            (Some(r), None) => Motion::Rate(r),
            (None, Some(l)) => Motion::Lag(l),
            (Some(_), Some(_)) => {
                return Err(format!(
                    "{name}: response: a `rate` or a `lag`, not both (how the real device moves toward its command)"
                ))
            }
            (None, None) => {
                return Err(format!(
                    "{name}: response: expected `rate = 1.0` (units a second) or `lag = \"80ms\"` (how the real device moves toward its command)"
                ))
            }
        };
        let span = range[1] - range[0];
        Ok(Response {
            motion,
            noise: self.noise.unwrap_or(span * NOISE_SHARE),
            tolerance: self.tolerance.unwrap_or(span * TOLERANCE_SHARE),
            deadband: self.deadband.unwrap_or(span * DEADBAND_SHARE),
            override_threshold: self.override_threshold.unwrap_or(span * OVERRIDE_SHARE),
            override_time: self
                .override_time
                .unwrap_or(limits::OVERRIDE_TIME.default_value()),
        })
    }
}

/// Every value of a response within its limit, in a device whose range is `range`.
pub(crate) fn check(r: &Response, range: [f64; 2]) -> Result<(), Violation> {
    let span = range[1] - range[0];
    match r.motion {
        Motion::Lag(l) => {
            limits::RESPONSE_LAG.check(l)?;
        }
        Motion::Rate(v) if !(v.is_finite() && v > 0.0 && v <= span * 1000.0) => {
            return Err(limits::RESPONSE_IN_UNITS
                .violation(&["response.rate"], format!("response.rate {v}")));
        }
        Motion::Rate(_) => {}
    }
    for (key, v) in [
        ("response.noise", r.noise),
        ("response.tolerance", r.tolerance),
        ("response.deadband", r.deadband),
        ("response.override_threshold", r.override_threshold),
    ] {
        if !(v.is_finite() && v > 0.0 && v < span) {
            return Err(limits::RESPONSE_IN_UNITS.violation(&[key], format!("{key} {v}")));
        }
    }
    limits::OVERRIDE_TIME.check(r.override_time)?;
    if r.tolerance <= r.noise {
        return Err(limits::RESPONSE_IN_UNITS.violation(
            &["response.tolerance", "response.noise"],
            format!(
                "response.tolerance {}, response.noise {}",
                r.tolerance, r.noise
            ),
        ));
    }
    Ok(())
}
