//! [`Controls`] over the engine in this process, as one source: the embedded console,
//! and each console attached to the control socket, which the server serves through a
//! `Live` of its own.

use super::scene::{capture, Scene, Sources};
use super::{Characterizing, Controls, Thread, Tune};
use crate::characterize::background::{self, Background};
use crate::characterize::Procedure;
use crate::engine::Gate;
use crate::safety::{Ask, Done, Refused};
use crate::value::{Command, DeviceId, Source};
use std::path::Path;
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

/// [`Controls`] over the real vehicle, as one source: the embedded console
/// ([`Source::Console`]), or an attached one ([`Source::Attached`], for the control
/// socket, which serves each connection through its own `Live`).
pub struct Live<'a> {
    pub gate: &'a Gate,
    pub sources: &'a Sources,
    pub source: Source,
    /// The embedded console's characterizations (`None` for an attached console's).
    pub characterize: Option<&'a Background>,
}

/// A console edit of a device's settings, checked as the vehicle file is, and logged.
pub(crate) fn change_settings(
    vehicle: &crate::vehicle::Vehicle,
    id: DeviceId,
    change: impl FnOnce(&mut crate::config::DeviceConfig),
) -> Result<(), String> {
    let dev = vehicle
        .devices()
        .get(id.index())
        .ok_or_else(|| format!("no device #{}", id.index()))?;
    dev.change_settings(change).map_err(|v| v.message)?;
    tracing::info!(
        device = dev.name(),
        "from the console: status_period {}, command_timeout {}",
        crate::config::fmt_duration(dev.settings().status_period()),
        crate::config::fmt_duration(dev.settings().command_timeout())
    );
    Ok(())
}

impl Controls for Live<'_> {
    fn scene(&self, now: Instant, bench: Option<DeviceId>) -> Scene {
        capture(self.gate, self.sources, now, bench)
    }
    fn parse(&self, id: DeviceId, text: &str) -> Result<Command, String> {
        match self.gate.vehicle().devices().get(id.index()) {
            Some(d) => d.config().parse_command(text),
            None => Err("no such device".into()),
        }
    }
    fn ask(&self, ask: Ask) -> Result<Done, Refused> {
        self.gate.admit(self.source, ask, Instant::now())
    }
    fn tune(&self, tune: Tune) -> Result<(), String> {
        if let Err(why) = self.gate.tune(self.source) {
            if let Tune::Enabled(_, thread, _) = tune {
                tracing::warn!(
                    "{thread:?} thread switch from {} refused: {why}",
                    self.source
                );
            }
            return Err(why.to_string());
        }
        let vehicle = self.gate.vehicle();
        match tune {
            Tune::StatusPeriod(id, d) => change_settings(vehicle, id, |c| c.status_period = d),
            Tune::CommandTimeout(id, d) => change_settings(vehicle, id, |c| c.command_timeout = d),
            Tune::Enabled(id, thread, on) => {
                if let Some(dev) = vehicle.devices().get(id.index()) {
                    let flag = match thread {
                        Thread::Status => &dev.settings().status_enabled,
                        Thread::Command => &dev.settings().command_enabled,
                    };
                    flag.store(on, Relaxed);
                    tracing::info!(device = %dev.name(), "{thread:?} thread {}", if on { "enabled" } else { "disabled" });
                }
                Ok(())
            }
            Tune::Wake(id) => {
                if let Some(dev) = vehicle.devices().get(id.index()) {
                    dev.slot().nudge();
                }
                Ok(())
            }
        }
    }
    fn set_interlocks(&self, on: bool) -> Result<(), Refused> {
        self.gate.set_interlocks(self.source, on)
    }
    fn deadman(&self, armed: Option<Duration>) {
        self.gate.deadman(self.source, armed, Instant::now());
    }
    fn sim(&self, line: &str) -> Option<Result<String, String>> {
        let sim = self.sources.sim.as_ref()?;
        if let Err(why) = self.gate.tune(self.source) {
            return Some(Err(why.to_string()));
        }
        let done = sim.apply(line);
        match &done {
            Ok(what) => tracing::warn!("simulator, from the console: {what}"),
            Err(e) => tracing::info!("simulator refused {line:?}: {e}"),
        }
        Some(done)
    }
    fn answered(&self, at: Instant) {
        self.gate.answered(self.source, at);
        if let Some(b) = self.characterize {
            b.answered(at);
        }
    }
    fn characterize_check(&self, id: DeviceId) -> Result<String, String> {
        match self.characterize {
            Some(_) => background::check(self.gate, id),
            None => Err(super::CHARACTERIZE_WHERE.into()),
        }
    }
    fn characterize(
        &self,
        id: DeviceId,
        procedures: &[Procedure],
        out: &Path,
    ) -> Result<(), String> {
        match self.characterize {
            Some(b) => b.start(id, procedures, out),
            None => Err(super::CHARACTERIZE_WHERE.into()),
        }
    }
    fn characterizing(&self) -> Option<Characterizing> {
        self.characterize.and_then(Background::state)
    }
    fn characterize_end(&self, why: &str) {
        if let Some(b) = self.characterize {
            b.end(why);
        }
    }
}
