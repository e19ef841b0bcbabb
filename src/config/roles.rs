//! Safety roles as bindings. The safety rules, the safe state, `accel` and the
//! supervisor's procedures never name a device: they ask for the device (or the
//! reading) bound to a role in `[vehicle.roles]`. A rule whose devices are not bound is
//! simply absent (a cart without a gearbox has no shift rule), and adrive says at start
//! which rules are active and what is missing.
//!
//! Which roles may share one device is decided here once, in [`SHARED`]: a device
//! plays one role, except the pairs listed there with their reason. Every other pair
//! is refused at the line of its second binding (throttle and brake on one device
//! would be released and applied by the same set point).

use super::device::{DeviceConfig, Mistake, ReadingKind};
use crate::value::{DeviceId, EstopState, Kind};
use serde::Deserialize;
use std::fmt;
use toml::Spanned;

/// The roles the safety rules need.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Role {
    /// A setpoint actuator: the steering (held where it is on engage).
    Steering,
    /// A setpoint actuator: the throttle (0 in the safe state).
    Throttle,
    /// A setpoint actuator: the brake (its maximum in the safe state).
    Brake,
    /// A state actuator: the gearbox or direction switch.
    Gear,
    /// A state reading with disable, pause and run.
    Estop,
    /// A number reading: road speed, m/s.
    Speed,
    /// A flag (or number, non-zero) reading: the engine runs.
    EngineRunning,
    /// An actuator that takes the `start` control.
    Starter,
}

impl Role {
    pub const ALL: [Role; 8] = [
        Role::Steering,
        Role::Throttle,
        Role::Brake,
        Role::Gear,
        Role::Estop,
        Role::Speed,
        Role::EngineRunning,
        Role::Starter,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Role::Steering => "steering",
            Role::Throttle => "throttle",
            Role::Brake => "brake",
            Role::Gear => "gear",
            Role::Estop => "estop",
            Role::Speed => "speed",
            Role::EngineRunning => "engine_running",
            Role::Starter => "starter",
        }
    }

    /// Older names still understood (keymaps written for Alice's device names).
    pub(crate) fn from_word(w: &str) -> Option<Role> {
        match w {
            "steer" => Some(Role::Steering),
            "gas" => Some(Role::Throttle),
            "trans" => Some(Role::Gear),
            _ => Role::ALL.into_iter().find(|r| r.as_str() == w),
        }
    }
}

/// The pairs of roles one device may play, each with the reason it may; every other
/// pair on one device is refused ([`Role::shares_with`]). The guide's table
/// (docs/vehicles.md) is generated from this one ([`sharing_markdown`]).
pub(crate) const SHARED: [(Role, Role, &str); 2] = [
    (
        Role::Gear,
        Role::Starter,
        "the gearbox controller cranks the engine, and only in park or neutral (Alice's `trans`): `start_in_gear` reads the very device that starts",
    ),
    (
        Role::Speed,
        Role::EngineRunning,
        "two readings of one engine computer (an OBD-II adapter reports road speed and rpm); neither commands anything",
    ),
];

impl Role {
    /// Why `self` and `other` may be bound to one device; `None`: they may not.
    pub(crate) fn shares_with(self, other: Role) -> Option<&'static str> {
        SHARED
            .iter()
            .find(|(a, b, _)| [*a, *b] == [self, other] || [*b, *a] == [self, other])
            .map(|(_, _, why)| *why)
    }
}

/// The guide's table (docs/vehicles.md) of the roles that may share a device.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn sharing_markdown() -> String {
    let mut out = String::from("| roles | may share one device because |\n|---|---|\n");
    for (a, b, why) in SHARED {
        out.push_str(&format!("| `{a}`, `{b}` | {why} |\n"));
    }
    out
}

/// The pairs of [`SHARED`], as a user reads them in a refusal.
fn shared_pairs() -> String {
    SHARED
        .iter()
        .map(|(a, b, _)| format!("{a} with {b}"))
        .collect::<Vec<_>>()
        .join(", ")
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A reading of a device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReadingRef {
    pub device: DeviceId,
    pub reading: usize,
}

/// The gearbox binding: which of its states drive forward or backward, and which one
/// parks (where an engine is started).
#[derive(Clone, Debug, PartialEq)]
pub struct GearBinding {
    pub device: DeviceId,
    pub forward: Vec<u8>,
    pub reverse: Vec<u8>,
    /// The state to start the engine in (park, else neutral).
    pub park: Option<u8>,
}

impl GearBinding {
    /// A state in which the engine drives the wheels.
    pub fn drives(&self, state: u8) -> bool {
        self.forward.contains(&state) || self.reverse.contains(&state)
    }
}

/// The e-stop binding: a state reading and which of its states mean what.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstopBinding {
    pub at: ReadingRef,
    /// State index of disable, pause, run.
    pub states: [u8; 3],
}

impl EstopBinding {
    /// What a reported value means (an unknown state counts as disable).
    pub fn state(&self, v: f64) -> EstopState {
        let i = v as u8;
        if i == self.states[2] {
            EstopState::Run
        } else if i == self.states[1] {
            EstopState::Pause
        } else {
            EstopState::Disable
        }
    }
}

/// Every binding of a vehicle, checked against its devices.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Bindings {
    pub steering: Option<DeviceId>,
    pub throttle: Option<DeviceId>,
    pub brake: Option<DeviceId>,
    pub gear: Option<GearBinding>,
    pub estop: Option<EstopBinding>,
    pub speed: Option<ReadingRef>,
    pub engine_running: Option<ReadingRef>,
    pub starter: Option<DeviceId>,
}

impl Bindings {
    /// The actuator bound to `role`, if that role binds an actuator.
    pub fn actuator(&self, role: Role) -> Option<DeviceId> {
        match role {
            Role::Steering => self.steering,
            Role::Throttle => self.throttle,
            Role::Brake => self.brake,
            Role::Gear => self.gear.as_ref().map(|g| g.device),
            Role::Starter => self.starter,
            Role::Estop | Role::Speed | Role::EngineRunning => None,
        }
    }

    /// The device a role reaches (an actuator, or the device of a reading).
    pub fn device(&self, role: Role) -> Option<DeviceId> {
        match role {
            Role::Estop => self.estop.map(|e| e.at.device),
            Role::Speed => self.speed.map(|r| r.device),
            Role::EngineRunning => self.engine_running.map(|r| r.device),
            other => self.actuator(other),
        }
    }

    pub(crate) fn is_bound(&self, role: Role) -> bool {
        self.device(role).is_some()
    }

    /// The roles an actuator plays (commands to it are checked by their rules).
    pub(crate) fn roles_of(&self, d: DeviceId) -> impl Iterator<Item = Role> + '_ {
        Role::ALL
            .into_iter()
            .filter(move |r| self.actuator(*r) == Some(d))
    }

    /// `accel` exists when throttle and brake are bound.
    pub(crate) fn has_accel(&self) -> bool {
        self.throttle.is_some() && self.brake.is_some()
    }
}

/// `[vehicle.roles]` as written: role = "device" or "device.reading".
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct RawRoles {
    steering: Option<Spanned<String>>,
    throttle: Option<Spanned<String>>,
    brake: Option<Spanned<String>>,
    gear: Option<Spanned<String>>,
    estop: Option<Spanned<String>>,
    speed: Option<Spanned<String>>,
    engine_running: Option<Spanned<String>>,
    starter: Option<Spanned<String>>,
}

impl RawRoles {
    /// The binding of `role`, as written.
    fn get(&self, role: Role) -> Option<&Spanned<String>> {
        match role {
            Role::Steering => self.steering.as_ref(),
            Role::Throttle => self.throttle.as_ref(),
            Role::Brake => self.brake.as_ref(),
            Role::Gear => self.gear.as_ref(),
            Role::Estop => self.estop.as_ref(),
            Role::Speed => self.speed.as_ref(),
            Role::EngineRunning => self.engine_running.as_ref(),
            Role::Starter => self.starter.as_ref(),
        }
    }
}

/// `[vehicle.gear]`: which gearbox states drive, and where to park.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawGear {
    #[serde(default)]
    forward: Vec<String>,
    #[serde(default)]
    reverse: Vec<String>,
    #[serde(default)]
    park: Option<String>,
}

/// Check every binding against the devices; `line` gives the line of a byte offset of
/// the file (a refusal about two bindings names both lines).
pub(super) fn bind(
    raw: RawRoles,
    gear: Option<Spanned<RawGear>>,
    devices: &[DeviceConfig],
    line: &dyn Fn(usize) -> usize,
) -> Result<Bindings, Mistake> {
    let to = Binder { devices };
    to.check_sharing(&raw, line)?;
    let mut b = Bindings {
        steering: to.actuator(Role::Steering, &raw.steering, Kind::Setpoint)?,
        throttle: to.actuator(Role::Throttle, &raw.throttle, Kind::Setpoint)?,
        brake: to.actuator(Role::Brake, &raw.brake, Kind::Setpoint)?,
        ..Bindings::default()
    };
    to.check_released_at_zero(&raw, &b)?;
    b.gear = to.gear(&raw, gear)?;
    b.estop = to.estop(&raw.estop)?;
    b.speed = to.reading(
        Role::Speed,
        &raw.speed,
        &["speed"],
        &|k| *k == ReadingKind::Number,
        "a number reading (m/s)",
    )?;
    b.engine_running = to.reading(
        Role::EngineRunning,
        &raw.engine_running,
        &["running"],
        &|k| matches!(k, ReadingKind::Flag | ReadingKind::Number),
        "a flag reading",
    )?;
    b.starter = to.starter(&raw.starter)?;
    Ok(b)
}

/// The devices that bindings name, and the checks of one binding each.
struct Binder<'a> {
    devices: &'a [DeviceConfig],
}

impl Binder<'_> {
    /// The device `"device"` or `"device.reading"` names, and the reading's index.
    fn find(&self, s: &Spanned<String>) -> Result<(DeviceId, Option<usize>), Mistake> {
        let devices = self.devices;
        let at = s.span().start;
        let text = s.get_ref();
        let (dev, reading) = match text.split_once('.') {
            Some((d, r)) => (d, Some(r)),
            None => (text.as_str(), None),
        };
        let Some(i) = devices.iter().position(|d| d.name == dev) else {
            return Err((
                at,
                format!(
                    "roles: no device named {dev:?} ({})",
                    super::device_list(devices)
                ),
            ));
        };
        let reading = match reading {
            None => None,
            Some(r) => Some(devices[i].reading(r).ok_or_else(|| {
                (
                    at,
                    format!(
                        "roles: {dev} has no reading {r:?} (its readings: {})",
                        devices[i]
                            .readings
                            .iter()
                            .map(|r| r.name.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                )
            })?),
        };
        Ok((DeviceId(i as u16), reading))
    }

    /// One device, two roles: only the pairs of SHARED. Checked first, in the order the
    /// file writes them, so the refusal names the second binding and quotes both.
    fn check_sharing(&self, raw: &RawRoles, line: &dyn Fn(usize) -> usize) -> Result<(), Mistake> {
        let mut written: Vec<(Role, &Spanned<String>)> = Role::ALL
            .into_iter()
            .filter_map(|r| raw.get(r).map(|s| (r, s)))
            .collect();
        written.sort_by_key(|(_, s)| s.span().start);
        let mut seen: Vec<(Role, &Spanned<String>, DeviceId)> = Vec::new();
        for (role, s) in written {
            let (id, _) = self.find(s)?;
            if let Some((first, f, _)) = seen
                .iter()
                .find(|(r, _, d)| *d == id && r.shares_with(role).is_none())
            {
                return Err((
                    s.span().start,
                    format!(
                        "roles: {role} = {:?} (line {}) and {first} = {:?} (line {}) are one device, {}: \
                         a device plays one role, except {}",
                        s.get_ref(),
                        line(s.span().start),
                        f.get_ref(),
                        line(f.span().start),
                        self.devices[id.index()].name,
                        shared_pairs()
                    ),
                ));
            }
            seen.push((role, s, id));
        }
        Ok(())
    }

    /// An actuator role: a whole device of kind `want`.
    fn actuator(
        &self,
        role: Role,
        s: &Option<Spanned<String>>,
        want: Kind,
    ) -> Result<Option<DeviceId>, Mistake> {
        let Some(s) = s else { return Ok(None) };
        let (id, reading) = self.find(s)?;
        let d = &self.devices[id.index()];
        let at = s.span().start;
        if reading.is_some() {
            return Err((
                at,
                format!(
                    "roles: {role} binds a device, not a reading (write {:?})",
                    d.name
                ),
            ));
        }
        if d.kind != want {
            return Err((
                at,
                format!(
                    "roles: {role} must be a {want} device; {} is a {}",
                    d.name, d.kind
                ),
            ));
        }
        Ok(Some(id))
    }

    /// A reading role: `"device.reading"`, or a device whose reading is one of
    /// `default`; its kind must pass `ok` (`want` says what that is).
    fn reading(
        &self,
        role: Role,
        s: &Option<Spanned<String>>,
        default: &[&str],
        ok: &dyn Fn(&ReadingKind) -> bool,
        want: &str,
    ) -> Result<Option<ReadingRef>, Mistake> {
        let Some(s) = s else { return Ok(None) };
        let (id, r) = self.find(s)?;
        let d = &self.devices[id.index()];
        let at = s.span().start;
        let r = match r {
            Some(r) => r,
            None => default.iter().find_map(|n| d.reading(n)).ok_or_else(|| {
                (
                    at,
                    format!(
                        "roles: {role} = {:?}: name the reading as \"{}.READING\"",
                        d.name, d.name
                    ),
                )
            })?,
        };
        if !ok(&d.readings[r].kind) {
            return Err((
                at,
                format!(
                    "roles: {role} must be {want}; {}.{} is not",
                    d.name, d.readings[r].name
                ),
            ));
        }
        Ok(Some(ReadingRef {
            device: id,
            reading: r,
        }))
    }

    /// The throttle and the brake are released at 0: their ranges start there.
    fn check_released_at_zero(&self, raw: &RawRoles, b: &Bindings) -> Result<(), Mistake> {
        for (role, id) in [(Role::Throttle, b.throttle), (Role::Brake, b.brake)] {
            if let (Some(id), Some(s)) = (id, raw.get(role)) {
                let [lo, _] = self.devices[id.index()].range;
                if lo != 0.0 {
                    return Err((
                        s.span().start,
                        format!(
                            "roles: {role} {}: its range must start at 0 (released), got [{lo}, …]",
                            self.devices[id.index()].name
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The gear role and its `[vehicle.gear]` table: both or neither.
    fn gear(
        &self,
        raw: &RawRoles,
        gear: Option<Spanned<RawGear>>,
    ) -> Result<Option<GearBinding>, Mistake> {
        let (Some(g), Some(s)) = (
            self.actuator(Role::Gear, &raw.gear, Kind::State)?,
            raw.get(Role::Gear),
        ) else {
            return match gear {
                Some(g) => Err((
                    g.span().start,
                    "vehicle.gear goes with a gear binding in [vehicle.roles]".into(),
                )),
                None => Ok(None),
            };
        };
        let d = &self.devices[g.index()];
        let at = s.span().start;
        let Some(spec) = gear else {
            return Err((
                at,
                format!(
                    "roles: gear needs a [vehicle.gear] table saying which of {}'s states drive, e.g. forward = [\"drive\"], reverse = [\"reverse\"], park = \"park\"",
                    d.name
                ),
            ));
        };
        let at = spec.span().start;
        let spec = spec.into_inner();
        let state = |s: &str| {
            d.states
                .iter()
                .position(|x| x == s)
                .map(|i| i as u8)
                .ok_or_else(|| {
                    (
                        at,
                        format!(
                            "vehicle.gear: {s:?} is not a state of {} ({})",
                            d.name,
                            d.states.join(", ")
                        ),
                    )
                })
        };
        let forward = spec
            .forward
            .iter()
            .map(|s| state(s))
            .collect::<Result<Vec<_>, _>>()?;
        let reverse = spec
            .reverse
            .iter()
            .map(|s| state(s))
            .collect::<Result<Vec<_>, _>>()?;
        if forward.is_empty() && reverse.is_empty() {
            return Err((
                at,
                "vehicle.gear: expected at least one state in forward or reverse".into(),
            ));
        }
        if forward.iter().any(|s| reverse.contains(s)) {
            return Err((
                at,
                "vehicle.gear: a state cannot drive both forward and reverse".into(),
            ));
        }
        let park = spec.park.as_deref().map(state).transpose()?;
        if park.is_some_and(|p| forward.contains(&p) || reverse.contains(&p)) {
            return Err((
                at,
                "vehicle.gear: park must be a state that does not drive".into(),
            ));
        }
        Ok(Some(GearBinding {
            device: g,
            forward,
            reverse,
            park,
        }))
    }

    /// The e-stop role: a state reading with disable, pause and run.
    fn estop(&self, s: &Option<Spanned<String>>) -> Result<Option<EstopBinding>, Mistake> {
        let estop_kind = |k: &ReadingKind| match k {
            ReadingKind::States(s) => EstopState::ALL
                .iter()
                .all(|e| s.iter().any(|x| x == e.as_str())),
            _ => false,
        };
        let Some(r) = self.reading(
            Role::Estop,
            s,
            &["estop", super::device::STATE],
            &estop_kind,
            "a state reading with disable, pause and run",
        )?
        else {
            return Ok(None);
        };
        let ReadingKind::States(s) = &self.devices[r.device.index()].readings[r.reading].kind
        else {
            unreachable!("checked above")
        };
        let idx = |e: EstopState| s.iter().position(|x| x == e.as_str()).expect("checked") as u8;
        Ok(Some(EstopBinding {
            at: r,
            states: [
                idx(EstopState::Disable),
                idx(EstopState::Pause),
                idx(EstopState::Run),
            ],
        }))
    }

    /// The starter role: an actuator that takes the start control.
    fn starter(&self, s: &Option<Spanned<String>>) -> Result<Option<DeviceId>, Mistake> {
        let Some(s) = s else { return Ok(None) };
        let (id, r) = self.find(s)?;
        let d = &self.devices[id.index()];
        if r.is_some() || !d.is_actuator() {
            return Err((
                s.span().start,
                format!(
                    "roles: starter must be an actuator that takes the start control; {} is not",
                    d.name
                ),
            ));
        }
        Ok(Some(id))
    }
}
