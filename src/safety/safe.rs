//! The safe state: what every actuator is commanded when the vehicle must stop — the
//! throttle released, the brake full, and every device's own `safe` value from the
//! vehicle file (horn off, hazard lights on). It comes from the bindings, never from
//! device names; a vehicle without a brake binding has a safe state that cannot brake
//! (adrive says so at start).

use crate::config::VehicleConfig;
use crate::value::{Command, DeviceId};

/// Every command of the safe state, by device, in the order they are given: the
/// throttle first, then the brake, then the devices' own safe values.
pub fn state(config: &VehicleConfig) -> Vec<(DeviceId, Command)> {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn alice_s_safe_state_is_gas_zero_and_brake_full() {
        let a = VehicleConfig::alice();
        let named: Vec<(String, Command)> = state(&a)
            .into_iter()
            .map(|(id, c)| (a.devices[id.index()].name.clone(), c))
            .collect();
        assert_eq!(
            named,
            vec![
                ("gas".to_string(), Command::Set(0.0)),
                ("brake".to_string(), Command::Set(1.0))
            ]
        );
    }
}
