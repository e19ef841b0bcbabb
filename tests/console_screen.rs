//! The whole console screen rendered into a `TestBackend`: text snapshots at 80×24
//! and 120×40 (volatile figures masked), the styles that must be red, `NO_COLOR`, and
//! small terminals. The vehicle is the sample Alice, or the tractor of 32 devices
//! (`vehicles/tractor.toml`) for the screen with many devices, driven by keys through
//! the keymap: real structures, no threads.

use adrive::config::limits::DEADMAN_DEFAULT as DEADMAN;
use adrive::config::Role;
use adrive::console::keymap::{Action, Key, Keymap, Mode};
use adrive::console::model::{Field, Model};
use adrive::console::theme::Theme;
use adrive::console::update::{tick, update};
use adrive::controls::Live;
use adrive::controls::{capture, Sources};
use adrive::engine::Gate;
use adrive::logging::ring::LogRing;
use adrive::port::trace::Dir;
use adrive::testkit;
use adrive::vehicle::Vehicle;
use ratatui::backend::TestBackend;
use ratatui::buffer::Buffer;
use ratatui::style::{Color, Modifier};
use ratatui::Terminal;
use std::sync::Arc;
use std::time::{Duration, Instant};

struct Fixture {
    vehicle: Arc<Vehicle>,
    gate: Gate,
    sources: Sources,
    now: Instant,
}

fn fixture(faulty: bool) -> Fixture {
    fixture_with(|v, now| {
        if faulty {
            testkit::make_faulty(v, "steer", now);
        }
    })
}

fn fixture_with(setup: impl Fn(&Vehicle, Instant)) -> Fixture {
    fixture_of(adrive::config::VehicleConfig::alice(), setup)
}

/// The tractor: 32 devices of every kind with free names.
fn tractor(setup: impl Fn(&Vehicle, Instant)) -> Fixture {
    let config = adrive::config::load(std::path::Path::new("vehicles/tractor.toml"))
        .expect("vehicles/tractor.toml loads");
    assert_eq!(config.devices.len(), 32);
    fixture_of(config, setup)
}

fn fixture_of(config: adrive::config::VehicleConfig, setup: impl Fn(&Vehicle, Instant)) -> Fixture {
    let now = Instant::now();
    let vehicle = Arc::new(testkit::vehicle_of(config, now));
    setup(&vehicle, now);
    let logs = LogRing::default();
    logs.push(
        tracing::Level::WARN,
        "status: no reply within 200ms device=steer errors_in_a_row=3".into(),
    );
    Fixture {
        gate: Gate::new(vehicle.clone()),
        vehicle,
        sources: Sources {
            logs: Some(logs),
            ..Sources::default()
        },
        now,
    }
}

impl Fixture {
    fn model(&self, theme: Theme) -> Model {
        let snap = capture(&self.gate, &self.sources, self.now, None);
        let mut m = Model::new(Keymap::default_map(), theme, snap, DEADMAN);
        m.now = self.now;
        m
    }
    fn live(&self) -> Live<'_> {
        Live {
            source: adrive::value::Source::Console,
            gate: &self.gate,
            sources: &self.sources,
            characterize: None,
        }
    }
    fn act(&self, m: &mut Model, actions: &[Action]) {
        for a in actions {
            // As the console's loop: an action acts on what the frame before it showed.
            drawn(m);
            update(m, *a, &self.live(), self.now);
        }
        tick(m, &self.live(), self.now);
    }
    /// Press keys, written as in a keymap (`/`, `<PageDown>`, `<Enter>`), as the
    /// console's loop takes them (teleop's holds, then the model's keymap), on a screen
    /// of `w`×`h`; then render it.
    fn press(&self, m: &mut Model, keys: &[&str], (w, h): (u16, u16)) -> Buffer {
        m.screen = ratatui::layout::Rect::new(0, 0, w, h);
        for k in keys {
            let key: Key = k.parse().unwrap_or_else(|e| panic!("{k}: {e}"));
            let mut mods = crossterm::event::KeyModifiers::NONE;
            if key.ctrl {
                mods |= crossterm::event::KeyModifiers::CONTROL;
            }
            let ev = crossterm::event::KeyEvent::new(key.code, mods);
            drawn(m);
            adrive::console::update::key(m, &ev, self.now, &self.live(), self.now);
        }
        render(m, w, h)
    }
}

/// Draw `m` at its screen size, keeping what the frame showed (what the next key may
/// act on), as the console's loop does.
fn drawn(m: &mut Model) {
    let mut buf = Buffer::empty(m.screen);
    m.drawn = adrive::console::view::draw(m, m.screen, &mut buf);
}

/// Every key of a word, to type it.
fn typed(s: &str) -> Vec<String> {
    s.chars().map(String::from).collect()
}

fn render(m: &Model, w: u16, h: u16) -> Buffer {
    let mut t = Terminal::new(TestBackend::new(w, h)).unwrap();
    t.draw(|f| f.render_widget(m, f.area())).unwrap();
    t.backend().buffer().clone()
}

fn text(b: &Buffer) -> String {
    let a = b.area;
    (0..a.height)
        .map(|y| {
            let mut line = String::new();
            let mut x = 0;
            while x < a.width {
                let s = b[(x, y)].symbol();
                line.push_str(s);
                x += 1;
            }
            line.trim_end().to_string()
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// Snapshot with the figures that change from run to run masked.
fn snapshot(name: &str, screen: &str) {
    let mut s = insta::Settings::clone_current();
    // Log timestamps (seconds since start) and trace ages.
    s.add_filter(r"\d+\.\ds (WARN|ERROR)", "[secs] $1");
    s.add_filter(r"(->|<-)\s+\d+\.\d{3}s ago", "$1 [ago] ago");
    s.add_filter(r"-\s*\d+\.\d{3}s", "-[ago]");
    // Fault ages and recovery times (the supervisor reads its own clock).
    s.add_filter(r"\b\d+\.\ds\b", "[s]");
    s.bind(|| insta::assert_snapshot!(name, screen));
}

fn find(b: &Buffer, needle: &str) -> (u16, u16) {
    for y in 0..b.area.height {
        let row: Vec<&str> = (0..b.area.width).map(|x| b[(x, y)].symbol()).collect();
        let line: String = row.concat();
        if let Some(i) = line.find(needle) {
            // Columns, not bytes: count the symbols before the match.
            let col = line[..i].chars().count() as u16;
            return (col, y);
        }
    }
    panic!("{needle:?} not on screen:\n{}", text(b));
}

#[test]
fn main_screen_80x24() {
    let f = fixture(false);
    snapshot(
        "main_80x24",
        &text(&render(&f.model(Theme::default()), 80, 24)),
    );
}

#[test]
fn main_screen_120x40() {
    let f = fixture(false);
    snapshot(
        "main_120x40",
        &text(&render(&f.model(Theme::default()), 120, 40)),
    );
}

#[test]
fn main_screen_in_a_tmux_pane_of_80x23() {
    let f = fixture(false);
    let screen = text(&render(&f.model(Theme::default()), 80, 23));
    assert!(screen.contains("SUPERVISORY"), "{screen}");
    assert!(
        screen.lines().last().unwrap().contains("? help"),
        "{screen}"
    );
}

#[test]
fn help_is_generated_from_the_keymap() {
    let f = fixture(false);
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Help]);
    assert_eq!(m.mode, Mode::Help);
    let screen = text(&render(&m, 80, 24));
    snapshot("help_80x24", &screen);
    // A user binding shows up in help.
    let mut km = Keymap::default_map();
    km.merge(
        Keymap::parse(
            "[main]\nkeymap = [{ on = \"<F9>\", run = \"engage\", desc = \"engage now\" }]\n",
            "user.toml",
        )
        .unwrap(),
    );
    m.keymap = km;
    let b = render(&m, 120, 60);
    find(&b, "F9");
    find(&b, "engage now");
}

#[test]
fn bench_view_with_traffic() {
    let f = fixture(false);
    let d = f.vehicle.find("gas").unwrap();
    d.trace()
        .record(Dir::Out, &[0x01, 0x03, 0x00, 0x00, 0x00, 0x02]);
    d.trace().record(Dir::In, b"\x01\x03\x04OK\x00\x00");
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Right, Action::Bench]);
    assert_eq!(m.bench, d.id());
    let b = render(&m, 80, 24);
    snapshot("bench_80x24", &text(&b));
    find(&b, "01 03 00 00 00 02");
}

#[test]
fn teleop_shows_the_deadman() {
    let f = fixture(false);
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Engage, Action::Confirm, Action::Teleop]);
    let b = render(&m, 80, 24);
    find(&b, "DEADMAN idle");
    // A teleop key arms the deadman, the console's watchdog in the intake: `→` held
    // for a key repeat's delay (its terminal reports presses only: `repeat`).
    f.press(&mut m, &["<Right>"], (80, 24));
    // No key for longer than the deadman: the intake trips it (gas 0, brake full,
    // disengaged), and the console shows it reversed in red. Five seconds after the
    // fixture's readings, not after the clock reads now: the estimate's σ on the
    // screen grows with that time, and the test's own run time must not change it.
    // The console's terminal answered its round trips all along: only keys stopped.
    let later = f.now + Duration::from_secs(5);
    f.gate.answered(adrive::value::Source::Console, later);
    let why = f.gate.watch(later).expect("the deadman trips");
    assert!(
        matches!(why, adrive::safety::owner::Trip::Deadman { .. }),
        "{why}"
    );
    assert!(!f.gate.is_engaged());
    tick(&mut m, &f.live(), later);
    let b = render(&m, 80, 24);
    let (x, y) = find(&b, "DEADMAN TRIPPED");
    assert_eq!(b[(x, y)].fg, Color::Red);
    assert!(b[(x, y)].modifier.contains(Modifier::REVERSED));
    snapshot("teleop_tripped_80x24", &text(&b));
}

#[test]
fn a_faulty_device_is_red() {
    let f = fixture(true);
    let b = render(&f.model(Theme::default()), 80, 24);
    let (x, y) = find(&b, "STEER");
    assert_eq!(b[(x, y)].fg, Color::Red);
    let (x, y) = find(&b, "FAULT ");
    assert_eq!(b[(x, y)].fg, Color::Red);
    let (x, y) = find(&b, "1 FAULTY");
    assert_eq!(b[(x, y)].fg, Color::Red);
    let (x, y) = find(&b, "FAULT steer faulty: no reply");
    assert_eq!(b[(x, y)].fg, Color::Red);
    // A healthy device is not.
    let (x, y) = find(&b, "GAS");
    assert_ne!(b[(x, y)].fg, Color::Red);
    snapshot("fault_80x24", &text(&b));
}

#[test]
fn no_color_means_no_colour_anywhere() {
    let f = fixture(true);
    let mut m = f.model(Theme::no_color());
    for screen in [Vec::new(), vec![Action::Help]] {
        f.act(&mut m, &screen);
        let b = render(&m, 120, 40);
        for c in b.content() {
            assert_eq!((c.fg, c.bg), (Color::Reset, Color::Reset), "{c:?}");
        }
        f.act(&mut m, &[Action::Back]);
    }
    // Faults still stand out, by modifiers.
    let b = render(&m, 80, 24);
    let (x, y) = find(&b, "STEER");
    assert!(b[(x, y)].modifier.contains(Modifier::REVERSED));
}

#[test]
fn a_bad_value_is_shown_inline_in_red() {
    let f = fixture(false);
    let mut m = f.model(Theme::default());
    f.act(
        &mut m,
        &[
            Action::EditOf(adrive::console::keymap::Target::Device(Role::Throttle)),
            Action::Input('7'),
            Action::Commit,
        ],
    );
    let b = render(&m, 80, 24);
    let (x, y) = find(&b, "gas command: 7 is out of range");
    assert_eq!(b[(x, y)].fg, Color::Red);
    let (x, y) = find(&b, "7▏");
    assert_eq!(b[(x, y)].fg, Color::Red);
}

#[test]
fn a_small_terminal_gets_a_message_not_a_crash() {
    let f = fixture(false);
    let m = f.model(Theme::default());
    let screen = text(&render(&m, 60, 20));
    assert!(
        screen.contains("at least 80×22") && screen.contains("60×20"),
        "{screen}"
    );
    for (w, h) in [(1, 1), (0, 0), (79, 40), (200, 21), (10, 3)] {
        render(&m, w, h);
    }
}

#[test]
fn a_recovery_in_progress_and_the_faults_at_80x24() {
    let f = fixture_with(testkit::make_recovering);
    let b = render(&f.model(Theme::default()), 80, 24);
    let screen = text(&b);
    snapshot("recovery_80x24", &screen);
    // The procedure on one line: name, step n/N, its name, the try.
    find(&b, "RECOVERY engine_stall 4/7 park (try 1/3)");
    find(&b, "then starter › back in drive");
    // Every fault with kind, cause and age, in red, cause included.
    for needle in [
        "FAULT engine_stall",
        "engine stopped (0 rpm) in drive",
        "FAULT brake silent",
        "no status for 1700 ms",
    ] {
        let (x, y) = find(&b, needle);
        assert_eq!(b[(x, y)].fg, Color::Red, "{needle}");
    }
    // The compact line counts them, and the brake's panel is red.
    let (x, y) = find(&b, "faults 2");
    assert_eq!(b[(x + 7, y)].fg, Color::Red);
    let (x, y) = find(&b, "BRAKE");
    assert_eq!(b[(x, y)].fg, Color::Red);
    // The hint bar is still there.
    assert!(
        screen.lines().last().unwrap().contains("? help"),
        "{screen}"
    );
}

#[test]
fn a_recovery_in_progress_and_the_faults_at_120x40() {
    let f = fixture_with(testkit::make_recovering);
    let b = render(&f.model(Theme::default()), 120, 40);
    snapshot("recovery_120x40", &text(&b));
    // Each step shown, the current one highlighted.
    find(&b, "✓ gas off");
    let (x, y) = find(&b, "▶ park");
    assert!(b[(x, y)].modifier.contains(Modifier::REVERSED));
    find(&b, "· release");
    find(&b, "step 4/7  try 1/3");
    let (x, y) = find(&b, "fault engine_stall");
    assert_eq!(b[(x, y)].fg, Color::Red);
    let (x, y) = find(&b, "fault brake silent");
    assert_eq!(b[(x, y)].fg, Color::Red);
    find(&b, "last recovery steering done in 0.9 s");
}

#[test]
fn the_bench_under_sim_shows_the_devices_faults_and_the_fault_keys() {
    use adrive::controls::SimFaults;
    let f = fixture(false);
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Bench]);
    // What a --sim run captures (the fixture has no simulator).
    m.snap.can_inject = true;
    m.snap.sim_vehicle = Some("e-stop run · engine running · steer drive ok".into());
    let n = m.snap.devices.len();
    m.snap.sim_faults = vec![
        Some(SimFaults {
            text: "none".into(),
            ..SimFaults::default()
        });
        n
    ];
    m.snap.sim_faults[0] = Some(SimFaults {
        silent: true,
        slow_ms: 150,
        text: "silent, slow 150ms".into(),
        ..SimFaults::default()
    });
    let b = render(&m, 80, 24);
    snapshot("bench_sim_80x24", &text(&b));
    let (x, y) = find(&b, "faults silent, slow 150ms");
    assert_eq!(b[(x + 7, y)].fg, Color::Red);
    find(&b, "e-stop run · engine running");
    // The legend comes from the keymap.
    for needle in [
        "s silent",
        "v vanish for 2s",
        "K engine stall",
        "p e-stop pause",
        "r e-stop run",
    ] {
        find(&b, needle);
    }
    find(
        &b,
        "steer raw traffic: dir, time ago, hex, text — sim: silent, slow 150ms",
    );
}

#[test]
fn the_bench_shows_the_supervisors_strip_too() {
    let f = fixture_with(testkit::make_recovering);
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Bench]);
    let b = render(&m, 80, 24);
    find(&b, "RECOVERY engine_stall 4/7 park");
    let (x, y) = find(&b, "FAULT engine_stall");
    assert_eq!(b[(x, y)].fg, Color::Red);
    find(&b, "steer raw traffic");
}

/// On the bench at 100 columns, the gas silenced, the header once ended `DISENGAGED
/// (gas is faulty (no reply within 100ms)`: cut mid-reason, a parenthesis left open;
/// then `(gas is faulty (no reply…))`, shortened beside `ADRIVE` and `interlocks on`.
/// The labels of the normal state give way and the reason is whole (where nothing is
/// left to give way it is shortened at a word, its parentheses closed: the header's
/// unit tests, at every width).
#[test]
fn the_header_at_100_columns_gives_the_reason_whole() {
    let f = fixture_with(|v, now| testkit::make_faulty(v, "gas", now));
    f.gate.disengage(adrive::snapshot::DisengageCause::Blocked {
        blocker: adrive::snapshot::Blocker::Faulty {
            device: "gas".into(),
            fault: "no reply within 100ms".into(),
        },
    });
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Bench]);
    let b = render(&m, 100, 30);
    let screen = text(&b);
    let header = screen.lines().next().unwrap();
    assert!(
        header.contains("│ DISENGAGED (gas is faulty (no reply within 100ms))"),
        "{header}"
    );
}

/// The device under the cursor.
fn under_cursor(m: &Model) -> String {
    m.snap.devices[m.cursor_device()].name.clone()
}

/// The screen's line `y`.
fn line(b: &Buffer, y: u16) -> String {
    (0..b.area.width).map(|x| b[(x, y)].symbol()).collect()
}

#[test]
fn thirty_two_devices_at_80x24_each_have_a_row_and_faulty_ones_are_red() {
    let f = tractor(|v, now| {
        testkit::make_faulty(v, "hitch", now);
        testkit::make_faulty(v, "gnss", now);
    });
    let m = f.model(Theme::default());
    let b = render(&m, 80, 24);
    let screen = text(&b);
    snapshot("many_80x24", &screen);
    // A row for every device: its name whole at the start of a column, then its
    // values, a state whole (the delay's column gave way: it read `parking_br…
    // relea…`).
    for d in &m.snap.devices {
        let shown = format!("{} ", d.name);
        let rows = (2..18).flat_map(|y| [(0, y), (40, y)]).filter(|&(x, y)| {
            let row: String = line(&b, y).chars().skip(x).collect();
            row.starts_with(&shown)
        });
        assert_eq!(rows.count(), 1, "{} has no row:\n{screen}", d.name);
    }
    find(&b, "parking_brake        - released");
    // Faulty rows are red from the name to the error code; a healthy one is not.
    for name in ["hitch ", "gnss "] {
        let (x, y) = find(&b, name);
        for dx in [0, 12, 30, 38] {
            assert_eq!(b[(x + dx, y)].fg, Color::Red, "{name} at +{dx}");
        }
        assert_eq!(b[(x + 38, y)].symbol(), "1", "{name}'s error code");
    }
    let (x, y) = find(&b, "throttle");
    assert_ne!(b[(x, y)].fg, Color::Red);
    // The cursor's device in full under the list, and the name prompt's key hinted.
    find(&b, "STEER -1…1 cmd - meas 0.231  st delay 50ms");
    assert!(
        screen.lines().last().unwrap().contains("/ find device"),
        "{screen}"
    );
}

#[test]
fn page_down_and_up_turn_the_page_of_full_panels() {
    let f = tractor(|_, _| {});
    let mut m = f.model(Theme::default());
    // 100×40: the list, then three rows of two panels.
    let b = f.press(&mut m, &[], (100, 40));
    find(&b, "STEER -1…1");
    find(&b, "ESTOP  run");
    assert!(!text(&b).contains("ENGINE "), "{}", text(&b));
    let b = f.press(&mut m, &["<PageDown>"], (100, 40));
    assert_eq!(under_cursor(&m), "engine");
    find(&b, "ENGINE  700 rpm");
    find(&b, "VALVE1 -1…1");
    assert!(!text(&b).contains("STEER -1…1"));
    // The cursor keeps to its kind of field: the engine's st delay, then the same
    // field of the devices a page on.
    let b = f.press(&mut m, &["<PageDown>", "<PageDown>"], (100, 40));
    assert_eq!(under_cursor(&m), "work_lights");
    let (x, y) = find(&b, "WORK_LIGHTS");
    assert_eq!(find(&b, "st delay 100ms"), (x, y + 1));
    assert!(b[(x + 9, y + 1)].modifier.contains(Modifier::REVERSED));
    let b = f.press(&mut m, &["<PageUp>"], (100, 40));
    assert_eq!(under_cursor(&m), "valve2");
    find(&b, "VALVE2 -1…1");
    // Far enough down, the last field (accel, the last device's page); up again,
    // the first device.
    let b = f.press(&mut m, &["<PageDown>"; 9], (100, 40));
    assert_eq!(m.field(), Field::Accel);
    find(&b, "TYRE_PRESSURE");
    let b = f.press(&mut m, &["<PageUp>"; 9], (100, 40));
    assert_eq!(m.field(), Field::StDelay(m.snap.id_of("steer").unwrap()));
    find(&b, "STEER -1…1");
}

#[test]
fn the_cursor_moving_off_the_page_turns_it() {
    let f = tractor(|_, _| {});
    let mut m = f.model(Theme::default());
    // 80×24: the window holds the cursor's device alone, packed.
    let b = f.press(&mut m, &["l"], (80, 24));
    assert_eq!(under_cursor(&m), "throttle");
    find(&b, "THROTTLE 0…1");
    // Down through the throttle's fields (command, st delay, cm delay, status,
    // command thread), then onto the brake's command.
    let b = f.press(&mut m, &["j"; 4], (80, 24));
    assert_eq!(
        m.field(),
        Field::CommandOn(m.snap.id_of("throttle").unwrap())
    );
    let (x, y) = find(&b, "command 1");
    assert!(
        b[(x + 8, y)].modifier.contains(Modifier::REVERSED),
        "{}",
        text(&b)
    );
    let b = f.press(&mut m, &["j"], (80, 24));
    assert_eq!(under_cursor(&m), "brake");
    find(&b, "BRAKE 0…1");
    assert!(!text(&b).contains("THROTTLE 0…1"));
    // On a taller screen the same move turns a page of six.
    let b = f.press(&mut m, &["l", "l", "l", "l"], (100, 40));
    assert_eq!(under_cursor(&m), "engine");
    find(&b, "ENGINE  700 rpm");
    assert!(!text(&b).contains("BRAKE 0…1"));
}

#[test]
fn slash_jumps_to_a_device_by_its_name() {
    let f = tractor(|_, _| {});
    let mut m = f.model(Theme::default());
    // Each key moves the cursor to the best match at once.
    let b = f.press(&mut m, &["/", "h"], (80, 24));
    assert_eq!(m.mode, Mode::Find);
    assert_eq!(under_cursor(&m), "hitch");
    find(&b, "/h▏  hitch 2 of 9");
    // The names it matches are marked in the list.
    let (x, y) = find(&b, "headlights");
    assert!(b[(x, y)].modifier.contains(Modifier::UNDERLINED));
    let (x, y) = find(&b, "brake");
    assert!(!b[(x, y)].modifier.contains(Modifier::UNDERLINED));
    let keys = typed("itch_");
    let keys: Vec<&str> = keys.iter().map(String::as_str).collect();
    let b = f.press(&mut m, &keys, (80, 24));
    assert_eq!(under_cursor(&m), "hitch_load");
    find(&b, "HITCH_LOAD  3.200 kN");
    // Enter keeps it; the panel stays.
    let b = f.press(&mut m, &["<Enter>"], (80, 24));
    assert_eq!(m.mode, Mode::Main);
    assert_eq!(under_cursor(&m), "hitch_load");
    find(&b, "HITCH_LOAD");
    // n and N: the next and previous device matching the same name.
    f.press(&mut m, &["N"], (80, 24));
    assert_eq!(under_cursor(&m), "hitch_load", "the only match");
    // Esc goes back to where the prompt was opened.
    f.press(&mut m, &["/", "w", "i"], (80, 24));
    assert_eq!(under_cursor(&m), "wiper");
    f.press(&mut m, &["<Esc>"], (80, 24));
    assert_eq!(
        (m.mode, under_cursor(&m).as_str()),
        (Mode::Main, "hitch_load")
    );
    // Something that matches nothing is said, in red, and the cursor stays.
    let b = f.press(&mut m, &["/", "x", "y"], (80, 24));
    let (x, y) = find(&b, "no device matches \"xy\"");
    assert_eq!(b[(x, y)].fg, Color::Red);
    assert_eq!(under_cursor(&m), "hitch_load");
    f.press(&mut m, &["<Esc>"], (80, 24));
}

#[test]
fn the_name_prompt_completes_walks_its_matches_and_stops_on_space() {
    let f = tractor(|_, _| {});
    let mut m = f.model(Theme::default());
    // Tab completes to what the matches share: hitch and hitch_load.
    let b = f.press(&mut m, &["/", "h", "i", "<Tab>"], (80, 24));
    assert_eq!(m.find.as_ref().unwrap().query, "hitch");
    find(&b, "/hitch▏");
    // Down and up walk the matches in the vehicle's order.
    f.press(&mut m, &["<Down>"], (80, 24));
    assert_eq!(under_cursor(&m), "hitch_load");
    f.press(&mut m, &["<Down>"], (80, 24));
    assert_eq!(under_cursor(&m), "hitch", "wraps around");
    f.press(&mut m, &["<Up>"], (80, 24));
    assert_eq!(under_cursor(&m), "hitch_load");
    // A name that only contains what is typed matches after those starting with it.
    f.press(&mut m, &["<C-u>", "b", "r", "a", "k", "e"], (80, 24));
    assert_eq!(under_cursor(&m), "brake");
    f.press(&mut m, &["<Down>"], (80, 24));
    assert_eq!(under_cursor(&m), "parking_brake");
    // Space is STOP here too: the prompt is dropped, the vehicle disengaged.
    let b = f.press(&mut m, &["<Space>"], (80, 24));
    assert_eq!((m.mode, m.find.as_ref()), (Mode::Main, None));
    find(&b, "STOP: disengaged");
    let gate = f.gate.snapshot_at(0, f.now).gate;
    assert_eq!(
        gate.cause,
        adrive::snapshot::GateCause::Disengaged {
            why: adrive::snapshot::DisengageCause::Stop {
                by: "console".into()
            }
        },
        "{}",
        gate.reason
    );
}

#[test]
fn the_bench_jumps_by_name_too() {
    let f = tractor(|_, _| {});
    let mut m = f.model(Theme::default());
    let keys = typed("/cabin");
    let mut keys: Vec<&str> = keys.iter().map(String::as_str).collect();
    keys.insert(0, "x");
    keys.push("<Enter>");
    let b = f.press(&mut m, &keys, (80, 24));
    assert_eq!(m.mode, Mode::Bench);
    assert_eq!(m.snap.devices[m.bench.index()].name, "cabin");
    find(&b, "CABIN");
}

/// 64 devices do not all have a row at 80×24: the list pages too, saying which rows
/// it shows, and follows the cursor.
#[test]
fn a_list_longer_than_the_screen_pages_with_the_cursor() {
    let mut toml = String::from("[vehicle]\nname = \"sixty-four\"\n");
    for i in 0..64 {
        toml.push_str(&format!(
            "[[device]]\nname = \"valve{i:02}\"\nkind = \"setpoint\"\nrange = [0.0, 1.0]\ndriver = \"line\"\n"
        ));
    }
    let config = adrive::config::parse(&toml, "sixty-four.toml").unwrap();
    let f = fixture_of(config, |_, _| {});
    let mut m = f.model(Theme::default());
    let b = f.press(&mut m, &[], (80, 24));
    let screen = text(&b);
    assert!(screen.contains("1–34/64"), "{screen}");
    find(&b, "valve33 ");
    assert!(!screen.contains("valve34 "), "{screen}");
    let b = f.press(&mut m, &["/", "5", "0"], (80, 24));
    assert_eq!(under_cursor(&m), "valve50");
    let screen = text(&b);
    assert!(screen.contains("35–64/64"), "{screen}");
    find(&b, "valve63 ");
    assert!(!screen.contains("valve00 "), "{screen}");
}

/// The bench chart: the gas commanded from 0 to 0.6 five seconds ago, the drive
/// following it at its rate and the estimate tracking the readings, over the last 10 s.
#[test]
fn the_bench_charts_measured_estimate_and_command_through_a_step() {
    use adrive::snapshot::EstimateView;
    use adrive::value::Value;
    let f = fixture(false);
    let gas = f.vehicle.find("gas").unwrap().id();
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Right, Action::Bench]);
    assert_eq!(m.bench, gas);
    // What ten seconds of ticks would have fed it, a sample each 100 ms.
    m.trail = adrive::console::trail::Trail::default();
    let mut d = m.snap.at(gas).unwrap().clone();
    for k in 0..=100u32 {
        let t = k as f64 / 10.0;
        let cmd = if t < 5.0 { 0.0 } else { 0.6 };
        let at = (if t < 5.0 { 0.0 } else { (t - 5.0) * 0.4 }).min(0.6);
        let est = (if t < 5.2 { 0.0 } else { (t - 5.2) * 0.4 }).min(0.6);
        d.commanded = Some(Value::Number(cmd));
        for (name, v) in &mut d.readings.0 {
            if name == "position" {
                *v = Some(Value::Number(at));
            }
        }
        d.estimate = Some(EstimateView {
            position: est,
            ..EstimateView::default()
        });
        m.trail.push(
            gas,
            &d,
            f.now - Duration::from_millis(10_000 - 100 * k as u64),
        );
    }
    let b = render(&m, 120, 40);
    snapshot("bench_chart_step_120x40", &text(&b));
    for needle in [
        "gas over the last 10 s",
        "measured",
        "estimate",
        "command",
        "now",
    ] {
        find(&b, needle);
    }
    // At 80×24 the chart gives way: the bench keeps every line it had.
    let small = text(&render(&m, 80, 24));
    assert!(!small.contains("over the last 10 s"), "{small}");
    assert!(small.contains("gas raw traffic"), "{small}");
}

/// The incident: a vehicle file naming a port that does not exist showed, at 100
/// columns, a FAULT line cut off in the middle of the path. A fault's cause too long
/// for the line goes on over the next, between words: the path is read whole, in red.
#[test]
fn a_long_fault_cause_wraps_and_keeps_the_path_whole() {
    const PATH: &str = "/dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A50285BI-if00-port0";
    let f = fixture_with(|v, now| {
        v.supervision()
            .set_faults(vec![adrive::vehicle::supervision::Fault {
                kind: adrive::snapshot::FaultKind::Disconnected,
                device: Some("steer".into()),
                cause: format!("cannot open {PATH}: No such file or directory"),
                since: now,
            }]);
    });
    let b = render(&f.model(Theme::default()), 100, 30);
    let screen = text(&b);
    assert!(screen.contains("FAULT steer disconnected"), "{screen}");
    let (x, y) = find(&b, PATH);
    assert_eq!(b[(x, y)].fg, Color::Red, "{screen}");
    assert!(
        screen.contains("No such file or directory"),
        "the OS error too:\n{screen}"
    );
}

/// OSCC (`vehicles/oscc.toml`): kit modules on a CAN bus that report no position.
fn oscc(setup: impl Fn(&Vehicle, Instant)) -> Fixture {
    let config = adrive::config::load(std::path::Path::new("vehicles/oscc.toml"))
        .expect("vehicles/oscc.toml loads");
    fixture_of(config, setup)
}

/// The bus up (on a pseudo-terminal), a few frames on it, the brake reporting its
/// operator-override fault code.
fn busy_kit(v: &Vehicle, now: Instant) {
    use adrive::can::{Frame, Id};
    let bus = &v.buses()[0];
    let (port, _other) = serialport::TTYPort::pair().expect("a pseudo-terminal pair");
    bus.up(Box::new(port));
    let dbc = bus.config().dbc.clone();
    let frame =
        |name: &str, values: &[(&str, f64)]| dbc.message(name).unwrap().encode(values).unwrap();
    let ago = |ms| now - Duration::from_millis(ms);
    let report = frame("STEERING_REPORT", &[("enabled", 1.0)]);
    for _ in 0..3 {
        bus.note(&report, ago(12), false);
    }
    bus.note(
        &frame("STEERING_COMMAND", &[("torque_command", 0.25)]),
        ago(1),
        true,
    );
    bus.note(&frame("BRAKE_REPORT", &[("dtcs", 2.0)]), ago(5), false);
    bus.note(
        &Frame::new(Id::Standard(0x123), &[1, 2, 0xAB]).unwrap(),
        ago(40),
        false,
    );
    let brake = v.find("brake").unwrap();
    let mut c = brake.cached();
    c.reading.fault = 2;
    brake.store(c);
}

/// A kit's steering reports whether it is enabled and overridden, and no position: its
/// panel shows the command and those flags, not a `meas` that would be its `enabled`
/// flag; the brake's fault code by its DBC name, in red.
#[test]
fn can_kit_modules_on_the_main_screen_show_their_flags_and_fault_names() {
    let f = oscc(busy_kit);
    let b = render(&f.model(Theme::default()), 80, 24);
    let screen = text(&b);
    snapshot("oscc_main_80x24", &screen);
    let (_, y) = find(&b, "STEER");
    let title = line(&b, y);
    assert!(title.contains("STEER -1…1 cmd -"), "{title}");
    assert!(!title.contains("meas"), "{title}");
    find(&b, "enabled 0  override 0");
    let (x, y) = find(&b, "OPERATOR_OVERRIDE");
    assert_eq!(b[(x, y)].fg, Color::Red);
}

/// The bench of a module on a bus: every identifier's last frame decoded by the DBC,
/// sorted by identifier, adrive's own marked `->`, an unknown one by its bytes.
#[test]
fn the_bench_of_a_can_module_shows_its_bus_decoded_like_cantools_monitor() {
    let f = oscc(busy_kit);
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Bench]);
    assert_eq!(under_cursor(&m), "steer");
    for (w, h) in [(80, 24), (100, 30)] {
        let b = render(&m, w, h);
        let screen = text(&b);
        snapshot(&format!("oscc_bench_{w}x{h}"), &screen);
        find(&b, "bus kit: last frame of each id");
        find(&b, "up  500 kbit/s");
        let at = |needle: &str| find(&b, needle).1;
        let rows = [
            at("<- 0x073 BRAKE_REPORT"),
            at("-> 0x082 STEERING_COMMAND"),
            at("<- 0x083 STEERING_REPORT"),
        ];
        assert!(
            rows.windows(2).all(|r| r[0] < r[1]),
            "by identifier:\n{screen}"
        );
        let report = line(&b, rows[2]);
        assert!(report.contains("enabled: ENABLED"), "{report}");
        if w == 100 {
            find(&b, "operator_override: NONE  dtcs: 0  age 12ms ×3");
            find(&b, "torque_command: 0.25  age 1ms ×1");
            find(&b, "dtcs: OPERATOR_OVERRIDE");
            find(&b, "<- 0x123 (unknown)  01 02 AB  age 40ms ×1");
        }
    }
}

/// Under `--sim` without a simulated adapter, or with the adapter unplugged: the bench
/// says the bus is down and why, in red.
#[test]
fn the_bench_of_a_can_module_says_why_its_bus_is_down() {
    let f = oscc(|v, _| {
        v.buses()[0].go_down("cannot open /dev/ttyACM0: No such file or directory".into())
    });
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Bench]);
    let b = render(&m, 80, 24);
    let (x, y) = find(&b, "DOWN: cannot open /dev/ttyACM0");
    assert_eq!(b[(x, y)].fg, Color::Red);
    find(&b, "no frames yet");
}

/// Under `--sim` at 100×30 (the simulator box takes four rows), the bus of a kit with
/// six identifiers showed three and "… 3 more identifiers" above the device's own
/// traffic box, which said only "no traffic yet". The bus comes first: the traffic
/// keeps its rows only where every identifier keeps its line.
#[test]
fn the_bus_takes_the_traffics_rows_before_it_hides_an_identifier() {
    let reports = |n: usize| {
        move |v: &Vehicle, now: Instant| {
            let bus = &v.buses()[0];
            let dbc = bus.config().dbc.clone();
            for m in dbc
                .messages()
                .iter()
                .filter(|m| m.name().contains("REPORT"))
                .take(n)
            {
                bus.note(&m.encode(&[]).unwrap(), now, false);
            }
            for i in 0..n.saturating_sub(4) {
                let f = adrive::can::Frame::new(adrive::can::Id::Standard(0x300 + i as u16), &[1]);
                bus.note(&f.unwrap(), now, false);
            }
        }
    };
    for (n, traffic) in [(2, true), (6, false)] {
        let f = oscc(reports(n));
        let mut m = f.model(Theme::default());
        f.act(&mut m, &[Action::Bench]);
        m.snap.can_inject = true;
        let b = render(&m, 100, 30);
        let screen = text(&b);
        assert_eq!(
            screen.contains("steer raw traffic"),
            traffic,
            "{n} ids:\n{screen}"
        );
        assert!(!screen.contains("more identifiers"), "{n} ids:\n{screen}");
        let shown = screen.matches("<- 0x").count();
        assert_eq!(shown, n, "{n} ids:\n{screen}");
    }
}
