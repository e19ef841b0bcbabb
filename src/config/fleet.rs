//! The `[fleet]` section of a vehicle file: how this vehicle joins a fleet, many
//! vehicles on one Zenoh network (`adrive --fleet`, built with the cargo feature
//! `fleet`). A vehicle file with the section joins; `--fleet ID` joins without it.
//! Plain data, read in every build. Every key has a default: the id is the vehicle's
//! name in lower case, the session is a Zenoh client of the fleet's router at
//! `tcp/localhost:7447` (every member and watcher reaches the others through it; a
//! router does not carry a peer's declarations to other peers), listens nowhere and
//! does not scout by multicast. A client whose router cannot be reached at start is
//! refused, named.

use super::limits::Violation;
use super::ros2::{check_endpoint, check_session, Mode};
use serde::Deserialize;

/// The router a fleet session connects to by default (Zenoh's own port).
pub(crate) const DEFAULT_CONNECT: &str = "tcp/localhost:7447";
/// The longest fleet id.
pub(crate) const MAX_ID: usize = 64;

/// `[fleet]`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FleetConfig {
    /// The vehicle's name in the fleet: its key space is `adrive/<id>/…`. Empty: the
    /// vehicle's name in lower case.
    pub id: String,
    /// `client` (through the router) or `peer` (directly, to peers that `listen`).
    pub mode: Mode,
    /// Zenoh endpoints to connect to: the fleet's router (`tcp/10.0.0.1:7447`).
    pub connect: Vec<String>,
    /// Zenoh endpoints to listen on, for peers that connect to this vehicle.
    pub listen: Vec<String>,
    /// Discover peers on the local network by UDP multicast.
    pub(crate) multicast_scouting: bool,
    /// Take commands from the fleet: a console or an operator's command linked from
    /// elsewhere that proves the vehicle's key (`[network] key_file`) may command it.
    /// Without it, the fleet only watches.
    pub command: bool,
}

impl Default for FleetConfig {
    fn default() -> Self {
        FleetConfig {
            id: String::new(),
            mode: Mode::Client,
            connect: vec![DEFAULT_CONNECT.to_string()],
            listen: Vec::new(),
            multicast_scouting: false,
            command: false,
        }
    }
}

/// What a fleet id is, for messages.
pub(crate) const ID_FORM: &str =
    "a fleet id such as \"car1\" (1 to 64 letters, digits, '_' and '-')";

/// Is `id` a fleet id: one chunk of a Zenoh key, no wildcard or separator in it.
pub(crate) fn valid_id(id: &str) -> bool {
    !id.is_empty()
        && id.len() <= MAX_ID
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

/// The id a vehicle named `vehicle` has by default: its name in lower case, every
/// other character `_` (as [`super::Ros2Config::namespace_for`] makes a namespace).
pub(crate) fn default_id(vehicle: &str) -> String {
    let id: String = vehicle
        .to_lowercase()
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .take(MAX_ID)
        .collect();
    if id.is_empty() {
        "adrive".into()
    } else {
        id
    }
}

impl FleetConfig {
    /// The id in use: the one written, else [`default_id`].
    pub fn id_for(&self, vehicle: &str) -> String {
        if self.id.is_empty() {
            default_id(vehicle)
        } else {
            self.id.clone()
        }
    }

    /// Every value usable; the message names the key.
    pub fn check(&self) -> Result<(), Violation> {
        let bad = |key: &str, msg: String| {
            Err(Violation {
                paths: vec![key.to_string()],
                message: format!("{key}: {msg}"),
            })
        };
        if !self.id.is_empty() && !valid_id(&self.id) {
            return bad("id", format!("expected {ID_FORM}, got {:?}", self.id));
        }
        if let Err((key, why)) = check_session(self.mode, &self.connect, &self.listen) {
            return bad(key, why);
        }
        Ok(())
    }

    /// This file's `[fleet]` (if any) with the command line's `--fleet [ID]` (`Some("")`:
    /// no id given) and `--fleet-connect` over it: `None` when the vehicle joins no
    /// fleet. A command-line value is checked here, named by its flag.
    pub(crate) fn joining(
        file: Option<&FleetConfig>,
        flag: Option<&str>,
        connect: &[String],
    ) -> Result<Option<FleetConfig>, String> {
        let mut c = match (file, flag) {
            (None, None) if connect.is_empty() => return Ok(None),
            (None, None) => {
                return Err(
                    "--fleet-connect: this vehicle joins no fleet (give --fleet ID, \
                            or write a [fleet] section in its vehicle file)"
                        .into(),
                )
            }
            (Some(c), _) => c.clone(),
            (None, Some(_)) => FleetConfig::default(),
        };
        if let Some(id) = flag.filter(|id| !id.is_empty()) {
            if !valid_id(id) {
                return Err(format!("--fleet: expected {ID_FORM}, got {id:?}"));
            }
            c.id = id.to_string();
        }
        if !connect.is_empty() {
            for e in connect {
                check_endpoint(e).map_err(|why| format!("--fleet-connect: {why}"))?;
            }
            c.connect = connect.to_vec();
        }
        Ok(Some(c))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_one_chunk_of_a_key() {
        for ok in ["car1", "Alice", "a-b_c", &"x".repeat(MAX_ID)] {
            assert!(valid_id(ok), "{ok}");
        }
        for bad in [
            "",
            "a/b",
            "*",
            "a b",
            "car$1",
            "**",
            &"x".repeat(MAX_ID + 1),
        ] {
            assert!(!valid_id(bad), "{bad}");
        }
        assert_eq!(default_id("Alice"), "alice");
        assert_eq!(default_id("Bob's car"), "bob_s_car");
        assert!(valid_id(&default_id(&"é".repeat(100))));
    }

    #[test]
    fn the_command_line_joins_and_overrides_the_file() {
        assert_eq!(FleetConfig::joining(None, None, &[]), Ok(None));
        let e = FleetConfig::joining(None, None, &["tcp/h:1".into()]).unwrap_err();
        assert!(
            e.contains("--fleet-connect: this vehicle joins no fleet"),
            "{e}"
        );
        let c = FleetConfig::joining(None, Some(""), &[]).unwrap().unwrap();
        assert_eq!(c, FleetConfig::default());
        assert_eq!(c.id_for("Alice"), "alice");
        let file = FleetConfig {
            id: "bob".into(),
            ..FleetConfig::default()
        };
        let c = FleetConfig::joining(Some(&file), None, &[])
            .unwrap()
            .unwrap();
        assert_eq!(c.id_for("Alice"), "bob");
        let c = FleetConfig::joining(Some(&file), Some("car2"), &["tcp/10.0.0.1:7447".into()])
            .unwrap()
            .unwrap();
        assert_eq!(c.id, "car2");
        assert_eq!(c.connect, ["tcp/10.0.0.1:7447"]);
        let e = FleetConfig::joining(None, Some("a/b"), &[]).unwrap_err();
        assert!(e.starts_with("--fleet: expected a fleet id such as"), "{e}");
        let e = FleetConfig::joining(None, Some("car1"), &["10.0.0.1:7447".into()]).unwrap_err();
        assert!(
            e.starts_with("--fleet-connect: expected a Zenoh endpoint"),
            "{e}"
        );
    }
}
