//! The paper's two figures, redrawn from one bench run as SVG (plotters): Fig. 3,
//! receipt → first byte against the number of actuators, beside the machine's floor;
//! Fig. 4, CPU against the command rate.

use plotters::coord::ranged1d::ValueFormatter;
use plotters::prelude::*;
use std::path::Path;

/// One line of a figure: its name, colour and points.
pub struct Series<'a> {
    pub name: &'a str,
    pub color: RGBColor,
    pub points: Vec<(f64, f64)>,
}

/// Write a [`figure`] and say where it went (or why it did not: a plot is a
/// by-product, never a reason to lose the run's figures).
pub fn save(
    path: &Path,
    title: &str,
    axes: (&str, &str),
    x: std::ops::Range<f64>,
    log_y: bool,
    series: &[Series],
) {
    match figure(path, title, axes, x, log_y, series) {
        Ok(()) => println!("plot: {}", path.display()),
        Err(e) => println!("plot {}: {e}", path.display()),
    }
}

/// A figure with a logarithmic x axis (actuators, datagrams a second); the y axis is
/// logarithmic too with `log_y` (delays from microseconds to milliseconds).
fn figure(
    path: &Path,
    title: &str,
    (x_label, y_label): (&str, &str),
    x: std::ops::Range<f64>,
    log_y: bool,
    series: &[Series],
) -> Result<(), Box<dyn std::error::Error>> {
    let ys = || series.iter().flat_map(|s| s.points.iter().map(|p| p.1));
    let y_max = ys().fold(0.0f64, f64::max) * 1.3;
    let y_min = ys().filter(|y| *y > 0.0).fold(f64::INFINITY, f64::min) / 1.5;
    let root = SVGBackend::new(path, (720, 440)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut builder = ChartBuilder::on(&root);
    builder
        .caption(title, ("sans-serif", 20))
        .margin(14)
        .x_label_area_size(44)
        .y_label_area_size(60);
    if log_y {
        let mut chart = builder.build_cartesian_2d(x.log_scale(), (y_min..y_max).log_scale())?;
        draw(&mut chart, x_label, y_label, series)?;
    } else {
        let mut chart = builder.build_cartesian_2d(x.log_scale(), 0.0..y_max.max(1e-9))?;
        draw(&mut chart, x_label, y_label, series)?;
    }
    root.present()?;
    Ok(())
}

fn draw<'a, Y>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<LogCoord<f64>, Y>>,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<(), String>
where
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .x_label_formatter(&|v| format!("{v}"))
        .draw()
        .map_err(|e| e.to_string())?;
    for s in series {
        let c = s.color;
        chart
            .draw_series(LineSeries::new(s.points.clone(), c.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label(s.name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2)));
        chart
            .draw_series(
                s.points
                    .iter()
                    .map(|&(x, y)| Circle::new((x, y), 3, c.filled())),
            )
            .map_err(|e| e.to_string())?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|e| e.to_string())?;
    Ok(())
}
