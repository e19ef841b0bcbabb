//! The `[console]` section of a vehicle file: what a console that commands the vehicle
//! must keep proving. Every key has a default, so a vehicle file without the section
//! gets the default bound.

use crate::config::limits::{self, Violation};
use serde::Deserialize;
use std::time::Duration;

/// `[console]`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConsoleConfig {
    /// A console that commands the engaged vehicle (embedded or `adrive attach`) and
    /// whose terminal has not answered a round trip for this long — its operator can
    /// no longer see or reach the vehicle — brings it to the safe state and disengages
    /// it (`adrive run --terminal-timeout` overrides it).
    #[serde(deserialize_with = "crate::config::duration")]
    pub terminal_timeout: Duration,
}

impl Default for ConsoleConfig {
    fn default() -> Self {
        ConsoleConfig {
            terminal_timeout: limits::TERMINAL_TIMEOUT.default_value(),
        }
    }
}

impl ConsoleConfig {
    /// Every value within its limit.
    pub fn check(&self) -> Result<(), Violation> {
        limits::TERMINAL_TIMEOUT.check(self.terminal_timeout)?;
        Ok(())
    }
}
