//! `adrive watch --ros2`: every vehicle on a Zenoh network, and one of them followed.
//! A vehicle is a namespace whose node publishes Autoware's velocity report (adrive, or
//! any other Autoware vehicle interface on rmw_zenoh); the graph's liveliness tokens
//! say which, as they come and go. The followed vehicle's steering, velocity, gear and
//! control mode reports are printed twice a second.

use super::keys::{self, Entity};
use super::msgs::{self, gear, mode, Message};
use super::node::topics;
use crate::config::ros2::{Mode, Ros2Config};
use std::collections::BTreeSet;
use std::io::Write as _;
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::time::{Duration, Instant};
use zenoh::sample::SampleKind;
use zenoh::Wait;

/// What `adrive watch --ros2` was asked.
#[derive(Clone, Debug)]
pub(crate) struct WatchOptions {
    pub domain: u32,
    /// Routers or peers to connect to.
    pub connect: Vec<String>,
    /// The vehicle to follow (else the first one seen).
    pub namespace: Option<String>,
    /// Stop after this many report lines.
    pub count: Option<u64>,
}

/// How often the followed vehicle's line is printed.
const EVERY: Duration = Duration::from_millis(500);

enum Event {
    Token(String, bool),
    Report(&'static str, Vec<u8>),
}

/// The followed vehicle's latest reports.
#[derive(Default)]
struct Latest {
    steering: Option<msgs::SteeringReport>,
    velocity: Option<msgs::VelocityReport>,
    gear: Option<msgs::GearReport>,
    mode: Option<msgs::ControlModeReport>,
}

impl Latest {
    fn line(&self, ns: &str) -> String {
        let mode = match self.mode.map(|m| m.mode) {
            None => "-".to_string(),
            Some(mode::AUTONOMOUS) => "AUTONOMOUS".into(),
            Some(mode::MANUAL) => "MANUAL".into(),
            Some(mode::NOT_READY) => "NOT_READY".into(),
            Some(m) => format!("mode {m}"),
        };
        let gear = match self.gear.map(|g| g.report) {
            None => "-".to_string(),
            Some(gear::PARK) => "park".into(),
            Some(gear::NEUTRAL) => "neutral".into(),
            Some(gear::REVERSE | gear::REVERSE_2) => "reverse".into(),
            Some(gear::DRIVE..=gear::DRIVE_18) => "drive".into(),
            Some(g) => format!("{g}"),
        };
        let speed = self
            .velocity
            .as_ref()
            .map_or("-".into(), |v| format!("{:.2}", v.longitudinal_velocity));
        let steer = self
            .steering
            .map_or("-".into(), |s| format!("{:.3}", s.steering_tire_angle));
        format!("{ns}  {mode:<10} gear {gear:<8} speed {speed} m/s  steer {steer} rad")
    }
}

/// The namespace of a vehicle whose velocity report `topic` is (`/alice/vehicle/…`).
fn vehicle_of(topic: &str) -> Option<String> {
    let ns = topic.strip_suffix(&format!("/{}", topics::VELOCITY_STATUS))?;
    Some(if ns.is_empty() { "/".into() } else { ns.into() })
}

pub(crate) fn watch(opts: &WatchOptions, stop: &AtomicBool) -> anyhow::Result<i32> {
    let c = Ros2Config {
        domain_id: opts.domain,
        mode: Mode::Peer,
        connect: opts.connect.clone(),
        listen: Vec::new(),
        ..Ros2Config::default()
    };
    let session = zenoh::open(super::node::zenoh_config(&c)?)
        .wait()
        .map_err(|e| anyhow::anyhow!("cannot open the Zenoh session: {e}"))?;
    let (tx, rx) = crossbeam_channel::unbounded();
    let t = tx.clone();
    let _tokens = session
        .liveliness()
        .declare_subscriber(format!("{}/{}/**", keys::ADMIN_SPACE, opts.domain))
        .history(true)
        .callback(move |s| {
            let alive = s.kind() == SampleKind::Put;
            let _ = t.send(Event::Token(s.key_expr().as_str().to_string(), alive));
        })
        .wait()
        .map_err(|e| anyhow::anyhow!("liveliness subscription: {e}"))?;
    // A standard output closed by its reader (`| head`) ends the watch quietly.
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "watching ROS 2 domain {} through {} for vehicles (Ctrl-C stops)",
        opts.domain,
        opts.connect.join(", ")
    )?;
    let mut seen = BTreeSet::new();
    let mut followed: Option<String> = None;
    let mut subs = Vec::new();
    let mut latest = Latest::default();
    let mut lines = 0u64;
    let mut next = Instant::now() + EVERY;
    while !stop.load(Relaxed) {
        match rx.recv_timeout(next.saturating_duration_since(Instant::now())) {
            Ok(Event::Token(key, alive)) => {
                let Some(t) = keys::parse_token(&key) else {
                    continue;
                };
                let Some(ns) = t
                    .topic
                    .as_ref()
                    .filter(|_| t.entity == Entity::Publisher)
                    .and_then(|(topic, _, _)| vehicle_of(topic))
                else {
                    continue;
                };
                if alive && seen.insert(ns.clone()) {
                    writeln!(
                        out,
                        "vehicle {ns}  (node {}, zid {})",
                        t.node.fqn(),
                        t.node.zid
                    )?;
                    let wanted = opts.namespace.as_deref().is_none_or(|w| w == ns);
                    if followed.is_none() && wanted {
                        writeln!(out, "following {ns}")?;
                        subs = follow(&session, opts.domain, &ns, &tx)?;
                        followed = Some(ns);
                    }
                } else if !alive && seen.remove(&ns) {
                    // The token is withdrawn when the node stops and when the network
                    // to it breaks: this end cannot tell which.
                    writeln!(
                        out,
                        "gone {ns}: its node left the graph (it stopped, or the network to it broke)"
                    )?;
                }
            }
            Ok(Event::Report(topic, bytes)) => match topic {
                topics::STEERING_STATUS => latest.steering = msgs::decode(&bytes).ok(),
                topics::VELOCITY_STATUS => latest.velocity = msgs::decode(&bytes).ok(),
                topics::GEAR_STATUS => latest.gear = msgs::decode(&bytes).ok(),
                _ => latest.mode = msgs::decode(&bytes).ok(),
            },
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => {
                next += EVERY;
                // While it is gone, its last reports are not printed as if current.
                if let Some(ns) = followed.as_ref().filter(|ns| seen.contains(*ns)) {
                    writeln!(out, "{}", latest.line(ns))?;
                    lines += 1;
                    if opts.count.is_some_and(|n| lines >= n) {
                        break;
                    }
                }
            }
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
        }
    }
    drop(subs);
    let _ = session.close().wait();
    Ok(0)
}

/// Subscribe to one vehicle's reports.
fn follow(
    session: &zenoh::Session,
    domain: u32,
    ns: &str,
    tx: &crossbeam_channel::Sender<Event>,
) -> anyhow::Result<Vec<zenoh::pubsub::Subscriber<()>>> {
    let wanted: [(&'static str, keys::TypeInfo); 4] = [
        (topics::STEERING_STATUS, msgs::SteeringReport::TYPE),
        (topics::VELOCITY_STATUS, msgs::VelocityReport::TYPE),
        (topics::GEAR_STATUS, msgs::GearReport::TYPE),
        (topics::CONTROL_MODE, msgs::ControlModeReport::TYPE),
    ];
    let mut subs = Vec::new();
    for (topic, ty) in wanted {
        let key = keys::topic_key(domain, &keys::qualified(ns, topic), &ty);
        let tx = tx.clone();
        let sub = session
            .declare_subscriber(key.clone())
            .callback(move |s| {
                let _ = tx.send(Event::Report(topic, s.payload().to_bytes().into_owned()));
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("subscription {key}: {e}"))?;
        subs.push(sub);
    }
    Ok(subs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_vehicle_is_the_namespace_of_a_velocity_report() {
        assert_eq!(
            vehicle_of("/alice/vehicle/status/velocity_status"),
            Some("/alice".into())
        );
        assert_eq!(
            vehicle_of("/vehicle/status/velocity_status"),
            Some("/".into())
        );
        assert_eq!(vehicle_of("/alice/vehicle/status/steering_status"), None);
    }
}
