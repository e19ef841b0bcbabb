//! The bottom two lines: the outcome of the last action (or the edit in progress and
//! its error), and the hint bar, generated from the loaded keymap for the current mode.

use crate::console::keymap::{Action, Binding, Key, Keymap, Mode};
use crate::console::model::Model;
use crate::console::theme::Theme;
use crossterm::event::KeyCode;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Paragraph, Widget};
use std::time::Duration;

/// How long an outcome message stays.
pub const MESSAGE_FOR: Duration = Duration::from_secs(8);

/// A key as the hint bar writes it: arrows as arrows, the rest as in keymaps.
pub fn short(k: Key) -> String {
    let plain = !(k.ctrl || k.alt || k.shift);
    match k.code {
        KeyCode::Up if plain => "↑".into(),
        KeyCode::Down if plain => "↓".into(),
        KeyCode::Left if plain => "←".into(),
        KeyCode::Right if plain => "→".into(),
        _ => {
            let s = k.to_string();
            if plain && s.starts_with('<') {
                s.trim_start_matches('<').trim_end_matches('>').to_string()
            } else {
                s
            }
        }
    }
}

/// The bindings of `mode` grouped by action, in file order, help and quit first.
pub fn grouped(map: &Keymap, mode: Mode) -> Vec<(String, String, Action)> {
    let mut out: Vec<(String, String, Action)> = Vec::new();
    let bs: &[Binding] = map.bindings(mode);
    for b in bs {
        match out.iter_mut().find(|(_, _, a)| *a == b.run) {
            Some(e) => {
                e.0.push('/');
                e.0.push_str(&short(b.on));
            }
            None => out.push((short(b.on), b.desc.clone(), b.run)),
        }
    }
    out.sort_by_key(|(_, _, a)| match a {
        Action::Help => 0,
        Action::Quit => 1,
        _ => 2,
    });
    out
}

pub struct HintBar<'a> {
    pub map: &'a Keymap,
    pub mode: Mode,
    pub theme: Theme,
}

impl Widget for &HintBar<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        let mut spans = Vec::new();
        let mut used = 0usize;
        for (keys, desc, _) in grouped(self.map, self.mode) {
            let w = keys.chars().count() + 1 + desc.chars().count() + 2;
            if used + w > area.width as usize {
                break;
            }
            used += w;
            spans.push(Span::styled(keys, self.theme.key()));
            spans.push(Span::raw(format!(" {desc}  ")));
        }
        Paragraph::new(Line::from(spans)).render(area, buf);
    }
}

pub struct MessageLine<'a> {
    pub m: &'a Model,
}

impl Widget for &MessageLine<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        let (m, t) = (self.m, &self.m.theme);
        let line = if let (Mode::Edit, Some(e)) = (m.mode, &m.edit) {
            match &e.error {
                Some(err) => Line::from(vec![
                    Span::styled(format!("{}: ", e.field.name(&m.snap)), t.fault()),
                    Span::styled(err.clone(), t.fault()),
                ]),
                None => {
                    let k = |a| {
                        m.keymap
                            .key_for(Mode::Edit, a)
                            .map(short)
                            .unwrap_or_else(|| "?".into())
                    };
                    Line::from(vec![
                        Span::styled(format!("edit {}: ", e.field.name(&m.snap)), t.editing()),
                        Span::raw(format!(
                            "{} applies, {} cancels",
                            k(Action::Commit),
                            k(Action::Cancel)
                        )),
                    ])
                }
            }
        } else {
            match &m.message {
                Some(msg) if m.now.saturating_duration_since(msg.at) < MESSAGE_FOR => {
                    let style = if msg.bad { t.fault() } else { t.good() };
                    Line::from(Span::styled(msg.text.clone(), style))
                }
                _ => Line::default(),
            }
        };
        Paragraph::new(line).render(area, buf);
    }
}
