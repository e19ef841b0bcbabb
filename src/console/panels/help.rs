//! The help overlay, generated from the loaded keymap: every mode's bindings with
//! key, description and action name; and, on its key (`e`), the last key events as the
//! terminal sent them, with their kinds (press, repeat, release) and the time between
//! them — how an operator tests what their terminal gives teleop.

use super::fit::{self, Fitted};
use super::hint::short;
use crate::console::hold::{Drive, Figures};
use crate::console::keymap::{describe, Key, Keymap, Mode};
use crate::console::model::SeenKey;
use crate::console::theme::Theme;
use crossterm::event::{KeyEvent, KeyEventKind, KeyEventState};
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Clear, Widget};

pub(crate) struct HelpPanel<'a> {
    pub map: &'a Keymap,
    pub theme: Theme,
    pub(crate) scroll: u16,
    /// The vehicle's role bindings, for the keys' descriptions.
    pub roles: &'a crate::snapshot::Pairs<String>,
    /// The key-event viewer, when it is on.
    pub events: Option<KeyEvents<'a>>,
}

/// What the key-event viewer shows.
pub(crate) struct KeyEvents<'a> {
    pub seen: &'a std::collections::VecDeque<SeenKey>,
    /// The terminal reports releases.
    pub releases: bool,
    pub drive: Drive,
    pub figures: Figures,
}

impl KeyEvents<'_> {
    fn lines(&self, t: &Theme) -> Vec<Line<'static>> {
        let terminal = match self.releases {
            true => "this terminal reports presses, repeats and releases",
            false => "this terminal reports presses only (a held key is its key repeat)",
        };
        let f = &self.figures;
        let hz = 1.0 / f.interval.as_secs_f64();
        let repeat = match f.learnt {
            true => format!(
                "key repeat learnt: {} ms, then every {} ms ({hz:.0} Hz)",
                f.delay.as_millis(),
                f.interval.as_millis()
            ),
            false => format!(
                "key repeat not learnt yet: {} ms, then every {} ms assumed (hold a key)",
                f.delay.as_millis(),
                f.interval.as_millis()
            ),
        };
        let mut out = vec![
            Line::from(Span::styled("KEY EVENTS (e hides them)", t.title())),
            Line::from(format!(
                "{terminal}: teleop drives in {}",
                self.drive.as_str()
            )),
            Line::from(Span::styled(repeat, t.label())),
        ];
        let mut last: Option<std::time::Instant> = None;
        for k in self.seen {
            let key = Key::from_event(&KeyEvent {
                code: k.code,
                modifiers: k.modifiers,
                kind: k.kind,
                state: KeyEventState::NONE,
            });
            let kind = match k.kind {
                KeyEventKind::Press => "press",
                KeyEventKind::Repeat => "repeat",
                KeyEventKind::Release => "release",
            };
            let gap = last.map_or(String::new(), |l| {
                format!("+{} ms", k.at.saturating_duration_since(l).as_millis())
            });
            last = Some(k.at);
            out.push(Line::from(vec![
                Span::styled(format!("  {:<11}", short(key)), t.key()),
                Span::raw(format!("{kind:<8}")),
                Span::styled(gap, t.label()),
            ]));
        }
        if self.seen.is_empty() {
            out.push(Line::from(Span::styled(
                "  (press, hold and let go of a key)",
                t.label(),
            )));
        }
        out
    }
}

impl HelpPanel<'_> {
    pub(crate) fn lines(&self) -> Vec<Line<'static>> {
        let t = &self.theme;
        let mut out = self.events.as_ref().map_or(Vec::new(), |e| e.lines(t));
        out.extend([
            Line::from(Span::styled(
                "Error codes: 0 is good, ≥ 1 is bad:",
                t.label(),
            )),
            Line::from(Span::styled(
                "1 timeout 2 garbled 3 refused 4 unsupported 5 i/o",
                t.label(),
            )),
        ]);
        for mode in [
            Mode::Main,
            Mode::Teleop,
            Mode::Bench,
            Mode::Edit,
            Mode::Find,
            Mode::Confirm,
            Mode::Help,
        ] {
            out.push(Line::from(Span::styled(
                mode.as_str().to_uppercase(),
                t.title(),
            )));
            for b in self.map.bindings(mode) {
                out.push(Line::from(vec![
                    Span::styled(format!("  {:<11}", short(b.on)), t.key()),
                    Span::raw(format!(
                        "{:<22}",
                        describe(&b.desc, self.roles)
                            .unwrap_or_else(|| "(not on this vehicle)".into())
                    )),
                    Span::styled(b.run.to_string(), t.label()),
                ]));
            }
        }
        out.push(Line::from(Span::styled(
            "  <C-c>      stop adrive (safe state first; cannot be rebound)",
            t.label(),
        )));
        out
    }
}

impl Widget for &HelpPanel<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        Clear.render(area, buf);
        let block = Block::bordered()
            .title(Span::styled(
                fit::title(" help — keys from the loaded keymap ", area.width),
                self.theme.title(),
            ))
            .title_bottom(fit::title(
                " ↑↓ scroll  e key events  Esc close ",
                area.width,
            ));
        let inner = block.inner(area);
        block.render(area, buf);
        let lines = self.lines();
        let max = lines.len().saturating_sub(inner.height as usize) as u16;
        if inner.width >= 100 && lines.len() > inner.height as usize {
            // Two columns when wide.
            let half = inner.width / 2;
            let rows = inner.height as usize;
            let skip = self.scroll.min(max) as usize;
            let left: Vec<Line> = lines.iter().skip(skip).take(rows).cloned().collect();
            let right: Vec<Line> = lines.iter().skip(skip + rows).take(rows).cloned().collect();
            Fitted(left).render(
                Rect {
                    width: half,
                    ..inner
                },
                buf,
            );
            Fitted(right).render(
                Rect {
                    x: inner.x + half,
                    width: inner.width - half,
                    ..inner
                },
                buf,
            );
        } else {
            let skip = usize::from(self.scroll.min(max));
            Fitted(lines.into_iter().skip(skip).collect()).render(inner, buf);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// At 60 columns the last line of help ran off the box: cut at a word, marked.
    #[test]
    fn a_help_line_without_room_is_cut_with_a_mark() {
        let map = Keymap::default_map();
        let roles = crate::snapshot::Pairs::default();
        let h = HelpPanel {
            map: &map,
            theme: Theme::default(),
            scroll: u16::MAX,
            roles: &roles,
            events: None,
        };
        let mut buf = Buffer::empty(Rect::new(0, 0, 50, 8));
        (&h).render(buf.area, &mut buf);
        let rows: Vec<String> = (0..8)
            .map(|y| (0..50).map(|x| buf[(x, y)].symbol()).collect())
            .collect();
        assert_eq!(
            rows[6],
            "│  <C-c>      stop adrive (safe state first…)    │"
        );
        assert_eq!(
            rows[0],
            "┌ help — keys from the loaded keymap ────────────┐"
        );
    }
}
