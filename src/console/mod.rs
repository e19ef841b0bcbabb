//! The operator console: a Sparrow-style full-screen view of every device over the
//! running engine, built on the Elm architecture.
//!
//! - [`keymap`]: keys → [`Action`](keymap::Action)s per mode, from `keymaps/*.toml`;
//!   [`keymap::key_to_action`] is the pure key handler.
//! - [`model`]: the state; [`update`]: the only code that changes it, through the
//!   [`controls::Controls`] trait (the engine, or a fake in tests).
//! - [`view`] and [`panels`]: `impl Widget for &Model`, free of side effects;
//!   [`view::draw`] also says what the frame showed, and [`sight`] is the rule that no
//!   key acts on what the last frame did not show (STOP and quit always act);
//!   [`layout`]: where the devices go (a panel each, or with many devices a row each
//!   and a window of full panels that pages), for the view and for paging alike;
//!   [`find`]: a device by its name, for the name prompt; [`trail`]: the bench
//!   device's last seconds, for the bench chart.
//! - [`run`]: the loop — one `select!` over terminal events (read on their own
//!   thread), a 10 Hz tick and the exits channel (signals, panics). ratatui's diffing
//!   sends only changed cells; [`terminal`] leaves the terminal as it was on every way
//!   out, and turns a terminal that died (an SSH session dropping) into a hang-up.
//! - [`replay`]: the same console playing a recording, read-only.

pub mod controls;
pub mod find;
pub mod keymap;
pub mod layout;
pub mod model;
pub mod panels;
pub mod replay;
pub mod sight;
pub mod terminal;
pub mod theme;
pub mod trail;
pub mod update;
pub mod view;

use crate::engine::Gate;
use crate::exit::Exit;
use controls::{Controls, Live, Sources};
use crossbeam_channel::{select, Receiver};
use crossterm::event::{self, Event};
use keymap::Keymap;
use model::Model;
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use terminal::Keyboard;
use theme::Theme;
use update::Flow;

/// The console's refresh period.
pub(crate) const TICK: Duration = Duration::from_millis(100);
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
pub fn run(gate: &Gate, exits: &Receiver<Exit>) -> std::io::Result<Exit> {
    run_with(gate, exits, Options::default())
}

/// What the input thread delivers.
pub(crate) enum Input {
    Event(Event),
    /// The terminal is gone; the cause.
    Closed(String),
}

/// Read terminal events on a thread of their own until `stop`, so the loop can
/// `select!` over them. crossterm reads only bytes that [`Keyboard::wait`] saw
/// waiting; a terminal that hung up is reported once and the thread ends.
pub(crate) fn spawn_reader(
    stop: Arc<AtomicBool>,
) -> std::io::Result<(Receiver<Input>, JoinHandle<()>)> {
    let keyboard = Keyboard::open()?;
    let (tx, rx) = crossbeam_channel::bounded(256);
    let h = std::thread::Builder::new()
        .name("console/input".into())
        .spawn(move || {
            let closed = |why: String| {
                let _ = tx.send(Input::Closed(why));
            };
            while !stop.load(Relaxed) {
                match keyboard.wait(TICK) {
                    terminal::Input::Idle => continue,
                    terminal::Input::Closed(why) => return closed(why),
                    terminal::Input::Pending => {}
                }
                // Everything crossterm has parsed from the bytes waiting. Its event
                // source does not read at all with a zero timeout, hence the short one.
                loop {
                    match event::poll(terminal::DRAIN)
                        .and_then(|ready| ready.then(event::read).transpose())
                    {
                        Ok(Some(ev)) => {
                            if tx.send(Input::Event(ev)).is_err() {
                                return;
                            }
                        }
                        Ok(None) => break,
                        Err(e) => return closed(e.to_string()),
                    }
                }
            }
        })?;
    Ok((rx, h))
}

/// Run the console until the operator quits (`q`, Ctrl-C) or an exit arrives. The
/// terminal is restored before this returns; a terminal that dies (it cannot be
/// drawn on, or its input hung up) ends the console with [`Exit::HangUp`], and the
/// caller brings the vehicle to the safe state as for SIGHUP.
pub(crate) fn run_with(
    gate: &Gate,
    exits: &Receiver<Exit>,
    opts: Options,
) -> std::io::Result<Exit> {
    let live = Live {
        gate,
        sources: &opts.sources,
        source: crate::value::Source::Console,
    };
    drive(&live, exits, opts.keymap, opts.deadman, opts.panic_after)
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
        live.frame(Instant::now(), None),
        deadman,
    );
    let mut screen = terminal::enter()?;
    let stop = Arc::new(AtomicBool::new(false));
    let (events, reader) = spawn_reader(stop.clone())?;
    let ticker = crossbeam_channel::tick(TICK);
    let started = Instant::now();
    let why = loop {
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
        enum Msg {
            Exit(Exit),
            Tick,
            Event(Event),
            Gone(String),
        }
        let msg = select! {
            recv(exits) -> why => Msg::Exit(why.unwrap_or(Exit::Quit)),
            recv(ticker) -> _ => Msg::Tick,
            recv(events) -> input => match input {
                Ok(Input::Event(ev)) => Msg::Event(ev),
                Ok(Input::Closed(why)) => Msg::Gone(why),
                Err(_) => Msg::Gone("input thread ended".into()),
            },
        };
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
            Msg::Event(Event::Key(k)) => match sight::key(&model, &k) {
                Some(a) => update::update(&mut model, a, live, start),
                None => Flow::Continue,
            },
            // A resize: the next draw adapts to the new size.
            Msg::Event(_) => Flow::Continue,
            Msg::Gone(why) => Flow::Exit(Exit::HangUp(format!("input: {why}"))),
        };
        let took = start.elapsed();
        if took > TURN_BUDGET {
            tracing::warn!("console: a loop turn took {} ms", took.as_millis());
        }
        if let Flow::Exit(why) = flow {
            break why;
        }
    };
    stop.store(true, Relaxed);
    drop(screen);
    let deadline = Instant::now() + 2 * TICK;
    while !reader.is_finished() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    Ok(why)
}
