//! The bench chart: the bench device's measured position, its estimate and its
//! command over the console's [`Trail`] (the last ten seconds), in the device's
//! units, each line named in the legend. A step in the command, the drive following
//! it and the estimator tracking both read at a glance, where the numbers of the
//! device panel show only the present.

use super::fit;
use crate::console::theme::Theme;
use crate::console::trail::{Sample, Trail, WINDOW};
use crate::snapshot::DeviceView;
use crate::value::DeviceId;
use ratatui::buffer::Buffer;
use ratatui::layout::{Constraint, Rect};
use ratatui::symbols::Marker;
use ratatui::text::Span;
use ratatui::widgets::{Axis, Block, Chart, Dataset, GraphType, Widget};
use std::time::Instant;

/// The fewest rows the chart is drawn in (its border, axes and a few rows of plot).
pub(crate) const CHART_MIN: u16 = 8;
/// The most rows it takes.
pub(crate) const CHART_MAX: u16 = 16;

pub(crate) struct TrailChart<'a> {
    pub id: DeviceId,
    pub d: &'a DeviceView,
    pub trail: &'a Trail,
    pub now: Instant,
    pub theme: Theme,
}

/// The lines: name, marker, and the value a sample gives it.
type Series = (&'static str, Marker, fn(&Sample) -> Option<f64>);
/// Drawn in this order: the measured line last, over the estimate's dots, so the
/// dots show where the estimate parts from the readings.
const SERIES: [Series; 3] = [
    ("command", Marker::HalfBlock, |s| s.command),
    ("estimate", Marker::Dot, |s| s.estimate),
    ("measured", Marker::Braille, |s| s.measured),
];

impl TrailChart<'_> {
    /// (seconds before now, value) of one line, oldest first.
    fn points(&self, value: fn(&Sample) -> Option<f64>) -> Vec<(f64, f64)> {
        self.trail
            .of(self.id)
            .filter_map(|s| {
                let ago = self.now.saturating_duration_since(s.at).as_secs_f64();
                value(s).map(|v| (-ago, v))
            })
            .collect()
    }

    /// The y axis: the device's range, widened to what was seen outside it.
    fn bounds(&self, lines: &[Vec<(f64, f64)>]) -> [f64; 2] {
        let seen = lines.iter().flatten().map(|p| p.1);
        let [mut lo, mut hi] = self.d.range.unwrap_or([f64::INFINITY, f64::NEG_INFINITY]);
        for v in seen {
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if !lo.is_finite() || !hi.is_finite() {
            return [0.0, 1.0];
        }
        if hi - lo < 1e-9 {
            return [lo - 0.5, hi + 0.5];
        }
        [lo, hi]
    }
}

impl Widget for &TrailChart<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        let t = &self.theme;
        let lines: Vec<Vec<(f64, f64)>> = SERIES.iter().map(|s| self.points(s.2)).collect();
        let [lo, hi] = self.bounds(&lines);
        let datasets = SERIES
            .iter()
            .zip(&lines)
            .enumerate()
            .map(|(i, ((name, marker, _), points))| {
                Dataset::default()
                    .name(*name)
                    .marker(*marker)
                    .graph_type(GraphType::Line)
                    .style(t.plot(i))
                    .data(points)
            })
            .collect();
        let secs = WINDOW.as_secs_f64();
        let title = format!(" {} over the last {secs:.0} s ", self.d.name);
        let mut y_axis = Axis::default();
        if !self.d.units.is_empty() {
            y_axis = y_axis.title(Span::styled(self.d.units.as_str(), t.label()));
        }
        Chart::new(datasets)
            .block(Block::bordered().title(Span::styled(fit::title(&title, area.width), t.title())))
            .x_axis(
                Axis::default()
                    .style(t.label())
                    .bounds([-secs, 0.0])
                    .labels([
                        format!("-{secs:.0}s"),
                        format!("-{:.0}s", secs / 2.0),
                        "now".into(),
                    ]),
            )
            .y_axis(y_axis.style(t.label()).bounds([lo, hi]).labels([
                format!("{lo:.2}"),
                format!("{:.2}", (lo + hi) / 2.0),
                format!("{hi:.2}"),
            ]))
            .legend_position(Some(ratatui::widgets::LegendPosition::TopLeft))
            .hidden_legend_constraints((Constraint::Percentage(50), Constraint::Percentage(100)))
            .render(area, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::controls::{capture, Sources};

    /// The chart's title in a narrow box is cut at a word with a mark, inside its
    /// corners.
    #[test]
    fn a_title_without_room_is_cut_with_a_mark() {
        let now = Instant::now();
        let f = capture(&crate::testkit::gate(now), &Sources::default(), now, None);
        let id = f.id_of("steer").unwrap();
        let trail = Trail::default();
        let c = TrailChart {
            id,
            d: f.at(id).unwrap(),
            trail: &trail,
            now,
            theme: Theme::default(),
        };
        let mut buf = Buffer::empty(Rect::new(0, 0, 24, 6));
        (&c).render(buf.area, &mut buf);
        let row: String = (0..24).map(|x| buf[(x, 0)].symbol()).collect();
        assert_eq!(row, "┌ steer over the last… ┐");
    }
}
