//! Where the main screen's devices go, from the screen's size, the number of devices
//! and the device under the cursor: one pure function that the view draws with and
//! that `update` pages with, so a page is exactly what the operator sees.
//!
//! While every device's panel fits with the supervisory lines under them (Alice's six
//! at 80×24), the screen is the paper's grid of panels, [`Devices::Panels`]. With more
//! devices than that, [`Devices::Many`]: every device gets a one-line row in a list,
//! in columns as the width allows (two at 80 columns, one more for every further 40),
//! and under the list a window shows the full panels of one page of devices — the
//! page holding the device under the cursor, so a cursor moving off the page turns
//! it. A window too short for one panel shows the cursor's device alone, its panel
//! packed into the lines there are. The list itself pages the same way when even one
//! row a device does not fit (64 devices at 80×24).

use ratatui::layout::{Constraint, Layout, Rect};

/// A device panel's height on a small screen: the title and five lines.
pub(crate) const PANEL: u16 = 6;
/// A bordered device panel's height on a large screen: its border and nine lines, the
/// last the measured value beside the estimate.
pub(crate) const BIG_PANEL: u16 = 11;
/// The width of one column of the device list.
pub(crate) const LIST_COL: u16 = 40;
/// The supervisory lines (or teleop's) under the devices on a small screen.
pub(crate) const HEAD: u16 = 2;
/// The fewest lines the panels' window keeps under the list.
pub(crate) const MIN_WINDOW: u16 = 1;
/// The most lines the supervisor's strip takes.
pub(crate) const MAX_STRIP: u16 = 4;
/// The smallest screen the console draws (80×24, less a tmux status line and one).
pub const MIN_WIDTH: u16 = 80;
pub const MIN_HEIGHT: u16 = 22;

/// The screen's rows: the top bar, the body, the message line (when there is room
/// for it) and the hint bar.
pub(crate) fn split(area: Rect) -> [Rect; 4] {
    let msg_h = u16::from(area.height > MIN_HEIGHT);
    Layout::vertical([
        Constraint::Length(1),
        Constraint::Min(0),
        Constraint::Length(msg_h),
        Constraint::Length(1),
    ])
    .areas(area)
}

/// Columns of the grid of device panels: two, three from 120 columns.
pub(crate) fn grid_cols(width: u16) -> u16 {
    if width >= 120 {
        3
    } else {
        2
    }
}

/// How the devices are laid out in the body.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Devices {
    /// A panel for every device, `cols` × `rows`; bordered and taller when `big`.
    Panels { cols: u16, rows: u16, big: bool },
    /// Too many devices for a panel each.
    Many(Many),
}

/// A body with a row for every device and a window of full panels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Many {
    /// The list: a header line, then `rows` lines of `cols` devices each (column by
    /// column), from device `first`.
    pub list: Rect,
    pub(crate) list_cols: u16,
    pub(crate) list_rows: u16,
    pub(crate) list_first: usize,
    /// The panels' window: `cols` panels a row, `per_page` devices from device
    /// `first`; or, when `packed`, the device `first` alone across the window.
    pub window: Rect,
    pub cols: u16,
    pub(crate) per_page: usize,
    pub first: usize,
    pub packed: bool,
    /// Everything under the window: teleop or the supervisory lines, the supervisor's
    /// strip (`strip_h` lines) and the log.
    pub below: Rect,
    pub(crate) strip_h: u16,
}

impl Many {
    /// How many devices the list shows at once.
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn list_page(&self) -> usize {
        usize::from(self.list_rows) * usize::from(self.list_cols)
    }
}

/// The first index of the page of `size` that holds `i`.
fn page_start(i: usize, size: usize) -> usize {
    i / size.max(1) * size.max(1)
}

/// Lay `n` devices out in `body`. `strip` is how many lines the supervisor has to show
/// (the recovery and its faults); `cursor` is the index of the device under the
/// cursor (the last device when the cursor is on something else).
pub(crate) fn devices(n: usize, body: Rect, strip: usize, cursor: usize) -> Devices {
    let n = n.max(1);
    let h = body.height;
    let cols = grid_cols(body.width);
    let rows = u16::try_from(n.div_ceil(usize::from(cols))).unwrap_or(u16::MAX);
    let big = u32::from(h) >= u32::from(rows) * u32::from(BIG_PANEL) + 4 + 3;
    if big || u32::from(rows) * u32::from(PANEL) + u32::from(HEAD) <= u32::from(h) {
        return Devices::Panels { cols, rows, big };
    }
    let cursor = cursor.min(n - 1);
    let list_cols = (body.width / LIST_COL).max(1);
    let rows_all = u16::try_from(n.div_ceil(usize::from(list_cols))).unwrap_or(u16::MAX);
    let list_rows = rows_all.min(h.saturating_sub(1 + HEAD + MIN_WINDOW)).max(1);
    let list_h = (1 + list_rows).min(h);
    let list_page = usize::from(list_rows) * usize::from(list_cols);
    let avail = h - list_h;
    let avail = avail.saturating_sub(HEAD);
    let strip_h = u16::try_from(strip)
        .unwrap_or(u16::MAX)
        .min(MAX_STRIP)
        .min(avail.saturating_sub(MIN_WINDOW));
    let avail = avail - strip_h;
    let packed = avail < PANEL;
    let (window_h, per_page) = if packed {
        (avail, 1)
    } else {
        let r = avail / PANEL;
        (r * PANEL, usize::from(r) * usize::from(cols))
    };
    let [list, window, below] = Layout::vertical([
        Constraint::Length(list_h),
        Constraint::Length(window_h),
        Constraint::Min(0),
    ])
    .areas(body);
    Devices::Many(Many {
        list,
        list_cols,
        list_rows,
        list_first: page_start(cursor, list_page),
        window,
        cols,
        per_page,
        first: page_start(cursor, per_page),
        packed,
        below,
        strip_h,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn body(w: u16, h: u16) -> Rect {
        split(Rect::new(0, 0, w, h))[1]
    }

    fn many(n: usize, w: u16, h: u16, strip: usize, cursor: usize) -> Many {
        match devices(n, body(w, h), strip, cursor) {
            Devices::Many(m) => m,
            other => panic!("{n} devices at {w}×{h}: {other:?}"),
        }
    }

    #[test]
    fn six_devices_keep_their_panels_at_every_size_the_console_draws() {
        for (w, h) in [
            (80, 22),
            (80, 23),
            (80, 24),
            (100, 30),
            (120, 40),
            (200, 60),
        ] {
            assert!(
                matches!(devices(6, body(w, h), 0, 0), Devices::Panels { .. }),
                "{w}×{h}"
            );
        }
        assert_eq!(
            devices(6, body(80, 24), 0, 0),
            Devices::Panels {
                cols: 2,
                rows: 3,
                big: false
            }
        );
    }

    #[test]
    fn thirty_two_devices_at_80x24_have_a_row_each_and_one_packed_panel() {
        let m = many(32, 80, 24, 0, 0);
        assert_eq!((m.list_cols, m.list_rows, m.list_first), (2, 16, 0));
        assert_eq!(m.list.height, 17, "a header line and 16 rows");
        assert!(m.packed);
        assert_eq!((m.window.height, m.per_page), (2, 1));
        assert_eq!(m.below.height, HEAD);
        // The window follows the cursor, one device a page.
        assert_eq!(many(32, 80, 24, 0, 20).first, 20);
        // Faults to show take the window's lines but its last one.
        let m = many(32, 80, 24, 3, 0);
        assert_eq!((m.strip_h, m.window.height), (1, MIN_WINDOW));
    }

    #[test]
    fn a_taller_screen_pages_whole_panels_and_a_wider_one_adds_list_columns() {
        let m = many(32, 100, 40, 0, 13);
        assert_eq!((m.list_cols, m.list_rows), (2, 16));
        assert!(!m.packed);
        // 40 − 3 = 37 lines: 17 of list, 2 of supervisory lines, 3 rows of panels.
        assert_eq!((m.cols, m.per_page), (2, 6));
        assert_eq!(m.first, 12, "the page holding device 13");
        let m = many(32, 160, 40, 0, 0);
        assert_eq!((m.list_cols, m.list_rows, m.cols), (4, 8, 3));
    }

    #[test]
    fn a_list_too_long_for_the_screen_pages_too() {
        // 21 lines: the supervisory two, the window's one, the list's header and 17.
        let m = many(64, 80, 24, 0, 40);
        assert_eq!((m.list_rows, m.list_page()), (17, 34));
        assert_eq!(m.list_first, 34);
        assert_eq!(m.window.height, MIN_WINDOW);
    }
}
