//! The `[ros2]` section of a vehicle file: how adrive joins a ROS 2 graph over Zenoh
//! (`adrive --ros2`, built with the cargo feature `ros2`). Plain data, read in every
//! build, so one vehicle file serves a lean build and a ROS 2 one alike. Every key has
//! a default: those of rmw_zenoh's own sessions (peer mode, a router at
//! `tcp/localhost:7447`, no multicast scouting), domain 0 and the namespace
//! `/<vehicle name in lower case>`.

use super::limits::{self, Violation};
use serde::Deserialize;

/// The router an rmw_zenoh session connects to by default.
pub(crate) const DEFAULT_CONNECT: &str = "tcp/localhost:7447";
/// Where an rmw_zenoh session listens by default (any free port, this host only).
pub(crate) const DEFAULT_LISTEN: &str = "tcp/localhost:0";
/// The highest ROS domain id (ROS_DOMAIN_ID) ROS 2 allows.
pub(crate) const MAX_DOMAIN_ID: u32 = 232;

/// How the Zenoh session takes part in the network.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Talks to other peers directly, and to routers (rmw_zenoh's default).
    #[default]
    Peer,
    /// Talks only through the routers it connects to.
    Client,
}

impl Mode {
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::Peer => "peer",
            Mode::Client => "client",
        }
    }
}

/// `[ros2]`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Ros2Config {
    /// The ROS domain (ROS_DOMAIN_ID): graphs of different domains never meet.
    pub(crate) domain_id: u32,
    /// The namespace of every topic adrive publishes and subscribes to, `/alice`; `/`
    /// for none. Empty: `/<vehicle name in lower case>`.
    pub namespace: String,
    pub mode: Mode,
    /// Zenoh endpoints to connect to: routers, or peers (`tcp/10.0.0.2:7447`).
    pub connect: Vec<String>,
    /// Zenoh endpoints to listen on (`tcp/0.0.0.0:7448` to take peers from other hosts).
    pub listen: Vec<String>,
    /// Discover peers on the local network by UDP multicast (off, as in rmw_zenoh:
    /// discovery goes through the router).
    pub(crate) multicast_scouting: bool,
    /// Reports (steering, velocity, gear, …) published a second.
    pub(crate) report_rate: f64,
    /// Radians of tire angle per unit of the steering device, for the steering report;
    /// negative when the device's positive is to the right (ROS turns left positive).
    pub tire_angle_per_unit: f64,
    /// A state device with the states `off`, `left` and `right` that the turn
    /// indicator commands drive (none: the vehicle has none).
    pub(crate) turn_indicators: Option<String>,
    /// A state device with the states `off` and `on` that the hazard light commands
    /// drive (none: the vehicle has none).
    pub(crate) hazard_lights: Option<String>,
}

impl Default for Ros2Config {
    fn default() -> Self {
        Ros2Config {
            domain_id: 0,
            namespace: String::new(),
            mode: Mode::Peer,
            connect: vec![DEFAULT_CONNECT.to_string()],
            listen: vec![DEFAULT_LISTEN.to_string()],
            multicast_scouting: false,
            report_rate: limits::REPORT_RATE.default_value(),
            tire_angle_per_unit: 1.0,
            turn_indicators: None,
            hazard_lights: None,
        }
    }
}

/// The states a turn-indicator device must have, and a hazard-light device.
pub(crate) const TURN_STATES: [&str; 3] = ["off", "left", "right"];
pub(crate) const HAZARD_STATES: [&str; 2] = ["off", "on"];

impl Ros2Config {
    /// The namespace in use: the one written, else `/<vehicle name in lower case>`
    /// (characters ROS names do not take become `_`). Always starts with `/`, never
    /// ends with one (except `/` itself).
    #[cfg_attr(not(feature = "ros2"), allow(dead_code))]
    pub(crate) fn namespace_for(&self, vehicle: &str) -> String {
        let raw = if self.namespace.is_empty() {
            let name: String = vehicle
                .to_lowercase()
                .chars()
                .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
                .collect();
            format!("/{name}")
        } else {
            self.namespace.clone()
        };
        let trimmed = raw.trim_end_matches('/');
        if trimmed.is_empty() {
            "/".into()
        } else if trimmed.starts_with('/') {
            trimmed.to_string()
        } else {
            format!("/{trimmed}")
        }
    }

    /// Every value usable; the message names the key.
    pub fn check(&self, devices: &[super::DeviceConfig]) -> Result<(), Violation> {
        let bad = |key: &str, msg: String| {
            Err(Violation {
                paths: vec![key.to_string()],
                message: format!("{key}: {msg}"),
            })
        };
        if self.domain_id > MAX_DOMAIN_ID {
            return bad(
                "domain_id",
                format!("expected 0 … {MAX_DOMAIN_ID}, got {}", self.domain_id),
            );
        }
        if !self.namespace.is_empty() && !valid_namespace(&self.namespace) {
            return bad(
                "namespace",
                format!(
                    "expected a ROS namespace such as \"/alice\" or \"/fleet/car1\" (letters, \
                     digits and _ between slashes, not starting with a digit), got {:?}",
                    self.namespace
                ),
            );
        }
        limits::REPORT_RATE.check(self.report_rate)?;
        if !(self.tire_angle_per_unit.is_finite() && self.tire_angle_per_unit != 0.0) {
            return bad(
                "tire_angle_per_unit",
                format!(
                    "expected radians per unit of the steering device, not 0, got {}",
                    self.tire_angle_per_unit
                ),
            );
        }
        if let Err((key, why)) = check_session(self.mode, &self.connect, &self.listen) {
            return bad(key, why);
        }
        let bound = [
            ("turn_indicators", &self.turn_indicators, &TURN_STATES[..]),
            ("hazard_lights", &self.hazard_lights, &HAZARD_STATES[..]),
        ];
        for (key, name, states) in bound {
            let Some(name) = name else { continue };
            let Some(d) = devices.iter().find(|d| &d.name == name) else {
                return bad(key, format!("no device named {name:?}"));
            };
            let missing: Vec<&str> = states
                .iter()
                .copied()
                .filter(|s| d.state_index(s).is_none())
                .collect();
            if !d.is_actuator() || !missing.is_empty() {
                let why = if missing.is_empty() {
                    format!("it is a {}", d.kind)
                } else {
                    format!("missing: {}", missing.join(", "))
                };
                return bad(
                    key,
                    format!(
                        "{name} must be a state device with the states {} ({why})",
                        states.join(", ")
                    ),
                );
            }
        }
        Ok(())
    }
}

/// A Zenoh session's `mode`, `connect` and `listen` (`[ros2]`'s and `[fleet]`'s alike);
/// the key at fault and why.
pub(crate) fn check_session(
    mode: Mode,
    connect: &[String],
    listen: &[String],
) -> Result<(), (&'static str, String)> {
    if mode == Mode::Client && connect.is_empty() {
        return Err((
            "connect",
            "client mode needs a router to connect to (\"tcp/localhost:7447\")".into(),
        ));
    }
    let endpoints = connect
        .iter()
        .map(|e| ("connect", e))
        .chain(listen.iter().map(|e| ("listen", e)));
    for (key, e) in endpoints {
        check_endpoint(e).map_err(|why| (key, why))?;
    }
    Ok(())
}

/// A Zenoh endpoint, `proto/address` (`[ros2]`'s and `[fleet]`'s alike).
pub(crate) fn check_endpoint(e: &str) -> Result<(), String> {
    match e.split_once('/') {
        Some((proto, addr)) if !proto.is_empty() && !addr.is_empty() => Ok(()),
        _ => Err(format!(
            "expected a Zenoh endpoint such as \"tcp/10.0.0.2:7447\", got {e:?}"
        )),
    }
}

/// A ROS 2 namespace: `/` or `/name(/name)*`, each name letters, digits and `_`, not
/// starting with a digit.
fn valid_namespace(ns: &str) -> bool {
    let Some(rest) = ns.strip_prefix('/').filter(|_| !ns.contains("//")) else {
        return false;
    };
    let rest = rest.strip_suffix('/').unwrap_or(rest);
    rest.is_empty()
        || rest.split('/').all(|n| {
            !n.is_empty()
                && !n.starts_with(|c: char| c.is_ascii_digit())
                && n.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_namespace_defaults_to_the_vehicle_name_in_lower_case() {
        let c = Ros2Config::default();
        assert_eq!(c.namespace_for("Alice"), "/alice");
        assert_eq!(c.namespace_for("Bob's car"), "/bob_s_car");
        let c = Ros2Config {
            namespace: "/".into(),
            ..Ros2Config::default()
        };
        assert_eq!(c.namespace_for("Alice"), "/");
        let c = Ros2Config {
            namespace: "/fleet/car1/".into(),
            ..Ros2Config::default()
        };
        assert_eq!(c.namespace_for("Alice"), "/fleet/car1");
    }

    #[test]
    fn namespaces_are_checked() {
        for ok in ["/", "/alice", "/fleet/car_1"] {
            assert!(valid_namespace(ok), "{ok}");
        }
        for bad in ["alice", "/1car", "/a b", "//", "/a//b"] {
            assert!(!valid_namespace(bad), "{bad}");
        }
    }
}
