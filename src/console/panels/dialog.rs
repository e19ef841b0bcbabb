//! The confirmation dialog: the question and its answers, from the keymap.

use super::hint::short;
use crate::console::keymap::{Action, Keymap, Mode};
use crate::console::model::Ask;
use crate::console::theme::Theme;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Clear, Paragraph, Widget, Wrap};

pub(crate) struct Dialog<'a> {
    pub ask: Ask,
    pub map: &'a Keymap,
    pub theme: Theme,
}

fn keys(map: &Keymap, a: Action) -> String {
    map.bindings(Mode::Confirm)
        .iter()
        .filter(|b| b.run == a)
        .map(|b| short(b.on))
        .collect::<Vec<_>>()
        .join("/")
}

impl Widget for &Dialog<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        let w = area.width.min(60);
        let h = area.height.min(6);
        let r = Rect {
            x: area.x + (area.width - w) / 2,
            y: area.y + (area.height - h) / 2,
            width: w,
            height: h,
        };
        Clear.render(r, buf);
        let style = match self.ask {
            Ask::Interlocks(false) | Ask::Engage | Ask::Take => self.theme.warn(),
            _ => self.theme.title(),
        };
        let block = Block::bordered()
            .border_style(style)
            .title(Span::styled(" confirm ", style));
        let inner = block.inner(r);
        block.render(r, buf);
        let lines = vec![
            Line::from(Span::styled(self.ask.question(), style)),
            Line::default(),
            Line::from(vec![
                Span::styled(keys(self.map, Action::Confirm), self.theme.key()),
                Span::raw(" yes   "),
                Span::styled(keys(self.map, Action::Cancel), self.theme.key()),
                Span::raw(" no"),
            ]),
        ];
        Paragraph::new(lines)
            .wrap(Wrap { trim: true })
            .render(inner, buf);
    }
}
