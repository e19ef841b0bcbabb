//! The third-party ROS 2 peer: its script, and a Python with Eclipse Zenoh's Python
//! API, rosbags and xxhash, pinned (see `python_env.rs`).

#[path = "python_env.rs"]
mod python_env;

use std::sync::OnceLock;

pub const PACKAGES: [&str; 3] = ["eclipse-zenoh==1.10.2", "rosbags==0.11.9", "xxhash==3.5.0"];

/// The peer script.
pub const PEER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/support/ros2_peer.py");

/// A Python interpreter with the pinned packages.
pub fn python() -> &'static str {
    static PYTHON: OnceLock<String> = OnceLock::new();
    PYTHON.get_or_init(|| python_env::python("ros2-venv", &PACKAGES, "zenoh, rosbags, xxhash"))
}
