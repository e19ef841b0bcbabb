//! One device, laid out like a quarter of the paper's Figure 2: name, range, commanded
//! and measured value; `st delay` / `cm delay`; thread flags and error codes with the
//! status age; the device's own fields, with the estimated position (`est ± σ`) beside
//! the measured one where the line has room; a CAN kit's fault codes by name; receipt → first-byte delay p50/p99/max;
//! counters; and, where the estimate did not fit beside the readings, `meas` and
//! `est ± σ` (and the drift its command does not explain) on a line of their own, last,
//! so that a small panel loses it before any counter. Editable fields show the cursor
//! and an edit in progress in place. In a window too short for it (many devices on a
//! small screen), the same panel is packed side by side into the lines there are
//! ([`DevicePanel::packed_seen`]). A line too long for the panel is cut at a word with
//! `…`, and drawing says which of the editable fields were drawn whole (what keys may
//! then act on).

use super::{fit, fmt_age, fmt_us, pack};
use crate::config::device::POSITION;
use crate::console::model::{Edit, Field};
use crate::console::theme::Theme;
use crate::console::update::fmt_ms;
use crate::controls::SimFaults;
use crate::snapshot::{DeviceView, LatencySummary};
use crate::value::{DeviceId, Kind, Value};
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::style::Style;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Widget};
use std::time::Duration;

pub(crate) struct DevicePanel<'a> {
    pub id: DeviceId,
    pub d: &'a DeviceView,
    /// Faulty to the engine or the supervisor: drawn red.
    pub red: bool,
    /// In a driver's hands (`override`): labelled so, not red.
    pub overridden: bool,
    /// The faults injected into its simulated device (`--sim`).
    pub sim: Option<&'a SimFaults>,
    pub theme: Theme,
    /// The field under the cursor, when the cursor is shown.
    pub cursor: Option<Field>,
    pub edit: Option<&'a Edit>,
    /// Draw a border (larger screens).
    pub(crate) bordered: bool,
}

/// A number as a panel shows it: 3 decimals below 10, 1 below 1000, none above.
pub(crate) fn fmt_num(v: f64) -> String {
    let a = v.abs();
    if a < 10.0 {
        format!("{v:.3}")
    } else if a < 1000.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.0}")
    }
}

/// A value as a panel shows it (flags as 1 or 0, as on the paper's screen).
pub(crate) fn fmt_value(v: Option<&Value>) -> String {
    match v {
        None => "-".into(),
        Some(Value::Number(x)) => fmt_num(*x),
        Some(Value::Flag(b)) => u8::from(*b).to_string(),
        Some(Value::Text(s)) => s.clone(),
    }
}

/// A reading's value: a well-known reading with its usual decimals (`700` rpm,
/// `0.00` m/s), any other as [`fmt_value`].
pub(crate) fn fmt_reading(name: &str, v: Option<&Value>) -> String {
    match (v, crate::config::device::well_known(name)) {
        (Some(Value::Number(x)), Some(w)) => format!("{x:.*}", w.decimals),
        _ => fmt_value(v),
    }
}

/// What a device takes, short: `-1…1`, `P/R/N/D` (initials when they are distinct),
/// `off/left/right/hazard`.
pub(crate) fn domain(d: &DeviceView) -> String {
    match d.kind {
        Kind::Setpoint => {
            let [lo, hi] = d.range.unwrap_or([0.0, 0.0]);
            if d.units.is_empty() {
                format!("{lo}…{hi}")
            } else {
                format!("{lo}…{hi} {}", d.units)
            }
        }
        Kind::State => {
            let initials: Vec<String> = d
                .states
                .iter()
                .map(|s| {
                    s.chars()
                        .next()
                        .unwrap_or('?')
                        .to_ascii_uppercase()
                        .to_string()
                })
                .collect();
            let distinct = initials
                .iter()
                .enumerate()
                .all(|(i, x)| !initials[..i].contains(x));
            if distinct {
                initials.join("/")
            } else {
                d.states.join("/")
            }
        }
        Kind::Sensor => String::new(),
    }
}

/// The measured value: a setpoint actuator's position (`-` when it reports none, as a
/// CAN kit's module may not); a state actuator's first reading; a sensor's first, with
/// its units.
pub(crate) fn measured(d: &DeviceView) -> String {
    let first = if d.kind == Kind::Setpoint {
        d.readings.0.iter().find(|(n, _)| n == POSITION)
    } else {
        d.readings.0.first()
    };
    let Some((name, v)) = first else {
        return "-".into();
    };
    let text = fmt_reading(name, v.as_ref());
    let units = d.reading_units.get(name).map_or("", String::as_str);
    if d.is_actuator() || units.is_empty() || !matches!(v, Some(Value::Number(_))) {
        text
    } else {
        format!("{text} {units}")
    }
}

pub(crate) fn age(d: &DeviceView) -> Option<Duration> {
    d.status_age_ms.map(|ms| Duration::from_secs_f64(ms / 1e3))
}

impl<'a> DevicePanel<'a> {
    /// A value of an editable field: the edit in progress, the cursor, or plain.
    fn field(&self, f: Field, text: String, base: Style) -> Span<'a> {
        let t = &self.theme;
        if let Some(e) = self.edit.filter(|e| e.field == f) {
            let style = if e.error.is_some() {
                t.fault().patch(t.cursor())
            } else {
                t.editing()
            };
            return Span::styled(format!("{}▏", e.buffer), style);
        }
        if self.cursor == Some(f) {
            return Span::styled(text, base.patch(t.cursor()));
        }
        Span::styled(text, base)
    }

    /// The title line, and where the command sits on it (an actuator's).
    fn title_marked(&self) -> (Line<'a>, Vec<Spot>) {
        let (d, t) = (self.d, &self.theme);
        let mut spots = Vec::new();
        let name_style = if self.red { t.fault() } else { t.title() };
        let mut spans = vec![Span::styled(d.name.to_uppercase(), name_style)];
        let range = domain(d);
        if !range.is_empty() {
            spans.push(Span::styled(format!(" {range}"), t.label()));
        }
        let meas_style = if d.stale { t.stale() } else { Style::new() };
        if d.is_actuator() {
            spans.push(Span::styled(" cmd ", t.label()));
            spots.push(Spot::new(Field::Command(self.id), 0, spans.len()));
            spans.push(self.field(
                Field::Command(self.id),
                fmt_value(d.commanded.as_ref()),
                Style::new(),
            ));
            // A kit's module that reports no position has no measured value to show.
            if d.kind != Kind::Setpoint || d.readings.get(POSITION).is_some() {
                spans.push(Span::styled(" meas ", t.label()));
                spans.push(Span::styled(measured(d), meas_style));
            }
        } else {
            spans.push(Span::styled("  ", t.label()));
            spans.push(Span::styled(measured(d), meas_style));
        }
        if self.red {
            spans.push(Span::styled(" FAULT", t.fault()));
        }
        if self.overridden {
            spans.push(Span::styled(" OVERRIDE", t.warn()));
        }
        if let Some(f) = self.sim.filter(|f| f.any()) {
            spans.push(Span::styled(format!(" sim: {}", f.text), t.warn()));
        }
        (Line::from(spans), spots)
    }

    fn code(&self, code: u32) -> Span<'a> {
        let style = if code > 0 {
            self.theme.fault()
        } else {
            Style::new()
        };
        Span::styled(code.to_string(), style)
    }

    fn flag(&self, f: Field, on: bool) -> Span<'a> {
        let base = if on { Style::new() } else { self.theme.warn() };
        self.field(f, (on as u8).to_string(), base)
    }

    /// The readings line: `name value` pairs two spaces apart, with the well-known
    /// readings' short names when the full ones do not fit `width`.
    fn readings(&self, width: u16, style: Style) -> Line<'a> {
        let t = &self.theme;
        let pairs = |short: bool| -> Vec<(String, String)> {
            self.d
                .readings
                .iter()
                .map(|(n, v)| {
                    let label = if short {
                        crate::config::device::well_known(n).map_or(n, |w| w.line_key)
                    } else {
                        n
                    };
                    (label.to_string(), fmt_reading(n, v.as_ref()))
                })
                .collect()
        };
        let len = |p: &[(String, String)]| -> usize {
            p.iter().map(|(a, b)| a.len() + 1 + b.len()).sum::<usize>()
                + 2 * p.len().saturating_sub(1)
        };
        let mut p = pairs(false);
        if len(&p) > width as usize {
            p = pairs(true);
        }
        let mut spans = Vec::new();
        for (i, (name, v)) in p.into_iter().enumerate() {
            if i > 0 {
                spans.push(Span::raw("  "));
            }
            spans.push(Span::styled(format!("{name} "), t.label()));
            spans.push(Span::styled(v, style));
        }
        Line::from(spans)
    }

    /// Every line under the title, most important first, and where the editable
    /// fields sit on them (their lines counted from the first detail line).
    fn details_marked(&self, width: u16) -> (Vec<Line<'a>>, Vec<Spot>) {
        let (d, t) = (self.d, &self.theme);
        let r = self.id;
        let l = |s: &'static str| Span::styled(s, t.label());
        let ms = |x: f64| fmt_ms(Duration::from_secs_f64(x / 1e3));
        let mut out = Vec::new();
        let mut spots = Vec::new();
        // st delay / cm delay
        let mut delays = vec![l("st delay ")];
        spots.push(Spot::new(Field::StDelay(r), 0, delays.len()));
        delays.push(self.field(
            Field::StDelay(r),
            ms(d.settings.status_period_ms),
            Style::new(),
        ));
        if d.is_actuator() {
            delays.push(l("  cm delay "));
            spots.push(Spot::new(Field::CmDelay(r), 0, delays.len()));
            delays.push(self.field(
                Field::CmDelay(r),
                ms(d.settings.command_timeout_ms),
                Style::new(),
            ));
        }
        if d.settings.polling == "adaptive" {
            delays.push(l(" adaptive"));
        }
        out.push(Line::from(delays));
        // thread flags, error codes, age
        let mut flags = vec![l("status ")];
        spots.push(Spot::new(Field::StatusOn(r), 1, flags.len()));
        flags.extend([
            self.flag(Field::StatusOn(r), d.settings.status_on),
            l(" e"),
            self.code(d.health.status_error),
        ]);
        if d.is_actuator() {
            flags.push(l("  command "));
            spots.push(Spot::new(Field::CommandOn(r), 1, flags.len()));
            flags.extend([
                self.flag(Field::CommandOn(r), d.settings.command_on),
                l(" e"),
                self.code(d.health.command_error),
            ]);
        }
        let age_style = if d.stale { t.stale() } else { Style::new() };
        flags.push(l("  age "));
        flags.push(Span::styled(fmt_age(age(d)), age_style));
        out.push(Line::from(flags));
        // The estimate beside the measured position where the readings line has room;
        // else on its own line, last, where the panel has a line to spare (Alice's
        // 80×24 panels keep every counter).
        let mut readings = self.readings(width, age_style);
        let estimate = d.estimate.as_ref().map(|e| {
            let est = vec![
                l("est "),
                Span::raw(fmt_num(e.position)),
                l(" ± "),
                Span::raw(fmt_num(e.sigma)),
            ];
            (est, fmt_num(e.drift))
        });
        let mut own_line = None;
        if let Some((est, drift)) = estimate {
            let est_width: usize = est.iter().map(Span::width).sum();
            if readings.width() + 2 + est_width <= usize::from(width) {
                readings.spans.push(Span::raw("  "));
                readings.spans.extend(est);
            } else {
                let meas = fmt_value(d.reading(crate::config::device::POSITION));
                let mut line = vec![l("meas "), Span::raw(meas), Span::raw("  ")];
                line.extend(est);
                // The drift (units a second its command does not explain), where it fits.
                let used: usize = line.iter().map(Span::width).sum();
                if used + "  drift ".len() + drift.len() <= usize::from(width) {
                    line.extend([l("  drift "), Span::raw(drift)]);
                }
                own_line = Some(Line::from(line));
            }
        }
        out.push(readings);
        // A CAN kit's fault codes, by the DBC's names.
        if !d.faults.is_empty() {
            out.push(Line::from(vec![
                l("faults "),
                Span::styled(d.faults.join(" "), t.fault()),
            ]));
        }
        let s = &d.counters;
        let lat = |name: &'static str, x: &LatencySummary| {
            Line::from(vec![
                l(name),
                l(" p50 "),
                Span::raw(fmt_us(x.p50_us)),
                l(" p99 "),
                Span::raw(fmt_us(x.p99_us)),
                l(" max "),
                Span::raw(fmt_us(x.max_us)),
            ])
        };
        let num = |n: u64| Span::raw(n.to_string());
        if d.is_actuator() {
            out.push(lat("delay", &d.delay_us));
            out.push(Line::from(vec![
                l("rx "),
                num(s.received),
                l(" ex "),
                num(s.executed),
                l(" sup "),
                num(s.superseded),
                l(" rs "),
                num(s.resent),
                l(" rj "),
                Span::styled(
                    s.rejected.to_string(),
                    if s.rejected > 0 {
                        t.warn()
                    } else {
                        Style::new()
                    },
                ),
            ]));
            out.push(lat("txn", &d.command_txn_us));
        }
        out.push(lat("poll", &d.status_txn_us));
        out.push(Line::from(vec![
            l("polls "),
            num(s.polls),
            l(" st err "),
            num(s.status_errors),
            l(" cm err "),
            num(s.command_errors),
            l(" reconn "),
            num(s.reconnects),
        ]));
        if let Some(e) = &d.health.last_error {
            let style = if self.red { t.fault() } else { t.label() };
            out.push(Line::from(vec![
                l("last error "),
                Span::styled(e.clone(), style),
            ]));
        }
        out.extend(own_line);
        (out, spots)
    }
}

impl<'a> DevicePanel<'a> {
    /// The whole panel in `height` lines of `width` columns: the title and each line
    /// under it side by side, two spaces apart, in the panel's order, each cut to the
    /// width; and what of the panel those lines show. When the field under the cursor
    /// (or being edited) would fall below, the first lines give way.
    pub(crate) fn packed_seen(&self, width: u16, height: u16) -> (Vec<Line<'a>>, Seen) {
        let (title, mut spots) = self.title_marked();
        let (details, more) = self.details_marked(width);
        // Each line of the panel is a group; its fields' lines become group numbers.
        spots.extend(more.into_iter().map(|s| Spot {
            line: s.line + 1,
            ..s
        }));
        let name_w = title.spans.first().map_or(0, Span::width);
        let mut groups = vec![title.spans];
        groups.extend(details.into_iter().map(|l| l.spans));
        let widths: Vec<Vec<usize>> = groups
            .iter()
            .map(|g| g.iter().map(Span::width).collect())
            .collect();
        let (lines, at) = pack(groups, width, "");
        // The groups holding editable fields: the title (the command), the delays,
        // the thread flags.
        let group = match self.edit.map(|e| e.field).or(self.cursor) {
            Some(f) if f.device() == Some(self.id) => match f {
                Field::Command(_) => 0,
                Field::StDelay(_) | Field::CmDelay(_) => 1,
                _ => 2,
            },
            _ => 0,
        };
        let line = at.get(group).map_or(0, |a| a.0);
        let skip = (line + 1).saturating_sub(usize::from(height.max(1)));
        let mut lines: Vec<Line> = lines
            .into_iter()
            .skip(skip)
            .take(usize::from(height))
            .collect();
        let kept: Vec<usize> = lines.iter().map(|l| fit::kept(l, width)).collect();
        lines = lines.into_iter().map(|l| fit::line(l, width)).collect();
        // Where a group's span ends: the group's line and start, plus its spans.
        let shown = |group: usize, span: usize| {
            let Some(&(line, col)) = at.get(group) else {
                return false;
            };
            let end = col + widths[group][..=span].iter().sum::<usize>();
            line >= skip && kept.get(line - skip).is_some_and(|&k| end <= k)
        };
        let seen = Seen {
            name: shown(0, 0) && name_w > 0,
            fields: spots
                .iter()
                .filter(|s| shown(s.line, s.span))
                .map(|s| s.field)
                .collect(),
        };
        (lines, seen)
    }

    /// Draw the panel in `area`, each line cut to its width, and say what of it was
    /// drawn: the device's name, the editable fields whole.
    pub(crate) fn render_seen(&self, area: Rect, buf: &mut Buffer) -> Seen {
        let (title, title_spots) = self.title_marked();
        // The title's room and the details' area.
        let (title_w, inner) = if self.bordered {
            let border = if self.red {
                self.theme.fault()
            } else {
                self.theme.label()
            };
            let title_w = area.width.saturating_sub(2);
            let block = Block::bordered()
                .border_style(border)
                .title(fit::line(title.clone(), title_w));
            let inner = block.inner(area);
            block.render(area, buf);
            (title_w, inner)
        } else {
            if area.height > 0 {
                let first = Rect { height: 1, ..area };
                fit::Fitted(vec![title.clone()]).render(first, buf);
            }
            let inner = Rect {
                y: area.y + 1.min(area.height),
                height: area.height.saturating_sub(1),
                ..area
            };
            (area.width, inner)
        };
        let (details, spots) = self.details_marked(inner.width);
        let title_kept = fit::kept(&title, title_w);
        let ends = |l: &Line, span: usize| l.spans[..=span].iter().map(Span::width).sum::<usize>();
        let mut seen = Seen {
            name: area.height > 0 && title.spans.first().is_some_and(|n| n.width() <= title_kept),
            fields: Vec::new(),
        };
        if area.height > 0 {
            seen.fields.extend(
                title_spots
                    .iter()
                    .filter(|s| ends(&title, s.span) <= title_kept)
                    .map(|s| s.field),
            );
        }
        for s in &spots {
            let shown = s.line < usize::from(inner.height)
                && details
                    .get(s.line)
                    .is_some_and(|l| ends(l, s.span) <= fit::kept(l, inner.width));
            if shown {
                seen.fields.push(s.field);
            }
        }
        fit::Fitted(details).render(inner, buf);
        seen
    }
}

/// Where an editable field sits in a panel: its line and its span on that line.
#[derive(Clone, Copy, Debug)]
struct Spot {
    field: Field,
    line: usize,
    span: usize,
}

impl Spot {
    fn new(field: Field, line: usize, span: usize) -> Spot {
        Spot { field, line, span }
    }
}

/// What of a device's panel was drawn: its name, and its editable fields whole (the
/// value, or an edit with its caret).
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Seen {
    pub name: bool,
    pub fields: Vec<Field>,
}

impl Widget for &DevicePanel<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        self.render_seen(area, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::controls::{capture, Sources};
    use crate::testkit;
    use ratatui::style::{Color, Modifier};
    use std::time::Instant;
    use unicode_width::UnicodeWidthStr;

    fn snap_of(name: &str, faulty: bool) -> (DeviceId, DeviceView) {
        let now = Instant::now();
        let g = testkit::gate(now);
        if faulty {
            testkit::make_faulty(g.vehicle(), name, now);
        }
        let f = capture(&g, &Sources::default(), now, None);
        let id = f.id_of(name).unwrap();
        (id, f.at(id).unwrap().clone())
    }

    fn panel<'a>(id: DeviceId, d: &'a DeviceView) -> DevicePanel<'a> {
        DevicePanel {
            id,
            d,
            red: d.health.faulty,
            overridden: false,
            sim: None,
            theme: Theme::default(),
            cursor: None,
            edit: None,
            bordered: false,
        }
    }

    fn render(p: &DevicePanel, w: u16, h: u16) -> Buffer {
        let mut buf = Buffer::empty(Rect::new(0, 0, w, h));
        p.render(buf.area, &mut buf);
        buf
    }

    #[test]
    fn a_state_device_shows_its_states_by_initial() {
        let (id, d) = snap_of("trans", false);
        let p = panel(id, &d);
        let buf = render(&p, 40, 1);
        let line: String = (0..40).map(|x| buf[(x, 0)].symbol().to_string()).collect();
        assert_eq!(line.trim_end(), "TRANS P/R/N/D cmd - meas park");
    }

    #[test]
    fn a_steering_panel_reads_like_the_papers_screen() {
        let (id, d) = snap_of("steer", false);
        let p = panel(id, &d);
        let mut want = Buffer::with_lines([
            "STEER -1…1 cmd - meas 0.231             ",
            "st delay 50ms  cm delay 250ms           ",
            "status 1 e0  command 1 e0  age 20ms     ",
            "position 0.231  velocity 0.012          ",
            "delay p50 26µs p99 1.2ms max 1.2ms      ",
            "rx 120 ex 118 sup 2 rs 40 rj 0          ",
        ]);
        let got = render(&p, 40, 6);
        // Compare text only; styles are asserted separately.
        want.set_style(want.area, Style::reset());
        let mut plain = got.clone();
        plain.set_style(plain.area, Style::reset());
        assert_eq!(plain, want);
    }

    #[test]
    fn the_estimate_sits_beside_the_measured_position_where_it_fits_else_last() {
        let plain = |buf: &Buffer, y: u16| -> String {
            (0..buf.area.width)
                .map(|x| buf[(x, y)].symbol().to_string())
                .collect::<String>()
                .trim_end()
                .to_string()
        };
        // The gas has one reading: its estimate fits beside it at 40 columns.
        let (id, d) = snap_of("gas", false);
        let buf = render(&panel(id, &d), 40, 4);
        assert_eq!(plain(&buf, 3), "position 0.000  est 0.000 ± 0.001");
        // The steering's two readings leave no room: meas and est on a line of their
        // own, after every counter.
        let (id, d) = snap_of("steer", false);
        let buf = render(&panel(id, &d), 40, 9);
        assert_eq!(plain(&buf, 3), "position 0.231  velocity 0.012");
        assert_eq!(plain(&buf, 6), "txn p50 4.3ms p99 4.3ms max 4.3ms");
        assert_eq!(plain(&buf, 8), "polls 1200 st err 0 cm err 0 reconn 0");
        let buf = render(&panel(id, &d), 40, 10);
        assert_eq!(plain(&buf, 9), "meas 0.231  est 0.231 ± 0.003");
    }

    #[test]
    fn a_device_in_the_drivers_hands_is_labelled_override_in_yellow_not_red() {
        let (id, d) = snap_of("steer", false);
        let p = DevicePanel {
            overridden: true,
            ..panel(id, &d)
        };
        let buf = render(&p, 40, 1);
        let line: String = (0..40).map(|x| buf[(x, 0)].symbol().to_string()).collect();
        assert_eq!(line.trim_end(), "STEER -1…1 cmd - meas 0.231 OVERRIDE");
        let at = line.find("OVERRIDE").unwrap() as u16 - 2; // "…" is 3 bytes, 1 cell
        assert_eq!(buf[(at, 0)].symbol(), "O");
        assert_eq!(buf[(at, 0)].fg, Color::Yellow);
        assert_ne!(buf[(0, 0)].fg, Color::Red, "the name is not red");
    }

    #[test]
    fn a_sensor_panel_has_no_command_fields() {
        let (id, d) = snap_of("obd", false);
        let p = panel(id, &d);
        let mut want = Buffer::with_lines([
            "OBD  700 rpm                            ",
            "st delay 250ms                          ",
            "status 1 e0  age 20ms                   ",
            "rpm 700  spd 0.00  clt 85  run 1        ",
            "poll p50 3.1ms p99 3.1ms max 3.1ms      ",
        ]);
        want.set_style(want.area, Style::reset());
        let mut got = render(&p, 40, 5);
        got.set_style(got.area, Style::reset());
        assert_eq!(got, want);
    }

    #[test]
    fn a_faulty_device_is_red_and_its_values_dimmed() {
        let (id, d) = snap_of("steer", true);
        let p = panel(id, &d);
        let buf = render(&p, 50, 6);
        let name = &buf[(0, 0)];
        assert_eq!(name.symbol(), "S");
        assert_eq!(name.fg, Color::Red);
        // "status 1 e1": the error code is red.
        let line: String = (0..50).map(|x| buf[(x, 2)].symbol().to_string()).collect();
        let at = line.find("e1").unwrap() as u16 + 1;
        assert_eq!(buf[(at, 2)].fg, Color::Red);
        // The stale position is dimmed.
        let pos = &buf[(9, 3)];
        assert_eq!(pos.symbol(), "0");
        assert!(pos.modifier.contains(Modifier::DIM));
    }

    #[test]
    fn the_cursor_and_an_edit_show_in_place() {
        let (id, d) = snap_of("gas", false);
        let edit = Edit {
            field: Field::CmDelay(id),
            buffer: "300".into(),
            fresh: false,
            error: None,
        };
        let p = DevicePanel {
            cursor: Some(Field::StDelay(id)),
            edit: Some(&edit),
            ..panel(id, &d)
        };
        let buf = render(&p, 40, 3);
        let line: String = (0..40).map(|x| buf[(x, 1)].symbol().to_string()).collect();
        assert_eq!(line.trim_end(), "st delay 100ms  cm delay 300▏");
        assert!(buf[(9, 1)].modifier.contains(Modifier::REVERSED));
        assert!(buf[(25, 1)].modifier.contains(Modifier::UNDERLINED));
    }

    fn row(buf: &Buffer, y: u16) -> String {
        (0..buf.area.width)
            .map(|x| buf[(x, y)].symbol().to_string())
            .collect::<String>()
    }

    /// On the bench at 100×30 with simulator faults on, a panel's title ended
    /// `… FAULT s`: cut mid-word, nothing to say more was there. A line too long for
    /// its panel is cut at a word and marked, bordered or not; a field cut off is not
    /// said to be drawn.
    #[test]
    fn a_line_too_long_for_the_panel_is_cut_at_a_word_with_a_mark() {
        let (id, d) = snap_of("steer", true);
        let faults = SimFaults {
            silent: true,
            corrupt: true,
            slow_ms: 150,
            text: "silent, corrupt, slow 150ms".into(),
            ..SimFaults::default()
        };
        let p = DevicePanel {
            sim: Some(&faults),
            bordered: true,
            ..panel(id, &d)
        };
        let mut buf = Buffer::empty(Rect::new(0, 0, 46, 11));
        let seen = p.render_seen(buf.area, &mut buf);
        assert_eq!(
            row(&buf, 0),
            "┌STEER -1…1 cmd - meas 0.231 FAULT sim…──────┐"
        );
        assert!(seen.name && seen.fields.contains(&Field::Command(id)));
        let p = DevicePanel {
            bordered: false,
            ..p
        };
        let mut buf = Buffer::empty(Rect::new(0, 0, 30, 6));
        let seen = p.render_seen(buf.area, &mut buf);
        assert_eq!(row(&buf, 0), "STEER -1…1 cmd - meas 0.231…  ");
        assert!(seen.fields.contains(&Field::Command(id)));
        // `st delay 50ms  cm delay 250ms` in 20 columns: cm delay is cut off; two
        // lines leave the thread flags out.
        let mut buf = Buffer::empty(Rect::new(0, 0, 20, 2));
        let seen = p.render_seen(buf.area, &mut buf);
        assert_eq!(row(&buf, 1), "st delay 50ms  cm…  ");
        assert!(seen.fields.contains(&Field::StDelay(id)));
        assert!(!seen.fields.contains(&Field::CmDelay(id)), "{seen:?}");
        assert!(!seen.fields.contains(&Field::StatusOn(id)), "{seen:?}");
    }

    /// Packed into the lines there are (many devices on a small screen), each line is
    /// cut with a mark, and only the fields on those lines count as drawn.
    #[test]
    fn a_packed_panel_cuts_its_lines_and_says_which_fields_it_shows() {
        let (id, d) = snap_of("steer", false);
        let p = DevicePanel {
            cursor: Some(Field::Command(id)),
            ..panel(id, &d)
        };
        let (lines, seen) = p.packed_seen(36, 2);
        let text: Vec<String> = lines
            .iter()
            .map(|l| l.spans.iter().map(|s| s.content.as_ref()).collect())
            .collect();
        assert_eq!(text.len(), 2, "{text:?}");
        assert!(text.iter().all(|l| l.width() <= 36), "{text:?}");
        assert!(
            seen.name && seen.fields.contains(&Field::Command(id)),
            "{seen:?}"
        );
        assert!(!seen.fields.contains(&Field::CommandOn(id)), "{seen:?}");
        // The cursor on the thread flags: the first lines give way to them.
        let p = DevicePanel {
            cursor: Some(Field::CommandOn(id)),
            ..p
        };
        let (_, seen) = p.packed_seen(36, 1);
        assert!(!seen.name, "{seen:?}");
        assert!(seen.fields.contains(&Field::StatusOn(id)), "{seen:?}");
    }
}
