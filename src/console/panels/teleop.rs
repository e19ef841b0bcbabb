//! The teleop panel: set points, a steering gauge and the deadman, impossible to miss.

use crate::console::model::{Deadman, Teleop};
use crate::console::theme::Theme;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::style::Modifier;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Paragraph, Widget};
use std::time::Instant;

pub(crate) struct TeleopPanel<'a> {
    pub t: &'a Teleop,
    pub now: Instant,
    pub theme: Theme,
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
            Deadman::Armed { left } => Span::styled(
                format!("DEADMAN ARMED {:.1}s left", left.as_secs_f64()),
                th.good().add_modifier(Modifier::BOLD),
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

impl Widget for &TeleopPanel<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        Paragraph::new(self.lines()).render(area, buf);
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
}
