//! The whole screen, drawn from the [`Model`] alone (`impl Widget for &Model`): a top
//! bar, the device panels in a grid (two columns at 80×24, three from 120 columns,
//! bordered with more figures when there is room), the supervisory and network panels
//! (or teleop), the log pane, the outcome line and the hint bar; the bench view
//! instead of the grid; help and confirmation over it. Below the minimum size it says
//! so instead.

use super::keymap::Mode;
use super::model::Model;
use super::panels::bench::BenchView;
use super::panels::device::DevicePanel;
use super::panels::dialog::Dialog;
use super::panels::header::Header;
use super::panels::help::HelpPanel;
use super::panels::hint::{HintBar, MessageLine};
use super::panels::log::LogPanel;
use super::panels::network::NetworkPanel;
use super::panels::supervisor::{SupervisorPanel, SupervisorStrip};
use super::panels::teleop::TeleopPanel;
use ratatui::buffer::Buffer;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::widgets::{Paragraph, Widget, Wrap};

/// The smallest screen the console draws (80×24, less a tmux status line and one).
pub const MIN_WIDTH: u16 = 80;
pub const MIN_HEIGHT: u16 = 22;

/// The bench view's height with its simulator box and three rows of traffic.
const BENCH_MIN: u16 = 18;

/// Height of a bordered device panel on a large screen.
const BIG_PANEL: u16 = 10;

impl Model {
    fn render_main(&self, body: Rect, buf: &mut Buffer) {
        let n = self.snap.devices.len().max(1) as u16;
        let cols: u16 = if body.width >= 120 { 3 } else { 2 };
        let rows = n.div_ceil(cols);
        let big = body.height >= rows * BIG_PANEL + 4 + 3;
        let show_cursor = !self.in_teleop();
        let sup = SupervisorPanel {
            m: self,
            cursor: show_cursor,
            compact: !big,
        };
        let strip = SupervisorStrip {
            snap: &self.snap,
            theme: self.theme,
        };
        // While the supervisor has faults or a recovery to show, a small screen's
        // device panels give up their last line (counters) to make room for them.
        let panel_h = match (big, sup.active()) {
            (true, _) => BIG_PANEL,
            (false, true) => 5,
            (false, false) => 6,
        };
        let teleop = self.in_teleop();
        let grid_h = rows * panel_h;
        let rest = body.height.saturating_sub(grid_h);
        let teleop_h = if teleop { 2 } else { 0 };
        // Small: teleop replaces the two supervisory lines; the strip goes under.
        // Large: the supervisory panel grows with what it shows, leaving the log 3.
        let (sup_h, strip_h) = if big {
            let want = (sup.full_lines(body.width / 2).len() as u16).max(4);
            (want.min(rest.saturating_sub(teleop_h + 3)), 0)
        } else {
            let head = if teleop { 0 } else { 2 };
            let room = rest.saturating_sub(teleop_h + head + 1);
            (head, (strip.lines().len() as u16).min(4).min(room))
        };
        let [grid, teleop_area, lower, strip_area, log] = Layout::vertical([
            Constraint::Length(grid_h),
            Constraint::Length(teleop_h),
            Constraint::Length(sup_h),
            Constraint::Length(strip_h),
            Constraint::Min(0),
        ])
        .areas(body);
        let cursor = show_cursor.then(|| self.field());
        let col_w = grid.width / cols;
        for (i, d) in self.snap.devices.iter().enumerate() {
            let id = crate::value::DeviceId(i as u16);
            let (r, c) = (i as u16 / cols, i as u16 % cols);
            let w = if c == cols - 1 {
                grid.width - col_w * c
            } else if big {
                col_w
            } else {
                col_w - 1
            };
            let area = Rect {
                x: grid.x + c * col_w,
                y: grid.y + r * panel_h,
                width: w,
                height: panel_h,
            }
            .intersection(grid);
            let p = DevicePanel {
                id,
                d,
                red: self.snap.red(d),
                sim: self.snap.sim_of(id),
                theme: self.theme,
                cursor,
                edit: self.edit.as_ref(),
                bordered: big,
            };
            (&p).render(area, buf);
        }
        if teleop {
            let p = TeleopPanel {
                t: &self.teleop,
                now: self.now,
                theme: self.theme,
            };
            (&p).render(teleop_area, buf);
        }
        if lower.height > 0 {
            let [left, right] =
                Layout::horizontal([Constraint::Percentage(50), Constraint::Percentage(50)])
                    .areas(lower);
            (&sup).render(
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
        if strip_area.height > 0 {
            (&strip).render(strip_area, buf);
        }
        if log.height > 0 {
            let p = LogPanel {
                lines: &self.snap.logs,
                theme: self.theme,
            };
            (&p).render(log, buf);
        }
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
        let msg_h = if area.height > MIN_HEIGHT { 1 } else { 0 };
        let [header, body, msg, hint] = Layout::vertical([
            Constraint::Length(1),
            Constraint::Min(0),
            Constraint::Length(msg_h),
            Constraint::Length(1),
        ])
        .areas(area);
        (&Header { m: self }).render(header, buf);
        if self.in_bench() {
            // The supervisor's strip under the bench, so an injected fault's effect
            // shows where it was injected.
            let strip = SupervisorStrip {
                snap: &self.snap,
                theme: self.theme,
            };
            let room = body.height.saturating_sub(BENCH_MIN);
            let strip_h = (strip.lines().len() as u16).min(3).min(room);
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
                    sim: self.snap.sim_of(self.bench),
                    buckets: &self.snap.buckets,
                    trace: &self.snap.trace,
                    theme: self.theme,
                    edit: self.edit.as_ref(),
                    now: self.now,
                    can_inject: self.snap.can_inject,
                    sim_vehicle: self.snap.sim_vehicle.as_deref(),
                    map: &self.keymap,
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
        } else if self.mode == Mode::Edit {
            // No room for both: the edit's line wins over the hints.
            (&MessageLine { m: self }).render(hint, buf);
            return;
        }
        let h = HintBar {
            map: &self.keymap,
            mode: self.mode,
            theme: self.theme,
        };
        (&h).render(hint, buf);
    }
}
