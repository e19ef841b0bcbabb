//! The loader on text: defaults, the errors a user makes, and one test per absurd
//! value that would switch safety off.

use super::*;

const GOOD: &str = r#"
[vehicle]
name = "bench"

[[device]]
name = "steer"
driver = "line"
port = "/dev/ttyUSB0"
status_period = "50ms"
"#;

#[test]
fn the_built_in_alice_parses_with_all_six_devices() {
    let a = VehicleConfig::alice();
    let names: Vec<_> = a.devices.iter().map(|d| d.name).collect();
    assert_eq!(names, Role::ALL.to_vec());
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
}

fn error(text: &str) -> String {
    parse(text, "v.toml").unwrap_err().to_string()
}

#[test]
fn an_unknown_driver_names_file_line_and_the_choices() {
    let e = error(&GOOD.replace("driver = \"line\"", "driver = \"modbsu\""));
    assert!(e.starts_with("v.toml:7: "), "{e}");
    assert!(e.contains("modbsu") && e.contains("line"), "{e}");
}

#[test]
fn a_bad_duration_names_its_line_and_form() {
    let e = error(&GOOD.replace("\"50ms\"", "\"fast\""));
    assert!(e.starts_with("v.toml:9: "), "{e}");
    assert!(e.contains("250ms"), "{e}");
}

#[test]
fn an_unknown_device_or_field_is_refused() {
    let e = error(&GOOD.replace("\"steer\"", "\"wiper\""));
    assert!(
        e.starts_with("v.toml:6: ") && e.contains("`steer`, `gas`"),
        "{e}"
    );
    let e = error(&GOOD.replace("port =", "prot ="));
    assert!(e.starts_with("v.toml:8: ") && e.contains("prot"), "{e}");
}

#[test]
fn cross_field_errors_point_at_the_device() {
    let e = error(&format!("{GOOD}range = [1.0, -1.0]\n"));
    assert!(
        e.starts_with("v.toml:10: steer: range [1, -1]: expected") && e.contains("min < max"),
        "{e}"
    );
    let e = error(&format!("{GOOD}status_max_age = \"10ms\"\n"));
    assert!(e.contains("status_max_age"), "{e}");
    let twice = format!("{GOOD}\n[[device]]\nname = \"steer\"\ndriver = \"line\"\n");
    assert!(error(&twice).contains("defined twice"));
}

#[test]
fn a_modbus_device_needs_its_table_and_a_sensible_map() {
    let modbus = GOOD.replace("driver = \"line\"", "driver = \"modbus\"");
    let e = error(&modbus);
    assert!(
        e.starts_with("v.toml:5: ") && e.contains("[device.modbus]"),
        "{e}"
    );
    let ok = format!(
        "{modbus}\n[device.modbus]\nslave = 7\nregisters = {{ target = 0, position = 0 }}\n"
    );
    let d = &parse(&ok, "v.toml").unwrap().devices[0];
    assert_eq!(d.modbus.as_ref().unwrap().slave, 7);
    let geared = ok.replace("position = 0", "gear = 0");
    assert!(error(&geared).contains("registers.gear"));
    let typo = ok.replace("position = 0", "postion = 0");
    let e = error(&typo);
    assert!(e.starts_with("v.toml:13: ") && e.contains("postion"), "{e}");
}

#[test]
fn broken_toml_names_the_line() {
    let e = error("[vehicle]\nname = \"x\"\n[[device]\n");
    assert!(e.starts_with("v.toml:3: "), "{e}");
}

/// A vehicle with every section, each with a marker line a case replaces.
const BASE: &str = r#"[vehicle]
name = "bench"

[network]
# network

[supervisor]
# supervisor

[[device]]
name = "brake"
driver = "modbus"
port = "/dev/ttyUSB0"
# device
[device.modbus]
slave = 3
registers = { target = 0, position = 0 }
[device.sim]
# sim
"#;

/// One absurd value: where it goes, the line and key the error must name, and the
/// accepted range (or form) it must say.
struct Absurd {
    incident: &'static str,
    replace: &'static str,
    with: &'static str,
    line: usize,
    says: &'static [&'static str],
}

/// A vehicle file can switch safety off: every one of these loaded before.
const ABSURD: &[Absurd] = &[
    Absurd {
        incident: "watchdog that never trips",
        replace: "# network",
        with: "watchdog_timeout = \"1000000000000s\"",
        line: 5,
        says: &["[network] watchdog_timeout:", "from 10ms to 2s", "got 1000000000000s"],
    },
    Absurd {
        incident: "silent device never flagged",
        replace: "# device",
        with: "reply_timeout = \"1000000000h\"",
        line: 14,
        says: &["brake: reply_timeout:", "from 1ms to 5s", "got 3600000000000s"],
    },
    Absurd {
        incident: "huge status period and max age",
        replace: "# device",
        with: "status_period = \"1000000000h\"\nstatus_max_age = \"1000000000h\"",
        line: 14,
        says: &["brake: status_period:", "from 1ms to 10s"],
    },
    Absurd {
        incident: "huge status max age alone",
        replace: "# device",
        with: "status_max_age = \"100000h\"",
        line: 14,
        says: &["brake: status_max_age:", "from 1ms to 10s"],
    },
    Absurd {
        incident: "resend never",
        replace: "# device",
        with: "command_timeout = \"0ms\"",
        line: 14,
        says: &["brake: command_timeout:", "from 1ms to 10s", "got 0s"],
    },
    Absurd {
        incident: "rate cap that holds back the brake",
        replace: "# device",
        with: "min_command_interval = \"1h\"",
        line: 14,
        says: &["brake: min_command_interval:", "from 1ms to 1s", "got 3600s"],
    },
    Absurd {
        incident: "baud zero",
        replace: "# device",
        with: "baud = 0",
        line: 14,
        says: &["brake: baud:", "a whole number from 300 to 4000000", "got 0"],
    },
    Absurd {
        incident: "supervisor that spins",
        replace: "# supervisor",
        with: "period = \"0ms\"",
        line: 8,
        says: &["[supervisor] period:", "from 10ms to 1s", "got 0s"],
    },
    Absurd {
        incident: "negative range margin",
        replace: "# supervisor",
        with: "range_margin = -3",
        line: 8,
        says: &["range_margin:", "a number from 0 to 0.5", "got -3"],
    },
    Absurd {
        incident: "error rate that can never be exceeded",
        replace: "# supervisor",
        with: "error_rate = 2.0",
        line: 8,
        says: &["[supervisor] error_rate:", "from 0.01 to 0.99", "got 2"],
    },
    Absurd {
        incident: "recovery with no attempt",
        replace: "# supervisor",
        with: "attempts = 0",
        line: 8,
        says: &["[supervisor] attempts:", "a whole number from 1 to 10", "got 0"],
    },
    Absurd {
        incident: "negative attempts",
        replace: "# supervisor",
        with: "attempts = -1",
        line: 8,
        says: &["attempts:", "a whole number from 1 to 10", "got -1"],
    },
    Absurd {
        incident: "negative follow tolerance",
        replace: "# supervisor",
        with: "follow_tolerance = -1",
        line: 8,
        says: &["follow_tolerance:", "a number from 0.01 to 0.5", "got -1"],
    },
    Absurd {
        incident: "follow time of an hour",
        replace: "# supervisor",
        with: "follow_time = \"1h\"",
        line: 8,
        says: &["[supervisor] follow_time:", "from 100ms to 10s"],
    },
    Absurd {
        incident: "error window of zero",
        replace: "# supervisor",
        with: "error_window = \"0s\"",
        line: 8,
        says: &["[supervisor] error_window:", "from 100ms to 60s"],
    },
    Absurd {
        incident: "recovery step that never times out",
        replace: "# supervisor",
        with: "step_timeout = \"100000h\"",
        line: 8,
        says: &["[supervisor] step_timeout:", "from 100ms to 30s"],
    },
    Absurd {
        incident: "modbus broadcast address as slave",
        replace: "slave = 3",
        with: "slave = 0",
        line: 16,
        says: &["brake: modbus.slave:", "a whole number from 1 to 247", "got 0"],
    },
    Absurd {
        incident: "modbus slave past a byte",
        replace: "slave = 3",
        with: "slave = 300",
        line: 16,
        says: &["modbus.slave:", "a whole number from 1 to 247", "got 300"],
    },
    Absurd {
        incident: "range of three values truncated",
        replace: "# device",
        with: "range = [-1.0, 0.0, 1.0]",
        line: 14,
        says: &["range: expected [min, max], two numbers, got 3 numbers"],
    },
    Absurd {
        incident: "brake range without full brake",
        replace: "# device",
        with: "range = [0.0, 0.5]",
        line: 14,
        says: &["brake: range [0, 0.5]: expected", "holding the safe state"],
    },
    Absurd {
        incident: "multicast ttl past a byte",
        replace: "# network",
        with: "multicast_ttl = 300",
        line: 5,
        says: &["[network] multicast_ttl:", "a whole number from 0 to 255", "got 300"],
    },
    Absurd {
        incident: "broadcast rate of zero",
        replace: "# network",
        with: "broadcast_rate = 0.0",
        line: 5,
        says: &["[network] broadcast_rate:", "a number from 0.1 to 1000"],
    },
    Absurd {
        incident: "simulated watchdog of zero",
        replace: "# sim",
        with: "watchdog = \"0ms\"",
        line: 19,
        says: &["brake: sim.watchdog:", "from 10ms to 10s", "got 0s"],
    },
    Absurd {
        incident: "simulated watchdog shorter than the resend",
        replace: "# sim",
        with: "watchdog = \"100ms\"",
        line: 19,
        says: &[
            "brake: sim.watchdog 100ms, command_timeout 250ms: expected `watchdog` longer",
        ],
    },
    Absurd {
        incident: "status period longer than the max age",
        replace: "# device",
        with: "status_period = \"1500ms\"\nstatus_max_age = \"250ms\"",
        line: 15,
        says: &["brake: status_max_age 250ms, status_period 1500ms: expected `status_max_age` at least `status_period`"],
    },
    Absurd {
        incident: "reply timeout past the max age",
        replace: "# device",
        with: "reply_timeout = \"2s\"",
        line: 14,
        says: &["brake: reply_timeout 2s, status_max_age 500ms: expected `reply_timeout` at most `status_max_age`"],
    },
];

#[test]
fn every_absurd_value_is_refused_with_file_line_key_and_range() {
    assert!(parse(BASE, "v.toml").is_ok(), "the base vehicle loads");
    for case in ABSURD {
        assert!(BASE.contains(case.replace), "{}", case.incident);
        let text = BASE.replacen(case.replace, case.with, 1);
        let e = match parse(&text, "v.toml") {
            Ok(_) => panic!("{}: `{}` was accepted", case.incident, case.with),
            Err(e) => e.to_string(),
        };
        let at = format!("v.toml:{}: ", case.line);
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

#[test]
fn a_device_without_a_port_is_refused_outside_sim_at_its_line() {
    let none = BASE.replace("port = \"/dev/ttyUSB0\"\n", "");
    let v = parse(&none, "v.toml").expect("a portless device loads, for --sim");
    let e = v.check_ports().unwrap_err().to_string();
    assert!(
        e.starts_with("v.toml:10: brake: port: expected the path of a serial port"),
        "{e}"
    );
    assert!(e.contains("--sim"), "{e}");
    let empty = BASE.replace("\"/dev/ttyUSB0\"", "\"\"");
    let e = parse(&empty, "v.toml").unwrap().check_ports().unwrap_err();
    assert!(e.to_string().starts_with("v.toml:13: brake: port:"), "{e}");
    assert!(parse(BASE, "v.toml").unwrap().check_ports().is_ok());
}

#[test]
fn the_console_s_status_period_goes_through_the_same_rule() {
    let d = &parse(BASE, "v.toml").unwrap().devices[0];
    let mut edited = d.clone();
    edited.status_period = Duration::from_millis(1500);
    let e = edited.check().unwrap_err();
    assert_eq!(e.paths[0], "status_max_age");
    assert!(e.message.contains("status_period 1500ms"), "{e}");
}

/// `[[devcie]]` made the `[device.modbus]` under it a duplicate of the one above, and
/// the error named that line, not the typo.
#[test]
fn a_misspelt_table_is_named_at_its_own_line_not_as_a_later_duplicate() {
    let typo = format!(
        "{BASE}\n[[devcie]]\nname = \"gas\"\ndriver = \"modbus\"\n[device.modbus]\nslave = 2\n"
    );
    let e = error(&typo);
    assert!(
        e.starts_with("v.toml:21: unknown table [[devcie]]: did you mean [[device]]?"),
        "{e}"
    );
    let e = error(&BASE.replace("[device.sim]", "[device.simm]"));
    assert!(
        e.starts_with("v.toml:18: unknown table [device.simm]: did you mean [device.sim]?"),
        "{e}"
    );
    let e = error(&format!("{BASE}[netwrok]\n"));
    assert!(e.starts_with("v.toml:20: unknown table [netwrok]"), "{e}");
}

#[test]
fn a_duplicate_key_is_named() {
    let e = error(&BASE.replace("# device", "baud = 9600\nbaud = 19200"));
    assert!(e.starts_with("v.toml:15: duplicate key `baud`"), "{e}");
}

#[test]
fn a_byte_that_is_not_utf8_names_its_line() {
    let mut bytes = BASE.as_bytes().to_vec();
    let at = BASE.find("# device").unwrap() + 2;
    bytes[at] = 0xff;
    let e = document::utf8(&bytes, "v.toml").unwrap_err().to_string();
    assert_eq!(
        e,
        "v.toml:14: byte 0xff at column 3 is not UTF-8: a vehicle file is UTF-8 text"
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
