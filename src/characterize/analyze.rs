//! The figures of a characterization, from its samples alone: pure functions over
//! (time, commanded, measured), so each is tested on made-up responses with known
//! answers, without a device.

use serde::Serialize;

/// One position reading, with the command in force when it was taken.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub(crate) struct Sample {
    /// Seconds since the procedure started (the middle of the status transaction).
    pub t: f64,
    pub commanded: f64,
    pub measured: f64,
}

/// What one step's response shows.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct StepFigures {
    /// Command to first movement, seconds: where the slew line leaves the start level.
    pub delay: f64,
    /// The slew rate, units a second (positive).
    pub rate: f64,
    /// 10 % to 90 % of the step, seconds.
    pub rise: f64,
    /// Beyond the final value, as a percentage of the step.
    pub overshoot_pct: f64,
    /// Command to staying within 2 % of the step of the final value, seconds.
    pub settle: f64,
    /// The first-order lag of the approach's tail, seconds, where it shows one.
    pub lag: Option<f64>,
}

/// The least-squares line through `points`: (slope, intercept).
pub(crate) fn fit_line(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    let n = points.len() as f64;
    if points.len() < 2 {
        return None;
    }
    let (sx, sy) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
    let (mx, my) = (sx / n, sy / n);
    let (sxy, sxx) = points.iter().fold((0.0, 0.0), |(a, b), (x, y)| {
        (a + (x - mx) * (y - my), b + (x - mx) * (x - mx))
    });
    if sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    Some((slope, my - slope * mx))
}

/// The time (interpolated between samples) at which `f` of the measured value first
/// holds, from the samples `s`.
fn first_time(s: &[Sample], f: impl Fn(f64) -> bool, progress: impl Fn(f64) -> f64) -> Option<f64> {
    let i = s.iter().position(|x| f(progress(x.measured)))?;
    if i == 0 {
        return Some(s[0].t);
    }
    let (a, b) = (s[i - 1], s[i]);
    let (pa, pb) = (progress(a.measured), progress(b.measured));
    // Linear between the two samples, toward the threshold the predicate crossed.
    let target = if f(pa) {
        pa
    } else {
        threshold_between(pa, pb, &f)
    };
    let k = if (pb - pa).abs() > 0.0 {
        ((target - pa) / (pb - pa)).clamp(0.0, 1.0)
    } else {
        1.0
    };
    Some(a.t + k * (b.t - a.t))
}

/// The threshold a monotone predicate crosses between `a` (false) and `b` (true).
fn threshold_between(a: f64, b: f64, f: &impl Fn(f64) -> bool) -> f64 {
    let (mut lo, mut hi) = (a, b);
    for _ in 0..50 {
        let mid = (lo + hi) / 2.0;
        if f(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}

/// The response to a step commanded at `at` from the settled value `start` to the
/// settled value `end`, over the samples `s` (from the command to the settling).
pub(crate) fn step(s: &[Sample], at: f64, start: f64, end: f64) -> Option<StepFigures> {
    let span = end - start;
    if span == 0.0 || s.len() < 4 {
        return None;
    }
    let progress = |y: f64| (y - start) / span;
    // The slew: the line through the response between 10 % and 50 % of the step.
    let slew: Vec<(f64, f64)> = s
        .iter()
        .filter(|x| (0.1..=0.5).contains(&progress(x.measured)))
        .map(|x| (x.t, x.measured))
        .collect();
    let (slope, intercept) = fit_line(&slew).filter(|(k, _)| k * span > 0.0)?;
    let rate = slope.abs();
    let left_start = (start - intercept) / slope;
    let t10 = first_time(s, |p| p >= 0.1, progress)?;
    let t90 = first_time(s, |p| p >= 0.9, progress)?;
    let peak = s
        .iter()
        .map(|x| progress(x.measured))
        .fold(f64::NEG_INFINITY, f64::max);
    let last_out = s
        .iter()
        .rposition(|x| (progress(x.measured) - 1.0).abs() > 0.02);
    let settle = match last_out {
        Some(i) if i + 1 < s.len() => s[i + 1].t - at,
        Some(i) => s[i].t - at,
        None => 0.0,
    };
    Some(StepFigures {
        delay: left_start - at,
        rate,
        rise: t90 - t10,
        overshoot_pct: ((peak - 1.0) * 100.0).max(0.0),
        settle,
        lag: s
            .iter()
            .position(|x| progress(x.measured) >= 0.5)
            .and_then(|i| tail_lag(&s[i..], end, (slope, intercept), span)),
    })
}

/// The first-order lag of a response's tail: once it falls behind its slew line `slew`
/// (slope, intercept), it closes on its final value as `end + B·e^(−t/τ)`. τ is the one whose least-squares
/// fit (with `end` and `B` fitted too, so neither the settled value's error nor the
/// reading's resolution bends it) leaves the least residual. `None` where the tail
/// shows no such approach (a drive that stops at its rate).
fn tail_lag(s: &[Sample], end: f64, slew: (f64, f64), span: f64) -> Option<f64> {
    // Where it falls behind its slew line by a hundredth of the step: the two samples a
    // velocity would be read from are too close in time for a shared machine's jitter.
    let (k, b) = slew;
    let slow = s
        .iter()
        .position(|x| ((k * x.t + b) - x.measured) * span.signum() > span.abs() * 0.01)?;
    let tail: Vec<(f64, f64)> = s[slow..]
        .iter()
        .map(|x| (x.t - s[slow].t, x.measured))
        .collect();
    if tail.len() < 6 || (tail[0].1 - end).abs() < span.abs() * 1e-3 {
        return None;
    }
    let sse = |tau: f64| {
        let pts: Vec<(f64, f64)> = tail.iter().map(|&(t, y)| ((-t / tau).exp(), y)).collect();
        match fit_line(&pts) {
            Some((b, e)) => pts
                .iter()
                .map(|(x, y)| (y - e - b * x).powi(2))
                .sum::<f64>(),
            None => f64::INFINITY,
        }
    };
    // A coarse look over 1 ms … 2 s, then golden-section search around the best.
    let grid: Vec<f64> = (0..=80)
        .map(|i| (1e-3f64).ln() + i as f64 * (2000f64).ln() / 80.0)
        .collect();
    let best =
        (0..grid.len()).min_by(|&a, &b| sse(grid[a].exp()).total_cmp(&sse(grid[b].exp())))?;
    let (mut lo, mut hi) = (
        grid[best.saturating_sub(1)],
        grid[(best + 1).min(grid.len() - 1)],
    );
    let g = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..60 {
        let (a, b) = (hi - g * (hi - lo), lo + g * (hi - lo));
        if sse(a.exp()) < sse(b.exp()) {
            hi = b;
        } else {
            lo = a;
        }
    }
    Some(((lo + hi) / 2.0).exp())
}

/// Mean and standard deviation.
pub(crate) fn mean_sd(v: &[f64]) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n;
    Some((m, var.sqrt()))
}

/// The median (the mean of the middle two of an even count).
pub(crate) fn median(v: &[f64]) -> Option<f64> {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(v[n / 2]),
        _ => Some((v[n / 2 - 1] + v[n / 2]) / 2.0),
    }
}

/// The value most of the `intervals` agree on: the middle of the stretch that lies in
/// the most of them (the first such stretch, if several tie). Each interval brackets
/// one measurement of a constant, as a reading before and a reading after bracket the
/// moment a state changed: where the brackets' phases are spread, their common part is
/// far narrower than any one of them, and a few that miss (a jittered timestamp, an
/// odd shift) only lower the count, not move the answer.
pub(crate) fn deepest(intervals: &[(f64, f64)]) -> Option<f64> {
    // Each start before each end at the same place: touching intervals share it.
    let mut edges: Vec<(f64, i32)> = intervals
        .iter()
        .flat_map(|&(lo, hi)| [(lo.min(hi), 1), (lo.max(hi), -1)])
        .collect();
    edges.sort_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)));
    let (mut depth, mut best, mut at) = (0, 0, None);
    for (i, &(x, step)) in edges.iter().enumerate() {
        depth += step;
        if step > 0 && depth > best {
            best = depth;
            // The stretch ends at the next edge, where the depth falls.
            at = edges.get(i + 1).map(|&(end, _)| (x + end) / 2.0);
        }
    }
    at
}

/// The static map of a sweep: each point's measured value approached from below and
/// from above, averaged (the hysteresis cancels), and the line through them: (gain,
/// offset).
pub(crate) fn static_map(
    up: &[(f64, f64)],
    down: &[(f64, f64)],
) -> (Vec<[f64; 2]>, Option<(f64, f64)>) {
    let map: Vec<[f64; 2]> = up
        .iter()
        .map(|&(c, m)| {
            let other = down
                .iter()
                .find(|(d, _)| (d - c).abs() < 1e-9)
                .map_or(m, |x| x.1);
            [c, (m + other) / 2.0]
        })
        .collect();
    let line = fit_line(&map.iter().map(|p| (p[0], p[1])).collect::<Vec<_>>());
    (map, line)
}

/// The backlash of a sweep: how much higher each point settles approached from above
/// than from below, averaged.
pub(crate) fn backlash(up: &[(f64, f64)], down: &[(f64, f64)]) -> Option<f64> {
    let gaps: Vec<f64> = up
        .iter()
        .filter_map(|&(c, m)| {
            down.iter()
                .find(|(d, _)| (d - c).abs() < 1e-9)
                .map(|x| x.1 - m)
        })
        .collect();
    mean_sd(&gaps).map(|(m, _)| m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_deepest_point_of_brackets_at_spread_phases_is_the_constant_they_bracket() {
        // A 400 ms shift read every 23–35 ms at 40 phases: each bracket is up to 35 ms
        // wide, their midpoints' median off by several ms; their common part is not.
        let (t, mut x, mut brackets) = (400.0, 7u64, Vec::new());
        for _ in 0..40 {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let (u, v) = (
                (x >> 11) as f64 / 2f64.powi(53),
                (x & 0xffff) as f64 / 65536.0,
            );
            let period = 23.0 + 12.0 * v;
            let lo = t - u * period;
            brackets.push((lo, lo + period));
        }
        let got = deepest(&brackets).unwrap();
        assert!((got - t).abs() < 2.0, "{got}");
        // One bracket that misses it entirely does not move it.
        brackets.push((500.0, 520.0));
        assert!((deepest(&brackets).unwrap() - t).abs() < 2.0);
        // Where two disjoint brackets tie, the first; none, none.
        assert_eq!(deepest(&[(0.0, 2.0), (5.0, 9.0)]), Some(1.0));
        assert_eq!(deepest(&[(0.0, 4.0), (2.0, 6.0)]), Some(3.0));
        assert_eq!(deepest(&[]), None);
    }

    /// A rate-limited first-order response: delay `d`, rate `r`, lag `tau`, from 0 to
    /// `to`, sampled every `dt`.
    fn response(d: f64, r: f64, tau: f64, to: f64, dt: f64, secs: f64) -> Vec<Sample> {
        let (mut y, mut out, mut t) = (0.0f64, Vec::new(), 0.0);
        let h = 1e-5;
        let mut next = 0.0;
        while t < secs {
            if t >= next {
                out.push(Sample {
                    t,
                    commanded: to,
                    measured: y,
                });
                next += dt;
            }
            if t >= d {
                let err: f64 = to - y;
                let s = err * (1.0 - (-h / tau).exp());
                y += s.clamp(-r * h, r * h);
            }
            t += h;
        }
        out
    }

    #[test]
    fn a_step_gives_its_delay_rate_lag_and_rise() {
        let s = response(0.04, 1.5, 0.06, 1.2, 0.005, 2.0);
        let f = step(&s, 0.0, 0.0, 1.2).unwrap();
        assert!((f.delay - 0.04).abs() < 0.001, "{f:?}");
        assert!((f.rate - 1.5).abs() / 1.5 < 0.005, "{f:?}");
        let lag = f.lag.unwrap();
        assert!((lag - 0.06).abs() / 0.06 < 0.02, "{f:?}");
        assert!(f.rise > 0.5 && f.rise < 0.8, "{f:?}");
        assert_eq!(f.overshoot_pct, 0.0);
        assert!(f.settle > f.delay + f.rise, "{f:?}");
        let down = response(0.04, 1.5, 0.06, -1.2, 0.005, 2.0);
        let f = step(&down, 0.0, 0.0, -1.2).unwrap();
        assert!((f.rate - 1.5).abs() / 1.5 < 0.005, "{f:?}");
    }

    /// The incidents: a lag read off the logarithm of the distance left came out 17 %
    /// long on a steering whose readings have 10⁻⁴ of resolution and whose settled
    /// value was read 2·10⁻⁴ off; and 60 % long where its tail was found by the
    /// velocity between two samples, whose times a loaded machine jitters by a
    /// millisecond or two.
    #[test]
    fn the_lag_survives_resolution_an_inexact_settled_value_and_jittered_times() {
        let mut s = response(0.03, 0.948, 0.0979, 1.2, 0.005, 2.0);
        for (i, x) in s.iter_mut().enumerate() {
            x.measured = (x.measured * 1e4).round() / 1e4;
            x.t += ((i * 7919 % 31) as f64 - 15.0) * 1e-4;
        }
        let f = step(&s, 0.0, 0.0, 1.2 + 2e-4).unwrap();
        let lag = f.lag.unwrap();
        assert!((lag - 0.0979).abs() / 0.0979 < 0.02, "{f:?}");
    }

    #[test]
    fn a_drive_that_stops_at_its_rate_shows_no_lag() {
        let s = response(0.0, 1.0, 1e-6, 1.0, 0.005, 1.5);
        let f = step(&s, 0.0, 0.0, 1.0).unwrap();
        assert_eq!(f.lag, None, "{f:?}");
    }

    #[test]
    fn a_sweep_gives_the_map_its_line_and_the_backlash() {
        let up: Vec<(f64, f64)> = [0.0, 0.5, 1.0]
            .iter()
            .map(|&c| (c, 2.0 * c + 0.1 - 0.02))
            .collect();
        let down: Vec<(f64, f64)> = [1.0, 0.5, 0.0]
            .iter()
            .map(|&c| (c, 2.0 * c + 0.1 + 0.02))
            .collect();
        let (map, line) = static_map(&up, &down);
        assert_eq!(map.len(), 3);
        let (g, o) = line.unwrap();
        assert!((g - 2.0).abs() < 1e-9 && (o - 0.1).abs() < 1e-9);
        assert!((backlash(&up, &down).unwrap() - 0.04).abs() < 1e-9);
    }
}
