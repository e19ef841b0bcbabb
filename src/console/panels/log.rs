//! The log pane: the most recent warnings and errors, newest at the bottom.

use crate::console::theme::Theme;
use crate::logging::ring::LogLine;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Paragraph, Widget};
use tracing::Level;

pub(crate) struct LogPanel<'a> {
    pub lines: &'a [LogLine],
    pub theme: Theme,
}

impl Widget for &LogPanel<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        let t = &self.theme;
        let n = area.height as usize;
        let lines: Vec<Line> = if self.lines.is_empty() {
            vec![Line::from(Span::styled("log: no warnings", t.label()))]
        } else {
            self.lines[self.lines.len().saturating_sub(n)..]
                .iter()
                .map(|l| {
                    let (tag, style) = if l.level == Level::ERROR {
                        ("ERROR", t.fault())
                    } else {
                        ("WARN ", t.warn())
                    };
                    Line::from(vec![
                        Span::styled(format!("{:>7.1}s ", l.secs), t.label()),
                        Span::styled(tag, style),
                        Span::raw(format!(" {}", l.text)),
                    ])
                })
                .collect()
        };
        Paragraph::new(lines).render(area, buf);
    }
}
