//! The paper's two figures, redrawn from one bench run as SVG (plotters): Fig. 3,
//! receipt → first byte against the number of actuators, beside the machine's floor;
//! Fig. 4, CPU against the command rate.

use plotters::prelude::*;
use std::path::Path;

/// One line of a figure: its name, colour and points.
pub struct Series<'a> {
    pub name: &'a str,
    pub color: RGBColor,
    pub points: Vec<(f64, f64)>,
}

/// A figure with a logarithmic x axis (actuators, datagrams a second) and a linear y.
pub fn figure(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    x: std::ops::Range<f64>,
    series: &[Series],
) -> Result<(), Box<dyn std::error::Error>> {
    let y_max = series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.1))
        .fold(0.0f64, f64::max)
        * 1.15;
    let root = SVGBackend::new(path, (720, 440)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(14)
        .x_label_area_size(44)
        .y_label_area_size(60)
        .build_cartesian_2d(x.log_scale(), 0.0..y_max.max(1e-9))?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .x_label_formatter(&|v| format!("{v}"))
        .draw()?;
    for s in series {
        let c = s.color;
        chart
            .draw_series(LineSeries::new(s.points.clone(), c.stroke_width(2)))?
            .label(s.name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2)));
        chart.draw_series(
            s.points
                .iter()
                .map(|&(x, y)| Circle::new((x, y), 3, c.filled())),
        )?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}
