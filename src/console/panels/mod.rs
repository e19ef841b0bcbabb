//! One widget per panel of the screen. Each takes plain data (a device of the
//! [`Snapshot`], the [`Model`]) and draws into a `Rect`; none touches the engine.
//!
//! [`Snapshot`]: crate::snapshot::Snapshot
//! [`Model`]: super::model::Model

pub(crate) mod bench;
pub(crate) mod bus;
pub(crate) mod characterize;
pub(crate) mod chart;
pub(crate) mod device;
pub(crate) mod dialog;
pub(crate) mod fit;
pub(crate) mod header;
pub(crate) mod help;
pub(crate) mod hint;
pub(crate) mod list;
pub(crate) mod log;
pub(crate) mod network;
pub(crate) mod supervisor;
pub(crate) mod teleop;

use ratatui::text::{Line, Span};
use std::time::Duration;

/// A latency in µs as `26µs`, `1.2ms`, `1.50s`, or `-` when there is none.
pub(crate) fn fmt_us(v: Option<f64>) -> String {
    match v {
        None => "-".into(),
        Some(us) if us < 1000.0 => format!("{us:.0}µs"),
        Some(us) if us < 1_000_000.0 => format!("{:.1}ms", us / 1000.0),
        Some(us) => format!("{:.2}s", us / 1e6),
    }
}

/// An age as `20ms` or `1.5s`.
pub(crate) fn fmt_age(d: Option<Duration>) -> String {
    match d {
        None => "never".into(),
        Some(d) if d < Duration::from_secs(10) && d.as_millis() < 1000 => {
            format!("{}ms", d.as_millis())
        }
        Some(d) => format!("{:.1}s", d.as_secs_f64()),
    }
}

/// Lay groups of spans (a group is never split) out in lines of at most `width`
/// columns, two spaces apart, each line starting with `indent`.
pub(crate) fn wrap<'a>(
    groups: Vec<Vec<Span<'a>>>,
    width: u16,
    indent: &'static str,
) -> Vec<Line<'a>> {
    pack(groups, width, indent).0
}

/// [`wrap`], also saying where each group landed: its line and the column it starts at.
pub(crate) fn pack<'a>(
    groups: Vec<Vec<Span<'a>>>,
    width: u16,
    indent: &'static str,
) -> (Vec<Line<'a>>, Vec<(usize, usize)>) {
    let width = width as usize;
    let start = indent.chars().count();
    let mut out = Vec::new();
    let mut at = Vec::with_capacity(groups.len());
    let mut line: Vec<Span> = vec![Span::raw(indent)];
    let mut used = start;
    for g in groups {
        let w: usize = g.iter().map(Span::width).sum();
        if line.len() > 1 && used + 2 + w > width {
            out.push(Line::from(std::mem::take(&mut line)));
            line.push(Span::raw(indent));
            used = start;
        }
        if line.len() > 1 {
            line.push(Span::raw("  "));
            used += 2;
        }
        at.push((out.len(), used));
        used += w;
        line.extend(g);
    }
    if line.len() > 1 {
        out.push(Line::from(line));
    }
    (out, at)
}
