//! The whole console screen rendered into a `TestBackend`: text snapshots at 80×24
//! and 120×40 (volatile figures masked), the styles that must be red, `NO_COLOR`, and
//! small terminals. The vehicle is the sample Alice: real structures, no threads.

use adrive::config::Role;
use adrive::console::controls::Live;
use adrive::console::controls::{capture, Sources};
use adrive::console::keymap::{Action, Keymap, Mode};
use adrive::console::logring::LogRing;
use adrive::console::model::{Model, DEADMAN};
use adrive::console::sample;
use adrive::console::theme::Theme;
use adrive::console::update::{tick, update};
use adrive::safety::Gate;
use adrive::vehicle::trace::Dir;
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
            sample::make_faulty(v, "steer", now);
        }
    })
}

fn fixture_with(setup: impl Fn(&Vehicle, Instant)) -> Fixture {
    let now = Instant::now();
    let vehicle = Arc::new(sample::vehicle(now));
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
            gate: &self.gate,
            sources: &self.sources,
        }
    }
    fn act(&self, m: &mut Model, actions: &[Action]) {
        for a in actions {
            update(m, *a, &self.live(), self.now);
        }
        tick(m, &self.live(), self.now);
    }
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
    d.trace
        .record(Dir::Out, &[0x01, 0x03, 0x00, 0x00, 0x00, 0x02]);
    d.trace.record(Dir::In, b"\x01\x03\x04OK\x00\x00");
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Right, Action::Bench]);
    assert_eq!(m.bench, d.id);
    let b = render(&m, 80, 24);
    snapshot("bench_80x24", &text(&b));
    find(&b, "01 03 00 00 00 02");
}

#[test]
fn teleop_shows_the_deadman() {
    let f = fixture(false);
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Teleop]);
    let b = render(&m, 80, 24);
    find(&b, "DEADMAN idle");
    f.act(&mut m, &[Action::SteerRight]);
    // Tripped: gas 0, brake full, shown reversed in red.
    m.teleop.last_key = Some(f.now - Duration::from_secs(5));
    tick(&mut m, &f.live(), f.now);
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
    let f = fixture_with(sample::make_recovering);
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
    let f = fixture_with(sample::make_recovering);
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
    use adrive::console::controls::SimFaults;
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
    find(&b, "steer raw traffic — sim: silent, slow 150ms");
}

#[test]
fn the_bench_shows_the_supervisors_strip_too() {
    let f = fixture_with(sample::make_recovering);
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Bench]);
    let b = render(&m, 80, 24);
    find(&b, "RECOVERY engine_stall 4/7 park");
    let (x, y) = find(&b, "FAULT engine_stall");
    assert_eq!(b[(x, y)].fg, Color::Red);
    find(&b, "steer raw traffic");
}

/// On the bench at 100 columns, the gas silenced, the header once ended `DISENGAGED
/// (gas is faulty (no reply within 100ms)`: cut mid-reason, a parenthesis left open.
/// The reason is shortened at a word instead, with "…" and its parentheses closed.
#[test]
fn the_header_at_100_columns_shortens_the_reason_and_closes_it() {
    let f = fixture_with(|v, now| sample::make_faulty(v, "gas", now));
    f.gate.disengage("gas is faulty (no reply within 100ms)");
    let mut m = f.model(Theme::default());
    f.act(&mut m, &[Action::Bench]);
    let b = render(&m, 100, 30);
    let screen = text(&b);
    let header = screen.lines().next().unwrap();
    assert!(
        header.contains("│ DISENGAGED (gas is faulty (no reply"),
        "{header}"
    );
    assert!(header.ends_with("…))"), "{header}");
}
