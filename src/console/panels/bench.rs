//! The bench view: one device up close. Its full panel and counters, its delay
//! histogram (receipt → first byte for an actuator, status transaction for a sensor)
//! as a bar chart over powers of two, and its raw traffic from the port's trace:
//! direction, time, hex and ASCII ("not available" while there is none). Under
//! `--sim`, a simulator box between them: the faults injected into this device, the
//! simulated e-stop, engine and steering drive, and the fault keys (from the keymap).
//! Where the screen is tall enough, a setpoint device's measured position, estimate
//! and command over the last seconds ([`TrailChart`]) above the traffic. A device on a
//! CAN bus shows its bus instead ([`BusMonitor`]): every identifier's last frame
//! decoded by the DBC, above its own traffic (the adapter lines it wrote) where every
//! identifier keeps a line; it has a chart only when it reports a position. While a
//! characterization started from the bench runs (and once it ended, until the bench
//! is left), its box ([`RunBox`]) takes the traffic's place, and the chart the
//! histogram's, whatever the height: at 80×24 too.

use super::bus::BusMonitor;
use super::characterize::{RunBox, RUN_BOX};
use super::chart::{TrailChart, CHART_MAX, CHART_MIN};
use super::device::{DevicePanel, Seen};
use super::fit;
use super::fmt_us;
use super::hint::grouped;
use super::pack;
use crate::config::device::POSITION;
use crate::console::keymap::{Action, Keymap, Mode, SimAction};
use crate::console::model::{Edit, Field};
use crate::console::theme::Theme;
use crate::console::trail::Trail;
use crate::controls::SimFaults;
use crate::port::trace::TraceEntry;
use crate::snapshot::{BusView, DeviceView};
use crate::value::DeviceId;
use ratatui::buffer::Buffer;
use ratatui::layout::{Constraint, Direction, Layout, Rect};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Bar, BarChart, BarGroup, Block, Borders, Paragraph, Widget};
use std::time::Instant;

pub(crate) struct BenchView<'a> {
    pub id: DeviceId,
    pub d: &'a DeviceView,
    /// Faulty to the engine or the supervisor.
    pub red: bool,
    /// In a driver's hands (`override`).
    pub overridden: bool,
    /// The faults injected into its simulated device.
    pub sim: Option<&'a SimFaults>,
    /// Its histogram: (upper edge µs, count).
    pub(crate) buckets: &'a [(f64, u64)],
    pub trace: &'a [TraceEntry],
    pub theme: Theme,
    pub edit: Option<&'a Edit>,
    pub now: Instant,
    pub can_inject: bool,
    /// A replay: nothing can be sent, faults included.
    pub(crate) read_only: bool,
    /// The simulated vehicle's state in words (`--sim` only).
    pub sim_vehicle: Option<&'a str>,
    /// For the fault keys' legend.
    pub map: &'a Keymap,
    /// The vehicle's role bindings, for the keys' descriptions.
    pub roles: &'a crate::snapshot::Pairs<String>,
    /// The device's last seconds, for the chart.
    pub trail: &'a Trail,
    /// The CAN bus it is on.
    pub(crate) bus: Option<&'a BusView>,
    /// The simulator keys whose line the simulator would refuse here (what they act on
    /// is not in this vehicle): not offered.
    pub(crate) refused: Vec<SimAction>,
    /// The characterization of this device started from the bench.
    pub(crate) run: Option<&'a crate::controls::Characterizing>,
}

/// Rows the simulator box takes.
const SIM_BOX: u16 = 4;
/// Rows the traffic keeps before the chart takes any: three lines and the border.
const TRAFFIC_MIN: u16 = 5;
/// Rows the bus monitor keeps at least before a CAN device's own traffic takes any:
/// its state and four identifiers, and the border.
const MONITOR_MIN: u16 = 7;

/// What of the bench was drawn: the device's panel, and the simulator's fault keys
/// in their box (`None` where there is no box: the devices are not simulated here).
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct BenchSeen {
    pub panel: Seen,
    pub sim_keys: Option<Vec<SimAction>>,
}

impl BenchView<'_> {
    /// The simulator box: this device's faults, the simulated vehicle, the keys; and
    /// which line (the first is the faults') and columns each fault key takes.
    fn sim_lines(&self, width: u16) -> (Vec<Line<'static>>, Vec<(SimAction, usize, usize)>) {
        let t = &self.theme;
        let faults = self.sim.filter(|f| f.any());
        let mut first = vec![
            Span::styled("faults ", t.label()),
            match faults {
                Some(f) => Span::styled(f.text.clone(), t.fault()),
                None => Span::raw("none"),
            },
        ];
        if let Some(v) = self.sim_vehicle {
            first.push(Span::styled(" · ", t.label()));
            first.push(Span::raw(v.to_string()));
        }
        let mut sims = Vec::new();
        let keys: Vec<Vec<Span>> = grouped(self.map, Mode::Bench, self.roles)
            .into_iter()
            .filter_map(|(k, desc, a)| match a {
                Action::Sim(s) if !self.refused.contains(&s) => Some((k, desc, s)),
                _ => None,
            })
            .map(|(k, desc, s)| {
                sims.push(s);
                let desc = desc.trim_start_matches("sim: ").trim_end_matches(" on/off");
                vec![Span::styled(k, t.key()), Span::raw(format!(" {desc}"))]
            })
            .collect();
        let widths: Vec<usize> = keys
            .iter()
            .map(|g| g.iter().map(Span::width).sum())
            .collect();
        let (lines, at) = pack(keys, width, "");
        let mut out = vec![Line::from(first)];
        out.extend(lines);
        let spots = sims
            .into_iter()
            .zip(at)
            .zip(widths)
            .map(|((s, (line, col)), w)| (s, line + 1, col + w))
            .collect();
        (out, spots)
    }
}

/// Histogram buckets (upper edge µs, count) regrouped by powers of two of µs:
/// (upper edge µs, count), from the lowest to the highest non-empty bin.
pub(crate) fn log2_bins(buckets: &[(f64, u64)]) -> Vec<(f64, u64)> {
    let mut bins: Vec<(f64, u64)> = Vec::new();
    for &(edge, n) in buckets {
        let k = edge.max(1.0).log2().ceil() as i32;
        let top = 2f64.powi(k);
        match bins.iter_mut().find(|(e, _)| *e == top) {
            Some(b) => b.1 += n,
            None => bins.push((top, n)),
        }
    }
    bins.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Fill the gaps so the shape reads right.
    let mut out = Vec::new();
    if let (Some(lo), Some(hi)) = (bins.first(), bins.last()) {
        let mut e = lo.0;
        while e <= hi.0 {
            let n = bins.iter().find(|b| b.0 == e).map_or(0, |b| b.1);
            out.push((e, n));
            e *= 2.0;
        }
    }
    out
}

/// One trace line: direction, time before now, hex, ASCII.
pub(crate) fn trace_line(e: &TraceEntry, now: Instant) -> String {
    let ago = now.saturating_duration_since(e.at).as_secs_f64();
    format!(
        "{} {ago:>7.3}s ago  {:<48} {}",
        e.dir.arrow(),
        e.hex(),
        e.ascii()
    )
}

/// The raw traffic's title: its columns, then the faults injected into the device, or
/// why none can be (not simulated here; a replay, which is read-only).
fn traffic_title(name: &str, sim: Option<&str>, can_inject: bool, read_only: bool) -> String {
    let mut title = format!(" {name} raw traffic: dir, time ago, hex, text ");
    match sim {
        Some(f) => title.push_str(&format!("— sim: {f} ")),
        None if read_only => title.push_str("— replay: read-only "),
        None if !can_inject => title.push_str("— fault injection needs --sim "),
        None => {}
    }
    title
}

impl Widget for &BenchView<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        self.render_seen(area, buf);
    }
}

impl BenchView<'_> {
    /// Draw the bench in `area`, every line and title cut to its room, and say what of
    /// it was drawn.
    pub(crate) fn render_seen(&self, area: Rect, buf: &mut Buffer) -> BenchSeen {
        let t = &self.theme;
        let mut seen = BenchSeen::default();
        let sim_h = if self.can_inject { SIM_BOX } else { 0 };
        let [top, sim, bottom] = Layout::vertical([
            Constraint::Length(11),
            Constraint::Length(sim_h),
            Constraint::Min(3),
        ])
        .areas(area);
        // The chart of a setpoint device where the traffic leaves it room; else it
        // gives way and the panels keep their lines.
        // A CAN device without a position has nothing to chart but its command: the
        // bus has the room.
        let has_chart = self.run.is_none()
            && self.d.range.is_some()
            && (self.bus.is_none() || self.d.readings.get(POSITION).is_some());
        // A characterization's box where the traffic was, the traffic below it with
        // what is left.
        let run_h = match self.run {
            Some(_) if bottom.height >= RUN_BOX + TRAFFIC_MIN => RUN_BOX,
            Some(_) => bottom.height,
            None => 0,
        };
        let [run_area, bottom] =
            Layout::vertical([Constraint::Length(run_h), Constraint::Min(0)]).areas(bottom);
        if let Some(run) = self.run {
            let b = RunBox {
                run,
                map: self.map,
                theme: *t,
            };
            (&b).render(run_area, buf);
        }
        let chart_h = if has_chart {
            bottom.height.saturating_sub(TRAFFIC_MIN).min(CHART_MAX)
        } else {
            0
        };
        let chart_h = if chart_h >= CHART_MIN { chart_h } else { 0 };
        let [chart, bottom] =
            Layout::vertical([Constraint::Length(chart_h), Constraint::Min(0)]).areas(bottom);
        // The bus first: the device's own traffic below only where every identifier
        // keeps its line above it.
        let monitor_h = match self.bus {
            Some(b) if bottom.height >= BusMonitor::rows(b).max(MONITOR_MIN) + TRAFFIC_MIN => {
                bottom.height - TRAFFIC_MIN
            }
            Some(_) => bottom.height,
            None => 0,
        };
        let [monitor, bottom] =
            Layout::vertical([Constraint::Length(monitor_h), Constraint::Min(0)]).areas(bottom);
        if let Some(bus) = self.bus {
            let m = BusMonitor { bus, theme: *t };
            (&m).render(monitor, buf);
        }
        if chart.height > 0 {
            let c = TrailChart {
                id: self.id,
                d: self.d,
                trail: self.trail,
                now: self.now,
                theme: *t,
            };
            (&c).render(chart, buf);
        }
        if self.can_inject {
            let block = Block::new().borders(Borders::TOP).title(Span::styled(
                fit::title(
                    &format!(
                        " simulator: {} and the vehicle (on/off keys toggle) ",
                        self.d.name
                    ),
                    sim.width,
                ),
                t.title(),
            ));
            let inner = block.inner(sim);
            block.render(sim, buf);
            let (lines, spots) = self.sim_lines(inner.width);
            let kept: Vec<usize> = lines.iter().map(|l| fit::kept(l, inner.width)).collect();
            seen.sim_keys = Some(
                spots
                    .into_iter()
                    .filter(|&(_, line, end)| {
                        line < usize::from(inner.height)
                            && kept.get(line).is_some_and(|&k| end <= k)
                    })
                    .map(|(s, _, _)| s)
                    .collect(),
            );
            fit::Fitted(lines).render(inner, buf);
        }
        let [left, right] = Layout::horizontal([Constraint::Length(46), Constraint::Min(20)])
            .direction(Direction::Horizontal)
            .areas(top);
        let panel = DevicePanel {
            id: self.id,
            d: self.d,
            red: self.red,
            overridden: self.overridden,
            sim: self.sim,
            theme: *t,
            cursor: self.d.is_actuator().then_some(Field::Command(self.id)),
            edit: self.edit,
            bordered: true,
        };
        seen.panel = panel.render_seen(left, buf);

        // During a characterization, the device's chart in the histogram's place.
        if self.run.is_some() && right.height >= CHART_MIN {
            let c = TrailChart {
                id: self.id,
                d: self.d,
                trail: self.trail,
                now: self.now,
                theme: *t,
            };
            (&c).render(right, buf);
        } else {
            self.histogram(right, buf);
        }
        self.traffic(bottom, buf);
        seen
    }

    /// The device's delay histogram, as a bar chart over powers of two.
    fn histogram(&self, right: Rect, buf: &mut Buffer) {
        let t = &self.theme;
        let bins = log2_bins(self.buckets);
        let what = if self.d.is_actuator() {
            " receipt → first byte "
        } else {
            " status transaction "
        };
        let block = Block::bordered().title(Span::styled(fit::title(what, right.width), t.title()));
        if bins.is_empty() {
            let inner = block.inner(right);
            block.render(right, buf);
            Paragraph::new(Span::styled("no samples yet", t.label())).render(inner, buf);
        } else {
            let bars: Vec<Bar> = bins
                .iter()
                .map(|(e, n)| {
                    Bar::default()
                        .value(*n)
                        .label(Line::from(format!("≤{:>6}", fmt_us(Some(*e)))))
                        .text_value(n.to_string())
                })
                .collect();
            BarChart::default()
                .block(block)
                .direction(Direction::Horizontal)
                .bar_width(1)
                .bar_gap(0)
                .bar_style(if t.color {
                    ratatui::style::Style::new().fg(ratatui::style::Color::Cyan)
                } else {
                    ratatui::style::Style::new()
                })
                .data(BarGroup::default().bars(&bars))
                .render(right, buf);
        }
    }

    /// The device's raw traffic, newest at the bottom.
    fn traffic(&self, bottom: Rect, buf: &mut Buffer) {
        let t = &self.theme;
        let title = traffic_title(
            &self.d.name,
            self.sim.filter(|f| f.any()).map(|f| f.text.as_str()),
            self.can_inject,
            self.read_only,
        );
        if bottom.height == 0 {
            return;
        }
        let block =
            Block::bordered().title(Span::styled(fit::title(&title, bottom.width), t.title()));
        let inner = block.inner(bottom);
        block.render(bottom, buf);
        let lines: Vec<Line> = if self.trace.is_empty() {
            vec![Line::from(Span::styled(
                "trace: not available (no traffic yet)",
                t.label(),
            ))]
        } else {
            let n = inner.height as usize;
            self.trace[self.trace.len().saturating_sub(n)..]
                .iter()
                .map(|e| Line::from(trace_line(e, self.now)))
                .collect()
        };
        fit::Fitted(lines).render(inner, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn buckets_regroup_by_powers_of_two_with_gaps_filled() {
        let b = [(20.0, 1), (26.5, 2), (30.0, 1), (45.0, 1), (1200.0, 1)];
        assert_eq!(
            log2_bins(&b),
            [
                (32.0, 4),
                (64.0, 1),
                (128.0, 0),
                (256.0, 0),
                (512.0, 0),
                (1024.0, 0),
                (2048.0, 1)
            ]
        );
        assert!(log2_bins(&[]).is_empty());
    }

    #[test]
    fn trace_lines_show_direction_time_hex_and_ascii() {
        let now = Instant::now();
        let e = TraceEntry::new(
            now - Duration::from_millis(12),
            crate::port::trace::Dir::Out,
            b"S 0.5\r",
        );
        assert_eq!(
            trace_line(&e, now),
            format!("->   0.012s ago  {:<48} S 0.5.", "53 20 30 2e 35 0d")
        );
    }

    /// The traffic's time column was a bare `-  0.012s`, and in a replay the title
    /// said "fault injection needs --sim" as if `--sim` would help.
    #[test]
    fn the_traffic_title_names_its_columns_and_what_injection_needs() {
        let title = |sim, inject, read_only| traffic_title("gas", sim, inject, read_only);
        assert_eq!(
            title(None, true, false),
            " gas raw traffic: dir, time ago, hex, text "
        );
        assert_eq!(
            title(None, false, false),
            " gas raw traffic: dir, time ago, hex, text — fault injection needs --sim "
        );
        assert_eq!(
            title(None, false, true),
            " gas raw traffic: dir, time ago, hex, text — replay: read-only "
        );
        assert_eq!(
            title(Some("silent"), true, false),
            " gas raw traffic: dir, time ago, hex, text — sim: silent "
        );
    }

    fn rows(buf: &Buffer) -> Vec<String> {
        (0..buf.area.height)
            .map(|y| (0..buf.area.width).map(|x| buf[(x, y)].symbol()).collect())
            .collect()
    }

    /// Incident: on the bench at 100×30 with simulator faults on, titles and the
    /// simulator's lines were cut mid-word at the edge. Every title and line is whole
    /// or cut at a word with `…`; the fault keys not drawn are not said to be.
    #[test]
    fn with_faults_on_every_title_and_line_is_whole_or_cut_with_a_mark() {
        use crate::controls::{capture, Sources};
        let now = Instant::now();
        let f = capture(&crate::testkit::gate(now), &Sources::default(), now, None);
        let id = f.id_of("steer").unwrap();
        let faults = SimFaults {
            silent: true,
            corrupt: true,
            slow_ms: 150,
            hand: Some(1.0),
            text: "silent, corrupt, slow 150ms".into(),
            ..SimFaults::default()
        };
        let map = Keymap::default_map();
        let trace = [TraceEntry::new(
            now,
            crate::port::trace::Dir::Out,
            b"a reply far too long for any traffic box, thirty-two bytes and more\r",
        )];
        let trail = Trail::default();
        let vehicle = "e-stop run · engine running · steer drive ok · a hand pushes it toward 1";
        let view = |roles| BenchView {
            id,
            d: f.at(id).unwrap(),
            red: true,
            overridden: true,
            sim: Some(&faults),
            buckets: &[],
            trace: &trace,
            theme: Theme::default(),
            edit: None,
            now,
            can_inject: true,
            read_only: false,
            sim_vehicle: Some(vehicle),
            map: &map,
            roles,
            trail: &trail,
            bus: None,
            refused: Vec::new(),
            run: None,
        };
        let roles = f.snap.gate.roles.clone();
        let v = view(&roles);
        let mut buf = Buffer::empty(Rect::new(0, 0, 100, 26));
        let seen = v.render_seen(buf.area, &mut buf);
        let r = rows(&buf);
        assert!(
            r[0].starts_with("┌STEER -1…1 cmd - meas 0.231 FAULT OVERRIDE…─"),
            "{}",
            r[0]
        );
        assert!(
            r[11].starts_with(" simulator: steer and the vehicle (on/off keys toggle) ─"),
            "{}",
            r[11]
        );
        assert_eq!(
            r[12].trim_end(),
            "faults silent, corrupt, slow 150ms · e-stop run · engine running · steer drive ok · a hand pushes…"
        );
        assert!(
            r[15].starts_with("┌ steer raw traffic: dir, time ago, hex, text — sim: silent, corrupt, slow 150ms ─"),
            "{}",
            r[15]
        );
        assert!(r[16].ends_with(" 6e…│"), "{}", r[16]);
        assert_eq!(seen.sim_keys.as_ref().map(Vec::len), Some(11), "{seen:?}");
        assert!(seen.panel.name);
        // At 60 columns the traffic's title is cut at a word, and the keys on a third
        // line of the simulator box are not drawn.
        let mut buf = Buffer::empty(Rect::new(0, 0, 60, 26));
        let seen = v.render_seen(buf.area, &mut buf);
        let r = rows(&buf);
        assert_eq!(
            r[11],
            " simulator: steer and the vehicle (on/off keys toggle) ─────"
        );
        assert!(
            r[15].starts_with("┌ steer raw traffic: dir, time ago, hex, text — sim… ─"),
            "{}",
            r[15]
        );
        let keys = seen.sim_keys.unwrap();
        assert!(keys.contains(&SimAction::Silent), "{keys:?}");
        assert!(
            !keys.contains(&SimAction::Estop(crate::value::EstopState::Run)),
            "{keys:?}"
        );
    }
}
