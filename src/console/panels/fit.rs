//! Text cut to fit its room, the one way for the whole console: whole when it fits;
//! else cut at the end of a word where one ends in the room, always marked with "…",
//! and every parenthesis the kept part opened closed. An operator reading
//! `FAULT steer silent 1.0s no answer…` knows there is more; one reading
//! `… FAULT s` (a title cut at the panel's edge) does not even know which fault.
//!
//! [`shorten`] cuts plain text (the header's reason, box titles); [`line`] cuts a
//! styled line, the mark in the style of the text it follows; [`kept`] says how many
//! columns of a line survive the cut, which the view uses to tell whether a field on
//! that line was drawn; [`Fitted`] renders lines each cut to the area's width (the
//! `Paragraph` every panel without wrapping would use, which cuts silently).

use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Paragraph, Widget};
use unicode_width::UnicodeWidthStr;

/// The mark of a cut.
pub(crate) const MARK: &str = "…";

/// `text` in at most `max` columns: whole when it fits; else its longest prefix that
/// ends at a word, then "…", then a ")" for each parenthesis the prefix left open;
/// empty when not even "…" fits.
pub(crate) fn shorten(text: &str, max: usize) -> String {
    if text.width() <= max {
        return text.to_string();
    }
    if max == 0 {
        return String::new();
    }
    let prefix = cut_prefix(text, max);
    format!("{prefix}{MARK}{}", ")".repeat(open_parens(prefix)))
}

/// The part of `text` (wider than `max`) that [`shorten`] keeps before its mark.
fn cut_prefix(text: &str, max: usize) -> &str {
    // The longest prefix (in characters) whose shortened form fits.
    let fits = |p: &str| p.width() + 1 + open_parens(p) <= max;
    let mut end = 0;
    for (i, c) in text.char_indices() {
        let next = i + c.len_utf8();
        if !fits(&text[..next]) {
            break;
        }
        end = next;
    }
    let mut prefix = &text[..end];
    // Back to the end of a word (words are what spaces separate) when the cut fell
    // inside one; a first word too long for the room is cut where it must be.
    let inside_word =
        !word_ends(&text[end..]) && prefix.chars().last().is_some_and(|c| !c.is_whitespace());
    if inside_word {
        if let Some(at) = prefix.rfind(char::is_whitespace) {
            prefix = &prefix[..at];
        }
    }
    // Nothing dangling before the "…": a space, an opening parenthesis, a separator.
    prefix.trim_end_matches([' ', '(', ';', ',', ':', '·', '—', '›'])
}

/// Whether a word ends where `rest` starts: at a space, at the end, or at a
/// separator (`,` `;` `:` `)`) that a space or the end follows.
fn word_ends(rest: &str) -> bool {
    let mut c = rest.chars();
    match c.next() {
        None => true,
        Some(x) if x.is_whitespace() => true,
        Some(',' | ';' | ':' | ')') => c.next().is_none_or(char::is_whitespace),
        Some(_) => false,
    }
}

/// How many parentheses `s` leaves open.
pub(crate) fn open_parens(s: &str) -> usize {
    s.chars().fold(0usize, |depth, c| match c {
        '(' => depth + 1,
        ')' => depth.saturating_sub(1),
        _ => depth,
    })
}

/// How many columns of `line` stay when it is cut to `width` ([`line`]): all of it
/// when it fits.
pub(crate) fn kept(l: &Line, width: u16) -> usize {
    let text: String = l.spans.iter().map(|s| s.content.as_ref()).collect();
    if text.width() <= usize::from(width) {
        return text.width();
    }
    if width == 0 {
        return 0;
    }
    cut_prefix(&text, usize::from(width)).width()
}

/// `l` in at most `width` columns, cut as [`shorten`] cuts; the spans keep their
/// styles, the mark takes the style of the last one kept.
pub(crate) fn line(l: Line<'_>, width: u16) -> Line<'_> {
    let width = usize::from(width);
    if l.width() <= width {
        return l;
    }
    let text: String = l.spans.iter().map(|s| s.content.as_ref()).collect();
    let prefix = if width == 0 {
        ""
    } else {
        cut_prefix(&text, width)
    };
    let mut left = prefix.len();
    let mut spans: Vec<Span> = Vec::new();
    let mut last = l.spans.first().map(|s| s.style).unwrap_or_default();
    for s in l.spans {
        if left == 0 {
            break;
        }
        last = s.style;
        if s.content.len() <= left {
            left -= s.content.len();
            spans.push(s);
        } else {
            let part: String = s.content[..left].to_string();
            spans.push(Span::styled(part, s.style));
            left = 0;
        }
    }
    if width > 0 {
        let mark = format!("{MARK}{}", ")".repeat(open_parens(prefix)));
        spans.push(Span::styled(mark, last));
    }
    Line {
        spans,
        style: l.style,
        alignment: l.alignment,
    }
}

/// A box title (` gas raw traffic … `) for a box `width` columns wide: its borders'
/// corners take one column each.
pub(crate) fn title(text: &str, width: u16) -> String {
    let room = usize::from(width.saturating_sub(2));
    if text.width() <= room {
        return text.to_string();
    }
    // The cut title keeps its leading space and gets a trailing one where it can.
    let inner = text.trim_end();
    let cut = shorten(inner, room.saturating_sub(1));
    if cut.width() < room {
        format!("{cut} ")
    } else {
        cut
    }
}

/// Lines, each cut to the area's width ([`line`]), top to bottom: what a
/// `Paragraph` of lines too long for their room draws, with the cut marked.
pub(crate) struct Fitted<'a>(pub Vec<Line<'a>>);

impl Widget for Fitted<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        let lines: Vec<Line> = self.0.into_iter().map(|l| line(l, area.width)).collect();
        Paragraph::new(lines).render(area, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ratatui::style::{Color, Style};

    #[test]
    fn shorten_cuts_at_words_and_closes_parentheses() {
        let s = "gas is faulty (no reply within 100ms)";
        assert_eq!(shorten(s, 100), s);
        assert_eq!(shorten(s, 20), "gas is faulty (no…)");
        assert_eq!(shorten(s, 16), "gas is faulty…");
        assert_eq!(shorten(s, 4), "gas…");
        assert_eq!(shorten(s, 3), "ga…");
        assert_eq!(shorten(s, 1), "…");
        assert_eq!(shorten(s, 0), "");
        assert_eq!(shorten("a (b (c d e f g) h)", 12), "a (b (c d…))");
        // Nothing dangling before the mark: a separator goes with the word it follows.
        assert_eq!(
            shorten("faults silent · e-stop run · engine running", 24),
            "faults silent · e-stop…"
        );
    }

    #[test]
    fn a_styled_line_is_cut_at_a_word_in_its_styles() {
        let red = Style::new().fg(Color::Red);
        let l = Line::from(vec![
            Span::raw("STEER -1…1 cmd 0.500 "),
            Span::styled("FAULT sim: silent", red),
        ]);
        let cut = line(l.clone(), 30);
        let text: String = cut.spans.iter().map(|s| s.content.as_ref()).collect();
        assert_eq!(text, "STEER -1…1 cmd 0.500 FAULT…");
        assert_eq!(
            cut.spans.last().unwrap().style,
            red,
            "the mark is the fault's"
        );
        assert_eq!(kept(&l, 30), "STEER -1…1 cmd 0.500 FAULT".width());
        assert_eq!(line(l.clone(), 200), l, "a line that fits is left alone");
        assert_eq!(kept(&l, 200), l.width());
    }

    #[test]
    fn fitted_lines_are_cut_with_the_mark_in_a_buffer() {
        let mut buf = Buffer::empty(Rect::new(0, 0, 24, 2));
        Fitted(vec![
            Line::from("  12.1s WARN  my.toml:3: [main] has no STOP key left"),
            Line::from("short"),
        ])
        .render(buf.area, &mut buf);
        assert_eq!(
            buf,
            Buffer::with_lines(["  12.1s WARN  my.toml:3…", "short                   "])
        );
        // A word is not cut inside: `10.5ms` stays whole or goes.
        for (width, want) in [(12, "txn p50…    "), (16, "txn p50 10.5ms… ")] {
            let mut buf = Buffer::empty(Rect::new(0, 0, width, 1));
            Fitted(vec![Line::from("txn p50 10.5ms p99")]).render(buf.area, &mut buf);
            assert_eq!(buf, Buffer::with_lines([want]));
        }
    }

    #[test]
    fn a_box_title_is_cut_inside_its_corners() {
        let t = " gas raw traffic: dir, time ago, hex, text — sim: silent ";
        assert_eq!(title(t, 100), t);
        let cut = title(t, 40);
        assert!(cut.width() <= 38, "{cut:?}");
        assert_eq!(cut, " gas raw traffic: dir, time ago, hex… ");
    }
}
