use super::*;
use crate::value::{Command, DeviceId, Kind};

const GOOD: &str = r#"
[vehicle]
name = "bench"

[[device]]
name = "steer"
kind = "setpoint"
range = [-1.0, 1.0]
driver = "line"
port = "/dev/ttyUSB0"
status_period = "50ms"
"#;

fn error(text: &str) -> String {
    parse(text, "v.toml").unwrap_err().to_string()
}

/// The line number an error names.
fn line(e: &str) -> usize {
    e.strip_prefix("v.toml:")
        .and_then(|r| r.split(':').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no file:line in {e:?}"))
}

#[test]
fn the_built_in_alice_parses_with_her_six_devices_and_every_role() {
    let a = VehicleConfig::alice();
    let names: Vec<_> = a.devices.iter().map(|d| d.name.as_str()).collect();
    assert_eq!(names, ["steer", "gas", "brake", "trans", "estop", "obd"]);
    let kinds: Vec<_> = a.devices.iter().map(|d| d.kind).collect();
    use Kind::*;
    assert_eq!(kinds, [Setpoint, Setpoint, Setpoint, State, Sensor, Sensor]);
    for role in Role::ALL {
        assert!(a.roles.is_bound(role), "{role}");
    }
    let g = a.roles.gear.as_ref().unwrap();
    assert_eq!(
        (g.forward.clone(), g.reverse.clone(), g.park),
        (vec![3], vec![1], Some(0))
    );
    let trans = a.device("trans").unwrap();
    assert_eq!(trans.parse_command("d"), Ok(Command::State(3)));
    assert_eq!(trans.parse_command("-1"), Ok(Command::State(1)));
    assert!(trans
        .parse_command("sport")
        .unwrap_err()
        .contains("park, reverse"));
}

#[test]
fn defaults_fill_what_is_not_said() {
    let v = parse(GOOD, "bench.toml").unwrap();
    let d = &v.devices[0];
    assert_eq!(d.status_period, Duration::from_millis(50));
    assert_eq!(d.baud, 9600);
    assert_eq!(d.port_rule, PortRule::Priority);
    assert_eq!(d.min_command_interval, None);
    assert_eq!(d.range(), [-1.0, 1.0]);
    assert_eq!(
        d.readings[0].name, "position",
        "a setpoint device reports its position"
    );
    assert_eq!(v.roles, Bindings::default(), "nothing bound unless said");
}

#[test]
fn an_unknown_driver_names_file_line_and_the_choices() {
    let e = error(&GOOD.replace("driver = \"line\"", "driver = \"modbsu\""));
    assert_eq!(line(&e), 9, "{e}");
    assert!(e.contains("modbsu") && e.contains("line"), "{e}");
}

#[test]
fn a_bad_duration_names_its_line_and_form() {
    let e = error(&GOOD.replace("\"50ms\"", "\"fast\""));
    assert_eq!(line(&e), 11, "{e}");
    assert!(e.contains("250ms"), "{e}");
}

#[test]
fn a_bad_name_or_an_unknown_field_is_refused() {
    for bad in ["Steer", "2nd", "turn-signal", "accel", "engage"] {
        let e = error(&GOOD.replace("\"steer\"", &format!("\"{bad}\"")));
        assert_eq!(line(&e), 6, "{e}");
        assert!(e.contains(bad), "{e}");
    }
    let e = error(&GOOD.replace("port =", "prot ="));
    assert_eq!(line(&e), 10, "{e}");
    assert!(e.contains("prot"), "{e}");
}

#[test]
fn a_duplicate_name_points_at_the_second() {
    let twice = format!(
        "{GOOD}\n[[device]]\nname = \"steer\"\nkind = \"sensor\"\nreadings = [\"rpm\"]\ndriver = \"line\"\n"
    );
    let e = error(&twice);
    assert_eq!(line(&e), 14, "{e}");
    assert!(e.contains("defined twice"), "{e}");
}

#[test]
fn cross_field_errors_point_at_the_device() {
    let e = error(&GOOD.replace("[-1.0, 1.0]", "[1.0, -1.0]"));
    assert!(e.contains("min < max"), "{e}");
    assert_eq!(line(&e), 8, "{e}");
    let e = error(&GOOD.replace("[-1.0, 1.0]", "[-1.0, 0.0, 1.0]"));
    assert!(
        e.contains("two finite numbers"),
        "a three-value range is refused: {e}"
    );
    let e = error(&format!("{GOOD}status_max_age = \"10ms\"\n"));
    assert!(e.contains("status_max_age"), "{e}");
}

fn cart(extra_roles: &str, extra: &str) -> String {
    format!(
        r#"
[vehicle]
name = "cart"
[vehicle.roles]
throttle = "throttle"
{extra_roles}

[[device]]
name = "throttle"
kind = "setpoint"
range = [0.0, 1.0]
driver = "line"

[[device]]
name = "direction"
kind = "state"
states = ["forward", "neutral", "reverse"]
driver = "line"

[[device]]
name = "wheels"
kind = "sensor"
readings = ["speed"]
driver = "line"
{extra}
"#
    )
}

#[test]
fn bindings_resolve_devices_and_readings() {
    let v = parse(
        &cart(
            "gear = \"direction\"\nspeed = \"wheels.speed\"\n[vehicle.gear]\nforward = [\"forward\"]\nreverse = [\"reverse\"]",
            "",
        ),
        "c.toml",
    )
    .unwrap();
    let r = &v.roles;
    assert_eq!(r.throttle, Some(DeviceId(0)));
    assert_eq!(r.gear.as_ref().map(|g| g.device), Some(DeviceId(1)));
    assert_eq!(
        r.speed.map(|s| (s.device, s.reading)),
        Some((DeviceId(2), 0))
    );
    assert_eq!(r.brake, None);
}

#[test]
fn a_binding_to_a_missing_device_or_the_wrong_kind_names_its_line() {
    let e = parse(&cart("brake = \"brakes\"", ""), "v.toml")
        .unwrap_err()
        .to_string();
    assert_eq!(line(&e), 6, "{e}");
    assert!(
        e.contains("no device named \"brakes\"") && e.contains("throttle, direction, wheels"),
        "{e}"
    );
    let e = parse(&cart("brake = \"direction\"", ""), "v.toml")
        .unwrap_err()
        .to_string();
    assert_eq!(line(&e), 6, "{e}");
    assert!(
        e.contains("brake must be a setpoint device; direction is a state"),
        "{e}"
    );
    let e = parse(&cart("speed = \"wheels.rpm\"", ""), "v.toml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("wheels has no reading \"rpm\""), "{e}");
    let e = parse(&cart("gear = \"direction\"", ""), "v.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("[vehicle.gear]"),
        "a gear binding says which states drive: {e}"
    );
}

#[test]
fn an_unknown_state_name_is_refused_wherever_it_is_used() {
    let e = parse(
        &cart(
            "gear = \"direction\"\n[vehicle.gear]\nforward = [\"drive\"]",
            "",
        ),
        "v.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("\"drive\" is not a state of direction (forward, neutral, reverse)"),
        "{e}"
    );
    let e = parse(&cart("", "aliases = { f = \"fwd\" }"), "v.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("is a sensor") || e.contains("aliases are for state devices"),
        "{e}"
    );
    let safe_bad = cart("", "").replace(
        "states = [\"forward\", \"neutral\", \"reverse\"]",
        "states = [\"forward\", \"neutral\", \"reverse\"]\nsafe = \"park\"",
    );
    let e = parse(&safe_bad, "v.toml").unwrap_err().to_string();
    assert_eq!(line(&e), 18, "{e}");
    assert!(
        e.contains("safe") && e.contains("forward, neutral, reverse"),
        "{e}"
    );
}

#[test]
fn a_state_without_a_wire_mapping_is_refused() {
    let text = r#"
[vehicle]
name = "t"
[[device]]
name = "signal"
kind = "state"
states = ["off", "left", "right", "hazard"]
driver = "modbus"
[device.modbus]
slave = 9
registers = { target = 0, state = 0 }
codes = { off = 0, left = 1, right = 2 }
"#;
    let e = parse(text, "v.toml").unwrap_err().to_string();
    assert_eq!(line(&e), 12, "{e}");
    assert!(e.contains("state hazard has no code"), "{e}");
    let e = parse(
        &text.replace("codes = { off = 0, left = 1, right = 2 }\n", ""),
        "v.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("modbus.codes: expected the code of each state"),
        "{e}"
    );
    assert!(
        e.contains("off = 0, left = 1, right = 2, hazard = 3"),
        "the expected form: {e}"
    );
}

#[test]
fn a_sensor_names_what_it_reports_and_custom_readings_their_units() {
    let text = r#"
[vehicle]
name = "t"
[[device]]
name = "battery"
kind = "sensor"
readings = ["voltage", "current", "soc", { name = "cells", units = "" }, { name = "mode", states = ["idle", "charging"] }]
driver = "line"
"#;
    let v = parse(text, "t.toml").unwrap();
    let b = &v.devices[0];
    assert_eq!(b.readings[0].units, "V");
    assert_eq!(b.readings[2].units, "%");
    assert_eq!(
        b.readings[4].kind,
        ReadingKind::States(vec!["idle".into(), "charging".into()])
    );
    let e = error(&text.replace("{ name = \"cells\", units = \"\" }", "\"cells\""));
    assert!(
        e.contains("reading cells is not a well-known one: give its units"),
        "{e}"
    );
    let e = error(&text.replace("readings = [", "readingz = ["));
    assert!(e.contains("readingz"), "{e}");
}

#[test]
fn a_modbus_device_needs_its_table_and_a_sensible_map() {
    let modbus = GOOD.replace("driver = \"line\"", "driver = \"modbus\"");
    let e = error(&modbus);
    assert_eq!(line(&e), 9, "{e}");
    assert!(e.contains("[device.modbus]"), "{e}");
    let ok = format!(
        "{modbus}\n[device.modbus]\nslave = 7\nregisters = {{ target = 0, position = 0 }}\n"
    );
    match &parse(&ok, "v.toml").unwrap().devices[0].wire {
        wire::Wire::Modbus(m) => assert_eq!(m.slave, 7),
        other => panic!("{other:?}"),
    }
    let typo = ok.replace("position = 0", "postion = 0");
    let e = error(&typo);
    assert!(
        e.contains("postion") && e.contains("its readings (position)"),
        "{e}"
    );
    for slave in ["0", "248", "-1"] {
        let e = error(&ok.replace("slave = 7", &format!("slave = {slave}")));
        assert!(e.contains("1 to 247"), "slave {slave}: {e}");
    }
}

#[test]
fn only_keeps_the_named_devices_and_their_bindings() {
    let mut a = VehicleConfig::alice();
    a.retain_only(&["brake".into(), "estop".into()]).unwrap();
    let names: Vec<_> = a.devices.iter().map(|d| d.name.as_str()).collect();
    assert_eq!(names, ["brake", "estop"]);
    assert_eq!(a.roles.brake, Some(DeviceId(0)));
    assert_eq!(a.roles.estop.map(|e| e.at.device), Some(DeviceId(1)));
    assert_eq!(a.roles.throttle, None);
    assert!(a.roles.gear.is_none());
    let e = VehicleConfig::alice()
        .retain_only(&["wiper".into()])
        .unwrap_err();
    assert!(
        e.contains("no such device") && e.contains("steer, gas"),
        "{e}"
    );
}

#[test]
fn broken_toml_names_the_line() {
    let e = error("[vehicle]\nname = \"x\"\n[[device]\n");
    assert_eq!(line(&e), 3, "{e}");
}

#[test]
fn a_bad_ros2_table_names_file_line_key_and_expected_form() {
    let with = |table: &str| error(&format!("{GOOD}\n[ros2]\n{table}\n"));
    // GOOD ends on line 11; `[ros2]` is line 13, its first key line 14.
    let e = with("mode = \"peer\"\ndomain_id = 300");
    assert_eq!(line(&e), 15, "{e}");
    assert!(
        e.contains("[ros2] domain_id: expected 0 … 232, got 300"),
        "{e}"
    );
    let e = with("namespace = \"alice\"");
    assert_eq!(line(&e), 14, "{e}");
    assert!(e.contains("expected a ROS namespace"), "{e}");
    let e = with("connect = [\"10.0.0.2:7447\"]");
    assert!(e.contains("expected a Zenoh endpoint such as"), "{e}");
    let e = with("hazard_lights = \"steer\"");
    assert!(
        e.contains("steer must be a state device with the states off, on"),
        "{e}"
    );
    let e = with("report_rate = 1000.0");
    assert_eq!(line(&e), 14, "{e}");
    assert!(
        e.contains("[ros2] report_rate: expected a number from 1 to 100, got 1000"),
        "{e}"
    );
    let e = with("mode = \"router\"");
    assert_eq!(line(&e), 14, "{e}");
    assert!(e.contains("router"), "{e}");
}

#[test]
fn ros2_defaults_are_rmw_zenohs_and_the_namespace_is_the_vehicles() {
    let v = parse(GOOD, "v.toml").unwrap();
    assert_eq!(v.ros2, Ros2Config::default());
    assert_eq!(v.ros2.namespace_for(&v.vehicle.name), "/bench");
    assert_eq!(v.ros2.connect, ["tcp/localhost:7447"]);
    assert!(!v.ros2.multicast_scouting);
}
