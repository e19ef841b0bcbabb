//! The confirmation dialog: the question and its answers, from the keymap.

use super::fit;
use super::hint::short;
use crate::console::keymap::{Action, Keymap, Mode};
use crate::console::model::Question;
use crate::console::theme::Theme;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Clear, Widget};
use unicode_width::{UnicodeWidthChar, UnicodeWidthStr};

pub(crate) struct Dialog<'a> {
    pub ask: Question,
    /// The question in words ([`crate::console::model::Model::question_text`]).
    pub text: &'a str,
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
        self.render_seen(area, buf);
    }
}

impl Dialog<'_> {
    /// Draw the dialog centred in `area`; whether its question and its answers were
    /// drawn whole (what may then be answered).
    pub(crate) fn render_seen(&self, area: Rect, buf: &mut Buffer) -> bool {
        let w = area.width.min(60);
        // Room for the whole question where the area has it, and its answers.
        let lines = wrapped(self.text, w.saturating_sub(2)).len() as u16;
        let h = area.height.min((lines + 4).max(6));
        let r = Rect {
            x: area.x + (area.width - w) / 2,
            y: area.y + (area.height - h) / 2,
            width: w,
            height: h,
        };
        Clear.render(r, buf);
        let style = match self.ask {
            Question::Interlocks(false)
            | Question::Engage
            | Question::Take
            | Question::Characterize(_) => self.theme.warn(),
            _ => self.theme.title(),
        };
        let block = Block::bordered()
            .border_style(style)
            .title(Span::styled(" confirm ", style));
        let inner = block.inner(r);
        block.render(r, buf);
        let answers = Line::from(vec![
            Span::styled(keys(self.map, Action::Confirm), self.theme.key()),
            Span::raw(" yes   "),
            Span::styled(keys(self.map, Action::Cancel), self.theme.key()),
            Span::raw(" no"),
        ]);
        let mut question = wrapped(self.text, inner.width);
        let whole = question.len() + 2 <= usize::from(inner.height)
            && answers.width() <= usize::from(inner.width)
            && question
                .iter()
                .all(|l| l.width() <= usize::from(inner.width));
        // Rows too few for the whole question: what is left out is marked.
        let rows = usize::from(inner.height.saturating_sub(2)).max(1);
        if question.len() > rows {
            question.truncate(rows);
            if let Some(last) = question.last_mut() {
                last.push_str(fit::MARK);
            }
        }
        let mut lines: Vec<Line> = question
            .into_iter()
            .map(|l| Line::from(Span::styled(l, style)))
            .collect();
        lines.push(Line::default());
        lines.push(answers);
        fit::Fitted(lines).render(inner, buf);
        whole
    }
}

/// `text` in lines of at most `width` columns, broken between words; a word longer
/// than a line (a directory's path) is broken across lines, so that a question drawn in
/// enough rows is drawn whole.
fn wrapped(text: &str, width: u16) -> Vec<String> {
    let width = usize::from(width.max(1));
    let mut out: Vec<String> = Vec::new();
    let mut line = String::new();
    for word in text.split_whitespace() {
        if !line.is_empty() && line.width() + 1 + word.width() > width {
            out.push(std::mem::take(&mut line));
        }
        if !line.is_empty() {
            line.push(' ');
        }
        for c in word.chars() {
            if line.width() + c.width().unwrap_or(0) > width {
                out.push(std::mem::take(&mut line));
            }
            line.push(c);
        }
    }
    if !line.is_empty() {
        out.push(line);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(buf: &Buffer) -> Vec<String> {
        (0..buf.area.height)
            .map(|y| (0..buf.area.width).map(|x| buf[(x, y)].symbol()).collect())
            .collect()
    }

    /// A dialog is answered only when drawn whole: its question and its answers. In
    /// too small a room it is cut, each line marked, and not whole.
    #[test]
    fn a_dialog_says_whether_it_was_drawn_whole() {
        let map = Keymap::default_map();
        let d = Dialog {
            ask: Question::Take,
            text: Question::Take.text(),
            map: &map,
            theme: Theme::default(),
        };
        let mut buf = Buffer::empty(Rect::new(0, 0, 80, 20));
        assert!(d.render_seen(buf.area, &mut buf));
        let text = rows(&buf).join("\n");
        assert!(
            text.contains("Take command? The source commanding now is refused from"),
            "{text}"
        );
        assert!(text.contains("y yes   n/Esc no"), "{text}");
        let mut buf = Buffer::empty(Rect::new(0, 0, 24, 5));
        assert!(!d.render_seen(buf.area, &mut buf));
        assert_eq!(rows(&buf)[1], "│Take command? The…    │");
    }

    /// A characterization's question names a directory longer than a line: the path is
    /// broken across lines, and the dialog grows to hold the whole question where the
    /// screen has the rows — at 80×24 too — so that it can be answered.
    #[test]
    fn a_long_question_with_a_path_is_drawn_whole_where_there_are_rows() {
        let map = Keymap::default_map();
        let text = "Characterize steer (step, sweep, deadband, backlash, rate, delay) into \
            /home/operator/a/rather/long/working/directory/characterize-steer-20261127-140812? \
            It moves steer over 90 % of its range for about 30 s; the vehicle must be \
            stopped, in park, with the brake held. Checked now: stopped, in park, the \
            brake held.";
        let d = Dialog {
            ask: Question::Characterize(crate::value::DeviceId(0)),
            text,
            map: &map,
            theme: Theme::default(),
        };
        // The bench's body at 80×24 is 21 rows.
        let mut buf = Buffer::empty(Rect::new(0, 0, 80, 21));
        assert!(d.render_seen(buf.area, &mut buf));
        let all = rows(&buf).join("\n");
        // The path, broken where the line ends.
        assert!(all.contains("directory/characteriz│"), "{all}");
        assert!(all.contains("│e-steer-20261127-140812?"), "{all}");
        assert!(all.contains("brake held."), "{all}");
        assert!(all.contains("y yes   n/Esc no"), "{all}");
        // Too few rows: not whole, and so not answerable.
        let mut buf = Buffer::empty(Rect::new(0, 0, 80, 8));
        assert!(!d.render_seen(buf.area, &mut buf));
    }
}
