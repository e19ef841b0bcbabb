//! The teleop panel: how the keys drive (`hold`, `repeat` with the bound it keeps,
//! `step`), set points, a steering gauge, the keys held, the deadman — impossible to
//! miss — and the levels a held key commands.
//!
//! Three lines where there is room; on two, the levels follow the deadman when they
//! fit. What was drawn whole is what the teleop keys act on ([`render_seen`]).
//!
//! [`render_seen`]: TeleopPanel::render_seen

use super::fit::Fitted;
use crate::console::hold::{Drive, Figures, HoldKey};
use crate::console::model::{Deadman, Teleop};
use crate::console::theme::Theme;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::style::Modifier;
use ratatui::text::{Line, Span};
use ratatui::widgets::Widget;
use std::time::Instant;

pub(crate) struct TeleopPanel<'a> {
    pub t: &'a Teleop,
    pub now: Instant,
    pub theme: Theme,
    /// This console commands the engaged vehicle: its keys arm the intake's deadman.
    pub commands: bool,
    /// How the keys drive.
    pub drive: Drive,
    /// The terminal's key repeat (learnt, or assumed).
    pub figures: Figures,
}

/// A gauge of `v` in −1…1, `width` cells, centre marked.
pub(crate) fn gauge(v: f64, width: usize) -> String {
    let w = width.max(3) | 1;
    let mid = w / 2;
    let at = (((v.clamp(-1.0, 1.0) + 1.0) / 2.0) * (w - 1) as f64).round() as usize;
    (0..w)
        .map(|i| match i {
            _ if i == at => '●',
            _ if i == mid => '┼',
            _ => '─',
        })
        .collect()
}

/// How the keys drive, in words: `hold`, `repeat: stops ≤ 100 ms after the repeats
/// end` (`long`) or `repeat ≤100ms`, `step`.
pub(crate) fn drive_label(drive: Drive, f: &Figures, long: bool) -> String {
    match (drive, long) {
        (Drive::Repeat, true) => {
            format!("repeat: stops ≤ {} ms after the repeats end", f.stops_ms())
        }
        (Drive::Repeat, false) => format!("repeat ≤{}ms", f.stops_ms()),
        (d, _) => d.as_str().to_string(),
    }
}

fn width(l: &Line) -> usize {
    l.width()
}

impl TeleopPanel<'_> {
    /// The first line, the longest of its forms that fits `room` columns.
    fn state(&self, room: usize) -> Line<'static> {
        let (t, th) = (self.t, &self.theme);
        let pedal = if t.accel > 0.0 {
            "gas"
        } else if t.accel < 0.0 {
            "brake"
        } else {
            "coast"
        };
        let held: Vec<&str> = t
            .holds
            .all()
            .map(|h| match h.key {
                HoldKey::Gas => "↑",
                HoldKey::Brake => "↓",
                HoldKey::Left => "←",
                HoldKey::Right => "→",
            })
            .collect();
        let make = |long: bool, gauge_w: usize| {
            let mut spans = vec![
                Span::styled("TELEOP ", th.title()),
                Span::styled(
                    drive_label(self.drive, &self.figures, long),
                    th.good().add_modifier(Modifier::BOLD),
                ),
                Span::styled("  steer ", th.label()),
                Span::raw(format!("{:+.2} ", t.steer)),
                Span::raw(gauge(t.steer, gauge_w)),
                Span::styled("  accel ", th.label()),
                Span::raw(format!("{:+.2} {pedal}", t.accel)),
            ];
            if !held.is_empty() {
                spans.push(Span::styled("  held ", th.label()));
                spans.push(Span::raw(held.join(" ")));
            }
            Line::from(spans)
        };
        [(true, 15), (true, 9), (false, 15), (false, 9)]
            .into_iter()
            .map(|(long, g)| make(long, g))
            .find(|l| width(l) <= room)
            .unwrap_or_else(|| make(false, 9))
    }

    fn deadman(&self) -> Span<'static> {
        let (t, th) = (self.t, &self.theme);
        match t.state(self.now) {
            Deadman::Idle => Span::styled(
                format!(
                    "DEADMAN idle: the first key arms it ({:.1}s)",
                    t.deadman.as_secs_f64()
                ),
                th.label(),
            ),
            Deadman::Armed { left } if self.commands => Span::styled(
                format!("DEADMAN ARMED {:.1}s left", left.as_secs_f64()),
                th.good().add_modifier(Modifier::BOLD),
            ),
            // The intake arms the deadman of the console that commands only.
            Deadman::Armed { .. } => Span::styled(
                "DEADMAN not armed: this console does not command (E engages)",
                th.warn(),
            ),
            Deadman::Tripped => Span::styled(
                "DEADMAN TRIPPED: gas 0, brake full, disengaged (E engages)",
                th.fault().add_modifier(Modifier::REVERSED),
            ),
        }
    }

    fn levels(&self) -> Vec<Span<'static>> {
        let (l, th) = (&self.t.levels, &self.theme);
        let mut out = Vec::new();
        for (i, (name, v)) in [
            ("gas ", format!("{:.2}", l.gas)),
            ("brake ", format!("{:.2}", l.brake)),
            ("hold ", format!("{:.2}", l.hold)),
            ("steer ", format!("{:.2}/s", l.steer_rate)),
        ]
        .into_iter()
        .enumerate()
        {
            if i > 0 {
                out.push(Span::styled(" · ", th.label()));
            }
            out.push(Span::styled(name, th.label()));
            out.push(Span::raw(v));
        }
        out
    }

    /// The lines for `rows` × `cols`, and whether the levels are among them whole.
    pub(crate) fn lines(&self, cols: u16, rows: u16) -> (Vec<Line<'static>>, bool) {
        let cols = usize::from(cols);
        let state = self.state(cols);
        let dead = Line::from(self.deadman());
        let levels = Line::from(self.levels());
        if rows >= 3 {
            let whole = width(&levels) <= cols;
            return (vec![state, dead, levels], whole);
        }
        let mut both = vec![self.deadman()];
        both.push(Span::raw("   "));
        both.extend(self.levels());
        let both = Line::from(both);
        if width(&both) <= cols {
            (vec![state, both], true)
        } else {
            (vec![state, dead], false)
        }
    }

    /// Draw the bar in `area`: whether its first two lines were drawn whole (what the
    /// teleop keys act on, and the deadman), and whether the levels were (what the
    /// level keys act on).
    pub(crate) fn render_seen(&self, area: Rect, buf: &mut Buffer) -> (bool, bool) {
        let (lines, levels) = self.lines(area.width, area.height);
        let rows = usize::from(area.height);
        let fits = |i: usize| {
            i < rows
                && lines
                    .get(i)
                    .is_some_and(|l| width(l) <= usize::from(area.width))
        };
        let whole = fits(0) && fits(1);
        let levels = levels && (lines.len() == 2 || fits(2));
        Fitted(lines).render(area, buf);
        (whole, levels)
    }
}

impl Widget for &TeleopPanel<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        self.render_seen(area, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::console::hold::{DEFAULT_DELAY, DEFAULT_INTERVAL};
    use std::time::Duration;

    #[test]
    fn the_gauge_marks_centre_and_value() {
        assert_eq!(gauge(0.0, 7), "───●───");
        assert_eq!(gauge(-1.0, 7), "●──┼───");
        assert_eq!(gauge(1.0, 7), "───┼──●");
    }

    fn figures(interval_ms: u64) -> Figures {
        Figures {
            delay: DEFAULT_DELAY,
            interval: Duration::from_millis(interval_ms),
            learnt: interval_ms != DEFAULT_INTERVAL.as_millis() as u64,
        }
    }

    fn panel(t: &Teleop, drive: Drive, commands: bool) -> TeleopPanel<'_> {
        TeleopPanel {
            t,
            now: Instant::now(),
            theme: Theme::default(),
            commands,
            drive,
            figures: figures(33),
        }
    }

    fn rows(buf: &Buffer) -> Vec<String> {
        let a = buf.area;
        (0..a.height)
            .map(|y| {
                (0..a.width)
                    .map(|x| buf[(x, y)].symbol())
                    .collect::<String>()
            })
            .map(|r| r.trim_end().to_string())
            .collect()
    }

    /// The bar in too narrow a room is cut at a word with a mark, and is not said to
    /// be drawn whole: the teleop keys are then refused.
    #[test]
    fn a_bar_without_room_is_cut_with_a_mark_and_not_whole() {
        let t = Teleop::new(Duration::from_secs(1));
        let p = panel(&t, Drive::Hold, true);
        let mut buf = Buffer::empty(Rect::new(0, 0, 30, 2));
        assert_eq!(p.render_seen(buf.area, &mut buf), (false, false));
        assert_eq!(rows(&buf)[0], "TELEOP hold  steer +0.00…");
        let mut buf = Buffer::empty(Rect::new(0, 0, 80, 2));
        assert!(p.render_seen(buf.area, &mut buf).0);
        let mut buf = Buffer::empty(Rect::new(0, 0, 80, 1));
        assert!(
            !p.render_seen(buf.area, &mut buf).0,
            "the deadman's line is cut off"
        );
    }

    /// The mode is named on the bar: `repeat` with its bound in full where there is
    /// room, in short at 80 columns; the levels on their own line where there are three.
    #[test]
    fn the_bar_names_the_mode_and_the_levels() {
        let t = Teleop::new(Duration::from_secs(1));
        let mut buf = Buffer::empty(Rect::new(0, 0, 100, 3));
        assert_eq!(
            panel(&t, Drive::Repeat, true).render_seen(buf.area, &mut buf),
            (true, true)
        );
        let r = rows(&buf);
        assert!(
            r[0].starts_with("TELEOP repeat: stops ≤ 100 ms after the repeats end  steer +0.00"),
            "{r:?}"
        );
        assert_eq!(r[2], "gas 0.20 · brake 0.60 · hold 0.30 · steer 0.50/s");
        let mut buf = Buffer::empty(Rect::new(0, 0, 80, 2));
        panel(&t, Drive::Repeat, true).render_seen(buf.area, &mut buf);
        assert!(
            rows(&buf)[0].starts_with("TELEOP repeat ≤100ms  steer"),
            "{:?}",
            rows(&buf)
        );
        for (d, word) in [(Drive::Hold, "hold"), (Drive::Step, "step")] {
            let mut buf = Buffer::empty(Rect::new(0, 0, 80, 2));
            panel(&t, d, true).render_seen(buf.area, &mut buf);
            assert!(rows(&buf)[0].starts_with(&format!("TELEOP {word}  steer")));
        }
    }

    /// On two lines the levels follow the deadman when they fit, and are not said to
    /// be drawn when they do not (their keys are then refused).
    #[test]
    fn on_two_lines_the_levels_share_the_deadman_s_when_they_fit() {
        let now = Instant::now();
        let mut t = Teleop::new(Duration::from_secs(1));
        t.last_key = Some(now);
        let p = TeleopPanel {
            now,
            ..panel(&t, Drive::Hold, true)
        };
        let mut buf = Buffer::empty(Rect::new(0, 0, 80, 2));
        assert_eq!(p.render_seen(buf.area, &mut buf), (true, true));
        assert_eq!(
            rows(&buf)[1],
            "DEADMAN ARMED 1.0s left   gas 0.20 · brake 0.60 · hold 0.30 · steer 0.50/s"
        );
        let p = TeleopPanel {
            commands: false,
            ..p
        };
        let mut buf = Buffer::empty(Rect::new(0, 0, 80, 2));
        assert_eq!(p.render_seen(buf.area, &mut buf), (true, false));
    }

    /// A teleop key arms the intake's deadman only for the console that commands: the
    /// bar does not say ARMED for one that does not.
    #[test]
    fn the_deadman_is_armed_only_for_the_console_that_commands() {
        let now = Instant::now();
        let mut t = Teleop::new(Duration::from_secs(1));
        t.last_key = Some(now);
        let text = |commands| {
            let p = TeleopPanel {
                now,
                ..panel(&t, Drive::Hold, commands)
            };
            p.deadman().content.to_string()
        };
        assert_eq!(text(true), "DEADMAN ARMED 1.0s left");
        assert_eq!(
            text(false),
            "DEADMAN not armed: this console does not command (E engages)"
        );
    }
}
