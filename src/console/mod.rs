//! The operator console: a full-screen view of every device over the running engine.
//! (A first, read-only screen; the Sparrow-style editing console grows here.)

use crate::exit::Exit;
use crate::vehicle::Vehicle;
use crossbeam_channel::Receiver;
use crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
use ratatui::layout::Constraint;
use ratatui::style::{Color, Style};
use ratatui::widgets::{Block, Row, Table};
use std::time::Duration;

/// Run the console until the operator quits or an exit arrives.
pub fn run(vehicle: &Vehicle, exits: &Receiver<Exit>) -> std::io::Result<Exit> {
    let mut terminal = ratatui::init();
    let why = loop {
        if let Ok(why) = exits.try_recv() {
            break why;
        }
        terminal.draw(|f| {
            let rows = vehicle.devices.iter().map(|d| {
                let c = d.cached();
                let s = d.stats.snapshot();
                let value = c
                    .reading
                    .position
                    .map(|p| format!("{p:.3}"))
                    .or(c.reading.gear.map(|g| g.to_string()))
                    .or(c.reading.estop.map(|e| e.to_string()))
                    .or(c.reading.rpm.map(|r| format!("{r:.0} rpm")))
                    .unwrap_or_else(|| "-".into());
                let style = if d.is_faulty() {
                    Style::default().fg(Color::Red)
                } else {
                    Style::default()
                };
                Row::new(vec![
                    d.role.to_string(),
                    d.slot.latest().map(|c| c.to_string()).unwrap_or("-".into()),
                    value,
                    s.received.to_string(),
                    s.executed.to_string(),
                    (s.command_errors + s.status_errors).to_string(),
                    c.age()
                        .map(|a| format!("{}ms", a.as_millis()))
                        .unwrap_or("-".into()),
                ])
                .style(style)
            });
            let table = Table::new(
                rows,
                [
                    Constraint::Length(6),
                    Constraint::Length(9),
                    Constraint::Length(10),
                    Constraint::Length(8),
                    Constraint::Length(8),
                    Constraint::Length(7),
                    Constraint::Length(7),
                ],
            )
            .header(Row::new(vec![
                "device", "command", "measured", "recv", "exec", "errors", "age",
            ]))
            .block(Block::bordered().title(format!(" adrive — {} — q quit ", vehicle.name)));
            f.render_widget(table, f.area());
        })?;
        if event::poll(Duration::from_millis(100))? {
            if let Event::Key(k) = event::read()? {
                let ctrl_c =
                    k.code == KeyCode::Char('c') && k.modifiers.contains(KeyModifiers::CONTROL);
                if k.kind == KeyEventKind::Press && (k.code == KeyCode::Char('q') || ctrl_c) {
                    break if ctrl_c {
                        Exit::Signal(signal_hook::consts::SIGINT)
                    } else {
                        Exit::Quit
                    };
                }
            }
        }
    };
    ratatui::restore();
    Ok(why)
}
