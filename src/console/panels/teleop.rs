//! The teleop panel: set points, a steering gauge and the deadman, impossible to miss.

use super::fit::Fitted;
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

impl TeleopPanel<'_> {
    pub fn lines(&self) -> Vec<Line<'static>> {
        let (t, th) = (self.t, &self.theme);
        let pedal = if t.accel > 0.0 {
            "gas"
        } else if t.accel < 0.0 {
            "brake"
        } else {
            "coast"
        };
        let dead = match t.state(self.now) {
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
        };
        vec![
            Line::from(vec![
                Span::styled("TELEOP ", th.title()),
                Span::styled("steer ", th.label()),
                Span::raw(format!("{:+.2} ", t.steer)),
                Span::raw(gauge(t.steer, 15)),
                Span::styled("  accel ", th.label()),
                Span::raw(format!("{:+.2} {pedal}", t.accel)),
            ]),
            Line::from(dead),
        ]
    }
}

impl TeleopPanel<'_> {
    /// Draw the bar in `area`; whether both its lines were drawn whole (what the
    /// teleop keys act on, and the deadman).
    pub(crate) fn render_seen(&self, area: Rect, buf: &mut Buffer) -> bool {
        let lines = self.lines();
        let whole = lines.len() <= usize::from(area.height)
            && lines.iter().all(|l| l.width() <= usize::from(area.width));
        Fitted(lines).render(area, buf);
        whole
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

    #[test]
    fn the_gauge_marks_centre_and_value() {
        assert_eq!(gauge(0.0, 7), "───●───");
        assert_eq!(gauge(-1.0, 7), "●──┼───");
        assert_eq!(gauge(1.0, 7), "───┼──●");
    }

    /// The bar in too narrow a room is cut at a word with a mark, and is not said to
    /// be drawn whole: the teleop keys are then refused.
    #[test]
    fn a_bar_without_room_is_cut_with_a_mark_and_not_whole() {
        let t = Teleop::new(std::time::Duration::from_secs(1));
        let p = TeleopPanel {
            t: &t,
            now: Instant::now(),
            theme: Theme::default(),
            commands: true,
        };
        let mut buf = Buffer::empty(Rect::new(0, 0, 30, 2));
        assert!(!p.render_seen(buf.area, &mut buf));
        let row: String = (0..30).map(|x| buf[(x, 0)].symbol()).collect();
        assert_eq!(row, "TELEOP steer +0.00…           ");
        let mut buf = Buffer::empty(Rect::new(0, 0, 80, 2));
        assert!(p.render_seen(buf.area, &mut buf));
        let mut buf = Buffer::empty(Rect::new(0, 0, 80, 1));
        assert!(
            !p.render_seen(buf.area, &mut buf),
            "the deadman's line is cut off"
        );
    }

    /// A teleop key arms the intake's deadman only for the console that commands: the
    /// bar does not say ARMED for one that does not.
    #[test]
    fn the_deadman_is_armed_only_for_the_console_that_commands() {
        let now = Instant::now();
        let mut t = Teleop::new(std::time::Duration::from_secs(1));
        t.last_key = Some(now);
        let text = |commands| {
            let p = TeleopPanel {
                t: &t,
                now,
                theme: Theme::default(),
                commands,
            };
            let l = &p.lines()[1];
            l.spans
                .iter()
                .map(|s| s.content.to_string())
                .collect::<String>()
        };
        assert_eq!(text(true), "DEADMAN ARMED 1.0s left");
        assert_eq!(
            text(false),
            "DEADMAN not armed: this console does not command (E engages)"
        );
    }
}
