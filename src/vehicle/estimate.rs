//! The state estimator of one setpoint actuator: the paper's open problem ("put Kalman
//! estimators into the code instead of just caching the last reported value").
//!
//! Between polls the position is predicted by the device's declared response
//! ([`Response`]: a rate limit or a first-order lag) from the command the device
//! acknowledged; every status reading corrects it. The filter is a small hand-written
//! Kalman filter over two states:
//!
//! - `position`, in the device's units;
//! - `drift`, the velocity the command does *not* explain (units a second): near 0 on a
//!   device that answers as declared, toward its command when something helps it,
//!   away from it when something holds it back or pushes it — a stuck motor, a driver's
//!   hand.
//!
//! Its σ (one standard deviation of the position) grows between polls — with the
//! motion the model predicts (a declared rate or lag is never exact) and with a drift
//! that may have begun — and shrinks with each reading. Adaptive polling polls by it;
//! readers only ever predict from a copy, so they never disturb the filter.

use crate::config::{Motion, Response};
use crate::value::flush_subnormal;
use std::time::Instant;

/// Share of a predicted move that may be wrong (a declared rate or lag is not exact).
const MODEL_ERROR: f64 = 0.1;
/// How fast an unexplained drift may appear, as a share of the range a second per √s
/// (the random walk of the drift state).
const DRIFT_WALK: f64 = 0.05;
/// A reading more than this many standard deviations from its prediction (and further
/// than the tolerance) is a surprise.
const SURPRISE_SIGMAS: f64 = 3.0;

/// What the filter believes of the device at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate {
    /// The estimated position, in the device's units.
    pub position: f64,
    /// The estimated velocity (the command's motion plus the drift), units a second.
    pub velocity: f64,
    /// One standard deviation of the position.
    pub sigma: f64,
    /// The velocity the command does not explain, units a second.
    pub drift: f64,
    /// One standard deviation of the drift.
    pub(crate) drift_sigma: f64,
    /// The command the device is moving to (the last it acknowledged).
    pub command: Option<f64>,
}

/// What one reading told the filter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Correction {
    /// Reading minus prediction.
    pub(crate) innovation: f64,
    /// Its predicted standard deviation.
    pub(crate) innovation_sigma: f64,
    /// The reading was far outside the prediction.
    pub surprise: bool,
}

/// The Kalman filter of one device.
#[derive(Clone, Debug)]
pub struct Estimator {
    response: Response,
    range: [f64; 2],
    /// Time of the state below; `None` before the first reading.
    at: Option<Instant>,
    /// Position and drift.
    x: [f64; 2],
    /// Their covariance.
    p: [[f64; 2]; 2],
    /// The command the device is moving to.
    command: Option<f64>,
}

impl Estimator {
    pub fn new(response: Response, range: [f64; 2]) -> Estimator {
        Estimator {
            response,
            range,
            at: None,
            x: [0.0; 2],
            p: [[0.0; 2]; 2],
            command: None,
        }
    }

    pub fn response(&self) -> &Response {
        &self.response
    }

    fn span(&self) -> f64 {
        self.range[1] - self.range[0]
    }

    /// The device acknowledged `command` at `at`: from then on it moves toward it.
    pub fn command(&mut self, command: f64, at: Instant) {
        if self.at.is_some() {
            self.advance(at);
        }
        self.command = Some(command);
    }

    /// The command the device is moving to.
    pub fn commanded(&self) -> Option<f64> {
        self.command
    }

    /// A status reading of `position` taken at `at` corrects the estimate.
    pub fn correct(&mut self, position: f64, at: Instant) -> Correction {
        let r = self.response.noise * self.response.noise;
        if self.at.is_none() {
            self.at = Some(at);
            self.x = [position, 0.0];
            let drift_var = (DRIFT_WALK * self.span()).powi(2);
            self.p = [[r, 0.0], [0.0, drift_var]];
            return Correction {
                innovation: 0.0,
                innovation_sigma: self.response.noise,
                surprise: false,
            };
        }
        self.advance(at);
        let p = self.p;
        let s = p[0][0] + r;
        let innovation = position - self.x[0];
        let k = [p[0][0] / s, p[1][0] / s];
        self.x[0] += k[0] * innovation;
        self.x[1] += k[1] * innovation;
        self.p = [
            [(1.0 - k[0]) * p[0][0], (1.0 - k[0]) * p[0][1]],
            [p[1][0] - k[1] * p[0][0], p[1][1] - k[1] * p[0][1]],
        ];
        self.flush();
        let innovation_sigma = s.sqrt();
        Correction {
            innovation,
            innovation_sigma,
            surprise: innovation.abs() > SURPRISE_SIGMAS * innovation_sigma
                && innovation.abs() > self.response.tolerance,
        }
    }

    /// The estimate at `now` (predicted from the last reading and command); `None`
    /// before the first reading.
    pub fn at(&self, now: Instant) -> Option<Estimate> {
        let at = self.at?;
        let mut e = self.clone();
        if now > at {
            e.advance(now);
        }
        let model = e.model_velocity(e.x[0]);
        Some(Estimate {
            position: e.x[0],
            velocity: flush_subnormal(model + e.x[1]),
            sigma: e.p[0][0].max(0.0).sqrt(),
            drift: e.x[1],
            drift_sigma: e.p[1][1].max(0.0).sqrt(),
            command: e.command,
        })
    }

    /// The first instant after `from` (and no later than `until`) at which σ passes the
    /// tolerance, if it does by then.
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn sigma_passes_tolerance(&self, from: Instant, until: Instant) -> Option<Instant> {
        let tol = self.response.tolerance;
        let passed = |t: Instant| self.at(t).is_some_and(|e| e.sigma > tol);
        if !passed(until) {
            return None;
        }
        // σ grows monotonically between readings: bisect to a millisecond.
        let (mut lo, mut hi) = (from, until);
        while hi - lo > std::time::Duration::from_millis(1) {
            let mid = lo + (hi - lo) / 2;
            if passed(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        Some(hi)
    }

    /// The velocity the declared response gives at `position`.
    fn model_velocity(&self, position: f64) -> f64 {
        let Some(c) = self.command else { return 0.0 };
        let d = c - position;
        match self.response.motion {
            Motion::Rate(_) if d.abs() <= self.response.deadband => 0.0,
            Motion::Rate(r) => r.copysign(d),
            Motion::Lag(tau) => d / tau.as_secs_f64(),
        }
    }

    /// Predict the state forward to `to`.
    fn advance(&mut self, to: Instant) {
        let Some(at) = self.at else { return };
        let dt = to.saturating_duration_since(at).as_secs_f64();
        self.at = Some(to.max(at));
        if dt <= 0.0 {
            return;
        }
        let [pos, drift] = self.x;
        // The response's own move, and how it carries a position error (its Jacobian).
        let (moved, carry) = match (self.command, self.response.motion) {
            (None, _) => (pos, 1.0),
            (Some(c), Motion::Rate(r)) => {
                let d = c - pos;
                if d.abs() <= r * dt {
                    (c, 0.0)
                } else {
                    (pos + (r * dt).copysign(d), 1.0)
                }
            }
            (Some(c), Motion::Lag(tau)) => {
                let a = (-dt / tau.as_secs_f64()).exp();
                (c + (pos - c) * a, a)
            }
        };
        let next = moved + drift * dt;
        // The device never leaves its range by itself (its end stops).
        let margin = self.response.deadband;
        self.x[0] = next.clamp(self.range[0] - margin, self.range[1] + margin);
        // Covariance: F = [[carry, dt], [0, 1]]; Q from the model's error on this move
        // and the drift's random walk.
        let p = self.p;
        let f = [[carry, dt], [0.0, 1.0]];
        let mut fp = [[0.0; 2]; 2];
        for i in 0..2 {
            for j in 0..2 {
                fp[i][j] = f[i][0] * p[0][j] + f[i][1] * p[1][j];
            }
        }
        let mut n = [[0.0; 2]; 2];
        for i in 0..2 {
            for j in 0..2 {
                n[i][j] = fp[i][0] * f[j][0] + fp[i][1] * f[j][1];
            }
        }
        let q = (DRIFT_WALK * self.span()).powi(2);
        let model = (MODEL_ERROR * (moved - pos)).powi(2);
        n[0][0] += model + q * dt * dt * dt / 3.0;
        n[0][1] += q * dt * dt / 2.0;
        n[1][0] += q * dt * dt / 2.0;
        n[1][1] += q * dt;
        self.p = n;
        self.flush();
    }

    /// A state that settles toward 0 (a lag closing on its command, a drift whose
    /// innovations vanish) stops at 0 rather than walking down the subnormal numbers.
    fn flush(&mut self) {
        self.x = self.x.map(flush_subnormal);
        self.p = self.p.map(|row| row.map(flush_subnormal));
    }
}

#[cfg(test)]
mod tests;
