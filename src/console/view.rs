//! The whole screen, drawn from the [`Model`] alone ([`draw`], and `impl Widget for
//! &Model`): a top bar, the devices, the supervisory and network panels (or teleop),
//! the log pane, the outcome line and the hint bar; the bench view instead of the
//! devices; help and confirmation over it. Below the minimum size it says so instead,
//! with the keys that still act and the outcome of the last one. [`draw`] also says
//! what the frame showed ([`Drawn`]): what keys may act on ([`sight`](super::sight)).
//!
//! The devices are laid out as [`layout`] says: a panel each in a grid
//! (two columns at 80×24, three from 120 columns, bordered with more figures when
//! there is room) while they fit; with more devices, a one-line row each in a
//! [`DeviceList`] and a window of full panels under it that pages.

use super::keymap::{Action, Mode};
use super::layout::{self, Devices, Many, BIG_PANEL, HEAD, PANEL};
use super::model::Model;
use super::names;
use super::panels::bench::BenchView;
use super::panels::device::DevicePanel;
use super::panels::dialog::Dialog;
use super::panels::fit;
use super::panels::header::Header;
use super::panels::help::{HelpPanel, KeyEvents};
use super::panels::hint::{key_name, HintBar, MessageLine};
use super::panels::list::DeviceList;
use super::panels::log::LogPanel;
use super::panels::network::NetworkPanel;
use super::panels::supervisor::{SupervisorPanel, SupervisorStrip};
use super::panels::teleop::TeleopPanel;
use super::sight::Drawn;
use crate::value::DeviceId;
use ratatui::buffer::Buffer;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Paragraph, Widget, Wrap};
use std::ops::Range;

pub use super::layout::{MIN_HEIGHT, MIN_WIDTH};

/// The bench view's height with its simulator box and three rows of traffic.
const BENCH_MIN: u16 = 18;

/// A grid of device panels: `cols` a row, `panel_h` lines each.
struct Grid {
    area: Rect,
    cols: u16,
    panel_h: u16,
    bordered: bool,
}

impl Model {
    /// The simulator keys the bench device's simulator would refuse: what they act on
    /// is not in this vehicle (an e-stop, an engine, a drive of its own).
    fn sim_refused(&self) -> Vec<crate::console::keymap::SimAction> {
        let Some(names) = &self.snap.sim_names else {
            return Vec::new();
        };
        crate::console::keymap::SimAction::ALL
            .into_iter()
            .filter(|&a| {
                let line = crate::console::update::sim_line(self, a, self.bench);
                crate::sim::commands::parse(&line, names).is_err()
            })
            .collect()
    }

    /// Device `i`'s panel as the main screen shows it.
    fn panel(&self, i: usize, bordered: bool) -> Option<DevicePanel<'_>> {
        let id = DeviceId(i as u16);
        let d = self.snap.devices.get(i)?;
        Some(DevicePanel {
            id,
            d,
            red: self.snap.red(d),
            overridden: self.snap.overridden(d),
            sim: self.snap.sim_of(id),
            theme: self.theme,
            cursor: (!self.in_teleop()).then(|| self.field()),
            edit: self.edit.as_ref(),
            bordered,
        })
    }

    /// The panels of devices `ids` in `g`, row by row.
    fn render_grid(&self, g: &Grid, ids: Range<usize>, buf: &mut Buffer, seen: &mut Drawn) {
        let col_w = g.area.width / g.cols;
        let first = ids.start;
        for i in ids {
            let k = (i - first) as u16;
            let (r, c) = (k / g.cols, k % g.cols);
            let w = if c == g.cols - 1 {
                g.area.width - col_w * c
            } else if g.bordered {
                col_w
            } else {
                col_w - 1
            };
            let area = Rect {
                x: g.area.x + c * col_w,
                y: g.area.y + r * g.panel_h,
                width: w,
                height: g.panel_h,
            }
            .intersection(g.area);
            if let Some(p) = self.panel(i, g.bordered) {
                let shown = p.render_seen(area, buf);
                if shown.name {
                    seen.devices.push(DeviceId(i as u16));
                }
                seen.fields.extend(shown.fields);
            }
        }
    }

    /// The supervisory and network panels side by side.
    fn render_lower(&self, sup: &SupervisorPanel, lower: Rect, buf: &mut Buffer, seen: &mut Drawn) {
        if lower.height == 0 {
            return;
        }
        let [left, right] =
            Layout::horizontal([Constraint::Percentage(50), Constraint::Percentage(50)])
                .areas(lower);
        let accel = sup.render_seen(
            Rect {
                width: left.width.saturating_sub(1),
                ..left
            },
            buf,
        );
        if accel {
            seen.fields.push(crate::console::model::Field::Accel);
        }
        let net = NetworkPanel {
            snap: &self.snap,
            theme: self.theme,
        };
        (&net).render(right, buf);
    }

    fn render_teleop(&self, area: Rect, buf: &mut Buffer, seen: &mut Drawn) {
        if area.height > 0 {
            let g = &self.snap.gate;
            let me = self.snap.you.as_deref().unwrap_or("console");
            let p = TeleopPanel {
                t: &self.teleop,
                now: self.now,
                theme: self.theme,
                commands: g.engaged && g.commander.as_deref() == Some(me),
                drive: self.drive(),
                figures: self.repeat.figures(),
            };
            (seen.teleop, seen.teleop_levels) = p.render_seen(area, buf);
        }
    }

    fn render_log(&self, area: Rect, buf: &mut Buffer) {
        if area.height > 0 {
            let p = LogPanel {
                lines: &self.snap.logs,
                theme: self.theme,
            };
            (&p).render(area, buf);
        }
    }

    fn strip(&self) -> SupervisorStrip<'_> {
        SupervisorStrip {
            snap: &self.snap,
            theme: self.theme,
        }
    }

    fn render_main(&self, body: Rect, buf: &mut Buffer, seen: &mut Drawn) {
        match self.layout_in(body) {
            Devices::Panels { cols, rows, big } => {
                self.render_panels(body, (cols, rows, big), buf, seen)
            }
            Devices::Many(l) => self.render_many(&l, buf, seen),
        }
    }

    /// A panel for every device (Alice at 80×24).
    fn render_panels(
        &self,
        body: Rect,
        (cols, rows, big): (u16, u16, bool),
        buf: &mut Buffer,
        seen: &mut Drawn,
    ) {
        let sup = SupervisorPanel {
            m: self,
            cursor: !self.in_teleop(),
            compact: !big,
        };
        let strip = self.strip();
        // While the supervisor has faults or a recovery to show, a small screen's
        // device panels give up their last line (counters) to make room for them.
        let panel_h = match (big, sup.active()) {
            (true, _) => BIG_PANEL,
            (false, true) => PANEL - 1,
            (false, false) => PANEL,
        };
        let teleop = self.in_teleop();
        let grid_h = rows * panel_h;
        let rest = body.height.saturating_sub(grid_h);
        // Teleop's bar takes a third line, for its levels, where there is one.
        let teleop_h = match (teleop, rest > HEAD) {
            (false, _) => 0,
            (true, true) => HEAD + 1,
            (true, false) => HEAD,
        };
        // Small: teleop replaces the two supervisory lines; the strip goes under.
        // Large: the supervisory panel grows with what it shows, leaving the log 3.
        let (sup_h, strip_h) = if big {
            let want = (sup.full_lines(body.width / 2).len() as u16).max(4);
            (want.min(rest.saturating_sub(teleop_h + 3)), 0)
        } else {
            let head = if teleop { 0 } else { HEAD };
            let room = rest.saturating_sub(teleop_h + head + 1);
            (
                head,
                (strip.lines_in(body.width).len() as u16).min(4).min(room),
            )
        };
        let [grid, teleop_area, lower, strip_area, log] = Layout::vertical([
            Constraint::Length(grid_h),
            Constraint::Length(teleop_h),
            Constraint::Length(sup_h),
            Constraint::Length(strip_h),
            Constraint::Min(0),
        ])
        .areas(body);
        let g = Grid {
            area: grid,
            cols,
            panel_h,
            bordered: big,
        };
        self.render_grid(&g, 0..self.snap.devices.len(), buf, seen);
        self.render_teleop(teleop_area, buf, seen);
        self.render_lower(&sup, lower, buf, seen);
        if strip_area.height > 0 {
            (&strip).render(strip_area, buf);
        }
        self.render_log(log, buf);
    }

    /// A row for every device and a window of full panels (many devices).
    fn render_many(&self, l: &Many, buf: &mut Buffer, seen: &mut Drawn) {
        let teleop = self.in_teleop();
        let names = self.snap.devices.iter().map(|d| d.name.as_str());
        let found = match (&self.find, self.mode) {
            (Some(f), Mode::Find) => names::matches(names, &f.query),
            _ => Vec::new(),
        };
        let list = DeviceList {
            snap: &self.snap,
            theme: self.theme,
            cols: l.list_cols,
            rows: l.list_rows,
            first: l.list_first,
            cursor: (!teleop).then(|| self.field()),
            edit: self.edit.as_ref(),
            found: &found,
        };
        let (rows, fields) = list.render_seen(l.list, buf);
        seen.devices.extend(rows);
        seen.fields.extend(fields);
        if l.packed {
            if let Some(p) = self.panel(l.first, false) {
                let (lines, shown) = p.packed_seen(l.window.width, l.window.height);
                Paragraph::new(lines).render(l.window, buf);
                seen.fields.extend(shown.fields);
            }
        } else {
            let g = Grid {
                area: l.window,
                cols: l.cols,
                panel_h: PANEL,
                bordered: false,
            };
            let n = self.snap.devices.len();
            self.render_grid(&g, l.first..(l.first + l.per_page).min(n), buf, seen);
        }
        let sup = SupervisorPanel {
            m: self,
            cursor: !teleop,
            compact: true,
        };
        let (teleop_h, head) = if teleop { (HEAD, 0) } else { (0, HEAD) };
        let [teleop_area, lower, strip_area, log] = Layout::vertical([
            Constraint::Length(teleop_h),
            Constraint::Length(head),
            Constraint::Length(l.strip_h),
            Constraint::Min(0),
        ])
        .areas(l.below);
        self.render_teleop(teleop_area, buf, seen);
        self.render_lower(&sup, lower, buf, seen);
        if strip_area.height > 0 {
            (&self.strip()).render(strip_area, buf);
        }
        self.render_log(log, buf);
    }
}

/// The screen below the minimum size: the last outcome (a key refused, the STOP
/// done), the size needed, the keys that still act, and the gate — each cut to the
/// width, wrapped, readable at 40×10.
fn too_small(m: &Model, area: Rect, buf: &mut Buffer) {
    let t = &m.theme;
    let key = |a| key_name(&m.keymap, Mode::Main, a);
    let mut lines = Vec::new();
    if let Some((text, bad)) = m.message_line() {
        let style = if bad { t.fault() } else { t.good() };
        lines.push(Line::from(Span::styled(text.into_owned(), style)));
    }
    lines.push(Line::from(format!(
        "adrive needs a terminal of at least {MIN_WIDTH}×{MIN_HEIGHT}; this one is {}×{}.",
        area.width, area.height
    )));
    lines.push(Line::from(format!(
        "Enlarge the window: until then only {} (STOP) and {} (quit) act; the engine \
         keeps running.",
        key(Action::Stop),
        key(Action::Quit)
    )));
    let g = &m.snap.gate;
    let gate = if g.engaged {
        let who = g.commander.as_deref().unwrap_or("nobody");
        Span::styled(format!("ENGAGED (by {who})"), t.good())
    } else {
        let why = g.cause.why();
        Span::styled(format!("DISENGAGED ({why})"), t.warn())
    };
    lines.push(fit::line(Line::from(gate), area.width));
    Paragraph::new(lines)
        .wrap(Wrap { trim: true })
        .render(area, buf);
}

/// Draw the whole screen of `m` into `buf` and say what the frame showed.
pub fn draw(m: &Model, area: Rect, buf: &mut Buffer) -> Drawn {
    let mut seen = Drawn {
        size: (area.width, area.height),
        ..Drawn::default()
    };
    if area.width < MIN_WIDTH || area.height < MIN_HEIGHT {
        too_small(m, area, buf);
        return seen;
    }
    seen.console = true;
    let [header, body, msg, hint] = layout::split(area);
    (&Header { m }).render(header, buf);
    if m.in_bench() {
        // The supervisor's strip under the bench, so an injected fault's effect
        // shows where it was injected.
        let strip = m.strip();
        let room = body.height.saturating_sub(BENCH_MIN);
        let strip_h = (strip.lines_in(body.width).len() as u16).min(3).min(room);
        let [body, strip_area] =
            Layout::vertical([Constraint::Min(0), Constraint::Length(strip_h)]).areas(body);
        if strip_h > 0 {
            (&strip).render(strip_area, buf);
        }
        if let Some(d) = m.bench_device() {
            let v = BenchView {
                id: m.bench,
                d,
                red: m.snap.red(d),
                overridden: m.snap.overridden(d),
                sim: m.snap.sim_of(m.bench),
                buckets: &m.snap.buckets,
                trace: &m.snap.trace,
                theme: m.theme,
                edit: m.edit.as_ref(),
                now: m.now,
                can_inject: m.snap.can_inject,
                read_only: m.snap.read_only,
                sim_vehicle: m.snap.sim_vehicle.as_deref(),
                map: &m.keymap,
                roles: &m.snap.gate.roles,
                trail: &m.trail,
                bus: d
                    .bus
                    .as_deref()
                    .and_then(|b| m.snap.buses.iter().find(|x| x.name == b)),
                refused: m.sim_refused(),
                run: m.bench_run(),
            };
            let shown = v.render_seen(body, buf);
            if shown.panel.name {
                seen.devices.push(m.bench);
            }
            seen.fields.extend(shown.panel.fields);
            if shown.sim_keys.is_some() {
                seen.sim_absent = v.refused;
            }
            seen.sim_keys = shown.sim_keys;
        }
    } else {
        m.render_main(body, buf, &mut seen);
    }
    match m.mode {
        Mode::Help => {
            let h = HelpPanel {
                map: &m.keymap,
                theme: m.theme,
                scroll: m.help_scroll,
                roles: &m.snap.gate.roles,
                events: m.key_viewer.then(|| KeyEvents {
                    seen: &m.keys,
                    releases: m.releases(),
                    drive: m.drive(),
                    figures: m.repeat.figures(),
                }),
            };
            (&h).render(body, buf);
            seen.covered();
            seen.help = body.height > 2 && body.width > 2;
        }
        Mode::Confirm => {
            if let Some(ask) = m.ask {
                let text = m.question_text(ask);
                let d = Dialog {
                    ask,
                    text: &text,
                    map: &m.keymap,
                    theme: m.theme,
                };
                let whole = d.render_seen(body, buf);
                seen.covered();
                seen.dialog = whole.then_some(ask);
            }
        }
        _ => {}
    }
    let line = MessageLine { m };
    // The prompt's line: what is typed, with its caret, whole.
    seen.prompt = m.mode == Mode::Find && line.prompt_fits(area.width);
    if msg.height > 0 {
        (&line).render(msg, buf);
    } else if matches!(m.mode, Mode::Edit | Mode::Find) || line.urgent() {
        // No room for both: the edit's (or the prompt's) line wins over the hints, as
        // does a refusal or a fault just said.
        (&line).render(hint, buf);
        return seen;
    }
    // With many devices, the name prompt's key is the first hint.
    let many = !m.in_bench() && matches!(m.layout_in(body), Devices::Many(_));
    let h = HintBar {
        map: &m.keymap,
        mode: m.mode,
        theme: m.theme,
        first: many.then_some(Action::Find),
        roles: &m.snap.gate.roles,
    };
    (&h).render(hint, buf);
    seen
}

impl Widget for &Model {
    fn render(self, area: Rect, buf: &mut Buffer) {
        draw(self, area, buf);
    }
}
