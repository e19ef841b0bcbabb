//! `adrive fleet --router`: the fleet's Zenoh router, for a fleet that has none. Every
//! vehicle and tool of a fleet is a client of one router (a router does not carry a
//! peer's declarations to other peers), and adrive links Zenoh already: this runs it
//! in router mode on the endpoints given, multicast scouting off (so that it meets no
//! other network by chance), until it is told to stop. Any other Zenoh router
//! (`zenohd`) serves as well.

use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::time::Duration;
use zenoh::Wait;

/// Where the router listens unless told: every address, Zenoh's port.
pub(crate) const DEFAULT_LISTEN: &str = "tcp/0.0.0.0:7447";

/// Run a router listening on `listen` until `stop`; the process status.
pub(crate) fn run(listen: &[String], stop: &AtomicBool) -> anyhow::Result<i32> {
    let mut z = zenoh::Config::default();
    let set = |z: &mut zenoh::Config, key: &str, value: String| {
        z.insert_json5(key, &value)
            .map_err(|e| anyhow::anyhow!("fleet router: Zenoh setting {key} = {value}: {e}"))
    };
    set(&mut z, "mode", "\"router\"".into())?;
    set(&mut z, "listen/endpoints", serde_json::to_string(listen)?)?;
    set(&mut z, "scouting/multicast/enabled", "false".into())?;
    let session = zenoh::open(z).wait().map_err(|e| {
        anyhow::anyhow!("fleet router: cannot listen on {}: {e}", listen.join(", "))
    })?;
    eprintln!(
        "adrive: the fleet's router listens on {} (Ctrl-C stops it)",
        listen.join(", ")
    );
    while !stop.load(Relaxed) {
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = session.close().wait();
    Ok(0)
}
