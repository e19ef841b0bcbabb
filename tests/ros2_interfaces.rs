//! Every ROS 2 interface adrive speaks, against a third party: rosbags computes the
//! RIHS01 type hash and the CDR bytes of each message from the official definitions
//! (in `tests/support/ros2_peer.py`), Eclipse Zenoh's own serializer writes the
//! attachment, and xxhash the GID; adrive's must be the same, byte for byte. A wrong
//! hash would leave adrive alone on the network: rmw_zenoh puts it in every key.
#![cfg(feature = "ros2")]

#[path = "support/ros2_env.rs"]
mod ros2_env;

use adrive::ros2::keys::{self, Attachment, Entity, NodeInfo};
use adrive::ros2::msgs::{self, *};
use adrive::ros2::node::topics;
use serde_json::{json, Value};
use std::io::Write;
use std::process::{Command as Process, Stdio};

fn entry<M: Message>(m: &M) -> Value {
    json!({
        "type": M::TYPE.name,
        "value": serde_json::to_value(m).unwrap(),
        "cdr": hex(&msgs::encode(m)),
        "rust_hash": M::TYPE.hash,
    })
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

fn stamp() -> Time {
    Time {
        sec: 1_700_000_123,
        nanosec: 456_789,
    }
}

fn header(frame: &str) -> Header {
    Header {
        stamp: stamp(),
        frame_id: frame.into(),
    }
}

/// One value of every message type, with fields that test alignment: an odd-length
/// frame id before float32s, float64s after a header, a sequence of structures.
fn every_message() -> Vec<Value> {
    vec![
        entry(&SteeringReport {
            stamp: stamp(),
            steering_tire_angle: -0.25,
        }),
        entry(&VelocityReport {
            header: header("base_link"),
            longitudinal_velocity: 1.5,
            lateral_velocity: -0.125,
            heading_rate: 0.5,
        }),
        entry(&GearCommand {
            stamp: stamp(),
            command: gear::DRIVE,
        }),
        entry(&GearReport {
            stamp: stamp(),
            report: gear::REVERSE,
        }),
        entry(&ControlModeReport {
            stamp: stamp(),
            mode: mode::AUTONOMOUS,
        }),
        entry(&TurnIndicatorsCommand {
            stamp: stamp(),
            command: lights::ENABLE_LEFT,
        }),
        entry(&TurnIndicatorsReport {
            stamp: stamp(),
            report: lights::ENABLE_RIGHT,
        }),
        entry(&HazardLightsCommand {
            stamp: stamp(),
            command: lights::ENABLE_LEFT,
        }),
        entry(&HazardLightsReport {
            stamp: stamp(),
            report: lights::DISABLE,
        }),
        entry(&ActuationCommand {
            accel_cmd: 0.3,
            brake_cmd: 0.0,
            steer_cmd: -0.75,
        }),
        entry(&ActuationCommandStamped {
            header: header("abc"),
            actuation: ActuationCommand {
                accel_cmd: 0.1,
                brake_cmd: 0.2,
                steer_cmd: 0.3,
            },
        }),
        entry(&ActuationStatus {
            accel_status: 0.5,
            brake_status: 0.25,
            steer_status: -1.0,
        }),
        entry(&ActuationStatusStamped {
            header: header("base_link"),
            status: ActuationStatus {
                accel_status: 0.5,
                brake_status: 0.0,
                steer_status: 0.125,
            },
        }),
        entry(&VehicleEmergencyStamped {
            stamp: stamp(),
            emergency: true,
        }),
        entry(&DiagnosticArray {
            header: header(""),
            status: vec![
                DiagnosticStatus {
                    level: level::ERROR,
                    name: "adrive: gas".into(),
                    message: "no reply within 200ms".into(),
                    hardware_id: "gas".into(),
                    values: vec![KeyValue {
                        key: "position".into(),
                        value: "0.250".into(),
                    }],
                },
                DiagnosticStatus {
                    level: level::OK,
                    name: "adrive: steer".into(),
                    message: "ok".into(),
                    hardware_id: "s".into(),
                    values: vec![],
                },
            ],
        }),
    ]
}

/// The peer's answer for `request`.
fn ask(request: &Value) -> Value {
    let mut child = Process::new(ros2_env::python())
        .args([ros2_env::PEER, "interfaces"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start the ROS 2 peer");
    child
        .stdin
        .take()
        .unwrap()
        .write_all(request.to_string().as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "the peer failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("the peer's JSON")
}

#[test]
fn hashes_cdr_bytes_attachment_gid_and_keys_match_rosbags_and_zenoh() {
    let messages = every_message();
    let node = NodeInfo {
        domain: 0,
        zid: "8b20917502ee955ac4476e0266340d5c".into(),
        node_id: 0,
        namespace: "/alice".into(),
        name: "adrive".into(),
        enclave: "/".into(),
    };
    let token = keys::token(
        &node,
        3,
        Entity::Publisher,
        Some((
            "/alice/vehicle/status/steering_status",
            &SteeringReport::TYPE,
            keys::DEFAULT_QOS,
        )),
    );
    let attachment = Attachment {
        sequence_number: 42,
        source_timestamp: 1_700_000_000_123_456_789,
        gid: keys::gid(&token),
    };
    let topics: Vec<(&str, keys::TypeInfo)> = vec![
        (topics::STEERING_STATUS, SteeringReport::TYPE),
        (topics::VELOCITY_STATUS, VelocityReport::TYPE),
        (topics::GEAR_STATUS, GearReport::TYPE),
        (topics::CONTROL_MODE, ControlModeReport::TYPE),
        (topics::ACTUATION_STATUS, ActuationStatusStamped::TYPE),
        (topics::TURN_INDICATORS_STATUS, TurnIndicatorsReport::TYPE),
        (topics::HAZARD_LIGHTS_STATUS, HazardLightsReport::TYPE),
        (topics::ACTUATION_CMD, ActuationCommandStamped::TYPE),
        (topics::GEAR_CMD, GearCommand::TYPE),
        (topics::TURN_INDICATORS_CMD, TurnIndicatorsCommand::TYPE),
        (topics::HAZARD_LIGHTS_CMD, HazardLightsCommand::TYPE),
        (topics::EMERGENCY_CMD, VehicleEmergencyStamped::TYPE),
        (topics::DIAGNOSTICS, DiagnosticArray::TYPE),
    ];
    let request_msg = ControlModeRequest {
        stamp: stamp(),
        mode: mode::AUTONOMOUS,
    };
    let response_msg = ControlModeResponse { success: true };
    let request = json!({
        "messages": messages,
        "service_values": {
            "ControlModeCommand_Request": serde_json::to_value(request_msg).unwrap(),
            "ControlModeCommand_Response": serde_json::to_value(response_msg).unwrap(),
        },
        "attachment": {
            "seq": attachment.sequence_number,
            "stamp": attachment.source_timestamp,
            "gid": hex(&attachment.gid),
        },
        "token": token,
        "keys": topics.iter().map(|(t, ty)| json!({
            "topic": keys::qualified("/alice", t),
            "type": ty.name,
            "domain": 7,
        })).collect::<Vec<_>>(),
    });
    let answer = ask(&request);

    for m in &messages {
        let name = m["type"].as_str().unwrap();
        let theirs = &answer["messages"][name];
        assert_eq!(m["rust_hash"], theirs["hash"], "RIHS01 hash of {name}");
        assert_eq!(m["cdr"], theirs["cdr"], "CDR bytes of {name}");
        assert_eq!(
            m["value"], theirs["decoded"],
            "rosbags reads adrive's {name} back"
        );
    }
    assert_eq!(
        answer["services"]["autoware_vehicle_msgs/srv/ControlModeCommand"],
        CONTROL_MODE_COMMAND.hash
    );
    // The control: rmw_zenoh's design document gives this service's hash, so the way
    // the peer hashes a service is right.
    assert_eq!(
        answer["services"]["example_interfaces/srv/AddTwoInts"],
        "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
    );
    assert_eq!(
        answer["messages"]["autoware_vehicle_msgs/srv/ControlModeCommand_Request"]["cdr"],
        hex(&msgs::encode(&request_msg))
    );
    assert_eq!(
        answer["messages"]["autoware_vehicle_msgs/srv/ControlModeCommand_Response"]["cdr"],
        hex(&msgs::encode(&response_msg))
    );
    assert_eq!(
        answer["attachment"],
        hex(&attachment.encode()),
        "the attachment as zenoh.ext.z_serialize writes it"
    );
    assert_eq!(answer["gid"], hex(&keys::gid(&token)), "the GID (XXH3-128)");
    for (t, ty) in &topics {
        let fqn = keys::qualified("/alice", t);
        assert_eq!(
            answer["keys"][&fqn],
            keys::topic_key(7, &fqn, ty),
            "the key expression of {fqn}"
        );
    }
}
