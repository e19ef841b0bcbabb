//! The log pane: the most recent warnings and errors, newest at the bottom, each
//! line cut to the width at a word with `…`.

use super::fit::Fitted;
use crate::console::theme::Theme;
use crate::logging::ring::LogLine;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::text::{Line, Span};
use ratatui::widgets::Widget;
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
        Fitted(lines).render(area, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A keymap's warning was cut at 100 columns, mid-word: cut at a word, marked.
    #[test]
    fn a_warning_too_long_for_the_pane_is_cut_at_a_word_with_a_mark() {
        let lines = [LogLine {
            secs: 12.1,
            level: Level::WARN,
            text: "my.toml:3: [main] has no STOP key left: this record takes <Space> \
                   away from stop; expected run = \"stop\" on some key in every mode"
                .into(),
        }];
        let p = LogPanel {
            lines: &lines,
            theme: Theme::default(),
        };
        let mut buf = Buffer::empty(Rect::new(0, 0, 100, 1));
        (&p).render(buf.area, &mut buf);
        let row: String = (0..100).map(|x| buf[(x, 0)].symbol()).collect();
        assert_eq!(
            row.trim_end(),
            "   12.1s WARN  my.toml:3: [main] has no STOP key left: this record takes <Space> away from stop…"
        );
    }
}
