//! A condition that repeats is logged once when it starts and then at most once a
//! minute, with a count — here from the real engine on a simulated device on a real
//! pseudo-terminal that stops answering. Its own test binary: it installs the process's
//! one tracing subscriber to read what was logged.

mod common;

use common::{steer_only, wait_for, Rig};
use parking_lot::Mutex;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::Layer;

/// Every event's message and fields, as one line.
#[derive(Clone, Default)]
struct Kept(Arc<Mutex<Vec<String>>>);

impl<S: tracing::Subscriber> Layer<S> for Kept {
    fn on_event(&self, event: &tracing::Event<'_>, _: tracing_subscriber::layer::Context<'_, S>) {
        self.0
            .lock()
            .push(adrive::logging::EventText::of(event).line());
    }
}

/// The incident: a silent device wrote "5 failed transactions in a row: reopening the
/// port" and "port reopened" every half second, and they filled the console's log pane.
/// Its port reopened again and again, each line is written once (the minute's count
/// comes with the next, a minute on: `logging::Repeats`' own tests).
#[test]
fn a_silent_device_reopened_again_and_again_is_logged_once() {
    let kept = Kept::default();
    tracing::subscriber::set_global_default(tracing_subscriber::registry().with(kept.clone()))
        .unwrap();
    let rig = Rig::start(&steer_only("", ""));
    let steer = rig.device("steer");
    wait_for("steer to report", || steer.cached().at.is_some());
    rig.sim.faults("steer").unwrap().silent.store(true, Relaxed);
    wait_for("its port reopened four times", || {
        steer.port_health().opens.load(Relaxed) >= 5
    });
    let lines = kept.0.lock().clone();
    let count = |what: &str| lines.iter().filter(|l| l.contains(what)).count();
    assert_eq!(count("reopening the port"), 1, "{lines:#?}");
    assert_eq!(count("port reopened"), 1, "{lines:#?}");
    assert_eq!(count("no reply within"), 1, "{lines:#?}");
}
