//! One device, laid out like a quarter of the paper's Figure 2: name, range, commanded
//! and measured value; `st delay` / `cm delay`; thread flags and error codes with the
//! status age; the device's own fields; receipt → first-byte delay p50/p99/max; and
//! counters. Editable fields show the cursor and an edit in progress in place.

use super::{fmt_age, fmt_f, fmt_us};
use crate::console::controls::DeviceSnap;
use crate::console::model::{Edit, Field};
use crate::console::theme::Theme;
use crate::console::update::fmt_ms;
use crate::value::{Command, Role};
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::style::Style;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Paragraph, Widget};

pub struct DevicePanel<'a> {
    pub d: &'a DeviceSnap,
    pub theme: Theme,
    /// The field under the cursor, when the cursor is shown.
    pub cursor: Option<Field>,
    pub edit: Option<&'a Edit>,
    /// Draw a border (larger screens).
    pub bordered: bool,
}

fn range_text(d: &DeviceSnap) -> String {
    match d.role {
        Role::Trans => "P/R/N/D".into(),
        _ if !d.actuator => String::new(),
        _ => {
            let [lo, hi] = d.range;
            format!("{lo}…{hi}")
        }
    }
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

    fn measured(&self) -> String {
        let r = &self.d.reading;
        match self.d.role {
            Role::Trans => r.gear.map(|g| g.to_string()).unwrap_or("-".into()),
            Role::Estop => r.estop.map(|e| e.to_string()).unwrap_or("-".into()),
            Role::Obd => r
                .rpm
                .map(|v| format!("{v:.0} rpm"))
                .unwrap_or_else(|| "-".into()),
            _ => fmt_f(r.position),
        }
    }

    /// The title line.
    pub fn title(&self) -> Line<'a> {
        let (d, t) = (self.d, &self.theme);
        let name_style = if d.faulty { t.fault() } else { t.title() };
        let mut spans = vec![Span::styled(d.role.as_str().to_uppercase(), name_style)];
        let range = range_text(d);
        if !range.is_empty() {
            spans.push(Span::styled(format!(" {range}"), t.label()));
        }
        let meas_style = if d.stale { t.stale() } else { Style::new() };
        if d.actuator {
            spans.push(Span::styled(" cmd ", t.label()));
            let cmd = d.latest.map(|c| match c {
                Command::Set(v) => format!("{v:.3}"),
                Command::Gear(g) => g.to_string(),
                Command::Control(c) => c.to_string(),
            });
            spans.push(self.field(
                Field::Command(d.role),
                cmd.unwrap_or_else(|| "-".into()),
                Style::new(),
            ));
            spans.push(Span::styled(" meas ", t.label()));
        } else {
            spans.push(Span::styled("  ", t.label()));
        }
        spans.push(Span::styled(self.measured(), meas_style));
        if d.faulty {
            spans.push(Span::styled(" FAULT", t.fault()));
        }
        if let Some(f) = d.sim.as_ref().filter(|f| f.any()) {
            spans.push(Span::styled(format!(" sim: {}", f.text), t.warn()));
        }
        Line::from(spans)
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

    /// Every line under the title, most important first.
    pub fn details(&self) -> Vec<Line<'a>> {
        let (d, t) = (self.d, &self.theme);
        let r = d.role;
        let l = |s: &'static str| Span::styled(s, t.label());
        let mut out = Vec::new();
        // st delay / cm delay
        let mut delays = vec![
            l("st delay "),
            self.field(Field::StDelay(r), fmt_ms(d.status_period), Style::new()),
        ];
        if d.actuator {
            delays.push(l("  cm delay "));
            delays.push(self.field(Field::CmDelay(r), fmt_ms(d.command_timeout), Style::new()));
        }
        out.push(Line::from(delays));
        // thread flags, error codes, age
        let mut flags = vec![
            l("status "),
            self.flag(Field::StatusOn(r), d.status_on),
            l(" e"),
            self.code(d.status_error),
        ];
        if d.actuator {
            flags.extend([
                l("  command "),
                self.flag(Field::CommandOn(r), d.command_on),
                l(" e"),
                self.code(d.command_error),
            ]);
        }
        let age_style = if d.stale { t.stale() } else { Style::new() };
        flags.push(l("  age "));
        flags.push(Span::styled(fmt_age(d.age), age_style));
        out.push(Line::from(flags));
        // device fields
        let rd = &d.reading;
        let v = |x: String| Span::styled(x, age_style);
        let fields: Vec<Span> = match r {
            Role::Steer => vec![
                l("position "),
                v(fmt_f(rd.position)),
                l("  velocity "),
                v(fmt_f(rd.velocity)),
            ],
            Role::Brake => vec![
                l("position "),
                v(fmt_f(rd.position)),
                l("  pressure "),
                v(rd.pressure.map(|p| format!("{p:.1}")).unwrap_or("-".into())),
            ],
            Role::Gas => vec![l("position "), v(fmt_f(rd.position))],
            Role::Trans => vec![
                l("gear "),
                v(rd.gear.map(|g| g.to_string()).unwrap_or("-".into())),
            ],
            Role::Estop => vec![
                l("state "),
                v(rd.estop.map(|e| e.to_string()).unwrap_or("-".into())),
            ],
            Role::Obd => vec![
                l("rpm "),
                v(rd.rpm.map(|x| format!("{x:.0}")).unwrap_or("-".into())),
                l(" speed "),
                v(rd.speed.map(|x| format!("{x:.1}")).unwrap_or("-".into())),
                l(" cool "),
                v(rd.coolant.map(|x| format!("{x:.0}")).unwrap_or("-".into())),
                l(" run "),
                v(rd.running
                    .map(|x| (x as u8).to_string())
                    .unwrap_or("-".into())),
            ],
        };
        out.push(Line::from(fields));
        let s = &d.stats;
        let lat = |name: &'static str, x: &crate::engine::stats::LatencySummary| {
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
        if d.actuator {
            out.push(lat("delay", &s.command_delay));
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
            out.push(lat("txn", &s.command_txn));
        }
        out.push(lat("poll", &s.status_txn));
        out.push(Line::from(vec![
            l("polls "),
            num(s.polls),
            l(" st err "),
            num(s.status_errors),
            l(" cm err "),
            num(s.command_errors),
            l(" reconn "),
            num(d.reconnects),
        ]));
        if let Some(e) = &d.last_error {
            let style = if d.faulty { t.fault() } else { t.label() };
            out.push(Line::from(vec![
                l("last error "),
                Span::styled(e.clone(), style),
            ]));
        }
        out
    }
}

impl Widget for &DevicePanel<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        if self.bordered {
            let border = if self.d.faulty {
                self.theme.fault()
            } else {
                self.theme.label()
            };
            let block = Block::bordered().border_style(border).title(self.title());
            let inner = block.inner(area);
            block.render(area, buf);
            Paragraph::new(self.details()).render(inner, buf);
        } else {
            let mut lines = vec![self.title()];
            lines.extend(self.details());
            Paragraph::new(lines).render(area, buf);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::console::controls::{capture, Sources};
    use crate::console::sample;
    use ratatui::style::{Color, Modifier};
    use std::time::Instant;

    fn snap_of(role: Role, faulty: bool) -> DeviceSnap {
        let now = Instant::now();
        let v = sample::vehicle(now);
        if faulty {
            sample::make_faulty(&v, role, now);
        }
        capture(&v, &Sources::default(), now, None)
            .device(role)
            .unwrap()
            .clone()
    }

    fn render(p: &DevicePanel, w: u16, h: u16) -> Buffer {
        let mut buf = Buffer::empty(Rect::new(0, 0, w, h));
        p.render(buf.area, &mut buf);
        buf
    }

    #[test]
    fn a_steering_panel_reads_like_the_papers_screen() {
        let d = snap_of(Role::Steer, false);
        let p = DevicePanel {
            d: &d,
            theme: Theme::default(),
            cursor: None,
            edit: None,
            bordered: false,
        };
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
    fn a_sensor_panel_has_no_command_fields() {
        let d = snap_of(Role::Obd, false);
        let p = DevicePanel {
            d: &d,
            theme: Theme::default(),
            cursor: None,
            edit: None,
            bordered: false,
        };
        let mut want = Buffer::with_lines([
            "OBD  700 rpm                            ",
            "st delay 250ms                          ",
            "status 1 e0  age 20ms                   ",
            "rpm 700 speed 0.0 cool 85 run 1         ",
            "poll p50 3.1ms p99 3.1ms max 3.1ms      ",
        ]);
        want.set_style(want.area, Style::reset());
        let mut got = render(&p, 40, 5);
        got.set_style(got.area, Style::reset());
        assert_eq!(got, want);
    }

    #[test]
    fn a_faulty_device_is_red_and_its_values_dimmed() {
        let d = snap_of(Role::Steer, true);
        let p = DevicePanel {
            d: &d,
            theme: Theme::default(),
            cursor: None,
            edit: None,
            bordered: false,
        };
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
        let d = snap_of(Role::Gas, false);
        let edit = Edit {
            field: Field::CmDelay(Role::Gas),
            buffer: "300".into(),
            fresh: false,
            error: None,
        };
        let p = DevicePanel {
            d: &d,
            theme: Theme::default(),
            cursor: Some(Field::StDelay(Role::Gas)),
            edit: Some(&edit),
            bordered: false,
        };
        let buf = render(&p, 40, 3);
        let line: String = (0..40).map(|x| buf[(x, 1)].symbol().to_string()).collect();
        assert_eq!(line.trim_end(), "st delay 100ms  cm delay 300▏");
        assert!(buf[(9, 1)].modifier.contains(Modifier::REVERSED));
        assert!(buf[(25, 1)].modifier.contains(Modifier::UNDERLINED));
    }
}
