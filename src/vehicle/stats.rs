//! Always-on measurement. Counters are atomics and latencies go into fixed-size atomic
//! histograms (`histogram::AtomicHistogram`): recording is one atomic add, never a lock
//! and never an allocation, so the command path can afford it on every command.
//! Readers (console, broadcast, summary) read summaries, which are recomputed only
//! when new samples arrived and the last one is older than [`SUMMARY_EVERY`] — a
//! snapshot never copies a whole histogram on every tick.

pub(crate) use crate::snapshot::{Counters, LatencySummary};
use histogram::{AtomicHistogram, Histogram};
use parking_lot::Mutex;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::{Duration, Instant};

/// Relative error ≈ 2^-6 < 2 %; values up to 2^35 ns ≈ 34 s.
const GROUPING_POWER: u8 = 6;
const MAX_VALUE_POWER: u8 = 35;

/// A summary is recomputed at most this often.
pub(crate) const SUMMARY_EVERY: Duration = Duration::from_millis(200);

/// A latency histogram in nanoseconds.
pub struct Latency {
    hist: AtomicHistogram,
    count: AtomicU64,
    /// Sum of every sample, in nanoseconds (for the mean).
    sum_ns: AtomicU64,
    cache: Mutex<Cache>,
}

/// The last summary.
struct Cache {
    count: u64,
    at: Option<Instant>,
    summary: LatencySummary,
}

thread_local! {
    /// Where a summary is computed: one copy of a histogram per reading thread, not
    /// one per histogram kept (15 kB each, three per device).
    static SCRATCH: std::cell::RefCell<Option<Histogram>> = const { std::cell::RefCell::new(None) };
}

impl Default for Latency {
    fn default() -> Self {
        Latency {
            hist: AtomicHistogram::new(GROUPING_POWER, MAX_VALUE_POWER)
                .expect("histogram parameters are valid"),
            count: AtomicU64::new(0),
            sum_ns: AtomicU64::new(0),
            cache: Mutex::new(Cache {
                count: 0,
                at: None,
                summary: LatencySummary::default(),
            }),
        }
    }
}

impl Latency {
    /// Record one sample; saturates at the histogram's top.
    pub fn record(&self, d: Duration) {
        let ns = (d.as_nanos() as u64).min((1u64 << MAX_VALUE_POWER) - 1);
        let _ = self.hist.increment(ns);
        self.sum_ns.fetch_add(ns, Relaxed);
        self.count.fetch_add(1, Relaxed);
    }

    /// Samples recorded so far.
    pub fn count(&self) -> u64 {
        self.count.load(Relaxed)
    }

    /// Count, p50, p99 and max of everything recorded so far, at most
    /// [`SUMMARY_EVERY`] old (and exact while nothing new arrives).
    pub fn summary(&self) -> LatencySummary {
        let count = self.count();
        let mut c = self.cache.lock();
        let fresh = c.at.is_some_and(|t| t.elapsed() < SUMMARY_EVERY);
        if c.count == count || (fresh && c.count > 0) {
            return c.summary;
        }
        c.summary = self.compute();
        c.count = count;
        c.at = Some(Instant::now());
        c.summary
    }

    /// The summary now, however recent the last one (tests, the exit summary).
    pub(crate) fn summary_now(&self) -> LatencySummary {
        let mut c = self.cache.lock();
        c.summary = self.compute();
        c.count = self.count();
        c.at = Some(Instant::now());
        c.summary
    }

    fn compute(&self) -> LatencySummary {
        let (out, count) = SCRATCH.with_borrow_mut(|scratch| {
            let h = match scratch {
                Some(h) => {
                    // Every histogram here has the same parameters, so the copy fits;
                    // were it not to, a fresh copy is made rather than stale figures.
                    if self.hist.load_into(h).is_err() {
                        *h = self.hist.load();
                    }
                    h
                }
                None => scratch.insert(self.hist.load()),
            };
            let mut out = [None, None, None];
            let _ = h.quantile_buckets_into(&[0.5, 0.99, 1.0], &mut out);
            (out, h.as_slice().iter().sum::<u64>())
        });
        // A bucket stands for its range; report its upper edge (conservative).
        let us = |b: &Option<histogram::Bucket>| b.as_ref().map(|b| b.end() as f64 / 1e3);
        // The sum and count are read apart from the histogram: a sample recorded in
        // between moves the mean by one sample's worth at most.
        let n = self.count.load(Relaxed);
        LatencySummary {
            count,
            p50_us: us(&out[0]),
            p99_us: us(&out[1]),
            max_us: us(&out[2]),
            mean_us: (n > 0).then(|| self.sum_ns.load(Relaxed) as f64 / n as f64 / 1e3),
        }
    }

    /// The non-empty buckets as (upper edge in µs, count), for plots.
    pub(crate) fn buckets(&self) -> Vec<(f64, u64)> {
        self.hist
            .load()
            .iter()
            .filter(|b| b.count() > 0)
            .map(|b| (b.end() as f64 / 1e3, b.count()))
            .collect()
    }
}

/// Every figure kept per device.
#[derive(Default)]
pub struct Stats {
    /// Commands accepted at intake into the device's slot.
    pub received: AtomicU64,
    /// Command transactions completed without error.
    pub executed: AtomicU64,
    /// Commands replaced by a newer one before they reached the wire.
    pub superseded: AtomicU64,
    /// Commands the thread that admitted them wrote to the idle port itself (the fast
    /// path, [`crate::engine::fast`]); kept for tests and benchmarks, not broadcast.
    pub fast: AtomicU64,
    /// Last command sent again after `command_timeout` (or a manual wake).
    pub resent: AtomicU64,
    /// Commands refused at intake (interlock, range, disengaged…).
    pub rejected: AtomicU64,
    pub command_errors: AtomicU64,
    pub polls: AtomicU64,
    pub status_errors: AtomicU64,
    /// Receipt of a command to the first byte of it written to the port.
    pub command_delay: Latency,
    /// One command transaction, first byte out to reply in.
    pub command_txn: Latency,
    /// One status transaction.
    pub status_txn: Latency,
}

impl Stats {
    pub(crate) fn bump(counter: &AtomicU64) {
        counter.fetch_add(1, Relaxed);
    }

    /// Recompute every latency summary now (the exit summary, tests that check a
    /// figure right after the event).
    pub fn refresh(&self) {
        self.command_delay.summary_now();
        self.command_txn.summary_now();
        self.status_txn.summary_now();
    }

    /// The counters as they are now, as the snapshot carries them. `reconnects` is
    /// the port's figure, not kept here: 0 (the vehicle's view fills it in).
    pub fn counters(&self) -> Counters {
        Counters {
            received: self.received.load(Relaxed),
            executed: self.executed.load(Relaxed),
            superseded: self.superseded.load(Relaxed),
            resent: self.resent.load(Relaxed),
            rejected: self.rejected.load(Relaxed),
            command_errors: self.command_errors.load(Relaxed),
            polls: self.polls.load(Relaxed),
            status_errors: self.status_errors.load(Relaxed),
            reconnects: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latency_summary_reports_quantiles_within_two_percent() {
        let l = Latency::default();
        for us in 1..=1000u64 {
            l.record(Duration::from_micros(us));
        }
        let s = l.summary_now();
        assert_eq!(s.count, 1000);
        let near = |got: Option<f64>, want: f64| {
            let g = got.unwrap();
            assert!((g - want).abs() / want < 0.02, "got {g}, want {want}");
        };
        near(s.p50_us, 500.0);
        near(s.p99_us, 990.0);
        near(s.max_us, 1000.0);
        near(s.mean_us, 500.5);
    }

    #[test]
    fn an_empty_histogram_has_no_quantiles() {
        let s = Latency::default().summary();
        assert_eq!((s.count, s.p50_us, s.max_us), (0, None, None));
    }

    #[test]
    fn huge_samples_saturate_instead_of_vanishing() {
        let l = Latency::default();
        l.record(Duration::from_secs(100_000));
        assert_eq!(l.summary().count, 1);
    }

    #[test]
    fn a_summary_is_reused_while_nothing_new_arrives() {
        let l = Latency::default();
        l.record(Duration::from_micros(10));
        let a = l.summary();
        assert_eq!(a.count, 1);
        assert_eq!(l.summary(), a);
        l.record(Duration::from_micros(20));
        // Recent: the cached figures stand until SUMMARY_EVERY passes.
        assert_eq!(l.summary().count, 1);
        assert_eq!(l.summary_now().count, 2);
    }
}
