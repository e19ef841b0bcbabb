//! The device list, for a vehicle with more devices than panels fit: one line a
//! device — its name, command, measurement, the age of its status, its receipt →
//! first-byte delay p50 (where the names and values are whole beside it: the full
//! panel under the list has it) and its error code — in columns down the screen, under a
//! header line (which, when the list pages, says which devices it shows: `35–64/64`).
//! A faulty device's line is red; a stale value is dimmed. The cursor shows on the
//! command when it stands there (an edit of it too), else on the name of its device;
//! while the name prompt is open, the names it matches are marked.
//!
//! Values keep their columns: numbers and states are right-aligned in widths fixed
//! by the screen, a name or value too long for its column ends in `…` (the full
//! panel under the list shows it whole).

use super::device::{age, fmt_value, measured};
use super::{fmt_age, fmt_us};
use crate::console::model::{Edit, Field};
use crate::console::theme::Theme;
use crate::controls::Scene;
use crate::snapshot::DeviceView;
use crate::value::DeviceId;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::style::Style;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Paragraph, Widget};

/// Columns of the age and the delay (`250ms`, `1.2ms`), and of the error code.
const AGE: usize = 5;
const P50: usize = 5;
const ERR: usize = 1;
/// The narrowest command and measurement columns, and how far they grow.
const VALUE: usize = 6;
const VALUE_MAX: usize = 9;
/// The narrowest name column.
const NAME_MIN: usize = 4;

pub(crate) struct DeviceList<'a> {
    pub snap: &'a Scene,
    pub theme: Theme,
    /// Columns and lines of devices, from device `first`, column by column.
    pub cols: u16,
    pub rows: u16,
    pub first: usize,
    /// The field under the cursor, when the cursor is shown.
    pub cursor: Option<Field>,
    pub edit: Option<&'a Edit>,
    /// Devices the name prompt matches, marked.
    pub found: &'a [usize],
}

/// The widths of a column's fields, and whether it has the delay's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Widths {
    name: usize,
    cmd: usize,
    meas: usize,
    p50: bool,
}

impl Widths {
    /// For a column `width` wide (its last character left blank), names up to
    /// `longest` and an actuator's values up to `value` (its longest state, its
    /// range's ends): the delay's p50 only where the names and values are whole
    /// beside it (the tractor at 80 columns read `parking_br… relea…`: the panel
    /// under the list has the delay); then the values at their narrowest, the name as
    /// long as it can be, and the values grow.
    fn of(width: usize, longest: usize, value: usize) -> Widths {
        let whole = longest.max(NAME_MIN) + 2 * value.clamp(VALUE, VALUE_MAX);
        // The line and the blank column after it.
        let p50 = whole + AGE + P50 + ERR + 5 < width;
        let fixed = 2 * VALUE + AGE + ERR + 1 + if p50 { P50 + 5 } else { 4 };
        let room = width.saturating_sub(fixed);
        let name = longest.clamp(NAME_MIN, room.max(NAME_MIN));
        let extra = room.saturating_sub(name);
        let cmd = VALUE + (extra / 2).min(VALUE_MAX - VALUE);
        let meas = VALUE + (extra - (cmd - VALUE)).min(VALUE_MAX - VALUE);
        Widths {
            name,
            cmd,
            meas,
            p50,
        }
    }

    /// The columns a line of them takes.
    #[cfg(test)]
    fn total(&self) -> usize {
        let p50 = if self.p50 { P50 + 1 } else { 0 };
        self.name + self.cmd + self.meas + AGE + ERR + 4 + p50
    }
}

/// The widest value an actuator's command or measurement can read: its longest
/// state, or its range's ends as the list writes numbers (a sensor's reading has both
/// columns).
fn widest_value(d: &DeviceView) -> usize {
    let states = d.states.iter().map(|s| s.chars().count());
    let ends = d
        .range
        .into_iter()
        .flatten()
        .map(|x| super::device::fmt_num(x).chars().count());
    states.chain(ends).max().unwrap_or(0)
}

/// `text` in `width` columns: cut with `…` when longer, padded on the left
/// (`right`) or the right.
fn fit(text: &str, width: usize, right: bool) -> String {
    let n = text.chars().count();
    let cut: String = if n > width {
        let mut s: String = text.chars().take(width.saturating_sub(1)).collect();
        if width > 0 {
            s.push('…');
        }
        s
    } else {
        text.to_string()
    };
    if right {
        format!("{cut:>width$}")
    } else {
        format!("{cut:<width$}")
    }
}

impl DeviceList<'_> {
    /// Which devices a list that pages shows: `35–64/64`.
    fn page(&self) -> Option<String> {
        let n = self.snap.devices.len();
        let page = usize::from(self.cols) * usize::from(self.rows);
        let last = (self.first + page).min(n);
        (page < n).then(|| format!("{}–{last}/{n}", self.first + 1))
    }

    /// A column's header: `name` over the names, then the values'.
    fn header(&self, name: &str, w: Widths, total: usize) -> Vec<Span<'static>> {
        let p50 = match w.p50 {
            true => format!("{} ", fit("p50", P50, true)),
            false => String::new(),
        };
        let text = format!(
            "{} {} {} {} {p50}{}",
            fit(name, w.name, false),
            fit("cmd", w.cmd, true),
            fit("meas", w.meas, true),
            fit("age", AGE, true),
            fit("e", ERR, true),
        );
        vec![Span::styled(fit(&text, total, false), self.theme.label())]
    }

    /// One device's line.
    fn row(&self, id: DeviceId, d: &DeviceView, w: Widths, total: usize) -> Vec<Span<'static>> {
        let t = &self.theme;
        let red = self.snap.red(d);
        let base = if red { t.fault() } else { Style::new() };
        let dim = if d.stale { t.stale() } else { Style::new() };
        let here = self.cursor.filter(|f| f.device() == Some(id));
        let mut name_style = base;
        if self.found.contains(&id.index()) {
            name_style = name_style.patch(t.editing());
        }
        if here.is_some_and(|f| f != Field::Command(id)) {
            name_style = name_style.patch(t.cursor());
        }
        let mut spans = vec![Span::styled(fit(&d.name, w.name, false), name_style)];
        spans.push(Span::raw(" "));
        if d.is_actuator() {
            let edit = self.edit.filter(|e| e.field == Field::Command(id));
            let cmd = match edit {
                // The end of what is typed, as much as fits.
                Some(e) => {
                    let typed: Vec<char> = format!("{}▏", e.buffer).chars().collect();
                    let tail: String = typed[typed.len().saturating_sub(w.cmd)..].iter().collect();
                    Span::styled(fit(&tail, w.cmd, true), t.editing())
                }
                None => {
                    let style = if here == Some(Field::Command(id)) {
                        base.patch(t.cursor())
                    } else {
                        base
                    };
                    Span::styled(fit(&fmt_value(d.commanded.as_ref()), w.cmd, true), style)
                }
            };
            spans.push(cmd);
            spans.push(Span::raw(" "));
            spans.push(Span::styled(
                fit(&measured(d), w.meas, true),
                base.patch(dim),
            ));
        } else {
            // A sensor takes no command: its measurement has both columns.
            let width = w.cmd + 1 + w.meas;
            spans.push(Span::styled(
                fit(&measured(d), width, true),
                base.patch(dim),
            ));
        }
        let p50 = if d.is_actuator() {
            fmt_us(d.delay_us.p50_us)
        } else {
            "-".into()
        };
        let code = d.health.status_error.max(d.health.command_error);
        let code_style = if code > 0 { t.fault() } else { base };
        spans.extend([
            Span::raw(" "),
            Span::styled(fit(&fmt_age(age(d)), AGE, true), base.patch(dim)),
            Span::raw(" "),
        ]);
        if w.p50 {
            spans.extend([Span::styled(fit(&p50, P50, true), base), Span::raw(" ")]);
        }
        spans.push(Span::styled(fit(&code.to_string(), ERR, true), code_style));
        let used: usize = spans.iter().map(|s| s.content.chars().count()).sum();
        spans.push(Span::raw(" ".repeat(total.saturating_sub(used))));
        spans
    }
}

impl Widget for &DeviceList<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        self.render_seen(area, buf);
    }
}

impl DeviceList<'_> {
    /// Draw the list in `area`; the devices whose rows were drawn, and the command
    /// fields on them (an actuator's command, or its edit, is in its row).
    pub(crate) fn render_seen(&self, area: Rect, buf: &mut Buffer) -> (Vec<DeviceId>, Vec<Field>) {
        let mut rows = Vec::new();
        let mut fields = Vec::new();
        let devices = &self.snap.devices;
        let cols = self.cols.max(1);
        let col_w = area.width / cols;
        let page = self.page();
        let longest = devices
            .iter()
            .map(|d| d.name.len())
            .chain(page.as_ref().map(|p| p.chars().count()))
            .max()
            .unwrap_or(0);
        let value = devices
            .iter()
            .filter(|d| d.is_actuator())
            .map(widest_value)
            .max()
            .unwrap_or(0);
        let w = Widths::of(usize::from(col_w), longest, value);
        for c in 0..cols {
            let x = area.x + c * col_w;
            let width = if c == cols - 1 {
                area.width - col_w * c
            } else {
                col_w
            };
            // The last character of a column is left blank, between it and the next.
            let total = usize::from(col_w.saturating_sub(1));
            // The first column's header says which devices a list that pages shows.
            let name = match (&page, c) {
                (Some(p), 0) => p.as_str(),
                _ => "device",
            };
            let mut lines = vec![Line::from(self.header(name, w, total))];
            for r in 0..self.rows {
                let i = self.first + usize::from(c) * usize::from(self.rows) + usize::from(r);
                let Some(d) = devices.get(i) else { break };
                let id = DeviceId(i as u16);
                // Its line (after the header) is in the area, and the column has room.
                if 1 + r < area.height && total > 0 && x < area.x + area.width {
                    rows.push(id);
                    if d.is_actuator() {
                        fields.push(Field::Command(id));
                    }
                }
                lines.push(Line::from(self.row(id, d, w, total)));
            }
            let at = Rect { x, width, ..area };
            Paragraph::new(lines).render(at.intersection(area), buf);
        }
        (rows, fields)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn at_80_columns_a_column_fits_a_name_of_eleven_and_every_number() {
        let w = Widths::of(40, 11, 6);
        assert_eq!(
            w,
            Widths {
                name: 11,
                cmd: 6,
                meas: 6,
                p50: true
            }
        );
        // Name, the five values and their spaces: 39 columns and the blank one.
        assert_eq!(w.total(), 39);
    }

    /// The tractor at 80 columns read `parking_br… relea…`: the delay gives way and
    /// the names and states are whole.
    #[test]
    fn at_80_columns_the_delay_gives_way_to_whole_names_and_states() {
        let w = Widths::of(40, 13, 8);
        assert_eq!(
            w,
            Widths {
                name: 13,
                cmd: 8,
                meas: 8,
                p50: false
            }
        );
        assert_eq!(w.total(), 39);
    }

    #[test]
    fn a_wider_column_gives_the_name_its_length_then_the_values_room() {
        assert_eq!(
            Widths::of(50, 13, 8),
            Widths {
                name: 13,
                cmd: 9,
                meas: 9,
                p50: true
            }
        );
        assert_eq!(Widths::of(60, 5, 0).name, 5);
        assert_eq!(Widths::of(60, 5, 0).cmd, VALUE_MAX);
    }

    #[test]
    fn a_value_too_long_is_cut_with_an_ellipsis() {
        assert_eq!(fit("parking_brake", 11, false), "parking_br…");
        assert_eq!(fit("released", 6, true), "relea…");
        assert_eq!(fit("0.5", 6, true), "   0.5");
        assert_eq!(fit("abc", 0, true), "");
    }
}
