//! adrive as a ROS 2 / Autoware vehicle interface over Zenoh (cargo feature `ros2`,
//! `adrive --ros2`). adrive joins a ROS 2 graph the way rmw_zenoh does — no ROS
//! installation, no DDS — so ROS 2 nodes on rmw_zenoh, `ros2 topic list/echo` and an
//! Autoware stack see the node `/<namespace>/adrive`, and several vehicles share one
//! Zenoh network under their own namespaces. adrive grows no messaging layer of its own.
//!
//! - [`keys`]: rmw_zenoh's key expressions, liveliness tokens, GIDs and attachment;
//! - [`msgs`]: the Autoware and ROS messages, with serde and their type hashes;
//! - [`bridge`]: what the messages mean on this vehicle (pure);
//! - [`node`]: the Zenoh session and the node's two threads;
//! - [`watch`]: `adrive watch --ros2`, every vehicle on the network, following one.

pub(crate) mod bridge;
pub mod keys;
pub mod msgs;
pub mod node;
pub(crate) mod watch;

pub use node::Node;
