//! The operator console: a Sparrow-style full-screen view of every device over the
//! running engine, built on the Elm architecture.
//!
//! - [`keymap`]: keys → [`Action`](keymap::Action)s per mode, from `keymaps/*.toml`;
//!   [`keymap::key_to_action`] is the pure key handler.
//! - [`model`]: the state; [`update`]: the only code that changes it, through the
//!   [`Controls`] trait (the engine, an attached console's
//!   adrive, a recording, or a fake in tests).
//! - [`view`] and [`panels`]: `impl Widget for &Model`, free of side effects;
//!   [`view::draw`] also says what the frame showed, and [`sight`] is the rule that no
//!   key acts on what the last frame did not show (STOP and quit always act);
//!   [`layout`]: where the devices go (a panel each, or with many devices a row each
//!   and a window of full panels that pages), for the view and for paging alike;
//!   [`names`]: a device by its name, for the name prompt; [`trail`]: the bench
//!   device's last seconds, for the bench chart.
//! - [`run`]: the loop — one biased `select!` over the terminal's input ([`input`]: keys,
//!   sizes and answers, read on their own thread), a 10 Hz tick and the exits channel
//!   (signals, panics). ratatui's diffing sends only changed cells; [`terminal`] never
//!   blocks on a terminal that stopped reading, leaves the terminal as it was on every
//!   way out, and turns a terminal that died (an SSH session dropping) into a hang-up.
//!   While the console commands, it proves its operator is there: the terminal answers
//!   a round trip every few hundred milliseconds ([`input::link`]), and the engine
//!   stops the vehicle when the answers stop.
//! - [`replay`]: the same console playing a recording, read-only.

pub(crate) mod hold;
pub(crate) mod input;
pub mod keymap;
pub(crate) mod layout;
pub mod model;
pub(crate) mod names;
pub(crate) mod panels;
pub mod replay;
pub(crate) mod sight;
pub(crate) mod terminal;
pub mod theme;
pub mod trail;
pub mod update;
pub mod view;

use crate::controls::{Controls, Live, Sources, TICK};
use crate::engine::Gate;
use crate::exit::Exit;
use crossbeam_channel::{select_biased, Receiver};
use input::link::{self, RoundTrips};
use input::probe::{self, Probe};
use input::{Input, Keyboard};
use keymap::Keymap;
use model::Model;
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use theme::Theme;
use update::Flow;

/// A loop turn longer than this is logged.
const TURN_BUDGET: Duration = Duration::from_millis(50);

/// How the console runs.
pub(crate) struct Options {
    pub keymap: Keymap,
    pub deadman: Duration,
    pub sources: Sources,
    /// Fault injection for tests (`--inject-panic main`): the console's loop panics
    /// this long after it starts, with the terminal in its hands.
    pub(crate) panic_after: Option<Duration>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            keymap: Keymap::default_map(),
            deadman: crate::config::limits::DEADMAN_DEFAULT,
            sources: Sources::default(),
            panic_after: None,
        }
    }
}

/// Run the console with the default keymap until the operator quits or an exit
/// arrives.
pub fn run(gate: &Arc<Gate>, exits: &Receiver<Exit>) -> std::io::Result<Exit> {
    run_with(gate, exits, Options::default())
}

/// Run the console until the operator quits (`q`, Ctrl-C) or an exit arrives. The
/// terminal is restored before this returns; a terminal that dies (it cannot be
/// drawn on, or its input hung up) ends the console with [`Exit::HangUp`], and the
/// caller brings the vehicle to the safe state as for SIGHUP.
pub(crate) fn run_with(
    gate: &Arc<Gate>,
    exits: &Receiver<Exit>,
    opts: Options,
) -> std::io::Result<Exit> {
    // A characterization from the bench runs beside the console, and ends with it.
    let characterize = crate::characterize::background::Background::new(gate.clone());
    let live = Live {
        gate,
        sources: &opts.sources,
        source: crate::value::Source::Console,
        characterize: Some(&characterize),
    };
    drive(&live, exits, opts.keymap, opts.deadman, opts.panic_after)
}

/// Start reading the terminal: under a terminal multiplexer on this machine, knowing
/// it reports presses only and that the liveness check cannot see past it; elsewhere
/// after asking whether it reports releases (console/input/probe.rs).
pub(crate) fn start_input(
    screen: &mut terminal::Screen,
    model: &mut Model,
    stop: Arc<AtomicBool>,
) -> std::io::Result<(Receiver<Input>, JoinHandle<()>)> {
    let mux = probe::multiplexer(|k| std::env::var(k).ok());
    model.terminal.multiplexer = mux;
    let now = Instant::now();
    let probe = match mux {
        Some(m) => {
            tracing::info!(
                "console: inside {m}, which answers for the terminal: keys are presses only, and the link to the operator is not checked"
            );
            Probe::known(Keyboard::PressesOnly, now)
        }
        None => {
            screen.send(probe::QUERY)?;
            Probe::sent(now)
        }
    };
    input::spawn(stop, probe)
}

/// The probe found what the terminal reports: where it reports releases, ask for them.
fn keyboard_found(screen: &mut terminal::Screen, model: &mut Model, k: Keyboard) {
    if model.terminal.keyboard != Some(k) {
        tracing::info!("console: the terminal reports {}", k.describe());
    }
    model.terminal.keyboard = Some(k);
    if k == Keyboard::Releases {
        if let Err(e) = screen.push_keyboard() {
            tracing::debug!("kitty keyboard flags not pushed: {e}");
        }
    }
}

/// What the console's loop handles in a turn.
enum Msg {
    Exit(Exit),
    Tick,
    Input(Input),
}

/// The next thing the loop handles: an exit first, then the terminal's input, then
/// time. Input comes before time: a key repeat read before a teleop hold's end is
/// handled before the tick that would end the hold for want of it — with a fair
/// choice, a turn late by an interval lost a held key's gas mid-hold.
fn next(exits: &Receiver<Exit>, events: &Receiver<Input>, ticker: &Receiver<Instant>) -> Msg {
    select_biased! {
        recv(exits) -> why => Msg::Exit(why.unwrap_or(Exit::Quit)),
        recv(events) -> input => Msg::Input(
            input.unwrap_or_else(|_| Input::Closed("input thread ended".into())),
        ),
        recv(ticker) -> _ => Msg::Tick,
    }
}

/// The console's loop over any [`Controls`]: the embedded engine ([`run_with`]) or
/// a running adrive's control socket (`adrive attach`).
pub fn drive(
    live: &dyn Controls,
    exits: &Receiver<Exit>,
    keymap: Keymap,
    deadman: Duration,
    panic_after: Option<Duration>,
) -> std::io::Result<Exit> {
    let mut model = Model::new(
        keymap,
        Theme::from_env(),
        live.scene(Instant::now(), None),
        deadman,
    );
    let mut screen = terminal::enter()?;
    let stop = Arc::new(AtomicBool::new(false));
    let (events, reader) = start_input(&mut screen, &mut model, stop.clone())?;
    let ticker = crossbeam_channel::tick(TICK);
    let started = Instant::now();
    let mut trips = RoundTrips::default();
    let why = loop {
        // Draw only once the terminal took the last frame: one that reads slowly, or
        // stopped reading, never blocks the loop (console/terminal.rs).
        let ready = match screen.ready() {
            Ok(r) => r,
            Err(e) => break Exit::HangUp(format!("cannot draw: {e}")),
        };
        if ready {
            // The size drawn at is the one the next key pages with, and what the frame
            // showed is what the next key may act on.
            let mut drawn = None;
            if let Err(e) = screen.terminal.draw(|f| {
                model.screen = f.area();
                drawn = Some(view::draw(&model, f.area(), f.buffer_mut()));
            }) {
                break Exit::HangUp(format!("cannot draw: {e}"));
            }
            model.drawn = drawn.unwrap_or_default();
            // The liveness check's request, after the frame it proves was read.
            // Asked while it commands, and while a characterization it started runs.
            let running = model.characterizing.as_ref().is_some_and(|c| c.running());
            if trips.due(model.snap.commands() || running, Instant::now()) {
                if let Err(e) = screen.send(link::ASK) {
                    break Exit::HangUp(format!("cannot write: {e}"));
                }
            }
        }
        let msg = next(exits, &events, &ticker);
        // Measure the turn from here: the wait is not work.
        let start = Instant::now();
        let flow = match msg {
            Msg::Exit(why) => Flow::Exit(why),
            Msg::Tick => {
                if panic_after.is_some_and(|d| started.elapsed() >= d) {
                    panic!("injected panic (--inject-panic main)");
                }
                update::tick(&mut model, live, start);
                Flow::Continue
            }
            Msg::Input(Input::Key(k, at)) => update::key(&mut model, &k, at, live, start),
            // A resize: the next draw adapts to the new size.
            Msg::Input(Input::Resize(..)) => Flow::Continue,
            Msg::Input(Input::Keyboard(k)) => {
                let before = model.drive();
                keyboard_found(&mut screen, &mut model, k);
                update::keyboard(&mut model, before, live, start);
                Flow::Continue
            }
            Msg::Input(Input::Answer(at)) => {
                if trips.answered() {
                    live.answered(at);
                }
                Flow::Continue
            }
            Msg::Input(Input::Closed(why)) => Flow::Exit(Exit::HangUp(format!("input: {why}"))),
        };
        let took = start.elapsed();
        if took > TURN_BUDGET {
            tracing::warn!("console: a loop turn took {} ms", took.as_millis());
        }
        if let Flow::Exit(why) = flow {
            break why;
        }
    };
    // A characterization under way ends first, the vehicle in its safe state, before
    // the terminal is given back.
    live.characterize_end(&format!("the console is stopping ({})", why.describe()));
    stop.store(true, Relaxed);
    drop(screen);
    let deadline = Instant::now() + 2 * TICK;
    while !reader.is_finished() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    Ok(why)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crossterm::event::{KeyCode, KeyEvent, KeyModifiers};

    /// A key read before the tick is handled before it, every time: a held key's repeat
    /// waiting behind a late turn keeps its hold.
    #[test]
    fn input_waiting_beside_a_tick_is_handled_first() {
        let (_exit_tx, exits) = crossbeam_channel::unbounded::<Exit>();
        let (key_tx, events) = crossbeam_channel::unbounded();
        let (tick_tx, ticker) = crossbeam_channel::unbounded();
        for _ in 0..200 {
            tick_tx.send(Instant::now()).unwrap();
            let k = KeyEvent::new(KeyCode::Up, KeyModifiers::NONE);
            key_tx.send(Input::Key(k, Instant::now())).unwrap();
            assert!(matches!(
                next(&exits, &events, &ticker),
                Msg::Input(Input::Key(..))
            ));
            assert!(matches!(next(&exits, &events, &ticker), Msg::Tick));
        }
    }
}
