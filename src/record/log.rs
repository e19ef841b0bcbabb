//! Log lines into a recording: a `tracing` layer beside the file and stderr layers
//! that hands every event at INFO and above to the vehicle's tap while a recording
//! runs (and costs one atomic load while none does).

use crate::logging::EventText;
use crate::vehicle::tap::{Event, Tap};
use std::sync::Arc;
use std::time::SystemTime;
use tracing::{Level, Subscriber};
use tracing_subscriber::layer::Context;
use tracing_subscriber::Layer;

/// The layer; made before the vehicle, with the tap the vehicle will use.
pub(crate) struct TapLayer {
    pub(crate) tap: Arc<Tap>,
}

impl<S: Subscriber> Layer<S> for TapLayer {
    fn on_event(&self, event: &tracing::Event<'_>, _ctx: Context<'_, S>) {
        let meta = event.metadata();
        if *meta.level() > Level::INFO || !self.tap.is_on() {
            return;
        }
        self.tap.send(|| Event::Log {
            at: SystemTime::now(),
            level: *meta.level(),
            target: meta.target(),
            file: meta.file(),
            line: meta.line(),
            text: EventText::of(event).line(),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracing_subscriber::layer::SubscriberExt;

    #[test]
    fn info_and_above_reach_the_tap() {
        let tap = Arc::new(Tap::default());
        let rx = tap.open(false).unwrap().rx;
        let sub = tracing_subscriber::registry().with(TapLayer { tap: tap.clone() });
        tracing::subscriber::with_default(sub, || {
            tracing::debug!("not this");
            tracing::info!(device = "steer", "engaged");
            tracing::error!("boom");
        });
        let texts: Vec<String> = rx
            .try_iter()
            .map(|e| match e {
                Event::Log { text, .. } => text,
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(texts, ["engaged device=steer", "boom"]);
    }
}
