//! A fleet: many vehicles on one Zenoh network (cargo feature `fleet`). adrive grows
//! no messaging layer of its own for it: each vehicle is a Zenoh session under its own
//! key space, `adrive/<id>/…`, announced by a liveliness token `adrive/<id>` that Zenoh
//! withdraws when the vehicle stops or the network to it breaks, so whoever watches the
//! fleet knows who is there without asking anyone.
//!
//! - [`keys`]: the key expressions (pure);
//! - [`state`]: what a member publishes (the snapshot's head, [`Snapshot::head`]) and
//!   when a change of it is worth telling at once (pure);
//! - [`member`]: a running adrive in the fleet (`--fleet`, `[fleet]`): its session,
//!   its token and the thread that publishes its state;
//! - [`list`]: `adrive fleet`, every vehicle visible, once or as it changes;
//! - [`pick`]: `adrive fleet --pick`, the list in the console, to attach to one;
//! - [`router`]: `adrive fleet --router`, the fleet's Zenoh router;
//! - [`link`]: a console or an operator's command reaching a vehicle's control socket
//!   over the fleet: what goes on the wire and how it is signed (pure);
//! - [`dial`]: the asking end of a link (`adrive attach --vehicle ID`, `adrive ctl
//!   --vehicle ID`);
//! - [`serve`]: the vehicle's end, which takes links to its control socket.
//!
//! [`Snapshot::head`]: crate::snapshot::Snapshot::head

pub mod dial;
pub mod keys;
pub(crate) mod link;
pub(crate) mod list;
pub mod member;
pub(crate) mod pick;
pub(crate) mod router;
pub(crate) mod serve;
pub mod state;

pub use member::Member;

use crate::config::ros2::Mode;
use zenoh::Wait;

/// How to reach the fleet's network.
#[derive(Clone, Debug)]
pub(crate) struct Network<'a> {
    pub mode: Mode,
    pub connect: &'a [String],
    pub listen: &'a [String],
    pub multicast_scouting: bool,
}

/// Open a Zenoh session on the fleet's network.
pub(crate) fn open(n: &Network<'_>) -> anyhow::Result<zenoh::Session> {
    let mut z = zenoh::Config::default();
    let set = |z: &mut zenoh::Config, key: &str, value: String| {
        z.insert_json5(key, &value)
            .map_err(|e| anyhow::anyhow!("fleet: Zenoh setting {key} = {value}: {e}"))
    };
    let json = |v: &dyn erased_json::Json| v.json();
    set(&mut z, "mode", json(&n.mode.as_str()))?;
    set(&mut z, "connect/endpoints", json(&n.connect))?;
    set(&mut z, "listen/endpoints", json(&n.listen))?;
    set(
        &mut z,
        "scouting/multicast/enabled",
        json(&n.multicast_scouting),
    )?;
    zenoh::open(z).wait().map_err(|e| {
        anyhow::anyhow!(
            "fleet: cannot reach the fleet's network through {} (is its router running?): {e}",
            n.connect.join(", ")
        )
    })
}

mod erased_json {
    /// A value as JSON, for the Zenoh configuration.
    pub(crate) trait Json {
        fn json(&self) -> String;
    }
    impl<T: serde::Serialize> Json for T {
        fn json(&self) -> String {
            serde_json::to_string(self).expect("plain values serialize")
        }
    }
}
