//! `adrive fleet --pick`: the fleet in the console, live — a row per vehicle as `adrive
//! fleet` lists it (there or gone, engaged or not and why, who commands, its faults,
//! the age of its state and the round trip to it) — to pick one from: ↑/↓ (or k/j)
//! choose, Enter attaches the console to it over the fleet, as `adrive attach
//! --vehicle ID` does (with the key given, commanding where the vehicle allows it),
//! and quitting that console comes back to the list; `q` or Esc leaves.

use super::dial::Dialer;
use super::list::{cells, Watching, HEAD};
use crate::console::input::probe::Probe;
use crate::console::input::{self, Input, Keyboard};
use crate::console::keymap::Keymap;
use crate::console::terminal;
use crate::exit::Exit;
use crate::net::auth::Auth;
use crossbeam_channel::{select, Receiver};
use crossterm::event::{KeyCode, KeyEventKind};
use ratatui::layout::{Constraint, Layout};
use ratatui::style::{Modifier, Style};
use ratatui::text::Line;
use ratatui::widgets::{Block, Paragraph, Row, Table};
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How often the list is drawn again.
const REDRAW: Duration = Duration::from_millis(250);

/// What the picker was given.
pub(crate) struct Options {
    pub connect: Vec<String>,
    pub key: Option<Auth>,
    /// The key's file, for the list's header.
    pub key_file: Option<String>,
    pub keymap: Keymap,
    pub deadman: Duration,
}

/// What the operator did in the list.
enum Picked {
    Vehicle(String),
    Leave(Exit),
}

/// Run the picker until the operator leaves; why.
pub(crate) fn run(opts: &Options, exits: &Receiver<Exit>) -> anyhow::Result<Exit> {
    let mut fleet = Watching::start(&opts.connect)?;
    fleet.ping_every()?;
    let mut chosen = 0;
    let mut note = String::new();
    let why = loop {
        match pick(&mut fleet, &mut chosen, &note, opts, exits)? {
            Picked::Leave(why) => break why,
            Picked::Vehicle(id) => {
                let dial = Arc::new(Dialer {
                    connect: opts.connect.clone(),
                    id: id.clone(),
                    key: opts.key.clone(),
                    links: parking_lot::Mutex::default(),
                });
                // The console's connection ending says so while it runs, not after: a
                // console left is not a link lost for the next one.
                let running = Arc::new(AtomicBool::new(true));
                let r = running.clone();
                let remote = match crate::socket::client::Remote::attach(dial.clone(), move |why| {
                    if r.load(Relaxed) {
                        crate::exit::request(Exit::Lost(why));
                    }
                }) {
                    Ok(r) => r,
                    Err(e) => {
                        note = format!("{id}: {e}");
                        continue;
                    }
                };
                let why =
                    crate::console::drive(&remote, exits, opts.keymap.clone(), opts.deadman, None)?;
                running.store(false, Relaxed);
                drop(remote);
                crate::socket::client::Dial::close(&*dial);
                note = match &why {
                    Exit::Quit => format!("left {id}"),
                    Exit::Lost(_) => format!("{id}: {}", why.describe()),
                    _ => break why,
                };
            }
        }
    };
    fleet.close();
    Ok(why)
}

/// The list, until a vehicle is picked or the operator leaves.
fn pick(
    fleet: &mut Watching,
    chosen: &mut usize,
    note: &str,
    opts: &Options,
    exits: &Receiver<Exit>,
) -> anyhow::Result<Picked> {
    let mut screen = terminal::enter()?;
    let stop = Arc::new(AtomicBool::new(false));
    let (keys, reader) = input::spawn(
        stop.clone(),
        Probe::known(Keyboard::PressesOnly, Instant::now()),
    )?;
    let redraw = crossbeam_channel::tick(REDRAW);
    let through = opts.connect.join(", ");
    let key = match &opts.key_file {
        Some(f) => format!("commanding where a vehicle allows it, with the key in {f}"),
        None => "watching only (no key: --key FILE to command)".into(),
    };
    let picked = loop {
        fleet.hear_all();
        let ids: Vec<String> = fleet.fleet.keys().cloned().collect();
        *chosen = (*chosen).min(ids.len().saturating_sub(1));
        if screen.ready()? {
            let now = Instant::now();
            let entries = fleet.entries(now);
            screen.terminal.draw(|f| {
                let [top, list, bottom] = Layout::vertical([
                    Constraint::Length(1),
                    Constraint::Min(3),
                    Constraint::Length(3),
                ])
                .areas(f.area());
                f.render_widget(
                    Paragraph::new(format!(
                        "adrive fleet — {} vehicles through {through}",
                        entries.len()
                    ))
                    .style(Style::new().add_modifier(Modifier::BOLD)),
                    top,
                );
                let rows = entries.iter().enumerate().map(|(i, e)| {
                    let row = Row::new(cells(e));
                    if i == *chosen {
                        row.style(Style::new().add_modifier(Modifier::REVERSED))
                    } else {
                        row
                    }
                });
                let widths = [
                    Constraint::Max(16),
                    Constraint::Length(6),
                    Constraint::Length(7),
                    Constraint::Fill(2),
                    Constraint::Fill(1),
                    Constraint::Fill(1),
                    Constraint::Length(9),
                    Constraint::Length(8),
                ];
                let table = Table::new(rows, widths)
                    .header(Row::new(HEAD).style(Style::new().add_modifier(Modifier::BOLD)))
                    .block(Block::bordered().title(" vehicles "));
                f.render_widget(table, list);
                if entries.is_empty() {
                    let inner = list.inner(ratatui::layout::Margin::new(2, 2));
                    f.render_widget(Paragraph::new("no vehicle on the network yet"), inner);
                }
                f.render_widget(
                    Paragraph::new(vec![
                        Line::from(key.as_str()),
                        Line::from(note.to_string()),
                        Line::from("↑/↓ choose · Enter attach · q leave"),
                    ]),
                    bottom,
                );
            })?;
        }
        select! {
            recv(keys) -> k => match k {
                Ok(Input::Key(k, _)) if k.kind != KeyEventKind::Release => match k.code {
                    KeyCode::Up | KeyCode::Char('k') => *chosen = chosen.saturating_sub(1),
                    KeyCode::Down | KeyCode::Char('j') => {
                        *chosen = (*chosen + 1).min(ids.len().saturating_sub(1));
                    }
                    KeyCode::Enter => {
                        if let Some(id) = ids.get(*chosen) {
                            break Picked::Vehicle(id.clone());
                        }
                    }
                    KeyCode::Char('q') | KeyCode::Esc => break Picked::Leave(Exit::Quit),
                    _ => {}
                },
                Ok(Input::Closed(why)) => break Picked::Leave(Exit::HangUp(format!("input: {why}"))),
                Ok(_) => {}
                Err(_) => break Picked::Leave(Exit::HangUp("input ended".into())),
            },
            recv(exits) -> why => match why {
                // A console left, whose link ended as it went: nothing to leave for.
                Ok(Exit::Lost(_)) => {}
                why => break Picked::Leave(why.unwrap_or(Exit::Quit)),
            },
            recv(redraw) -> _ => {}
        }
    };
    stop.store(true, Relaxed);
    drop(screen);
    let deadline = Instant::now() + 2 * REDRAW;
    while !reader.is_finished() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    Ok(picked)
}
