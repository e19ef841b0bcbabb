use super::*;
use crate::value::{Command, DeviceId, Kind};
use std::path::Path;
use std::time::Duration;

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
    assert_eq!(
        v.teleop,
        crate::config::TeleopConfig {
            gas: 0.2,
            brake: 0.6,
            hold: 0.3,
            steer_rate: 0.5
        },
        "teleop holds the vehicle still when no pedal key is held"
    );
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

/// The incident: a vehicle named with a newline or an escape sequence, or with
/// nothing, was accepted, and the headless log's lines split or the escape reached the
/// terminal. Every free-text name in a vehicle file is refused as a device name is: at
/// its line, the text quoted with its control characters escaped.
#[test]
fn a_free_text_name_with_a_control_character_or_blank_is_refused_at_its_line() {
    for bad in ["two\\nlines", "red\\u001b[31m", "", "   ", &"x".repeat(65)] {
        let e = error(&GOOD.replace("name = \"bench\"", &format!("name = \"{bad}\"")));
        assert_eq!(line(&e), 3, "{e}");
        assert!(
            e.contains("vehicle name")
                && e.contains(
                    "expected printable text on one line, not blank, at most 64 characters"
                ),
            "{e}"
        );
        assert!(!e.contains('\x1b') && !e.contains('\n'), "{e:?}");
    }
    let e = error(&GOOD.replace("name = \"bench\"", "name = \"a\\u001b[2J\""));
    assert!(e.contains("('\\u{1b}' is a control character)"), "{e}");
    // Units, of a setpoint device and of a reading: at the units' own line (they were
    // said at the device's name).
    let e = error(&GOOD.replace(
        "range = [-1.0, 1.0]",
        "range = [-1.0, 1.0]\nunits = \"deg\\r\"",
    ));
    assert_eq!(line(&e), 9, "{e}");
    assert!(e.contains("steer: units \"deg\\r\""), "{e}");
    let on_a_sensor = format!(
        "{GOOD}\n[[device]]\nname = \"bms\"\nkind = \"sensor\"\nreadings = [{{ name = \"volts\", units = \"V\" }}]\nunits = \"V\"\ndriver = \"line\"\n"
    );
    let e = error(&on_a_sensor);
    assert_eq!(line(&e), 17, "{e}");
    assert!(e.contains("bms: units are for setpoint devices"), "{e}");
    let sensor = format!(
        "{GOOD}\n[[device]]\nname = \"bms\"\nkind = \"sensor\"\nreadings = [{{ name = \"volts\", units = \"V\\u0007\" }}]\ndriver = \"line\"\n"
    );
    let e = error(&sensor);
    assert!(e.contains("bms: reading volts: units \"V\\u{7}\""), "{e}");
    // An alias is one word a command can carry.
    let state = format!(
        "{GOOD}\n[[device]]\nname = \"trans\"\nkind = \"state\"\nstates = [\"park\", \"drive\"]\naliases = {{ \"d rive\" = \"drive\" }}\ndriver = \"line\"\n"
    );
    let e = error(&state);
    assert!(
        e.contains("trans: aliases: \"d rive\": expected one word"),
        "{e}"
    );
    // What a vehicle file may write is still allowed.
    let ok = parse(
        &GOOD.replace("\"bench\"", "\"OSCC Kia Soul (°C, 2 m/s²)\""),
        "v.toml",
    )
    .unwrap();
    assert_eq!(ok.vehicle.name, "OSCC Kia Soul (°C, 2 m/s²)");
}

/// A list of names in a message is never empty: a file without devices says so.
#[test]
fn a_file_without_devices_says_so_where_a_message_lists_them() {
    let mut bare = parse("[vehicle]\nname = \"x\"\n", "v.toml").unwrap();
    assert_eq!(
        bare.retain_only(&["steer".to_string()]).unwrap_err(),
        "--only steer: no such device (the file has no [[device]])"
    );
    let e = error("[vehicle]\nname = \"x\"\n[vehicle.roles]\nsteering = \"steer\"\n");
    assert!(
        e.ends_with("roles: no device named \"steer\" (the file has no [[device]])"),
        "{e}"
    );
    let mut good = parse(GOOD, "v.toml").unwrap();
    assert_eq!(
        good.retain_only(&["gas".to_string()]).unwrap_err(),
        "--only gas: no such device (devices: steer)"
    );
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
        protocol_map::Wire::Modbus(m) => assert_eq!(m.slave, 7),
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
fn a_bad_fleet_table_names_file_line_key_and_expected_form() {
    let with = |table: &str| error(&format!("{GOOD}\n[fleet]\n{table}\n"));
    // GOOD ends on line 11; `[fleet]` is line 13, its first key line 14.
    let e = with("mode = \"client\"\nid = \"car/1\"");
    assert_eq!(line(&e), 15, "{e}");
    assert!(
        e.starts_with("v.toml:15: [fleet] id: expected a fleet id such as \"car1\""),
        "{e}"
    );
    let e = with("connect = [\"10.0.0.1:7447\"]");
    assert_eq!(line(&e), 14, "{e}");
    assert!(
        e.contains("[fleet] connect: expected a Zenoh endpoint such as"),
        "{e}"
    );
    let e = with("connect = []");
    assert!(
        e.contains("client mode needs a router to connect to"),
        "{e}"
    );
    let e = with("key = \"k\"");
    assert_eq!(line(&e), 14, "{e}");
    assert!(e.contains("unknown field `key`"), "{e}");
    let e = error(&format!("{GOOD}\n[flete]\nid = \"a\"\n"));
    assert!(e.contains("did you mean [fleet]?"), "{e}");
}

#[test]
fn a_fleet_section_joins_and_its_defaults_reach_a_router_on_this_host() {
    let v = parse(GOOD, "v.toml").unwrap();
    assert_eq!(v.fleet, None, "no [fleet]: the vehicle joins no fleet");
    let v = parse(&format!("{GOOD}\n[fleet]\n"), "v.toml").unwrap();
    let f = v.fleet.expect("[fleet] joins");
    assert_eq!(f.id_for(&v.vehicle.name), "bench");
    assert_eq!(f.connect, ["tcp/localhost:7447"]);
    assert_eq!(f.mode, crate::config::ros2::Mode::Client);
}

#[test]
fn ros2_defaults_are_rmw_zenohs_and_the_namespace_is_the_vehicles() {
    let v = parse(GOOD, "v.toml").unwrap();
    assert_eq!(v.ros2, Ros2Config::default());
    assert_eq!(v.ros2.namespace_for(&v.vehicle.name), "/bench");
    assert_eq!(v.ros2.connect, ["tcp/localhost:7447"]);
    assert!(!v.ros2.multicast_scouting);
}

/// A vehicle with every section, each with a marker line a case replaces.
const BASE: &str = r#"[vehicle]
name = "bench"
[vehicle.roles]
brake = "brake"

[network]
# network

[supervisor]
# supervisor

[[device]]
name = "brake"
kind = "setpoint"
range = [0.0, 1.0]
driver = "modbus"
port = "/dev/ttyUSB0"
# device
[device.modbus]
slave = 3
registers = { target = 0, position = 0 }
[device.sim]
# sim
[device.response]
lag = "80ms"
# response

[teleop]
# teleop
"#;

/// One absurd value: where it goes, the line the error must name (the first line of
/// the edited file that starts with `at`), and what the error must say (the key, the
/// accepted range or form).
struct Absurd {
    incident: &'static str,
    replace: &'static str,
    with: &'static str,
    at: &'static str,
    says: &'static [&'static str],
}

impl Absurd {
    /// The edited file and the line number its error must name.
    fn apply(&self) -> (String, usize) {
        let text = BASE.replacen(self.replace, self.with, 1);
        let line = text
            .lines()
            .position(|l| l.starts_with(self.at))
            .unwrap_or_else(|| panic!("{}: no line starts with {:?}", self.incident, self.at))
            + 1;
        (text, line)
    }
}

/// A vehicle file can switch safety off: every one of these loaded before.
const ABSURD: &[Absurd] = &[
    Absurd {
        incident: "watchdog that never trips",
        replace: "# network",
        with: "watchdog_timeout = \"1000000000000s\"",
        at: "watchdog_timeout",
        says: &["[network] watchdog_timeout:", "from 10ms to 2s", "got 1000000000000s"],
    },
    Absurd {
        incident: "silent device never flagged",
        replace: "# device",
        with: "reply_timeout = \"1000000000h\"",
        at: "reply_timeout",
        says: &["brake: reply_timeout:", "from 1ms to 5s", "got 3600000000000s"],
    },
    Absurd {
        incident: "huge status period and max age",
        replace: "# device",
        with: "status_period = \"1000000000h\"\nstatus_max_age = \"1000000000h\"",
        at: "status_period",
        says: &["brake: status_period:", "from 1ms to 10s"],
    },
    Absurd {
        incident: "huge status max age alone",
        replace: "# device",
        with: "status_max_age = \"100000h\"",
        at: "status_max_age",
        says: &["brake: status_max_age:", "from 1ms to 10s"],
    },
    Absurd {
        incident: "resend never",
        replace: "# device",
        with: "command_timeout = \"0ms\"",
        at: "command_timeout",
        says: &["brake: command_timeout:", "from 1ms to 10s", "got 0s"],
    },
    Absurd {
        incident: "rate cap that holds back the brake",
        replace: "# device",
        with: "min_command_interval = \"1h\"",
        at: "min_command_interval",
        says: &["brake: min_command_interval:", "from 1ms to 1s", "got 3600s"],
    },
    Absurd {
        incident: "baud zero",
        replace: "# device",
        with: "baud = 0",
        at: "baud",
        says: &["brake: baud:", "a whole number from 300 to 4000000", "got 0"],
    },
    Absurd {
        incident: "supervisor that spins",
        replace: "# supervisor",
        with: "period = \"0ms\"",
        at: "period",
        says: &["[supervisor] period:", "from 10ms to 1s", "got 0s"],
    },
    Absurd {
        incident: "negative range margin",
        replace: "# supervisor",
        with: "range_margin = -3",
        at: "range_margin",
        says: &["range_margin:", "a number from 0 to 0.5", "got -3"],
    },
    Absurd {
        incident: "error rate that can never be exceeded",
        replace: "# supervisor",
        with: "error_rate = 2.0",
        at: "error_rate",
        says: &["[supervisor] error_rate:", "from 0.01 to 0.99", "got 2"],
    },
    Absurd {
        incident: "recovery with no attempt",
        replace: "# supervisor",
        with: "attempts = 0",
        at: "attempts",
        says: &["[supervisor] attempts:", "a whole number from 1 to 10", "got 0"],
    },
    Absurd {
        incident: "negative attempts",
        replace: "# supervisor",
        with: "attempts = -1",
        at: "attempts",
        says: &["attempts:", "a whole number from 1 to 10", "got -1"],
    },
    Absurd {
        incident: "negative follow tolerance",
        replace: "# supervisor",
        with: "follow_tolerance = -1",
        at: "follow_tolerance",
        says: &["follow_tolerance:", "a number from 0.01 to 0.5", "got -1"],
    },
    Absurd {
        incident: "follow time of an hour",
        replace: "# supervisor",
        with: "follow_time = \"1h\"",
        at: "follow_time",
        says: &["[supervisor] follow_time:", "from 100ms to 10s"],
    },
    Absurd {
        incident: "error window of zero",
        replace: "# supervisor",
        with: "error_window = \"0s\"",
        at: "error_window",
        says: &["[supervisor] error_window:", "from 100ms to 60s"],
    },
    Absurd {
        incident: "recovery step that never times out",
        replace: "# supervisor",
        with: "step_timeout = \"100000h\"",
        at: "step_timeout",
        says: &["[supervisor] step_timeout:", "from 100ms to 30s"],
    },
    Absurd {
        incident: "a service that gives up on a device before it could be replugged",
        replace: "# supervisor",
        with: "give_up_after = \"0s\"",
        at: "give_up_after",
        says: &["[supervisor] give_up_after:", "from 1s to 86400s"],
    },
    Absurd {
        incident: "the key that made a recovery giving up end the run",
        replace: "# supervisor",
        with: "exit_on_give_up = true",
        at: "exit_on_give_up",
        says: &[
            "[supervisor] exit_on_give_up: no longer a key",
            "adrive keeps running while a device is gone",
            "give_up_after = \"30s\"",
        ],
    },
    Absurd {
        incident: "modbus broadcast address as slave",
        replace: "slave = 3",
        with: "slave = 0",
        at: "slave",
        says: &["brake: modbus.slave:", "a whole number from 1 to 247", "got 0"],
    },
    Absurd {
        incident: "modbus slave past a byte",
        replace: "slave = 3",
        with: "slave = 300",
        at: "slave",
        says: &["modbus.slave:", "a whole number from 1 to 247", "got 300"],
    },
    Absurd {
        incident: "range of three values truncated",
        replace: "range = [0.0, 1.0]",
        with: "range = [-1.0, 0.0, 1.0]",
        at: "range",
        says: &["range: expected [min, max], two finite numbers with min < max (got [-1.0, 0.0, 1.0])"],
    },
    Absurd {
        incident: "a brake that is never released",
        replace: "range = [0.0, 1.0]",
        with: "range = [0.2, 1.0]",
        at: "brake = ",
        says: &["brake", "its range must start at 0 (released)"],
    },
    Absurd {
        incident: "multicast ttl past a byte",
        replace: "# network",
        with: "multicast_ttl = 300",
        at: "multicast_ttl",
        says: &["[network] multicast_ttl:", "a whole number from 0 to 255", "got 300"],
    },
    Absurd {
        incident: "broadcast rate of zero",
        replace: "# network",
        with: "broadcast_rate = 0.0",
        at: "broadcast_rate",
        says: &["[network] broadcast_rate:", "a number from 0.1 to 1000"],
    },
    Absurd {
        incident: "simulated watchdog of zero",
        replace: "# sim",
        with: "watchdog = \"0ms\"",
        at: "watchdog",
        says: &["brake: sim.watchdog:", "from 10ms to 10s", "got 0s"],
    },
    Absurd {
        incident: "simulated watchdog shorter than the resend",
        replace: "# sim",
        with: "watchdog = \"100ms\"",
        at: "watchdog",
        says: &[
            "brake: sim.watchdog 100ms, command_timeout 250ms: expected `watchdog` longer",
        ],
    },
    Absurd {
        incident: "a simulated transport delay of an hour",
        replace: "# sim",
        with: "delay = \"1h\"",
        at: "delay",
        says: &["brake: sim.delay:", "from 0s to 1s", "got 3600s"],
    },
    Absurd {
        incident: "a simulated lag of zero",
        replace: "# sim",
        with: "lag = \"0ms\"",
        at: "lag",
        says: &["brake: sim.lag:", "from 1ms to 10s", "got 0s"],
    },
    Absurd {
        incident: "a simulated drive that never moves",
        replace: "# sim",
        with: "rate = 0.0",
        at: "rate",
        says: &["brake: sim.rate 0: expected `rate`, `deadband` and `backlash` in the device's units"],
    },
    Absurd {
        incident: "a simulated dead band as wide as the range",
        replace: "# sim",
        with: "deadband = 1.0",
        at: "deadband",
        says: &["brake: sim.deadband 1: expected", "from 0 to a tenth of its range"],
    },
    Absurd {
        incident: "a negative simulated backlash",
        replace: "# sim",
        with: "backlash = -0.01",
        at: "backlash",
        says: &["brake: sim.backlash -0.01: expected"],
    },
    Absurd {
        incident: "a simulated shift that never ends",
        replace: "# sim",
        with: "settle = \"1h\"",
        at: "settle",
        says: &["brake: sim.settle:", "from 0s to 10s", "got 3600s"],
    },
    Absurd {
        incident: "a simulated reading with negative noise",
        replace: "# sim",
        with: "readings = { pressure = { noise = -1.0 } }",
        at: "readings",
        says: &["brake: sim.readings.pressure.noise -1: expected", "a finite number from 0"],
    },
    Absurd {
        incident: "status period longer than the max age",
        replace: "# device",
        with: "status_period = \"1500ms\"\nstatus_max_age = \"250ms\"",
        at: "status_max_age",
        says: &["brake: status_max_age 250ms, status_period 1500ms: expected `status_max_age` at least `status_period`"],
    },
    Absurd {
        incident: "an estimate that never lags",
        replace: "lag = \"80ms\"",
        with: "lag = \"0ms\"",
        at: "lag",
        says: &["brake: response.lag:", "from 1ms to 10s", "got 0s"],
    },
    Absurd {
        incident: "a tolerance adaptive polling can never keep",
        replace: "# response",
        with: "noise = 0.05\ntolerance = 0.01",
        at: "tolerance",
        says: &["brake: response.tolerance 0.01, response.noise 0.05: expected", "`tolerance` above `noise`"],
    },
    Absurd {
        incident: "a negative dead band",
        replace: "# response",
        with: "deadband = -0.5",
        at: "deadband",
        says: &["brake: response.deadband -0.5: expected", "in the device's units, above 0"],
    },
    Absurd {
        incident: "an override that never trips",
        replace: "# response",
        with: "override_time = \"1h\"",
        at: "override_time",
        says: &["brake: response.override_time:", "from 50ms to 2s", "got 3600s"],
    },
    Absurd {
        incident: "an override threshold no hand can pass",
        replace: "# response",
        with: "override_threshold = 5.0",
        at: "override_threshold",
        says: &["brake: response.override_threshold 5: expected", "below the width of its range"],
    },
    Absurd {
        incident: "a tolerance wider than the whole range",
        replace: "# response",
        with: "tolerance = 7.0",
        at: "tolerance",
        says: &["brake: response.tolerance 7: expected", "below the width of its range"],
    },
    Absurd {
        incident: "a stuck motor never named",
        replace: "# supervisor",
        with: "stall_time = \"0s\"",
        at: "stall_time",
        says: &["[supervisor] stall_time:", "from 100ms to 10s", "got 0s"],
    },
    Absurd {
        incident: "full throttle held from a keyboard",
        replace: "# teleop",
        with: "gas = 1.0",
        at: "gas",
        says: &["[teleop] gas:", "a number from 0.01 to 0.5", "got 1"],
    },
    Absurd {
        incident: "a steering that never moves while its key is held",
        replace: "# teleop",
        with: "steer_rate = 0.0",
        at: "steer_rate",
        says: &["[teleop] steer_rate:", "a number from 0.05 to 2", "got 0"],
    },
    Absurd {
        incident: "letting go of the brake key brakes harder than holding it",
        replace: "# teleop",
        with: "brake = 0.2\nhold = 0.5",
        at: "hold",
        says: &["[teleop] hold 0.5, brake 0.2: expected `hold` at most `brake`"],
    },
    Absurd {
        incident: "reply timeout past the max age",
        replace: "# device",
        with: "reply_timeout = \"2s\"",
        at: "reply_timeout",
        says: &["brake: reply_timeout 2s, status_max_age 500ms: expected `reply_timeout` at most `status_max_age`"],
    },
];

#[test]
fn every_absurd_value_is_refused_with_file_line_key_and_range() {
    assert!(parse(BASE, "v.toml").is_ok(), "the base vehicle loads");
    for case in ABSURD {
        assert!(BASE.contains(case.replace), "{}", case.incident);
        let (text, line) = case.apply();
        let e = match parse(&text, "v.toml") {
            Ok(_) => panic!("{}: `{}` was accepted", case.incident, case.with),
            Err(e) => e.to_string(),
        };
        let at = format!("v.toml:{line}: ");
        assert!(
            e.starts_with(&at),
            "{}: wanted {at}…, got {e}",
            case.incident
        );
        for said in case.says {
            assert!(
                e.contains(said),
                "{}: wanted {said:?} in {e}",
                case.incident
            );
        }
    }
}

/// `[device.response]` declares the real device's answer to its command: one way of
/// moving, on a setpoint device, and adaptive polling only where there is an estimate.
#[test]
fn a_declared_response_is_checked_where_it_is_written() {
    let v = parse(BASE, "v.toml").unwrap();
    let r = v.devices[0].response.expect("declared");
    assert_eq!(r.motion, Motion::Lag(Duration::from_millis(80)));
    assert_eq!((r.noise, r.tolerance, r.deadband), (0.001, 0.01, 0.01));
    assert_eq!(v.devices[0].polling, Polling::Fixed);
    let a = VehicleConfig::alice();
    assert_eq!(
        a.device("steer").unwrap().response.unwrap().motion,
        Motion::Rate(1.0)
    );
    assert!(a.device("trans").unwrap().response.is_none());

    let both = BASE.replace("# response", "rate = 2.0");
    let e = error(&both);
    assert_eq!(
        line(&e),
        both.lines().position(|l| l == "[device.response]").unwrap() + 1,
        "{e}"
    );
    assert!(e.contains("a `rate` or a `lag`, not both"), "{e}");

    let neither = BASE.replace("lag = \"80ms\"", "noise = 0.01");
    assert!(
        error(&neither).contains("expected `rate = 1.0`"),
        "{}",
        error(&neither)
    );

    let typo = BASE.replace("# response", "tolerence = 0.1");
    let e = error(&typo);
    assert_eq!(
        line(&e),
        typo.lines()
            .position(|l| l.starts_with("tolerence"))
            .unwrap()
            + 1,
        "{e}"
    );
    assert!(e.contains("tolerance"), "{e}");

    let adaptive = BASE.replace("# device", "polling = \"adaptive\"");
    assert_eq!(
        parse(&adaptive, "v.toml").unwrap().devices[0].polling,
        Polling::Adaptive
    );
    let blind = adaptive.replace("[device.response]\nlag = \"80ms\"\n# response\n", "");
    let e = error(&blind);
    assert_eq!(
        line(&e),
        blind
            .lines()
            .position(|l| l.starts_with("polling"))
            .unwrap()
            + 1,
        "{e}"
    );
    assert!(
        e.contains("polling = \"adaptive\" needs a [device.response]"),
        "{e}"
    );
    let e = error(&BASE.replace("# device", "polling = \"sometimes\""));
    assert!(e.contains("sometimes") && e.contains("adaptive"), "{e}");

    let on_a_state = format!(
        "{BASE}\n[[device]]\nname = \"trans\"\nkind = \"state\"\nstates = [\"park\", \"drive\"]\ndriver = \"line\"\nport = \"/dev/ttyUSB1\"\n[device.response]\nrate = 1.0\n"
    );
    let e = error(&on_a_state);
    assert!(
        e.contains("trans: [device.response] is for setpoint devices"),
        "{e}"
    );

    let misspelt = BASE.replace("[device.response]", "[device.respnse]");
    assert!(
        error(&misspelt).contains("did you mean [device.response]"),
        "{}",
        error(&misspelt)
    );
}

#[test]
fn a_device_without_a_port_is_refused_outside_sim_at_its_line() {
    let none = BASE.replace("port = \"/dev/ttyUSB0\"\n", "");
    let v = parse(&none, "v.toml").expect("a portless device loads, for --sim");
    let e = v.check_ports().unwrap_err().to_string();
    assert!(
        e.starts_with("v.toml:12: brake: port: expected the path of a serial port"),
        "{e}"
    );
    assert!(e.contains("--sim"), "{e}");
    let empty = BASE.replace("\"/dev/ttyUSB0\"", "\"\"");
    let e = parse(&empty, "v.toml").unwrap().check_ports().unwrap_err();
    assert!(e.to_string().starts_with("v.toml:17: brake: port:"), "{e}");
    assert!(parse(BASE, "v.toml").unwrap().check_ports().is_ok());
}

#[test]
fn two_devices_on_one_serial_port_are_refused_at_the_second_s_port() {
    let two = format!(
        "{BASE}\n[[device]]\nname = \"horn\"\nkind = \"state\"\nstates = [\"off\", \"on\"]\ndriver = \"line\"\nport = \"/dev/ttyUSB0\"\n"
    );
    let e = parse(&two, "v.toml")
        .unwrap()
        .check_ports()
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with(
            "v.toml:36: horn: port: /dev/ttyUSB0 is brake's port too (v.toml:17): a serial port has one device"
        ),
        "{e}"
    );
    // The horn on a port of its own.
    let at = two.rfind("/dev/ttyUSB0").unwrap();
    let apart = format!(
        "{}/dev/ttyUSB1{}",
        &two[..at],
        &two[at + "/dev/ttyUSB0".len()..]
    );
    assert!(
        parse(&apart, "v.toml").unwrap().check_ports().is_ok(),
        "{apart}"
    );
}

/// Where each spelling of a port goes, in a vehicle file: the brake's at line 17, the
/// horn's (after it) at line 33.
fn brake_and_horn(brake: &str, horn: &str) -> String {
    let base = BASE.replace("/dev/ttyUSB0", brake);
    format!(
        "{base}\n[[device]]\nname = \"horn\"\nkind = \"state\"\nstates = [\"off\", \"on\"]\ndriver = \"line\"\nport = \"{horn}\"\n"
    )
}

/// The incident: `/dev/x` and `/dev/./x`, or a `/dev/serial/by-id/…` link and its
/// target, passed as two ports, and both devices opened one. Ports are compared by what
/// they resolve to — real files, links and device files here — and a port not plugged
/// in yet by its path made normal; the second is refused at its line, naming the first
/// with its own.
#[test]
fn two_spellings_of_one_port_are_refused_at_the_second_naming_the_first() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().display().to_string();
    std::fs::write(dir.path().join("ttyUSB0"), "").unwrap();
    std::fs::write(dir.path().join("ttyUSB1"), "").unwrap();
    std::fs::create_dir(dir.path().join("by-id")).unwrap();
    let link = format!("{d}/by-id/usb-FTDI_brake-if00-port0");
    std::os::unix::fs::symlink(format!("{d}/ttyUSB0"), &link).unwrap();
    let null = format!("{d}/null");
    std::os::unix::fs::symlink("/dev/null", &null).unwrap();
    let one = [
        (format!("{d}/ttyUSB0"), format!("{d}/./ttyUSB0")),
        (format!("{d}/ttyUSB0"), format!("{d}//ttyUSB0")),
        (format!("{d}/ttyUSB0"), format!("{d}/by-id/../ttyUSB0")),
        (link.clone(), format!("{d}/ttyUSB0")),
        (format!("{d}/ttyUSB0"), link.clone()),
        // Not plugged in yet.
        (format!("{d}/ttyUSB7"), format!("{d}/./ttyUSB7")),
        (
            format!("{d}/gone/ttyUSB7"),
            format!("{d}/gone/x/../ttyUSB7"),
        ),
        // Device files: one device number.
        ("/dev/null".to_string(), null.clone()),
        ("/dev/null".to_string(), "/dev/./null".to_string()),
    ];
    for (brake, horn) in &one {
        let v = parse(&brake_and_horn(brake, horn), "v.toml").unwrap();
        let e = v.check_ports().unwrap_err().to_string();
        assert!(
            e.starts_with(&format!(
                "v.toml:36: horn: port: {horn} is brake's port, {brake}, by another name (both are "
            )),
            "{brake} and {horn}: {e}"
        );
        assert!(
            e.ends_with(") (v.toml:17): a serial port has one device"),
            "{e}"
        );
    }
    let two = [
        (format!("{d}/ttyUSB0"), format!("{d}/ttyUSB1")),
        (link, format!("{d}/ttyUSB1")),
        (format!("{d}/ttyUSB7"), format!("{d}/ttyUSB8")),
        ("/dev/null".to_string(), "/dev/zero".to_string()),
        (null, "/dev/zero".to_string()),
    ];
    for (brake, horn) in &two {
        let v = parse(&brake_and_horn(brake, horn), "v.toml").unwrap();
        assert!(v.check_ports().is_ok(), "{brake} and {horn}");
    }
}

/// Two `[[bus]]` tables on one adapter once both started their reader on it; a device
/// and a bus on one port fight as two devices would. Every mix is refused at the second
/// one's port, naming the first.
#[test]
fn a_bus_s_adapter_port_is_compared_with_every_other_bus_and_device() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().display().to_string();
    std::fs::write(dir.path().join("ttyACM0"), "").unwrap();
    let link = format!("{d}/adapter");
    std::os::unix::fs::symlink(format!("{d}/ttyACM0"), &link).unwrap();
    let bus = |name: &str, port: &str| {
        format!("[[bus]]\nname = \"{name}\"\nport = \"{port}\"\ndbc = \"oscc.dbc\"\n")
    };
    let horn = |port: &str| {
        format!("[[device]]\nname = \"horn\"\nkind = \"state\"\nstates = [\"off\", \"on\"]\ndriver = \"line\"\nport = \"{port}\"\n")
    };
    // The DBC is found beside the vehicle file.
    let path = format!("{}/vehicles/test.toml", env!("CARGO_MANIFEST_DIR"));
    let refused = |body: String| {
        let text = format!("[vehicle]\nname = \"kit\"\n{body}");
        parse(&text, &path)
            .unwrap()
            .check_ports()
            .unwrap_err()
            .to_string()
    };
    // Two buses: the second's port (line 10) names the first (line 5).
    let e = refused(format!(
        "{}\n{}",
        bus("kit", &format!("{d}/ttyACM0")),
        bus("kat", &link)
    ));
    assert!(
        e.starts_with(&format!(
            "{path}:10: bus kat: port: {link} is the adapter of bus kit, {d}/ttyACM0, by another name (both are "
        )),
        "{e}"
    );
    assert!(
        e.ends_with(&format!(
            " ({path}:5): one adapter is one bus: its devices go on one [[bus]]"
        )),
        "{e}"
    );
    // A bus, then a device on its port.
    let e = refused(format!("{}{}", bus("kit", &link), horn(&link)));
    assert!(
        e.starts_with(&format!(
            "{path}:12: horn: port: {link} is the adapter of bus kit too ({path}:5): a device on the bus is `driver = \"can\"`, `bus = \"kit\"`"
        )),
        "{e}"
    );
    // A device, then a bus on its port.
    let e = refused(format!(
        "{}{}",
        horn(&format!("{d}/./ttyACM0")),
        bus("kit", &link)
    ));
    assert!(
        e.starts_with(&format!(
            "{path}:11: bus kit: port: {link} is horn's port, {d}/./ttyACM0, by another name"
        )),
        "{e}"
    );
    assert!(
        e.ends_with("a CAN adapter's port is its bus's alone"),
        "{e}"
    );
}

/// A device gone never ends the run unless the operator says so.
#[test]
fn give_up_after_is_off_unless_the_file_says_it() {
    assert_eq!(
        parse(BASE, "v.toml").unwrap().supervisor.give_up_after,
        None
    );
    let set = BASE.replace("# supervisor", "give_up_after = \"2m\"");
    assert_eq!(
        parse(&set, "v.toml").unwrap().supervisor.give_up_after,
        Some(Duration::from_secs(120))
    );
}

#[test]
fn the_console_s_status_period_goes_through_the_same_rule() {
    let d = &parse(BASE, "v.toml").unwrap().devices[0];
    let mut edited = d.clone();
    edited.status_period = Duration::from_millis(1500);
    let e = edited.check_limits().unwrap_err();
    assert_eq!(e.paths[0], "status_max_age");
    assert!(e.message.contains("status_period 1500ms"), "{e}");
}

/// `[[devcie]]` was answered "did you mean [[device]]?", a misspelt key such as
/// `baud_rate` only with the list of every key a device has.
#[test]
fn a_misspelt_key_gets_a_did_you_mean() {
    let e = error(&BASE.replace("# device", "baud_rate = 9600"));
    let at = BASE.lines().position(|l| l == "# device").unwrap() + 1;
    assert!(
        e.starts_with(&format!(
            "v.toml:{at}: unknown field `baud_rate`: did you mean `baud`? expected one of `name`,"
        )),
        "{e}"
    );
    let e = error(&BASE.replace("# network", "allow_engag = true"));
    assert!(e.contains("did you mean `allow_engage`?"), "{e}");
    let e = error(&BASE.replace("# device", "colour = \"red\""));
    assert!(!e.contains("did you mean"), "nothing is close: {e}");
}

/// `[[devcie]]` made the `[device.modbus]` under it a duplicate of the one above, and
/// the error named that line, not the typo.
#[test]
fn a_misspelt_table_is_named_at_its_own_line_not_as_a_later_duplicate() {
    let typo = format!(
        "{BASE}\n[[devcie]]\nname = \"gas\"\ndriver = \"modbus\"\n[device.modbus]\nslave = 2\n"
    );
    let e = error(&typo);
    let at = typo.lines().position(|l| l == "[[devcie]]").unwrap() + 1;
    assert!(
        e.starts_with(&format!(
            "v.toml:{at}: unknown table [[devcie]]: did you mean [[device]]?"
        )),
        "{e}"
    );
    let e = error(&BASE.replace("[device.sim]", "[device.simm]"));
    assert!(
        e.starts_with("v.toml:22: unknown table [device.simm]: did you mean [device.sim]?"),
        "{e}"
    );
    let e = error(&format!("{BASE}[netwrok]\n"));
    let at = BASE.lines().count() + 1;
    assert!(
        e.starts_with(&format!("v.toml:{at}: unknown table [netwrok]")),
        "{e}"
    );
}

#[test]
fn a_duplicate_key_is_named() {
    let e = error(&BASE.replace("# device", "baud = 9600\nbaud = 19200"));
    assert!(e.starts_with("v.toml:19: duplicate key `baud`"), "{e}");
}

#[test]
fn a_byte_that_is_not_utf8_names_its_line() {
    let mut bytes = BASE.as_bytes().to_vec();
    let at = BASE.find("# device").unwrap() + 2;
    bytes[at] = 0xff;
    let e = document::utf8(&bytes, "v.toml").unwrap_err().to_string();
    assert_eq!(
        e,
        "v.toml:18: byte 0xff at column 3 is not UTF-8: a vehicle file is UTF-8 text"
    );
}

#[test]
fn a_file_that_cannot_be_read_says_so_without_a_line() {
    let e = load(Path::new("/nonexistent/vehicle.toml")).unwrap_err();
    assert!(
        e.to_string()
            .starts_with("/nonexistent/vehicle.toml: cannot read: "),
        "{e}"
    );
}

/// The guide's table (docs/vehicles.md) of well-known readings is the loader's.
#[test]
fn the_guide_shows_the_well_known_readings() {
    let readme = include_str!("../../docs/vehicles.md");
    let table = device::well_known_markdown();
    crate::testkit::assert_guide_holds("docs/vehicles.md", readme, "well-known readings", &table);
}

/// Every way of writing one line wrong that the walk below tries, on a file whose first
/// line is a comment: delete it, write it twice, misspell its key, give it a value of
/// every wrong type, misspell its table; in `[vehicle.roles]`, bind it to every device
/// and reading, and add every role bound to every device. Each: the file and the line
/// edited.
fn mutations(text: &str) -> Vec<(String, usize)> {
    let lines: Vec<&str> = text.lines().collect();
    let v = parse(text, "v.toml").expect("the walked file loads");
    let targets: Vec<String> = v
        .devices
        .iter()
        .flat_map(|d| {
            std::iter::once(d.name.clone()).chain(
                d.readings
                    .iter()
                    .map(move |r| format!("{}.{}", d.name, r.name)),
            )
        })
        .collect();
    let wrong = [
        "\"x\"", "-1", "1e9", "[]", "{}", "true", "\"10h\"", "\"\"", "[0.0]",
    ];
    let edit = |i: usize, new: &[String]| {
        let mut out: Vec<&str> = lines[..i].to_vec();
        out.extend(new.iter().map(String::as_str));
        out.extend(&lines[i + 1..]);
        out.join("\n") + "\n"
    };
    let mut out = Vec::new();
    let mut table = "";
    for (i, l) in lines.iter().enumerate().skip(1) {
        let l = l.to_string();
        out.push((edit(i, &[]), i + 1));
        out.push((edit(i, &[l.clone(), l.clone()]), i + 1));
        if l.starts_with('[') {
            table = lines[i];
            out.push((edit(i, &[l.replacen('[', "[x", 1)]), i + 1));
        }
        let Some((key, value)) = l.split_once(" = ") else {
            continue;
        };
        out.push((edit(i, &[format!("zzz = {value}")]), i + 1));
        for w in wrong {
            out.push((edit(i, &[format!("{key} = {w}")]), i + 1));
        }
        if table == "[vehicle.roles]" {
            for t in &targets {
                out.push((edit(i, &[format!("{key} = {t:?}")]), i + 1));
                for r in Role::ALL {
                    out.push((edit(i, &[l.clone(), format!("{r} = {t:?}")]), i + 2));
                }
            }
        }
    }
    out
}

/// Throttle and brake on one device were refused at line 1 (the refusal was built at
/// byte 0): every refusal the walk provokes in the shipped vehicles and the test base
/// names a line of the file, and never line 1, which is a comment nobody edited.
#[test]
fn no_refusal_names_the_first_line_when_it_is_not_at_fault() {
    let base = format!("# a vehicle with every section\n{BASE}");
    let mut wrong = Vec::new();
    let mut refusals = 0;
    for (name, text) in [
        ("alice", ALICE_TOML),
        ("cart", include_str!("../../vehicles/cart.toml")),
        ("tractor", include_str!("../../vehicles/tractor.toml")),
        ("base", base.as_str()),
    ] {
        assert!(text.starts_with('#'), "{name}: its first line is a comment");
        for (edited, at) in mutations(text) {
            let Err(e) = parse(&edited, "v.toml") else {
                continue;
            };
            refusals += 1;
            if e.line <= 1 {
                wrong.push(format!("{name}, line {at} edited: {e}"));
            }
        }
    }
    assert!(refusals > 3000, "the walk provokes refusals: {refusals}");
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

/// Refusals the walk above cannot provoke by editing one line, each at its line.
#[test]
fn refusals_about_the_whole_file_name_no_line() {
    let e = parse("# my car\n\n[network]\n", "v.toml").unwrap_err();
    assert_eq!(
        e.to_string(),
        "v.toml: no [vehicle] table: a vehicle file has [vehicle] with name = \"…\""
    );
    let e = parse("# my car\n", "v.toml").unwrap_err();
    assert_eq!(e.line, 0, "{e}");
}

/// `[vehicle.roles]` binding `role_a` and then `role_b` to one device fit for both
/// (reading roles to its readings), with the gear table when gear is bound: the file
/// and the line of the second binding.
fn two_roles_on_one_device(a: Role, b: Role) -> (String, usize) {
    let setpoint = [Role::Steering, Role::Throttle, Role::Brake];
    let state = [Role::Gear, Role::Starter];
    let readings = "{ name = \"speed\" }, { name = \"running\" }, { name = \"estop\" }";
    let device = if setpoint.contains(&a) || setpoint.contains(&b) {
        format!("kind = \"setpoint\"\nrange = [0.0, 1.0]\nreadings = [\"position\", {readings}]")
    } else if state.contains(&a) || state.contains(&b) {
        format!(
            "kind = \"state\"\nstates = [\"park\", \"drive\"]\nreadings = [\"state\", {readings}]"
        )
    } else {
        format!("kind = \"sensor\"\nreadings = [{readings}]")
    };
    let target = |r: Role| match r {
        Role::Estop => "unit.estop",
        Role::Speed => "unit.speed",
        Role::EngineRunning => "unit.running",
        _ => "unit",
    };
    let gear = if a == Role::Gear || b == Role::Gear {
        "[vehicle.gear]\nforward = [\"drive\"]\npark = \"park\"\n"
    } else {
        ""
    };
    let text = format!(
        "# two roles, one device\n[vehicle]\nname = \"pair\"\n[vehicle.roles]\n{a} = {:?}\n{b} = {:?}\n{gear}\n[[device]]\nname = \"unit\"\n{device}\ndriver = \"line\"\n",
        target(a),
        target(b)
    );
    (text, 6)
}

/// Steering on the throttle device started, and ran one device in two roles. Over every
/// pair of roles, from the one table: a pair listed in `SHARED` loads with both roles on
/// the device, every other is refused at the line of its second binding, naming both
/// bindings with their lines.
#[test]
fn every_pair_of_roles_on_one_device_is_decided_by_the_sharing_table() {
    let mut allowed = 0;
    for (i, &a) in Role::ALL.iter().enumerate() {
        for &b in &Role::ALL[i + 1..] {
            for (first, second) in [(a, b), (b, a)] {
                let (text, at) = two_roles_on_one_device(first, second);
                match (first.shares_with(second), parse(&text, "v.toml")) {
                    (Some(_), Ok(v)) => {
                        allowed += 1;
                        let unit = v.device("unit").map(|_| DeviceId(0));
                        assert_eq!(v.roles.device(first), unit, "{first}, {second}");
                        assert_eq!(v.roles.device(second), unit, "{first}, {second}");
                    }
                    (Some(why), Err(e)) => {
                        panic!("{first} with {second} may share ({why}), yet: {e}\n{text}")
                    }
                    (None, Ok(_)) => panic!("{first} with {second} on one device was accepted"),
                    (None, Err(e)) => {
                        let want = format!(
                            "v.toml:{at}: roles: {second} = {:?} (line {at}) and {first} = {:?} (line {}) are one device, unit: a device plays one role, except ",
                            text.lines().nth(at - 1).unwrap().split('"').nth(1).unwrap(),
                            text.lines().nth(at - 2).unwrap().split('"').nth(1).unwrap(),
                            at - 1
                        );
                        assert!(e.to_string().starts_with(&want), "wanted {want}…\ngot {e}");
                    }
                }
            }
        }
    }
    assert_eq!(
        allowed,
        2 * roles::SHARED.len(),
        "each pair of SHARED, both ways"
    );
}

/// The roles whose sharing was decided when [`roles::SHARED`] was written. A new role
/// fails here (and the match fails to compile) until its pairs are decided there.
#[test]
fn every_role_s_sharing_with_every_other_was_decided() {
    let decided = |r: Role| match r {
        Role::Steering
        | Role::Throttle
        | Role::Brake
        | Role::Gear
        | Role::Estop
        | Role::Speed
        | Role::EngineRunning
        | Role::Starter => true,
    };
    assert!(Role::ALL.iter().all(|r| decided(*r)));
    assert_eq!(
        Role::ALL.len(),
        8,
        "a new role: decide in roles::SHARED which roles it may share a device with"
    );
    for (a, b, why) in roles::SHARED {
        assert_ne!(a, b);
        assert!(!why.is_empty());
        assert_eq!(b.shares_with(a), Some(why), "symmetric");
    }
}

/// The issue's own file: Alice with the brake on the gas device.
#[test]
fn throttle_and_brake_on_one_device_name_the_second_binding_and_quote_both() {
    let text = ALICE_TOML.replace("brake = \"brake\"", "brake = \"gas\"");
    let e = error(&text);
    assert!(
        e.starts_with(
            "v.toml:38: roles: brake = \"gas\" (line 38) and throttle = \"gas\" (line 37) are one device, gas: a device plays one role, except gear with starter, speed with engine_running"
        ),
        "{e}"
    );
}

/// The guide's table (docs/vehicles.md) of the roles that may share a device is the
/// loader's.
#[test]
fn the_guide_shows_which_roles_may_share_a_device() {
    let readme = include_str!("../../docs/vehicles.md");
    let table = roles::sharing_markdown();
    crate::testkit::assert_guide_holds("docs/vehicles.md", readme, "shared roles", &table);
}
