//! The supervisory panel: engaged or not and why, interlocks on/off, faulty devices
//! with their last error, the console's accel command, and recovery in progress
//! (`-` until the supervisor thread exists).

use crate::console::model::{Field, Model};
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::style::Style;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Paragraph, Widget};

pub struct SupervisorPanel<'a> {
    pub m: &'a Model,
    pub cursor: bool,
}

impl SupervisorPanel<'_> {
    pub fn lines(&self) -> Vec<Line<'static>> {
        let (s, t) = (&self.m.snap, &self.m.theme);
        let l = |x: &'static str| Span::styled(x, t.label());
        let engaged = if s.engaged {
            Span::styled("1", t.good())
        } else {
            Span::styled("0", t.warn())
        };
        let interlocks = if s.interlocks {
            Span::styled("on", t.good())
        } else {
            Span::styled("OFF", t.fault())
        };
        let accel_text = self
            .m
            .accel
            .map(|a| format!("{a:.3}"))
            .unwrap_or_else(|| "-".into());
        let accel = match &self.m.edit {
            Some(e) if e.field == Field::Accel => Span::styled(
                format!("{}▏", e.buffer),
                if e.error.is_some() {
                    t.fault()
                } else {
                    t.editing()
                },
            ),
            _ if self.cursor && self.m.field() == Field::Accel => {
                Span::styled(accel_text, t.cursor())
            }
            _ => Span::raw(accel_text),
        };
        let first = Line::from(vec![
            Span::styled("SUPERVISORY", t.title()),
            l(" engaged "),
            engaged,
            l(" interlocks "),
            interlocks,
        ]);
        let faulty: Vec<String> = s
            .devices
            .iter()
            .filter(|d| d.faulty)
            .map(|d| match &d.last_error {
                Some(e) => format!("{} ({e})", d.role),
                None => d.role.to_string(),
            })
            .collect();
        let faults = if faulty.is_empty() {
            Span::raw("none")
        } else {
            Span::styled(faulty.join(", "), t.fault())
        };
        let why_style = if s.engaged { Style::new() } else { t.warn() };
        let mut out = vec![
            first,
            Line::from(vec![
                l("faults "),
                faults,
                l("  accel "),
                accel,
                l("  recovery "),
                Span::raw("-"),
            ]),
            Line::from(vec![
                l("why "),
                Span::styled(s.gate_reason.clone(), why_style),
            ]),
        ];
        if !s.engaged && !s.blockers.is_empty() {
            out.push(Line::from(vec![
                l("engage blocked: "),
                Span::styled(s.blockers.join("; "), t.warn()),
            ]));
        }
        out
    }
}

impl Widget for &SupervisorPanel<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        Paragraph::new(self.lines()).render(area, buf);
    }
}
