//! What a drive-by-wire kit's module says of itself, judged. A module on a CAN bus
//! (OSCC's brake, steering and throttle) reports whether it is enabled, whether the
//! driver overrides it, and its fault codes; adrive enables it on engage and disables it
//! on every safe state ([`crate::driver::slcan::CanDriver`]). Here:
//!
//! - the kit's own override flag is a driver's override, beside the estimator's: the
//!   vehicle goes to the driver ([`FaultKind::Override`]). The flag names the override
//!   once — until the gate has latched it — and not again: a module that keeps it after
//!   the driver let go (firmware that latches it until the next enable; OSCC's clears
//!   it once the driver's torque drops) holds a memory of the override, not a hand on
//!   the controls, and must not keep the operator from clearing it;
//! - a module that reports itself disabled while the vehicle has been engaged longer
//!   than it takes to enable it — it disabled itself: a fault code, its watchdog, an
//!   override the flag missed — is a device fault, and so are its fault codes while
//!   engaged, by their DBC names;
//! - while disengaged a module is disabled by adrive, and the codes it reports (while
//!   their cause lasts, or latched until it is enabled again) are shown by name but
//!   block nothing: a module that cannot be enabled is caught by the rule above.

use crate::config::can::{ENABLED, OVERRIDE};
use crate::config::DeviceConfig;
use crate::snapshot::{DeviceView, FaultKind};
use crate::value::Value;
use std::time::Duration;

/// Judge one kit device; `engaged_for`: how long the vehicle has been engaged;
/// `latched`: the gate holds a driver's override of it; `handled`: the memory of
/// whether the flag now raised has been handed to the driver.
pub(super) fn faults(
    d: &DeviceView,
    c: &DeviceConfig,
    engaged_for: Option<Duration>,
    latched: bool,
    handled: &mut bool,
    raise: &mut impl FnMut(FaultKind, Option<&str>, String),
) {
    let Some(kit) = c.kit() else { return };
    let who = Some(d.name.as_str());
    match d.reading(OVERRIDE) {
        Some(Value::Flag(true)) => {
            // A module may keep the flag until its next enable: once the gate latched
            // the override it stands for, the flag says nothing of a hand still on
            // (clearing it is the operator's, engaging re-enables and clears it).
            *handled |= latched;
            if !*handled {
                raise(
                    FaultKind::Override,
                    who,
                    "the kit reports the driver's override".into(),
                );
                return;
            }
        }
        Some(Value::Flag(false)) => *handled = false,
        _ => {}
    }
    let Some(engaged_for) = engaged_for else {
        return;
    };
    // Time for the safe command and the enable to go out and a report to come back.
    let grace = c.command_timeout + 2 * c.status_max_age;
    if engaged_for <= grace {
        return;
    }
    if d.fault != 0 {
        raise(
            FaultKind::DeviceFault,
            who,
            format!("the kit reports {}", kit.fault_names(d.fault).join(", ")),
        );
    } else if d.reading(ENABLED) == Some(&Value::Flag(false)) {
        raise(
            FaultKind::DeviceFault,
            who,
            format!(
                "the kit reports {} disabled while engaged ({} ms)",
                d.name,
                engaged_for.as_millis()
            ),
        );
    }
}
