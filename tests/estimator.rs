//! The estimator and adaptive polling against a simulated drive on a real
//! pseudo-terminal: the estimate follows the device, and an adaptive status thread
//! stretches its period under a steady command but polls again within one period of
//! a command change or a surprise.

mod common;

use adrive::value::Command;
use adrive::vehicle::Device;
use common::{steer_only, wait_for, Rig, DEADLINE};
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

const PERIOD: Duration = Duration::from_millis(50);
/// What a loaded machine may add to a wake-up and a poll's transaction: up to the
/// next period's poll and then some, so that the bound (three periods) is where a
/// stretched interval begins ([`stretched_interval`]). Forty milliseconds was less
/// than one late wake-up seen on these machines (61 ms, in another test).
const SLACK: Duration = Duration::from_millis(100);

/// Steering polled adaptively: 50 ms at the fastest, a reading at most 1 s old.
fn adaptive_steer() -> String {
    steer_only(
        "status_period = \"50ms\"\nstatus_max_age = \"1s\"\nreply_timeout = \"100ms\"\ncommand_timeout = \"250ms\"\npolling = \"adaptive\"\n[device.response]\nrate = 1.0",
        "rate = 1.0",
    )
}

/// When the next poll of `d` completes (seen by its counter).
fn next_poll(d: &Device) -> Instant {
    let n = d.stats().polls.load(Relaxed);
    let end = Instant::now() + DEADLINE;
    loop {
        if d.stats().polls.load(Relaxed) > n {
            return Instant::now();
        }
        assert!(
            Instant::now() < end,
            "timed out waiting for a poll of {}",
            d.name()
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Engage, command 0.3 and wait for the estimate to settle there.
fn settled(rig: &Rig) -> &Device {
    rig.engage();
    rig.submit("steer", Command::Set(0.3)).unwrap();
    let steer = rig.device("steer");
    wait_for("the estimate to settle at 0.3", || {
        steer
            .estimate(Instant::now())
            .is_some_and(|e| (e.position - 0.3).abs() < 0.02)
    });
    steer
}

/// Time between polls once the steady command has let the period stretch.
fn stretched_interval(steer: &Device) -> Duration {
    let mut last = next_poll(steer);
    for _ in 0..20 {
        let now = next_poll(steer);
        if now - last > PERIOD + SLACK {
            return now - last;
        }
        last = now;
    }
    panic!("20 polls under a steady command, none more than 3 periods apart");
}

#[test]
fn adaptive_polling_stretches_under_a_steady_command() {
    let rig = Rig::start(&adaptive_steer());
    let steer = settled(&rig);
    stretched_interval(steer);
    // Over a second of steady command, far fewer polls than a fixed 50 ms period.
    let (start, polls) = (next_poll(steer), steer.stats().polls.load(Relaxed));
    wait_for("a second to pass", || {
        start.elapsed() >= Duration::from_secs(1)
    });
    let n = steer.stats().polls.load(Relaxed) - polls;
    assert!(n <= 10, "{n} polls in a second (fixed polling makes 20)");
    // The estimate stays within its tolerance of the device meanwhile.
    let e = steer.estimate(Instant::now()).unwrap();
    let sim = rig.sim.model().lock().devices[0].position;
    assert!((e.position - sim).abs() < 0.02, "{e:?} against {sim}");
}

#[test]
fn adaptive_polling_returns_to_the_fastest_period_after_a_command_change() {
    let rig = Rig::start(&adaptive_steer());
    let steer = settled(&rig);
    stretched_interval(steer);
    // Just after a poll: the next one would be stretched.
    next_poll(steer);
    let changed = Instant::now();
    rig.submit("steer", Command::Set(-0.2)).unwrap();
    let polled = next_poll(steer);
    assert!(
        polled - changed <= PERIOD + SLACK,
        "polled {:?} after the command change",
        polled - changed
    );
}

#[test]
fn adaptive_polling_returns_to_the_fastest_period_after_a_surprise() {
    let rig = Rig::start(&adaptive_steer());
    let steer = settled(&rig);
    stretched_interval(steer);
    // A slipped sensor: the next reading is far outside the prediction.
    rig.sim.apply("bias steer 0.3").unwrap();
    let surprised = next_poll(steer);
    let again = next_poll(steer);
    assert!(
        again - surprised <= PERIOD + SLACK,
        "polled {:?} after a surprise",
        again - surprised
    );
}

#[test]
fn fixed_polling_keeps_its_period() {
    let rig = Rig::start(&adaptive_steer().replace("polling = \"adaptive\"", ""));
    let steer = settled(&rig);
    let mut last = next_poll(steer);
    for _ in 0..5 {
        let now = next_poll(steer);
        assert!(
            now - last <= PERIOD + SLACK,
            "{:?} between fixed polls",
            now - last
        );
        last = now;
    }
}
