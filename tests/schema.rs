//! `schemas/snapshot-4.json` against real broadcasts: the datagrams the real binary
//! sends, engaged and driven by a planner, for the built-in Alice and for the utility
//! cart, each valid under the schema (checked by the `jsonschema` crate).

mod common;

use common::headless::Adrive;
use common::DEADLINE;
use std::net::UdpSocket;
use std::time::Duration;

const SCHEMA: &str = include_str!("../schemas/snapshot-4.json");

/// Drive `vehicle` with `commands` from a planner and check `n` broadcasts.
fn broadcasts_are_valid(tag: &str, vehicle: &str, commands: &str, n: usize) {
    let schema: serde_json::Value = serde_json::from_str(SCHEMA).expect("the schema is JSON");
    let validator = jsonschema::validator_for(&schema).expect("a valid JSON Schema");
    let a = Adrive::start(tag, vehicle, "watchdog_timeout = \"2s\"");
    let rx = UdpSocket::bind(&a.broadcast).unwrap();
    rx.set_read_timeout(Some(DEADLINE)).unwrap();
    let planner = a.planner();
    let mut buf = vec![0u8; 65536];
    let mut engaged = 0;
    for i in 0..n {
        planner
            .send(format!("seq {}\nengage\n{commands}", i + 1).as_bytes())
            .unwrap();
        let len = rx.recv(&mut buf).expect("a broadcast");
        let v: serde_json::Value = serde_json::from_slice(&buf[..len]).expect("JSON");
        let errors: Vec<String> = validator
            .iter_errors(&v)
            .map(|e| format!("{} at {}", e, e.instance_path()))
            .collect();
        assert!(
            errors.is_empty(),
            "broadcast {i} of {tag}:\n{}",
            errors.join("\n")
        );
        assert_eq!(v["schema"], 4);
        engaged += usize::from(v["gate"]["engaged"] == true);
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(engaged > 0, "{tag} was engaged in some broadcast");
}

#[test]
fn alice_s_broadcasts_follow_the_schema() {
    broadcasts_are_valid(
        "schema-alice",
        adrive::config::ALICE_TOML,
        "trans drive\nsteer 0.2\naccel -0.3\n",
        40,
    );
}

#[test]
fn the_cart_s_broadcasts_follow_the_schema() {
    broadcasts_are_valid(
        "schema-cart",
        include_str!("../vehicles/cart.toml"),
        "direction forward\nsignals left\naccel 0.2\n",
        40,
    );
}
