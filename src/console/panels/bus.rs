//! The bus monitor on the bench: for a device on a CAN bus, the bus's adapter (up or
//! down and why, bitrate, port, counters) and the last frame of every identifier on
//! the bus, decoded by its DBC, one identifier a line sorted by identifier, the way
//! `cantools monitor` shows a bus:
//!
//! ```text
//! <- 0x083 STEERING_REPORT  enabled: ENABLED  operator_override: NONE  dtcs: 0  age 12ms ×1234
//! ```
//!
//! `->` marks a frame adrive sent, `<-` one from the bus; an identifier the DBC does
//! not know shows its bytes. Where every frame's signals fit the box when wrapped, they
//! wrap under their identifier; else each identifier keeps one line, cut at the width,
//! and those below the box (or past the snapshot's cap) are counted on its last line. Drawn from the snapshot's
//! [`BusView`] alone, so an attached console shows the same.

use super::{fit, fmt_age, wrap};
use crate::console::theme::Theme;
use crate::snapshot::{BusView, FrameView};
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::style::Style;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Widget};
use std::time::Duration;

pub(crate) struct BusMonitor<'a> {
    pub bus: &'a BusView,
    pub theme: Theme,
}

/// Where a wrapped frame's signals continue.
const INDENT: &str = "      ";

impl<'a> BusMonitor<'a> {
    /// The rows the box takes with a line for each identifier (the state on one line,
    /// the count of those left out of the snapshot, the border).
    pub(crate) fn rows(bus: &BusView) -> u16 {
        let lines = 1 + bus.frames.len().max(1) + usize::from(bus.left_out > 0) + 2;
        u16::try_from(lines).unwrap_or(u16::MAX)
    }

    /// The box's title.
    pub(crate) fn title(&self) -> String {
        format!(
            " bus {}: last frame of each id (-> sent by adrive, <- from the bus) ",
            self.bus.name
        )
    }

    /// The adapter's state in groups: up or down and why, the bus error, bitrate,
    /// counters, port.
    fn state(&self) -> Vec<Vec<Span<'a>>> {
        let (b, t) = (self.bus, &self.theme);
        let l = |s: String| Span::styled(s, t.label());
        let mut groups = vec![match &b.down {
            Some(why) => vec![Span::styled(format!("DOWN: {why}"), t.fault())],
            None => vec![Span::styled("up", t.good())],
        }];
        if let Some(e) = &b.bus_error {
            groups.push(vec![Span::styled(format!("bus error: {e}"), t.fault())]);
        }
        groups.push(vec![Span::raw(format!("{} kbit/s", b.bitrate / 1000))]);
        let c = &b.counters;
        for (name, n, bad) in [
            ("rx", c.received, false),
            ("tx", c.sent, false),
            ("ack", c.acked, false),
            ("refused", c.refused, true),
            ("garbled", c.garbled, true),
            ("opens", c.opens, false),
        ] {
            let style = if bad && n > 0 { t.warn() } else { Style::new() };
            groups.push(vec![
                l(format!("{name} ")),
                Span::styled(n.to_string(), style),
            ]);
        }
        if !b.port.is_empty() {
            groups.push(vec![Span::raw(b.port.clone())]);
        }
        groups
    }

    /// One frame as groups of spans: the head (direction, identifier, message), each
    /// signal (or the bytes of an unknown one), then its age and count.
    fn groups(&self, f: &'a FrameView) -> Vec<Vec<Span<'a>>> {
        let t = &self.theme;
        let arrow = if f.sent {
            Span::styled("->", t.key())
        } else {
            Span::styled("<-", t.label())
        };
        let name = match &f.message {
            Some(m) => Span::styled(m.as_str(), t.title()),
            None => Span::styled("(unknown)", t.stale()),
        };
        let mut out = vec![vec![arrow, Span::raw(format!(" {} ", f.id)), name]];
        if f.message.is_none() || f.signals.is_empty() {
            if !f.data.is_empty() {
                out.push(vec![Span::raw(f.data.as_str())]);
            }
        } else {
            for (s, v) in f.signals.iter() {
                out.push(vec![
                    Span::styled(format!("{s}: "), t.label()),
                    Span::raw(v.as_str()),
                ]);
            }
        }
        let age = fmt_age(Some(Duration::from_secs_f64(f.age_ms.max(0.0) / 1e3)));
        out.push(vec![
            Span::styled("age ", t.label()),
            Span::raw(age),
            Span::styled(format!(" ×{}", f.count), t.label()),
        ]);
        out
    }

    /// One frame on one line, cut at `width` with `…`.
    fn one_line(&self, f: &'a FrameView, width: u16) -> Line<'a> {
        one_line(self.groups(f), width)
    }

    /// Every line of the box's inside, `width` × `height`: the adapter's state (on
    /// one line, cut, when the frames need the room), then the frames.
    pub(crate) fn lines(&self, width: u16, height: u16) -> Vec<Line<'a>> {
        let frames = &self.bus.frames;
        let state = wrap(self.state(), width, "");
        if frames.is_empty() {
            let mut out = state;
            out.push(Line::from(Span::styled(
                "no frames yet",
                self.theme.label(),
            )));
            return out;
        }
        let tight = state.len() + frames.len() > usize::from(height);
        let mut out = if tight {
            vec![one_line(self.state(), width)]
        } else {
            state
        };
        let room = usize::from(height).saturating_sub(out.len());
        let wrapped: Vec<Vec<Line>> = frames
            .iter()
            .map(|f| hanging(self.groups(f), width))
            .collect();
        let left_out = self.bus.left_out as usize;
        let note = |hidden: usize| {
            Line::from(Span::styled(
                format!("… {hidden} more identifiers"),
                self.theme.label(),
            ))
        };
        let need = usize::from(left_out > 0);
        if wrapped.iter().map(Vec::len).sum::<usize>() + need <= room {
            out.extend(wrapped.into_iter().flatten());
        } else {
            let shown = if frames.len() + need <= room {
                frames.len()
            } else {
                room.saturating_sub(1)
            };
            out.extend(frames[..shown].iter().map(|f| self.one_line(f, width)));
            let hidden = frames.len() - shown + left_out;
            if hidden > 0 {
                out.push(note(hidden));
            }
            return out;
        }
        if left_out > 0 {
            out.push(note(left_out));
        }
        out
    }
}

/// Groups two spaces apart in lines of at most `width` columns (a group is never
/// split), the first flush left and the others under [`INDENT`].
fn hanging<'a>(groups: Vec<Vec<Span<'a>>>, width: u16) -> Vec<Line<'a>> {
    let width = usize::from(width);
    let mut out: Vec<Line> = Vec::new();
    let mut line: Vec<Span> = Vec::new();
    let mut used = 0;
    // The line has no group yet.
    let mut fresh = true;
    for g in groups {
        let w: usize = g.iter().map(Span::width).sum();
        if !fresh && used + 2 + w > width {
            out.push(Line::from(std::mem::take(&mut line)));
            line.push(Span::raw(INDENT));
            used = INDENT.len();
            fresh = true;
        }
        if !fresh {
            line.push(Span::raw("  "));
            used += 2;
        }
        used += w;
        line.extend(g);
        fresh = false;
    }
    if !fresh {
        out.push(Line::from(line));
    }
    out
}

/// Groups two spaces apart on one line, cut at `width` with `…`.
fn one_line<'a>(groups: Vec<Vec<Span<'a>>>, width: u16) -> Line<'a> {
    let mut spans: Vec<Span> = Vec::new();
    for (i, g) in groups.into_iter().enumerate() {
        if i > 0 {
            spans.push(Span::raw("  "));
        }
        spans.extend(g);
    }
    fit::line(Line::from(spans), width)
}

impl Widget for &BusMonitor<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        let title = fit::title(&self.title(), area.width);
        let block = Block::bordered().title(Span::styled(title, self.theme.title()));
        let inner = block.inner(area);
        block.render(area, buf);
        fit::Fitted(self.lines(inner.width, inner.height)).render(inner, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::snapshot::Pairs;

    fn frame(id: u16, signals: &[(&str, &str)]) -> FrameView {
        FrameView {
            id: format!("0x{id:03X}"),
            message: Some(format!("MESSAGE_{id:X}")),
            sent: false,
            count: 7,
            age_ms: 20.0,
            data: "05 CC 00".into(),
            signals: signals
                .iter()
                .map(|(n, v)| (n.to_string(), v.to_string()))
                .collect::<Pairs<String>>(),
        }
    }

    fn text(lines: &[Line]) -> Vec<String> {
        lines.iter().map(|l| l.to_string()).collect()
    }

    /// More identifiers than the box has lines, on a narrow screen: one line each, cut
    /// with `…` where too long, the state on one line, and those below counted (the
    /// snapshot's own left-out ones too).
    #[test]
    fn a_small_box_keeps_one_line_per_identifier_and_counts_the_rest() {
        let long = [
            ("enabled", "ENABLED"),
            ("operator_override", "NONE"),
            ("dtcs", "0"),
        ];
        let bus = BusView {
            name: "kit".into(),
            port: "/dev/serial/by-id/usb-CANable_slcan-if00".into(),
            bitrate: 500_000,
            frames: (0..12).map(|i| frame(0x70 + i, &long)).collect(),
            left_out: 3,
            ..BusView::default()
        };
        let m = BusMonitor {
            bus: &bus,
            theme: Theme::default(),
        };
        let lines = text(&m.lines(60, 6));
        assert_eq!(lines.len(), 6, "{lines:#?}");
        assert!(lines.iter().all(|l| l.chars().count() <= 60), "{lines:#?}");
        assert!(lines[0].starts_with("up  500 kbit/s  rx 0"), "{lines:#?}");
        assert!(lines[0].ends_with('…'), "{lines:#?}");
        assert_eq!(
            lines[1],
            "<- 0x070 MESSAGE_70  enabled: ENABLED  operator_override…"
        );
        assert_eq!(lines[4].get(..9), Some("<- 0x073 "));
        // 12 - 4 shown, and 3 past the snapshot's cap.
        assert_eq!(lines[5], "… 11 more identifiers");
    }

    /// Room for every frame wrapped: the signals go on under their identifier, and
    /// its age and count close it.
    #[test]
    fn with_room_a_long_frame_wraps_under_its_identifier() {
        let bus = BusView {
            name: "kit".into(),
            bitrate: 250_000,
            frames: vec![frame(
                0x83,
                &[
                    ("enabled", "ENABLED"),
                    ("operator_override", "NONE"),
                    ("dtcs", "0"),
                ],
            )],
            ..BusView::default()
        };
        let m = BusMonitor {
            bus: &bus,
            theme: Theme::default(),
        };
        assert_eq!(
            text(&m.lines(64, 10)),
            [
                "up  250 kbit/s  rx 0  tx 0  ack 0  refused 0  garbled 0  opens 0",
                "<- 0x083 MESSAGE_83  enabled: ENABLED  operator_override: NONE",
                "      dtcs: 0  age 20ms ×7",
            ]
        );
    }
}
