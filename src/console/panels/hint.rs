//! The bottom two lines: the outcome of the last action (or the edit in progress and
//! its error, or the name prompt and what it finds), and the hint bar, generated from
//! the loaded keymap for the current mode.

use super::fit::Fitted;
use crate::config::Role;
use crate::console::keymap::{describe, Action, Binding, Key, Keymap, Mode, Target};
use crate::console::model::{Find, Model};
use crate::console::names;
use crate::console::theme::Theme;
use crate::snapshot::Pairs;
use crossterm::event::KeyCode;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Paragraph, Widget};
use unicode_width::UnicodeWidthStr;

/// A key as the hint bar writes it: arrows as arrows, the rest as in keymaps.
pub(crate) fn short(k: Key) -> String {
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

/// The first key bound to `action` in `mode` as the hint bar writes it; `?` when none
/// is.
pub(crate) fn key_name(map: &Keymap, mode: Mode, action: Action) -> String {
    map.key_for(mode, action)
        .map(short)
        .unwrap_or_else(|| "?".into())
}

/// The bindings of `mode` grouped by action, in file order, help and quit first, with
/// their descriptions for this vehicle's `roles` ([`describe`]; a key for a role the
/// vehicle lacks is left out).
pub(crate) fn grouped(
    map: &Keymap,
    mode: Mode,
    roles: &Pairs<String>,
) -> Vec<(String, String, Action)> {
    grouped_first(map, mode, None, roles)
}

/// [`grouped`], with `first` (when bound) right after help and quit.
pub(crate) fn grouped_first(
    map: &Keymap,
    mode: Mode,
    first: Option<Action>,
    roles: &Pairs<String>,
) -> Vec<(String, String, Action)> {
    let mut out: Vec<(String, String, Action)> = Vec::new();
    let bs: &[Binding] = map.bindings(mode);
    for b in bs.iter().filter(|b| available(b.run, roles)) {
        let Some(desc) = describe(&b.desc, roles) else {
            continue;
        };
        match out.iter_mut().find(|(_, _, a)| *a == b.run) {
            Some(e) => {
                e.0.push('/');
                e.0.push_str(&short(b.on));
            }
            None => out.push((short(b.on), desc, b.run)),
        }
    }
    out.sort_by_key(|(_, _, a)| match a {
        Action::Help => 0,
        Action::Quit => 1,
        a if Some(*a) == first => 2,
        _ => 3,
    });
    out
}

/// Whether the vehicle has what `action` acts on: `accel` exists only with a throttle
/// and a brake bound (the keys for a single role are left out by [`describe`]).
fn available(action: Action, roles: &Pairs<String>) -> bool {
    match action {
        Action::EditOf(Target::Accel) => [Role::Throttle, Role::Brake]
            .iter()
            .all(|r| roles.get(r.as_str()).is_some()),
        _ => true,
    }
}

pub(crate) struct HintBar<'a> {
    pub map: &'a Keymap,
    pub mode: Mode,
    pub theme: Theme,
    /// An action worth showing before the others (the name prompt, when the
    /// devices are too many for a panel each).
    pub first: Option<Action>,
    /// The vehicle's role bindings, for the keys' descriptions.
    pub roles: &'a Pairs<String>,
}

impl Widget for &HintBar<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        let mut spans = Vec::new();
        let mut used = 0usize;
        for (keys, desc, _) in grouped_first(self.map, self.mode, self.first, self.roles) {
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

pub(crate) struct MessageLine<'a> {
    pub m: &'a Model,
}

/// The name prompt's line: `/hi▏  hitch 1 of 2` (the device found, which of the
/// matches in the vehicle's order) and its keys; red when nothing matches.
fn prompt(m: &Model, f: &Find) -> Line<'static> {
    let t = &m.theme;
    let k = |a| key_name(&m.keymap, Mode::Find, a);
    let names = m.snap.devices.iter().map(|d| d.name.as_str());
    let found = names::matches(names, &f.query);
    let mut spans = vec![Span::styled(format!("/{}▏", f.query), t.editing())];
    match (found.is_empty(), f.query.is_empty()) {
        (true, true) => spans.push(Span::raw("  type a device's name")),
        (true, false) => spans.push(Span::styled(
            format!("  no device matches {:?}", f.query),
            t.fault(),
        )),
        (false, _) => {
            let at = m.found_device();
            let mut sorted = found;
            sorted.sort_unstable();
            let pos = sorted.iter().position(|&j| j == at);
            let name = m.snap.devices.get(at).map_or("", |d| d.name.as_str());
            let of = match pos {
                Some(p) => format!(" {} of {}", p + 1, sorted.len()),
                None => format!(" {} matches", sorted.len()),
            };
            spans.push(Span::styled(format!("  {name}"), t.title()));
            spans.push(Span::raw(of));
        }
    }
    spans.push(Span::styled(
        format!(
            "  {} jumps, {} cancels, {} completes, {}/{} next/previous",
            k(Action::Commit),
            k(Action::Cancel),
            k(Action::Complete),
            k(Action::FindNext),
            k(Action::FindPrev)
        ),
        t.label(),
    ));
    Line::from(spans)
}

impl MessageLine<'_> {
    /// The name prompt's query and caret fit `width` columns.
    pub(crate) fn prompt_fits(&self, width: u16) -> bool {
        self.m
            .find
            .as_ref()
            .is_some_and(|f| format!("/{}▏", f.query).width() <= usize::from(width))
    }

    /// A refusal or a fault said just now: worth the hint bar's line where there is no
    /// line of its own (80×22).
    pub(crate) fn urgent(&self) -> bool {
        self.m.message_line().is_some_and(|(_, bad)| bad)
    }
}

impl Widget for &MessageLine<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        let (m, t) = (self.m, &self.m.theme);
        let line = if let (Mode::Find, Some(f)) = (m.mode, &m.find) {
            prompt(m, f)
        } else if let (Mode::Edit, Some(e)) = (m.mode, &m.edit) {
            match &e.error {
                Some(err) => Line::from(vec![
                    Span::styled(format!("{}: ", e.field.name(&m.snap)), t.fault()),
                    Span::styled(err.clone(), t.fault()),
                ]),
                None => {
                    let k = |a| key_name(&m.keymap, Mode::Edit, a);
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
            match m.message_line() {
                Some((text, bad)) => {
                    let style = if bad { t.fault() } else { t.good() };
                    Line::from(Span::styled(text.into_owned(), style))
                }
                None => Line::default(),
            }
        };
        Fitted(vec![line]).render(area, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn bar(roles: &Pairs<String>, width: u16) -> String {
        let map = Keymap::default_map();
        let h = HintBar {
            map: &map,
            mode: Mode::Main,
            theme: Theme::default(),
            first: None,
            roles,
        };
        let mut buf = Buffer::empty(Rect::new(0, 0, width, 1));
        (&h).render(buf.area, &mut buf);
        (0..width).map(|x| buf[(x, 0)].symbol()).collect()
    }

    /// `adrive --only steer` (no throttle, no brake) offered `c accel`, a command the
    /// vehicle does not have.
    #[test]
    fn the_hint_bar_offers_accel_only_with_throttle_and_brake_bound() {
        let roles = |r: &[&str]| -> Pairs<String> {
            r.iter().map(|r| (r.to_string(), r.to_string())).collect()
        };
        let steer_only = bar(&roles(&["steering"]), 200);
        assert!(!steer_only.contains("accel"), "{steer_only}");
        assert!(steer_only.contains("s steering"), "{steer_only}");
        let brake_only = bar(&roles(&["steering", "brake"]), 200);
        assert!(!brake_only.contains("accel"), "{brake_only}");
        let both = bar(&roles(&["steering", "throttle", "brake"]), 200);
        assert!(both.contains("c accel"), "{both}");
    }

    /// An outcome longer than the line is cut at a word, marked, in its colour.
    #[test]
    fn a_message_without_room_is_cut_with_a_mark() {
        use crate::controls::{capture, Sources};
        let now = std::time::Instant::now();
        let frame = capture(&crate::testkit::gate(now), &Sources::default(), now, None);
        let mut m = Model::new(
            Keymap::default_map(),
            Theme::default(),
            frame,
            Duration::from_secs(1),
        );
        m.now = now;
        m.say(
            "refused: steer 0.50: commanded by network 127.0.0.1:5555 (release it there first)",
            true,
        );
        let mut buf = Buffer::empty(Rect::new(0, 0, 60, 1));
        (&MessageLine { m: &m }).render(buf.area, &mut buf);
        let row: String = (0..60).map(|x| buf[(x, 0)].symbol()).collect();
        assert_eq!(
            row,
            "refused: steer 0.50: commanded by network 127.0.0.1:5555…   "
        );
        assert_eq!(buf[(56, 0)].fg, ratatui::style::Color::Red, "the mark too");
    }
}
