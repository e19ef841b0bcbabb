//! The safe state: what every actuator is commanded when the vehicle must stop — the
//! throttle released, the brake full, and every device's own `safe` value from the
//! vehicle file (horn off, hazard lights on). It comes from the bindings, never from
//! device names; a vehicle without a brake binding has a safe state that cannot brake
//! (adrive says so at start).
//!
//! The manual state is the safe state while a driver has taken over (a latched
//! `override`): the throttle released and the brake released too — adrive never brakes
//! against the driver — and nothing else commanded: the steering drive keeps the set
//! point it has (the line protocols have no way to release it) and adrive stops
//! sending it any.

use crate::config::VehicleConfig;
use crate::value::{Command, DeviceId};

/// Every command of the safe state, by device, in the order they are given: the
/// throttle first, then the brake, then the devices' own safe values.
pub(crate) fn state(config: &VehicleConfig) -> Vec<(DeviceId, Command)> {
    let b = &config.roles;
    let mut out = Vec::new();
    if let Some(t) = b.throttle {
        out.push((t, Command::Set(config.devices[t.index()].range[0])));
    }
    if let Some(br) = b.brake {
        out.push((br, Command::Set(config.devices[br.index()].range[1])));
    }
    for (i, d) in config.devices.iter().enumerate() {
        let id = DeviceId(i as u16);
        if let Some(c) = d.safe {
            if !out.iter().any(|(o, _)| *o == id) {
                out.push((id, c));
            }
        }
    }
    out
}

/// Every command of the manual state: the throttle and the brake released.
pub(crate) fn manual(config: &VehicleConfig) -> Vec<(DeviceId, Command)> {
    let b = &config.roles;
    [b.throttle, b.brake]
        .into_iter()
        .flatten()
        .map(|id| (id, Command::Set(config.devices[id.index()].range[0])))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What `of` commands on Alice, by device name.
    fn named(of: fn(&VehicleConfig) -> Vec<(DeviceId, Command)>) -> Vec<(String, Command)> {
        let a = VehicleConfig::alice();
        of(&a)
            .into_iter()
            .map(|(id, c)| (a.devices[id.index()].name.clone(), c))
            .collect()
    }

    #[test]
    fn alice_s_safe_state_is_gas_zero_and_brake_full() {
        assert_eq!(
            named(state),
            vec![
                ("gas".to_string(), Command::Set(0.0)),
                ("brake".to_string(), Command::Set(1.0))
            ]
        );
    }

    /// The cart's horn and signals have safe values of their own: they follow the
    /// pedals. A pedal's own `safe` never stands beside its role's: the brake is
    /// commanded once, full.
    #[test]
    fn the_devices_own_safe_values_follow_the_pedals_and_a_pedal_is_commanded_once() {
        let brake = "name = \"brake\"            # hydraulic brake actuator, 0 … 1\n";
        let text = include_str!("../../vehicles/cart.toml");
        assert!(text.contains(brake));
        let text = text.replace(brake, &format!("{brake}safe = 0.3\n"));
        let cart = crate::config::parse(&text, "vehicles/cart.toml").unwrap();
        let name = |id: DeviceId| cart.devices[id.index()].name.as_str();
        let own = |n: &str| cart.devices.iter().find(|d| d.name == n).unwrap().safe;
        assert_eq!(own("brake"), Some(Command::Set(0.3)));
        let got: Vec<(&str, Command)> = state(&cart)
            .into_iter()
            .map(|(id, c)| (name(id), c))
            .collect();
        assert_eq!(
            got,
            vec![
                ("throttle", Command::Set(0.0)),
                ("brake", Command::Set(1.0)),
                ("horn", own("horn").unwrap()),
                ("signals", own("signals").unwrap()),
            ]
        );
    }

    #[test]
    fn alice_s_manual_state_releases_gas_and_brake_and_leaves_the_steering_alone() {
        assert_eq!(
            named(manual),
            vec![
                ("gas".to_string(), Command::Set(0.0)),
                ("brake".to_string(), Command::Set(0.0))
            ]
        );
    }
}
