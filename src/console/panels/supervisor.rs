//! The supervisory panel: engaged or not and why, interlocks on/off, the console's
//! accel command, and what the supervisor sees — every fault with its device, kind,
//! age and cause (in red), the recovery procedure in progress with each of its steps
//! (done, current, to come), its try and elapsed time, and the last outcome.
//!
//! On a small screen it is two lines beside the network panel ([`SupervisorPanel`]
//! with `compact`) plus, while there are faults or a recovery, a full-width strip
//! under them ([`SupervisorStrip`]): one line for the recovery
//! (`RECOVERY engine_stall 4/7 park (try 1/3) 2.1s  then starter › back in drive`)
//! and one per fault (a fault too long for the width goes on over the next lines
//! where there is room) — or all of them side by side when it has one line only. On a
//! larger screen it is one taller panel.

use super::{fit, wrap};
use crate::console::model::{Field, Model};
use crate::console::theme::Theme;
use crate::controls::{secs, Scene};
use crate::snapshot::RecoveryView;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::style::Style;
use ratatui::text::{Line, Span};
use ratatui::widgets::Widget;

pub(crate) struct SupervisorPanel<'a> {
    pub m: &'a Model,
    pub cursor: bool,
    /// Two lines only (the strip shows faults and recovery).
    pub compact: bool,
}

/// One fault on one line, all red.
fn fault_line(text: String, t: &Theme, tag: &'static str) -> Line<'static> {
    Line::from(vec![
        Span::styled(tag, t.fault()),
        Span::styled(text, t.fault()),
    ])
}

/// A device in the driver's hands: not a failure, so not red.
fn override_line(text: String, t: &Theme) -> Line<'static> {
    Line::from(vec![
        Span::styled("OVERRIDE ", t.warn()),
        Span::styled(text, t.warn()),
    ])
}

/// The step tokens of a procedure: `✓ done`, `▶ current` (highlighted), `· to come`.
fn step_spans(r: &RecoveryView, t: &Theme) -> Vec<Span<'static>> {
    r.steps
        .iter()
        .enumerate()
        .map(|(i, s)| {
            use std::cmp::Ordering::{Equal, Greater, Less};
            match i.cmp(&r.step) {
                Less => Span::styled(format!("✓ {s}"), t.good()),
                Equal => Span::styled(format!("▶ {s}"), t.warn().patch(t.cursor())),
                Greater => Span::styled(format!("· {s}"), t.label()),
            }
        })
        .collect()
}

impl SupervisorPanel<'_> {
    /// Whether there is anything to show beyond "all well".
    pub(crate) fn active(&self) -> bool {
        let s = &self.m.snap;
        s.supervisor.recovery.is_some() || !s.fault_texts().is_empty()
    }

    fn accel(&self) -> Span<'static> {
        let t = &self.m.theme;
        let text = self
            .m
            .accel
            .map(|a| format!("{a:.3}"))
            .unwrap_or_else(|| "-".into());
        // Gas and brake both applied (interlocks off): both, in the fault's colour.
        let both = self
            .m
            .accel
            .and(self.m.snap.gas_and_brake())
            .map(|(gas, brake)| format!("gas {gas:.3} + brake {brake:.3}"));
        match &self.m.edit {
            Some(e) if e.field == Field::Accel => Span::styled(
                format!("{}▏", e.buffer),
                if e.error.is_some() {
                    t.fault()
                } else {
                    t.editing()
                },
            ),
            _ if self.cursor && self.m.field() == Field::Accel => {
                Span::styled(both.unwrap_or(text), t.cursor())
            }
            _ => match both {
                Some(both) => Span::styled(both, t.fault()),
                None => Span::raw(text),
            },
        }
    }

    fn first(&self) -> Line<'static> {
        let (s, t) = (&self.m.snap, &self.m.theme);
        let l = |x: &'static str| Span::styled(x, t.label());
        Line::from(vec![
            Span::styled("SUPERVISORY", t.title()),
            l(" engaged "),
            if s.gate.engaged {
                Span::styled("1", t.good())
            } else {
                Span::styled("0", t.warn())
            },
            l(" interlocks "),
            if s.gate.interlocks {
                Span::styled("on", t.good())
            } else {
                Span::styled("OFF", t.fault())
            },
        ])
    }

    /// The two lines of a small screen: state, then accel, how many faults and the
    /// recovery step (the strip under them has the details).
    pub(crate) fn compact_lines(&self) -> Vec<Line<'static>> {
        let (sup, t) = (&self.m.snap.supervisor, &self.m.theme);
        let l = |x: &'static str| Span::styled(x, t.label());
        let recovery = match &sup.recovery {
            Some(r) => Span::styled(
                format!(
                    "{}/{} {}",
                    r.step + 1,
                    r.steps.len(),
                    r.steps.get(r.step).map(String::as_str).unwrap_or("done")
                ),
                t.warn(),
            ),
            None => Span::raw("-"),
        };
        let n = self.m.snap.fault_texts().len();
        let faults = if n == 0 {
            Span::raw("none")
        } else {
            Span::styled(n.to_string(), t.fault())
        };
        let mut second = Vec::new();
        if self.m.snap.gate.accel {
            second.extend([l("accel "), self.accel(), l("  ")]);
        }
        second.extend([l("faults "), faults, l("  recovery "), recovery]);
        vec![self.first(), Line::from(second)]
    }

    /// Everything, for a larger screen `width` columns wide.
    pub(crate) fn full_lines(&self, width: u16) -> Vec<Line<'static>> {
        let (s, t) = (&self.m.snap, &self.m.theme);
        let sup = &s.supervisor;
        let l = |x: &'static str| Span::styled(x, t.label());
        let first = self.first();
        // `accel` where the vehicle has it (throttle and brake bound): on the first
        // line when it fits there, else on a line of its own.
        let accel = s.gate.accel.then(|| [l("accel "), self.accel()]);
        let accel_width = accel
            .as_ref()
            .map_or(0, |a| 2 + a.iter().map(Span::width).sum::<usize>());
        let (first, accel_line) = match accel {
            Some(a) if first.width() + accel_width <= usize::from(width) => {
                let mut first = first;
                first.spans.push(l("  "));
                first.spans.extend(a);
                (first, None)
            }
            a => (first, a.map(|a| Line::from(Vec::from(a)))),
        };
        let why_style = if s.gate.engaged {
            Style::new()
        } else {
            t.warn()
        };
        let mut out = vec![first];
        out.extend(accel_line);
        out.push(Line::from(vec![
            l("why "),
            Span::styled(s.gate.reason.clone(), why_style),
        ]));
        if !s.gate.engaged && !s.gate.blockers.is_empty() {
            out.push(Line::from(vec![
                l("engage blocked: "),
                Span::styled(s.gate.blockers.join("; "), t.warn()),
            ]));
        }
        let faults = s.fault_texts();
        if faults.is_empty() {
            out.push(Line::from(vec![l("faults "), Span::raw("none")]));
        }
        out.extend(faults.into_iter().map(|f| fault_line(f, t, "fault ")));
        out.extend(s.override_texts().into_iter().map(|o| override_line(o, t)));
        match &sup.recovery {
            Some(r) => {
                out.push(Line::from(vec![
                    l("recovery "),
                    Span::styled(r.name.clone(), t.warn()),
                    Span::raw(format!(
                        "  step {}/{}  try {}/{}  {}",
                        r.step + 1,
                        r.steps.len(),
                        r.attempt,
                        r.attempts,
                        secs(r.elapsed_ms)
                    )),
                ]));
                let steps = step_spans(r, t).into_iter().map(|s| vec![s]).collect();
                out.extend(wrap(steps, width, "  "));
            }
            None => out.push(Line::from(vec![l("recovery "), Span::raw("-")])),
        }
        if let Some(o) = &sup.last_outcome {
            let style = if sup.outcome == Some(crate::snapshot::OutcomeKind::GaveUp) {
                t.fault()
            } else {
                Style::new()
            };
            out.push(Line::from(vec![l("last "), Span::styled(o.clone(), style)]));
        }
        out
    }
}

impl SupervisorPanel<'_> {
    /// Draw the panel in `area`, each line cut to its width; whether the accel value
    /// (or its edit) was drawn whole.
    pub(crate) fn render_seen(&self, area: Rect, buf: &mut Buffer) -> bool {
        let lines = if self.compact {
            self.compact_lines()
        } else {
            self.full_lines(area.width)
        };
        let accel = self.accel().content.into_owned();
        // The accel value is the span after its label.
        let shown = lines.iter().take(usize::from(area.height)).any(|l| {
            let mut end = 0;
            let mut label = false;
            for s in &l.spans {
                end += s.width();
                if label && s.content == accel {
                    return end <= fit::kept(l, area.width);
                }
                label = s.content == "accel ";
            }
            false
        });
        fit::Fitted(lines).render(area, buf);
        self.m.snap.gate.accel && shown
    }
}

impl Widget for &SupervisorPanel<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        self.render_seen(area, buf);
    }
}

/// The full-width lines of a small screen while the supervisor has something to
/// show: the recovery in progress, then one line per fault (as many as fit).
pub(crate) struct SupervisorStrip<'a> {
    pub snap: &'a Scene,
    pub theme: Theme,
}

impl SupervisorStrip<'_> {
    pub(crate) fn lines(&self) -> Vec<Line<'static>> {
        let t = &self.theme;
        let mut out = Vec::new();
        if let Some(r) = &self.snap.supervisor.recovery {
            let mut spans = vec![
                Span::styled("RECOVERY ", t.warn()),
                Span::styled(format!("{} {}", r.describe(), secs(r.elapsed_ms)), t.warn()),
            ];
            let next: Vec<&str> = r
                .steps
                .iter()
                .skip(r.step + 1)
                .map(String::as_str)
                .collect();
            if !next.is_empty() {
                spans.push(Span::styled("  then ", t.label()));
                spans.push(Span::styled(next.join(" › "), t.label()));
            }
            out.push(Line::from(spans));
        }
        out.extend(
            self.snap
                .fault_texts()
                .into_iter()
                .map(|f| fault_line(f, t, "FAULT ")),
        );
        out.extend(
            self.snap
                .override_texts()
                .into_iter()
                .map(|o| override_line(o, t)),
        );
        out
    }
}

/// `line` in lines of at most `width` columns, broken between words, each after the
/// first indented by `indent` columns: a fault's cause (a port's path) is read whole,
/// not cut at the edge. A word wider than a line is left to be cut.
fn wrap_words(line: Line<'static>, width: u16, indent: usize) -> Vec<Line<'static>> {
    let width = width as usize;
    if line.width() <= width || width <= indent {
        return vec![line];
    }
    let mut out: Vec<Line<'static>> = Vec::new();
    let mut current: Vec<Span<'static>> = Vec::new();
    let (mut used, mut words) = (0, 0);
    for span in line.spans {
        let style = span.style;
        for word in span.content.split_inclusive(' ') {
            let bare = word.trim_end().chars().count();
            if words > 0 && used + bare > width {
                out.push(Line::from(std::mem::take(&mut current)));
                current.push(Span::raw(" ".repeat(indent)));
                (used, words) = (indent, 0);
            }
            current.push(Span::styled(word.to_string(), style));
            used += word.chars().count();
            words += 1;
        }
    }
    out.push(Line::from(current));
    out
}

impl SupervisorStrip<'_> {
    /// [`SupervisorStrip::lines`] for `width` columns: a line too long for it goes on
    /// over the next lines, under its text.
    pub(crate) fn lines_in(&self, width: u16) -> Vec<Line<'static>> {
        self.lines()
            .into_iter()
            .flat_map(|l| {
                let indent = l.spans.first().map_or(0, |s| s.content.chars().count());
                wrap_words(l, width, indent)
            })
            .collect()
    }
}

impl Widget for &SupervisorStrip<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        let n = area.height as usize;
        // Wrapped where there is room for every line wrapped; else one line each, and
        // what is left out counted in whole lines.
        let wrapped = self.lines_in(area.width);
        let mut lines = if wrapped.len() <= n {
            wrapped
        } else {
            self.lines()
        };
        if lines.len() > 1 && n == 1 {
            // One line for all (many devices on a small screen): side by side, as
            // many as the width shows.
            let mut one = Vec::new();
            for (i, l) in lines.into_iter().enumerate() {
                if i > 0 {
                    one.push(Span::styled(" · ", self.theme.label()));
                }
                one.extend(l.spans);
            }
            lines = vec![Line::from(one)];
        } else if lines.len() > n && n > 0 {
            let more = lines.len() - (n - 1);
            lines.truncate(n - 1);
            lines.push(Line::from(Span::styled(
                format!("… {more} more (a larger terminal shows them all)"),
                self.theme.fault(),
            )));
        }
        fit::Fitted(lines).render(area, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::snapshot::{FaultKind, FaultView, Snapshot, SupervisorView};
    use ratatui::style::Color;
    use unicode_width::UnicodeWidthStr;

    fn sample() -> Scene {
        let supervisor = SupervisorView {
            faults: vec![
                FaultView {
                    kind: FaultKind::EngineStall,
                    device: None,
                    cause: "engine stopped (0 rpm) in drive".into(),
                    age_ms: 3_050.0,
                },
                FaultView {
                    kind: FaultKind::Silent,
                    device: Some("brake".into()),
                    cause: "no status for 1500 ms (max 500 ms)".into(),
                    age_ms: 1_500.0,
                },
            ],
            recovery: Some(RecoveryView {
                step: 3,
                elapsed_ms: 2_140.0,
                ..crate::testkit::engine_stall()
            }),
            last_outcome: None,
            history: Vec::new(),
            ..SupervisorView::default()
        };
        Scene {
            snap: Snapshot {
                supervisor,
                ..Snapshot::default()
            },
            ..Scene::default()
        }
    }

    fn render(w: &impl Fn(Rect, &mut Buffer), width: u16, height: u16) -> Buffer {
        let mut buf = Buffer::empty(Rect::new(0, 0, width, height));
        w(buf.area, &mut buf);
        buf
    }

    fn row(b: &Buffer, y: u16) -> String {
        (0..b.area.width)
            .map(|x| b[(x, y)].symbol().to_string())
            .collect::<String>()
            .trim_end()
            .to_string()
    }

    #[test]
    fn the_strip_shows_the_recovery_step_then_each_fault_in_red() {
        let snap = sample();
        let s = SupervisorStrip {
            snap: &snap,
            theme: Theme::default(),
        };
        let b = render(&|a, buf| (&s).render(a, buf), 80, 3);
        assert_eq!(
            row(&b, 0),
            "RECOVERY engine_stall 4/7 park (try 1/3) 2.1s  then starter › back in drive…"
        );
        assert_eq!(
            row(&b, 1),
            "FAULT engine_stall 3.0s engine stopped (0 rpm) in drive"
        );
        assert_eq!(
            row(&b, 2),
            "FAULT brake silent 1.5s no status for 1500 ms (max 500 ms)"
        );
        for y in [1, 2] {
            assert_eq!(b[(0, y)].fg, Color::Red);
            assert_eq!(b[(12, y)].fg, Color::Red, "the cause is red too");
        }
        // Too little room: the last line says how many are left out.
        let b = render(&|a, buf| (&s).render(a, buf), 80, 2);
        assert_eq!(row(&b, 1), "… 2 more (a larger terminal shows them all)");
    }

    /// A stuck engine thread comes first; a device gone says what adrive waits for, in
    /// red like any fault.
    #[test]
    fn the_strip_shows_a_stalled_thread_first_and_what_a_gone_device_waits_for() {
        use crate::snapshot::{StallView, WaitingView};
        let mut snap = sample();
        let sup = &mut snap.snap.supervisor;
        sup.recovery = None;
        sup.faults = vec![FaultView {
            kind: FaultKind::Disconnected,
            device: Some("horn".into()),
            cause: "cannot open /dev/ttyUSB3: No such file or directory".into(),
            age_ms: 25_300.0,
        }];
        sup.waiting = vec![WaitingView {
            device: "horn".into(),
            port: "/dev/ttyUSB3".into(),
            error: "No such file or directory".into(),
            gone_ms: 25_300.0,
            retry_ms: 5_000.0,
            needed: false,
        }];
        sup.stalled = vec![StallView {
            thread: "steer/status".into(),
            quiet_ms: 1_400.0,
            bound_ms: 100.0,
        }];
        let s = SupervisorStrip {
            snap: &snap,
            theme: Theme::default(),
        };
        let b = render(&|a, buf| (&s).render(a, buf), 120, 2);
        assert_eq!(
            row(&b, 0),
            "FAULT STALLED steer/status has not turned its loop for 1.4 s (bound 0.10 s)"
        );
        assert_eq!(
            row(&b, 1),
            "FAULT horn disconnected 25.3s waiting for horn on /dev/ttyUSB3: No such file or directory, retrying every 5s"
        );
        for y in [0, 1] {
            assert_eq!(b[(0, y)].fg, Color::Red);
        }
    }

    #[test]
    fn steps_wrap_and_the_current_one_is_highlighted() {
        let r = sample().snap.supervisor.recovery.clone().unwrap();
        let t = Theme::default();
        let steps = step_spans(&r, &t).into_iter().map(|s| vec![s]).collect();
        let lines = wrap(steps, 40, "  ");
        let text: Vec<String> = lines
            .iter()
            .map(|l| l.spans.iter().map(|s| s.content.as_ref()).collect())
            .collect();
        assert_eq!(
            text,
            [
                "  ✓ gas off  ✓ brake  ✓ wait stopped",
                "  ▶ park  · starter  · back in drive",
                "  · release",
            ]
        );
        let park = &lines[1].spans[1];
        assert_eq!(park.style, t.warn().patch(t.cursor()));
    }

    fn model(accel: bool) -> Model {
        use crate::console::keymap::Keymap;
        use crate::controls::{capture, Sources};
        use std::time::{Duration, Instant};
        let now = Instant::now();
        let mut frame = capture(&crate::testkit::gate(now), &Sources::default(), now, None);
        frame.snap.gate.accel = accel;
        Model::new(
            Keymap::default_map(),
            Theme::default(),
            frame,
            Duration::from_secs(1),
        )
    }

    fn texts(lines: &[Line]) -> Vec<String> {
        lines
            .iter()
            .map(|l| l.spans.iter().map(|s| s.content.as_ref()).collect())
            .collect()
    }

    /// With `--only steer` the panel is 40 columns wide and its first line ran on
    /// into `… interlocks on  ac` beside the network panel, offering an `accel` the
    /// vehicle did not have (no throttle and brake bound). `accel` shows only where
    /// it exists, and where it does not fit the first line it takes a line of its own.
    #[test]
    fn accel_shows_only_where_it_exists_and_never_runs_off_the_panel() {
        let without = model(false);
        let p = SupervisorPanel {
            m: &without,
            cursor: false,
            compact: false,
        };
        let full = texts(&p.full_lines(40));
        assert!(full.iter().all(|l| !l.contains("accel")), "{full:#?}");
        let compact = texts(&p.compact_lines());
        assert!(compact.iter().all(|l| !l.contains("accel")), "{compact:#?}");
        assert_eq!(compact[1], "faults none  recovery -");

        let with = model(true);
        let p = SupervisorPanel {
            m: &with,
            cursor: false,
            compact: false,
        };
        let full = texts(&p.full_lines(40));
        assert!(full.iter().all(|l| l.width() <= 40), "{full:#?}");
        assert_eq!(full[0], "SUPERVISORY engaged 0 interlocks on");
        assert_eq!(full[1], "accel -");
        let wide = texts(&p.full_lines(60));
        assert_eq!(wide[0], "SUPERVISORY engaged 0 interlocks on  accel -");
        let compact = texts(&p.compact_lines());
        assert_eq!(compact[1], "accel -  faults none  recovery -");
    }

    /// A recovery that gave up is red, whatever its words; any other outcome is not:
    /// the panel reads the outcome's type.
    #[test]
    fn an_outcome_that_gave_up_is_red_by_its_type() {
        use crate::snapshot::OutcomeKind;
        let mut m = model(false);
        let last = |m: &Model| {
            let p = SupervisorPanel {
                m,
                cursor: false,
                compact: false,
            };
            let lines = p.full_lines(80);
            let line = lines.last().unwrap().clone();
            (line.spans[1].content.to_string(), line.spans[1].style)
        };
        m.snap.snap.supervisor.last_outcome = Some("recovery steering: no more tries".into());
        m.snap.snap.supervisor.outcome = Some(OutcomeKind::GaveUp);
        let (text, style) = last(&m);
        assert_eq!(text, "recovery steering: no more tries");
        assert_eq!(style, m.theme.fault());
        m.snap.snap.supervisor.last_outcome =
            Some("recovery steering done, it gave up nothing".into());
        m.snap.snap.supervisor.outcome = Some(OutcomeKind::Done);
        assert_eq!(last(&m).1, Style::new());
    }

    /// A reason longer than the panel is cut at a word, marked, its parentheses
    /// closed; accel is said to be drawn only where it is.
    #[test]
    fn a_line_without_room_is_cut_with_a_mark_and_accel_is_seen_where_drawn() {
        let mut m = model(true);
        m.snap.snap.gate.reason =
            "disengaged: gas is faulty (no reply within 100ms); brake is faulty".into();
        let p = SupervisorPanel {
            m: &m,
            cursor: true,
            compact: false,
        };
        let mut buf = render(&|a, b| assert!(p.render_seen(a, b)), 40, 6);
        assert_eq!(row(&buf, 2), "why disengaged: gas is faulty (no…)");
        // Compact, on one line: accel is not on the screen.
        let p = SupervisorPanel { compact: true, ..p };
        buf = render(&|a, b| assert!(!p.render_seen(a, b)), 40, 1);
        assert_eq!(row(&buf, 0), "SUPERVISORY engaged 0 interlocks on");
    }
}
