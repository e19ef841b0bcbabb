//! The control socket's messages: one JSON object per line, each way.
//!
//! A client opens with [`Op::Hello`] (a console, or one operator command); the server
//! answers [`Msg::Welcome`] with the source the client is to the intake. A console then
//! receives a [`Msg::Frame`] at the console's rate — the one [`Snapshot`] and what only
//! a console shows — and sends the operator's operations as [`Request`]s, each answered
//! by a [`Msg::Reply`] with the same `id`. Everything is the engine's own types
//! (`Snapshot`, `Command`, `Refused`, `Done`), so an attached console shows and refuses
//! exactly what the embedded one does.

use crate::controls::{SimFaults, Thread, Tune};
use crate::logging::ring::LogLine;
use crate::port::trace::{Dir, TraceEntry};
use crate::safety::{Ask, Done, Held, Refused};
use crate::snapshot::Snapshot;
use crate::value::{Command, DeviceId};
use serde::{Deserialize, Serialize};
use std::time::{Duration, Instant};

/// The protocol's version; a client and a server of different versions refuse each
/// other with a clear message.
pub const VERSION: u32 = 2;

/// What a client is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// `adrive attach`: frames, and operations as an attached console.
    Console,
    /// `adrive ctl`: one operation as an operator, then gone (going away is not a
    /// watchdog stop).
    Once,
}

/// One operation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case")]
pub enum Op {
    Hello {
        role: Role,
        version: u32,
    },
    /// The device whose traffic and histogram the frames should carry (the bench view).
    Bench {
        device: Option<u16>,
    },
    /// A device's command from text, as its vehicle file defines it.
    Parse {
        device: u16,
        text: String,
    },
    Set {
        device: u16,
        command: Command,
    },
    Accel {
        accel: f64,
    },
    /// The accel while a key is held: gas on a lease of `lease_us` from receipt,
    /// then `release` ([`crate::safety::Ask::Held`]).
    Held {
        accel: f64,
        lease_us: u64,
        release: f64,
    },
    /// The key is still held: the running lease lasts `lease_us` from receipt.
    Renew {
        lease_us: u64,
    },
    Engage,
    Disengage,
    Stop,
    Take,
    Release,
    Hold,
    Clear,
    /// Arm (with its length) or disarm the teleop deadman.
    Deadman {
        ms: Option<u64>,
    },
    Interlocks {
        on: bool,
    },
    StatusPeriod {
        device: u16,
        us: u64,
    },
    CommandTimeout {
        device: u16,
        us: u64,
    },
    Enabled {
        device: u16,
        thread: Thread,
        on: bool,
    },
    Wake {
        device: u16,
    },
    /// One line of the simulator's command language.
    Sim {
        line: String,
    },
    /// The snapshot, once.
    Status,
    /// The console's terminal answered a round trip of the liveness check just now
    /// (its operator still sees the vehicle). Not answered.
    Answered,
}

impl Op {
    /// An ask of the intake as it goes on the wire.
    pub(crate) fn of_ask(ask: Ask) -> Op {
        match ask {
            Ask::Engage => Op::Engage,
            Ask::Disengage => Op::Disengage,
            Ask::Stop => Op::Stop,
            Ask::Release => Op::Release,
            Ask::Take => Op::Take,
            Ask::Clear => Op::Clear,
            Ask::Hold => Op::Hold,
            Ask::Set(id, command) => Op::Set {
                device: id.0,
                command,
            },
            Ask::Accel(accel) => Op::Accel { accel },
            Ask::Held(h) => Op::Held {
                accel: h.accel,
                lease_us: h.lease.as_micros() as u64,
                release: h.release,
            },
            Ask::Renew(lease) => Op::Renew {
                lease_us: lease.as_micros() as u64,
            },
        }
    }

    /// The ask of the intake this operation is, if it is one.
    pub(crate) fn ask(&self) -> Option<Ask> {
        Some(match *self {
            Op::Engage => Ask::Engage,
            Op::Disengage => Ask::Disengage,
            Op::Stop => Ask::Stop,
            Op::Release => Ask::Release,
            Op::Take => Ask::Take,
            Op::Clear => Ask::Clear,
            Op::Hold => Ask::Hold,
            Op::Set { device, command } => Ask::Set(DeviceId(device), command),
            Op::Accel { accel } => Ask::Accel(accel),
            Op::Held {
                accel,
                lease_us,
                release,
            } => Ask::Held(Held {
                accel,
                lease: Duration::from_micros(lease_us),
                release,
            }),
            Op::Renew { lease_us } => Ask::Renew(Duration::from_micros(lease_us)),
            _ => return None,
        })
    }

    /// A tuning as it goes on the wire.
    pub(crate) fn of_tune(tune: Tune) -> Op {
        match tune {
            Tune::StatusPeriod(id, d) => Op::StatusPeriod {
                device: id.0,
                us: d.as_micros() as u64,
            },
            Tune::CommandTimeout(id, d) => Op::CommandTimeout {
                device: id.0,
                us: d.as_micros() as u64,
            },
            Tune::Enabled(id, thread, on) => Op::Enabled {
                device: id.0,
                thread,
                on,
            },
            Tune::Wake(id) => Op::Wake { device: id.0 },
        }
    }

    /// The tuning this operation is, if it is one.
    pub(crate) fn tune(&self) -> Option<Tune> {
        Some(match *self {
            Op::StatusPeriod { device, us } => {
                Tune::StatusPeriod(DeviceId(device), Duration::from_micros(us))
            }
            Op::CommandTimeout { device, us } => {
                Tune::CommandTimeout(DeviceId(device), Duration::from_micros(us))
            }
            Op::Enabled { device, thread, on } => Tune::Enabled(DeviceId(device), thread, on),
            Op::Wake { device } => Tune::Wake(DeviceId(device)),
            _ => return None,
        })
    }
}

/// An operation with the id its reply carries.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Request {
    pub id: u64,
    #[serde(flatten)]
    pub op: Op,
}

/// What an operation came to.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Answer {
    /// Done; nothing to say.
    Ok,
    /// What the intake did.
    Done(Done),
    Command(Command),
    /// The simulator's answer.
    Said(String),
    /// No simulator in that process.
    NoSim,
    Snapshot(Box<Snapshot>),
    /// The intake refused: nothing changed.
    Refused(Refused),
    /// Not done, and why (a value the vehicle file refuses, a malformed request).
    Error(String),
}

/// From the server.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub(crate) enum Msg {
    /// The client is this source to the intake (`console #2`, `operator (uid 1000…)`).
    Welcome {
        version: u32,
        source: String,
    },
    Frame(Box<WireScene>),
    Reply {
        id: u64,
        answer: Answer,
    },
    /// The server refuses the connection (another version, a limit), and why.
    Bye {
        why: String,
    },
}

/// A console's scene on the wire (the `frame` message): [`crate::controls::Scene`] with
/// times as ages.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct WireScene {
    pub snap: Snapshot,
    /// Log lines not sent before.
    pub logs: Vec<WireLog>,
    pub trace: Vec<WireTrace>,
    pub(crate) buckets: Vec<(f64, u64)>,
    pub can_inject: bool,
    pub sim_vehicle: Option<String>,
    pub sim_faults: Vec<Option<SimFaults>>,
    /// The vehicle file's `[teleop]`.
    #[serde(default)]
    pub teleop: crate::config::TeleopConfig,
    #[serde(default)]
    pub sim_names: Option<crate::sim::commands::Names>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct WireLog {
    pub secs: f64,
    pub level: String,
    pub text: String,
}

impl WireLog {
    pub(crate) fn of(l: &LogLine) -> WireLog {
        WireLog {
            secs: l.secs,
            level: l.level.to_string(),
            text: l.text.clone(),
        }
    }

    pub(crate) fn line(&self) -> LogLine {
        LogLine {
            secs: self.secs,
            level: self.level.parse().unwrap_or(tracing::Level::WARN),
            text: self.text.clone(),
        }
    }
}

/// A chunk of the bench device's traffic, with its age when the frame was captured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct WireTrace {
    pub(crate) age_us: u64,
    pub dir: Dir,
    pub cut: bool,
    pub bytes: Vec<u8>,
}

impl WireTrace {
    pub(crate) fn of(e: &TraceEntry, now: Instant) -> WireTrace {
        WireTrace {
            age_us: now.saturating_duration_since(e.at).as_micros() as u64,
            dir: e.dir,
            cut: e.cut,
            bytes: e.bytes().to_vec(),
        }
    }

    /// The entry again, its age counted back from `now` (the frame's arrival).
    pub(crate) fn entry(&self, now: Instant) -> TraceEntry {
        let at = now
            .checked_sub(Duration::from_micros(self.age_us))
            .unwrap_or(now);
        let mut e = TraceEntry::new(at, self.dir, &self.bytes);
        e.cut |= self.cut;
        e
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_and_replies_read_back_as_written() {
        let reqs = [
            Request {
                id: 1,
                op: Op::Hello {
                    role: Role::Console,
                    version: VERSION,
                },
            },
            Request {
                id: 2,
                op: Op::Set {
                    device: 0,
                    command: Command::Set(0.25),
                },
            },
            Request {
                id: 3,
                op: Op::Engage,
            },
            Request {
                id: 4,
                op: Op::Held {
                    accel: 0.2,
                    lease_us: 533_000,
                    release: -0.3,
                },
            },
            Request {
                id: 5,
                op: Op::Renew { lease_us: 66_000 },
            },
        ];
        for r in reqs {
            let line = serde_json::to_string(&r).unwrap();
            assert!(!line.contains('\n'));
            assert_eq!(serde_json::from_str::<Request>(&line).unwrap(), r);
        }
        let line = r#"{"id":7,"op":"stop"}"#;
        assert_eq!(
            serde_json::from_str::<Request>(line).unwrap().op,
            Op::Stop,
            "a script can write a request by hand"
        );
        let reply = Msg::Reply {
            id: 2,
            answer: Answer::Refused(Refused::Owner(crate::safety::owner::Refusal::Commander(
                crate::value::Source::Console,
            ))),
        };
        let line = serde_json::to_string(&reply).unwrap();
        assert_eq!(serde_json::from_str::<Msg>(&line).unwrap(), reply);
    }

    /// Every ask and every tuning goes on the wire and comes back the same, and no
    /// other operation reads as one.
    #[test]
    fn asks_and_tunings_cross_the_wire_unchanged() {
        let id = DeviceId(3);
        let asks = [
            Ask::Engage,
            Ask::Disengage,
            Ask::Stop,
            Ask::Release,
            Ask::Take,
            Ask::Clear,
            Ask::Hold,
            Ask::Set(id, Command::Set(0.25)),
            Ask::Set(id, Command::State(2)),
            Ask::Accel(-0.4),
            Ask::Held(Held {
                accel: 0.2,
                lease: Duration::from_micros(533_000),
                release: -0.3,
            }),
            Ask::Renew(Duration::from_micros(66_000)),
        ];
        for a in asks {
            let line = serde_json::to_string(&Op::of_ask(a)).unwrap();
            let back: Op = serde_json::from_str(&line).unwrap();
            assert_eq!(back.ask(), Some(a), "{line}");
            assert_eq!(back.tune(), None, "{line}");
        }
        let tunes = [
            Tune::StatusPeriod(id, Duration::from_millis(20)),
            Tune::CommandTimeout(id, Duration::from_micros(150_500)),
            Tune::Enabled(id, Thread::Status, false),
            Tune::Enabled(id, Thread::Command, true),
            Tune::Wake(id),
        ];
        for t in tunes {
            let line = serde_json::to_string(&Op::of_tune(t)).unwrap();
            let back: Op = serde_json::from_str(&line).unwrap();
            assert_eq!(back.tune(), Some(t), "{line}");
            assert_eq!(back.ask(), None, "{line}");
        }
        for op in [
            Op::Status,
            Op::Answered,
            Op::Bench { device: Some(1) },
            Op::Interlocks { on: false },
            Op::Deadman { ms: Some(500) },
        ] {
            assert_eq!((op.ask(), op.tune()), (None, None), "{op:?}");
        }
    }

    #[test]
    fn a_trace_entry_keeps_its_bytes_and_age() {
        let now = Instant::now();
        let e = TraceEntry::new(now - Duration::from_millis(30), Dir::Out, b"! v 0.5\n");
        let w = WireTrace::of(&e, now);
        let back = w.entry(now);
        assert_eq!(back.bytes(), e.bytes());
        assert_eq!(back.dir, Dir::Out);
        assert_eq!(now - back.at, Duration::from_millis(30));
    }
}
