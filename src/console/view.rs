//! The whole screen, drawn from the [`Model`] alone (`impl Widget for &Model`): a top
//! bar, the devices, the supervisory and network panels (or teleop), the log pane,
//! the outcome line and the hint bar; the bench view instead of the devices; help and
//! confirmation over it. Below the minimum size it says so instead.
//!
//! The devices are laid out as [`layout`] says: a panel each in a grid
//! (two columns at 80×24, three from 120 columns, bordered with more figures when
//! there is room) while they fit; with more devices, a one-line row each in a
//! [`DeviceList`] and a window of full panels under it that pages.

use super::find;
use super::keymap::{Action, Mode};
use super::layout::{self, Devices, Many, BIG_PANEL, HEAD, PANEL};
use super::model::Model;
use super::panels::bench::BenchView;
use super::panels::device::DevicePanel;
use super::panels::dialog::Dialog;
use super::panels::header::Header;
use super::panels::help::HelpPanel;
use super::panels::hint::{HintBar, MessageLine};
use super::panels::list::DeviceList;
use super::panels::log::LogPanel;
use super::panels::network::NetworkPanel;
use super::panels::supervisor::{SupervisorPanel, SupervisorStrip};
use super::panels::teleop::TeleopPanel;
use crate::value::DeviceId;
use ratatui::buffer::Buffer;
use ratatui::layout::{Constraint, Layout, Rect};
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
    fn render_grid(&self, g: &Grid, ids: Range<usize>, buf: &mut Buffer) {
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
                (&p).render(area, buf);
            }
        }
    }

    /// The supervisory and network panels side by side.
    fn render_lower(&self, sup: &SupervisorPanel, lower: Rect, buf: &mut Buffer) {
        if lower.height == 0 {
            return;
        }
        let [left, right] =
            Layout::horizontal([Constraint::Percentage(50), Constraint::Percentage(50)])
                .areas(lower);
        sup.render(
            Rect {
                width: left.width.saturating_sub(1),
                ..left
            },
            buf,
        );
        let net = NetworkPanel {
            snap: &self.snap,
            theme: self.theme,
        };
        (&net).render(right, buf);
    }

    fn render_teleop(&self, area: Rect, buf: &mut Buffer) {
        if area.height > 0 {
            let p = TeleopPanel {
                t: &self.teleop,
                now: self.now,
                theme: self.theme,
            };
            (&p).render(area, buf);
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

    fn render_main(&self, body: Rect, buf: &mut Buffer) {
        match self.layout_in(body) {
            Devices::Panels { cols, rows, big } => self.render_panels(body, cols, rows, big, buf),
            Devices::Many(l) => self.render_many(&l, buf),
        }
    }

    /// A panel for every device (Alice at 80×24).
    fn render_panels(&self, body: Rect, cols: u16, rows: u16, big: bool, buf: &mut Buffer) {
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
        let teleop_h = if teleop { HEAD } else { 0 };
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
        self.render_grid(&g, 0..self.snap.devices.len(), buf);
        self.render_teleop(teleop_area, buf);
        self.render_lower(&sup, lower, buf);
        if strip_area.height > 0 {
            (&strip).render(strip_area, buf);
        }
        self.render_log(log, buf);
    }

    /// A row for every device and a window of full panels (many devices).
    fn render_many(&self, l: &Many, buf: &mut Buffer) {
        let teleop = self.in_teleop();
        let names = self.snap.devices.iter().map(|d| d.name.as_str());
        let found = match (&self.find, self.mode) {
            (Some(f), Mode::Find) => find::matches(names, &f.query),
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
        (&list).render(l.list, buf);
        if l.packed {
            if let Some(p) = self.panel(l.first, false) {
                let lines = p.packed(l.window.width, l.window.height);
                Paragraph::new(lines).render(l.window, buf);
            }
        } else {
            let g = Grid {
                area: l.window,
                cols: l.cols,
                panel_h: PANEL,
                bordered: false,
            };
            let n = self.snap.devices.len();
            self.render_grid(&g, l.first..(l.first + l.per_page).min(n), buf);
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
        self.render_teleop(teleop_area, buf);
        self.render_lower(&sup, lower, buf);
        if strip_area.height > 0 {
            (&self.strip()).render(strip_area, buf);
        }
        self.render_log(log, buf);
    }
}

fn too_small(area: Rect, buf: &mut Buffer) {
    let text = format!(
        "adrive needs a terminal of at least {MIN_WIDTH}×{MIN_HEIGHT}; this one is {}×{}. \
         Enlarge the window (the engine keeps running; q quits).",
        area.width, area.height
    );
    Paragraph::new(text)
        .wrap(Wrap { trim: true })
        .render(area, buf);
}

impl Widget for &Model {
    fn render(self, area: Rect, buf: &mut Buffer) {
        if area.width < MIN_WIDTH || area.height < MIN_HEIGHT {
            too_small(area, buf);
            return;
        }
        let [header, body, msg, hint] = layout::split(area);
        (&Header { m: self }).render(header, buf);
        if self.in_bench() {
            // The supervisor's strip under the bench, so an injected fault's effect
            // shows where it was injected.
            let strip = self.strip();
            let room = body.height.saturating_sub(BENCH_MIN);
            let strip_h = (strip.lines_in(body.width).len() as u16).min(3).min(room);
            let [body, strip_area] =
                Layout::vertical([Constraint::Min(0), Constraint::Length(strip_h)]).areas(body);
            if strip_h > 0 {
                (&strip).render(strip_area, buf);
            }
            if let Some(d) = self.bench_device() {
                let v = BenchView {
                    id: self.bench,
                    d,
                    red: self.snap.red(d),
                    overridden: self.snap.overridden(d),
                    sim: self.snap.sim_of(self.bench),
                    buckets: &self.snap.buckets,
                    trace: &self.snap.trace,
                    theme: self.theme,
                    edit: self.edit.as_ref(),
                    now: self.now,
                    can_inject: self.snap.can_inject,
                    read_only: self.snap.read_only,
                    sim_vehicle: self.snap.sim_vehicle.as_deref(),
                    map: &self.keymap,
                    roles: &self.snap.gate.roles,
                    trail: &self.trail,
                    bus: d
                        .bus
                        .as_deref()
                        .and_then(|b| self.snap.buses.iter().find(|x| x.name == b)),
                    refused: self.sim_refused(),
                };
                (&v).render(body, buf);
            }
        } else {
            self.render_main(body, buf);
        }
        match self.mode {
            Mode::Help => {
                let h = HelpPanel {
                    map: &self.keymap,
                    theme: self.theme,
                    scroll: self.help_scroll,
                    roles: &self.snap.gate.roles,
                };
                (&h).render(body, buf);
            }
            Mode::Confirm => {
                if let Some(ask) = self.ask {
                    let d = Dialog {
                        ask,
                        map: &self.keymap,
                        theme: self.theme,
                    };
                    (&d).render(body, buf);
                }
            }
            _ => {}
        }
        if msg.height > 0 {
            (&MessageLine { m: self }).render(msg, buf);
        } else if matches!(self.mode, Mode::Edit | Mode::Find) {
            // No room for both: the edit's (or the prompt's) line wins over the hints.
            (&MessageLine { m: self }).render(hint, buf);
            return;
        }
        // With many devices, the name prompt's key is the first hint.
        let many = !self.in_bench() && matches!(self.layout_in(body), Devices::Many(_));
        let h = HintBar {
            map: &self.keymap,
            mode: self.mode,
            theme: self.theme,
            first: many.then_some(Action::Find),
            roles: &self.snap.gate.roles,
        };
        (&h).render(hint, buf);
    }
}
