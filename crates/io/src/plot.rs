//! PNG charts on top of `plotters`: lines, points and points with error bars, with a legend and
//! automatic ranges. Made for docs figures and `hemodpd analyze --plot`.
//!
//! ```no_run
//! use hemodpd_io::plot::{line_chart, Series};
//! let sim = Series::line("simulation", vec![(0.0, 7.8), (100.0, 12.0), (200.0, 15.0)]);
//! let exp = Series::error_bars("Mills et al. 2004", vec![(0.0, 7.8), (88.0, 11.8)], vec![0.2, 0.5]);
//! line_chart("stretch.png", "Stretching", "force (pN)", "diameter (µm)", &[sim, exp]).unwrap();
//! ```
//!
//! Text is drawn with system fonts found by fontconfig (`sans-serif`); the build needs
//! `libfontconfig1-dev` and `libfreetype-dev`, and a font (e.g. `fonts-dejavu-core`) at run time.

use std::path::Path;

use plotters::prelude::*;

use crate::error::{IoError, Result};

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SeriesStyle {
    /// Straight segments between points.
    Line,
    /// Markers only.
    Points,
    /// Segments and markers.
    LineWithPoints,
    /// Markers with vertical error bars (`Series::errors`).
    ErrorBars,
}

/// One data series.
#[derive(Clone, Debug)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    /// Symmetric y errors, one per point (used by every style when present).
    pub errors: Option<Vec<f64>>,
    pub style: SeriesStyle,
    /// RGB colour; `None` picks the next colour of a colour-blind-safe palette.
    pub color: Option<(u8, u8, u8)>,
}

impl Series {
    pub fn line(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            name: name.into(),
            points,
            errors: None,
            style: SeriesStyle::Line,
            color: None,
        }
    }

    pub fn points(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            style: SeriesStyle::Points,
            ..Series::line(name, points)
        }
    }

    pub fn line_with_points(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            style: SeriesStyle::LineWithPoints,
            ..Series::line(name, points)
        }
    }

    /// Points with symmetric vertical error bars (`errors[i]` belongs to `points[i]`).
    pub fn error_bars(name: impl Into<String>, points: Vec<(f64, f64)>, errors: Vec<f64>) -> Self {
        Series {
            errors: Some(errors),
            style: SeriesStyle::ErrorBars,
            ..Series::line(name, points)
        }
    }

    /// Sets the colour (builder style).
    pub fn with_color(mut self, r: u8, g: u8, b: u8) -> Self {
        self.color = Some((r, g, b));
        self
    }
}

/// Chart size and optional fixed ranges.
#[derive(Clone, Debug)]
pub struct ChartOptions {
    pub width: u32,
    pub height: u32,
    pub x_range: Option<(f64, f64)>,
    pub y_range: Option<(f64, f64)>,
    /// Where the legend goes (`None`: no legend).
    pub legend: Option<LegendPosition>,
}

/// Legend corner.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LegendPosition {
    UpperLeft,
    UpperRight,
    LowerLeft,
    LowerRight,
}

impl Default for ChartOptions {
    fn default() -> Self {
        ChartOptions {
            width: 900,
            height: 600,
            x_range: None,
            y_range: None,
            legend: Some(LegendPosition::UpperRight),
        }
    }
}

/// The Okabe–Ito colour-blind-safe palette, in the order series take it.
pub const PALETTE: [(u8, u8, u8); 8] = [
    (0, 114, 178),
    (213, 94, 0),
    (0, 158, 115),
    (204, 121, 167),
    (86, 180, 233),
    (230, 159, 0),
    (0, 0, 0),
    (240, 228, 66),
];

/// Draws `series` into a PNG at `path` with a legend and automatic ranges.
pub fn line_chart(path: impl AsRef<Path>, title: &str, x_label: &str, y_label: &str, series: &[Series]) -> Result<()> {
    line_chart_with(path, title, x_label, y_label, series, &ChartOptions::default())
}

fn padded(lo: f64, hi: f64) -> (f64, f64) {
    if !lo.is_finite() || !hi.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo <= f64::EPSILON * lo.abs().max(hi.abs()).max(1e-300) {
        let d = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
        return (lo - d, hi + d);
    }
    let pad = 0.05 * (hi - lo);
    (lo - pad, hi + pad)
}

/// [`line_chart`] with size and ranges.
pub fn line_chart_with(
    path: impl AsRef<Path>,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    options: &ChartOptions,
) -> Result<()> {
    let path = path.as_ref();
    for s in series {
        if let Some(e) = &s.errors {
            if e.len() != s.points.len() {
                return Err(IoError::Plot {
                    path: path.to_path_buf(),
                    message: format!("series `{}`: {} errors for {} points", s.name, e.len(), s.points.len()),
                });
            }
        }
    }
    let finite = |p: &(f64, f64)| p.0.is_finite() && p.1.is_finite();
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for s in series {
        for (i, p) in s.points.iter().enumerate() {
            if !finite(p) {
                continue;
            }
            let e = s
                .errors
                .as_ref()
                .map(|e| e[i].abs())
                .filter(|e| e.is_finite())
                .unwrap_or(0.0);
            x0 = x0.min(p.0);
            x1 = x1.max(p.0);
            y0 = y0.min(p.1 - e);
            y1 = y1.max(p.1 + e);
        }
    }
    let (x0, x1) = options.x_range.unwrap_or_else(|| padded(x0, x1));
    let (y0, y1) = options.y_range.unwrap_or_else(|| padded(y0, y1));
    let err = |e: &dyn std::fmt::Display| IoError::Plot {
        path: path.to_path_buf(),
        message: e.to_string(),
    };

    let root = BitMapBackend::new(path, (options.width, options.height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 26))
        .margin(15)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .label_style(("sans-serif", 16))
        .axis_desc_style(("sans-serif", 18))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(|e| err(&e))?;

    let cap = 0.006 * (x1 - x0);
    for (k, s) in series.iter().enumerate() {
        let (r, g, b) = s.color.unwrap_or(PALETTE[k % PALETTE.len()]);
        let color = RGBColor(r, g, b);
        let pts: Vec<(f64, f64)> = s.points.iter().copied().filter(finite).collect();
        let line = matches!(s.style, SeriesStyle::Line | SeriesStyle::LineWithPoints);
        let marker = !matches!(s.style, SeriesStyle::Line);
        // The legend entry is attached to the first element drawn for the series.
        let anno = if line {
            chart
                .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
                .map_err(|e| err(&e))?
        } else {
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 4, color.filled())))
                .map_err(|e| err(&e))?
        };
        anno.label(s.name.clone()).legend(move |(x, y)| {
            if line {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)).into_dyn()
            } else {
                Circle::new((x + 10, y), 4, color.filled()).into_dyn()
            }
        });
        if marker && line {
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 4, color.filled())))
                .map_err(|e| err(&e))?;
        }
        if let Some(errors) = &s.errors {
            let bars = s
                .points
                .iter()
                .zip(errors)
                .filter(|(p, e)| finite(p) && e.is_finite())
                .flat_map(|(&(x, y), &e)| {
                    let e = e.abs();
                    [
                        PathElement::new(vec![(x, y - e), (x, y + e)], color.stroke_width(1)),
                        PathElement::new(vec![(x - cap, y - e), (x + cap, y - e)], color.stroke_width(1)),
                        PathElement::new(vec![(x - cap, y + e), (x + cap, y + e)], color.stroke_width(1)),
                    ]
                });
            chart.draw_series(bars).map_err(|e| err(&e))?;
        }
    }
    if let Some(pos) = options.legend {
        let pos = match pos {
            LegendPosition::UpperLeft => SeriesLabelPosition::UpperLeft,
            LegendPosition::UpperRight => SeriesLabelPosition::UpperRight,
            LegendPosition::LowerLeft => SeriesLabelPosition::LowerLeft,
            LegendPosition::LowerRight => SeriesLabelPosition::LowerRight,
        };
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 16))
            .position(pos)
            .draw()
            .map_err(|e| err(&e))?;
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}
