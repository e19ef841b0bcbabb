//! The estimator on synthetic traces: a true device moves as declared (or is pushed),
//! readings carry noise, and the bound the estimator promises — the true position
//! within 3σ of the estimate — is checked at every millisecond.

use super::*;
use crate::config::{Motion, Response};
use std::time::Duration;

/// A reproducible noise source (xorshift, Box–Muller).
struct Noise(u64);

impl Noise {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn gauss(&mut self, sigma: f64) -> f64 {
        let (u, v) = (self.uniform().max(1e-12), self.uniform());
        sigma * (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

fn lag() -> Response {
    Response {
        motion: Motion::Lag(Duration::from_millis(80)),
        noise: 0.002,
        tolerance: 0.01,
        deadband: 0.01,
        override_threshold: 0.1,
        override_time: Duration::from_millis(300),
    }
}

fn rate() -> Response {
    Response {
        motion: Motion::Rate(1.0),
        noise: 0.002,
        tolerance: 0.02,
        deadband: 0.02,
        override_threshold: 0.1,
        override_time: Duration::from_millis(300),
    }
}

/// The true device: the declared response, run at 1 ms steps; a hand that pushes it
/// (units a second) overpowers the drive.
fn step_true(r: &Response, pos: f64, command: f64, push: f64) -> f64 {
    let dt = 0.001;
    if push != 0.0 {
        return pos + push * dt;
    }
    let moved = match r.motion {
        Motion::Rate(v) => pos + (command - pos).clamp(-v * dt, v * dt),
        Motion::Lag(t) => command + (pos - command) * (-dt / t.as_secs_f64()).exp(),
    };
    moved + push * dt
}

/// What a run found: the worst error in σ, the share of instants beyond 3σ, the RMS
/// error, the largest σ.
struct Run {
    worst_sigmas: f64,
    beyond: f64,
    rms: f64,
    max_sigma: f64,
    surprises: usize,
}

/// Run a trace of `ms` milliseconds: `command(t)` at each millisecond (sent when it
/// changes), a poll every `poll_ms` unless `dropped(t)`, `push(t)` units a second.
fn run(
    r: Response,
    range: [f64; 2],
    ms: u64,
    poll_ms: u64,
    command: impl Fn(u64) -> f64,
    dropped: impl Fn(u64) -> bool,
    push: impl Fn(u64) -> f64,
) -> (Run, Estimator, Instant) {
    let t0 = Instant::now();
    let mut e = Estimator::new(r, range);
    let mut noise = Noise(0x9e37_79b9_7f4a_7c15);
    let mut pos = command(0);
    let mut sent = None;
    let (mut worst, mut beyond, mut sq, mut max_sigma, mut surprises) = (0.0f64, 0, 0.0, 0.0f64, 0);
    for t in 0..ms {
        let now = t0 + Duration::from_millis(t);
        let c = command(t);
        if sent != Some(c) {
            e.command(c, now);
            sent = Some(c);
        }
        if t % poll_ms == 0 && !dropped(t) {
            surprises += usize::from(e.correct(pos + noise.gauss(r.noise), now).surprise);
        }
        let est = e.at(now).expect("read once");
        let err = (est.position - pos).abs();
        // The bound counts the reading's own noise: σ never claims better than it.
        let sigma = est.sigma.max(r.noise);
        worst = worst.max(err / sigma);
        beyond += usize::from(err > 3.0 * sigma);
        sq += err * err;
        max_sigma = max_sigma.max(est.sigma);
        pos = step_true(&r, pos, c, push(t));
    }
    let run = Run {
        worst_sigmas: worst,
        beyond: beyond as f64 / ms as f64,
        rms: (sq / ms as f64).sqrt(),
        max_sigma,
        surprises,
    };
    (run, e, t0 + Duration::from_millis(ms))
}

#[test]
fn a_step_through_a_lag_stays_within_three_sigma() {
    let (run, _, _) = run(
        lag(),
        [0.0, 1.0],
        2000,
        50,
        |t| if t < 500 { 0.0 } else { 0.8 },
        |_| false,
        |_| 0.0,
    );
    assert!(run.beyond < 0.01, "{:.3} of instants beyond 3σ", run.beyond);
    assert!(run.worst_sigmas < 5.0, "worst {:.1}σ", run.worst_sigmas);
    assert!(run.rms < 0.01, "rms {:.4}", run.rms);
    assert_eq!(run.surprises, 0, "the declared response explains a step");
}

#[test]
fn a_full_range_ramp_at_the_top_rate_stays_within_three_sigma() {
    // A sweep from -1 to 1 and back at the device's own rate, commands at 100 Hz.
    let sweep = |t: u64| {
        let s = (t / 10 * 10) as f64 / 1000.0;
        match s {
            s if s < 2.0 => -1.0 + s,
            s if s < 4.0 => 1.0 - (s - 2.0),
            _ => -1.0,
        }
    };
    let (run, e, end) = run(rate(), [-1.0, 1.0], 4500, 50, sweep, |_| false, |_| 0.0);
    assert!(run.beyond < 0.01, "{:.3} of instants beyond 3σ", run.beyond);
    assert!(run.rms < 0.02, "rms {:.4}", run.rms);
    assert_eq!(run.surprises, 0);
    let last = e.at(end).unwrap();
    assert!(
        last.drift.abs() < 3.0 * last.drift_sigma.max(0.01),
        "{last:?}"
    );
}

#[test]
fn noisy_readings_are_smoothed_below_their_noise() {
    let mut r = lag();
    r.noise = 0.01;
    r.tolerance = 0.05;
    let (run, _, _) = run(r, [0.0, 1.0], 3000, 20, |_| 0.4, |_| false, |_| 0.0);
    assert!(
        run.rms < 0.7 * r.noise,
        "rms {:.4} against noise {}",
        run.rms,
        r.noise
    );
    assert!(run.beyond < 0.01, "{:.3}", run.beyond);
}

#[test]
fn a_dropped_poll_widens_sigma_and_the_bound_still_holds() {
    let gap = |t: u64| (600..1000).contains(&t);
    let cmd = |t: u64| if t < 500 { 0.0 } else { 0.8 };
    let (with_gap, _, _) = run(lag(), [0.0, 1.0], 2000, 50, cmd, gap, |_| 0.0);
    let (without, _, _) = run(lag(), [0.0, 1.0], 2000, 50, cmd, |_| false, |_| 0.0);
    assert!(with_gap.beyond < 0.01, "{:.3}", with_gap.beyond);
    assert!(
        with_gap.max_sigma > without.max_sigma,
        "σ grows while nothing is read"
    );
}

#[test]
fn sigma_grows_between_polls_and_passes_the_tolerance_late_under_a_steady_command() {
    let (_, e, end) = run(lag(), [0.0, 1.0], 2000, 50, |_| 0.5, |_| false, |_| 0.0);
    let settled = e.at(end).unwrap().sigma;
    assert!(settled < lag().tolerance / 2.0, "σ {settled}");
    let passes = e
        .sigma_passes_tolerance(end, end + Duration::from_secs(5))
        .expect("σ passes the tolerance at last");
    // Well after the fastest period: adaptive polling has room to stretch.
    assert!(
        passes - end > Duration::from_millis(150),
        "{:?}",
        passes - end
    );
}

#[test]
fn a_push_away_from_the_command_shows_as_drift_and_surprises() {
    // A hand pushes the device at 0.5 range a second from 1.5 s on.
    let (run, e, end) = run(
        rate(),
        [-1.0, 1.0],
        2000,
        20,
        |_| 0.0,
        |_| false,
        |t| if t >= 1500 { 0.5 } else { 0.0 },
    );
    let last = e.at(end).unwrap();
    assert!(
        last.drift > 0.3 && last.drift > 3.0 * last.drift_sigma,
        "{last:?}"
    );
    assert!(
        run.surprises > 0,
        "the first readings of the push are surprises"
    );
}

/// Every number of an estimate (what the snapshot carries), none subnormal.
fn assert_normal(e: &Estimate, when: &str) {
    for (name, x) in [
        ("position", e.position),
        ("velocity", e.velocity),
        ("sigma", e.sigma),
        ("drift", e.drift),
        ("drift_sigma", e.drift_sigma),
    ] {
        assert!(!x.is_subnormal(), "{name} {x:e} {when}");
    }
}

/// The incident: the gas estimate showed velocity and drift of 1.5e-323 after a minute
/// idle, and a 100 s recording held 502 subnormal numbers. A lag closing on 0 and a
/// drift whose innovations vanish decay geometrically; the filter stops them at 0.
/// Ten idle minutes, polled every 100 ms, the estimate read at every poll and between.
#[test]
fn ten_idle_minutes_leave_no_subnormal_number_in_the_estimate() {
    for (r, range) in [(lag(), [0.0, 1.0]), (rate(), [-1.0, 1.0])] {
        let t0 = Instant::now();
        let mut e = Estimator::new(r, range);
        e.correct(0.6, t0);
        e.command(0.0, t0);
        for k in 1..=6_000u32 {
            let t = t0 + Duration::from_millis(100 * u64::from(k));
            // The device settles on its command as declared; an idle sensor reads 0.
            let reading = if k < 10 {
                0.6 * 0.3f64.powi(k as i32)
            } else {
                0.0
            };
            e.correct(reading, t);
            for (at, what) in [(t, "at a poll"), (t + Duration::from_millis(50), "between")] {
                let est = e.at(at).expect("a reading was taken");
                assert_normal(&est, &format!("{what}, {} s idle ({r:?})", k / 10));
            }
        }
        let last = e.at(t0 + Duration::from_secs(600)).unwrap();
        assert_eq!(last.position, 0.0, "{r:?}");
        assert!(
            last.velocity.abs() < 1e-12 && last.drift.abs() < 1e-12,
            "{last:?}"
        );
    }
}
