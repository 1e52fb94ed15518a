//! Figures made by the project: stretching curves against Mills et al. (the paper's Fig. 1) and
//! rendered cell shapes (its Fig. 2).

use crate::stretching::mills_2004;
use glam::DVec3;
use hemodpd_io::plot::{line_chart_with, ChartOptions, LegendPosition, Series, PALETTE};
use plotters::prelude::*;
use std::path::Path;

/// One stretching curve: a label and (force pN, D_A µm, D_T µm) per force.
#[derive(Clone, Debug)]
pub struct Curve {
    pub label: String,
    pub force_pn: Vec<f64>,
    pub axial_um: Vec<f64>,
    pub transverse_um: Vec<f64>,
}

impl Curve {
    /// Reads the curve from a stretching run's `summary.json`.
    pub fn from_summary(label: &str, summary: &serde_json::Value) -> Option<Self> {
        let r = &summary["results"];
        let arr = |k: &str| -> Option<Vec<f64>> { r[k].as_array()?.iter().map(|v| v.as_f64()).collect() };
        Some(Curve {
            label: label.to_string(),
            force_pn: arr("force_pn")?,
            axial_um: arr("axial_diameter_um")?,
            transverse_um: arr("transverse_diameter_um")?,
        })
    }
}

/// D_A and D_T against force for each curve, with Mills et al. (2004) and their error bars.
pub fn stretching_chart(path: &Path, title: &str, curves: &[Curve]) -> Result<(), hemodpd_io::IoError> {
    let mut series = Vec::new();
    for (k, c) in curves.iter().enumerate() {
        let (r, g, b) = PALETTE[k % 6]; // the first six: black and yellow are kept for the data
        series.push(
            Series::line(
                format!("{} D_A", c.label),
                c.force_pn.iter().cloned().zip(c.axial_um.iter().cloned()).collect(),
            )
            .with_color(r, g, b),
        );
        series.push(
            Series::line(
                format!("{} D_T", c.label),
                c.force_pn
                    .iter()
                    .cloned()
                    .zip(c.transverse_um.iter().cloned())
                    .collect(),
            )
            .with_color(r, g, b),
        );
    }
    let m = mills_2004();
    series.push(
        Series::error_bars(
            "Mills 2004 D_A",
            m.iter().map(|p| (p.force_pn, 0.5 * (p.da_lo + p.da_hi))).collect(),
            m.iter().map(|p| 0.5 * (p.da_hi - p.da_lo)).collect(),
        )
        .with_color(0, 0, 0),
    );
    series.push(
        Series::error_bars(
            "Mills 2004 D_T",
            m.iter().map(|p| (p.force_pn, 0.5 * (p.dt_lo + p.dt_hi))).collect(),
            m.iter().map(|p| 0.5 * (p.dt_hi - p.dt_lo)).collect(),
        )
        .with_color(90, 90, 90),
    );
    let opts = ChartOptions {
        width: 1000,
        height: 700,
        x_range: Some((-5.0, 205.0)),
        y_range: Some((
            0.0,
            curves
                .iter()
                .flat_map(|c| c.axial_um.iter())
                .fold(19.0f64, |m, &v| m.max(v + 1.0)),
        )),
        legend: Some(LegendPosition::UpperLeft),
    };
    line_chart_with(path, title, "stretching force (pN)", "diameter (µm)", &series, &opts)
}

/// A shape to render: a title, vertex positions (µm) and triangles.
pub struct Shape<'a> {
    pub title: String,
    pub positions: &'a [DVec3],
    pub triangles: &'a [[u32; 3]],
}

/// How shapes are viewed: each maps a point (relative to the shape's centroid) to (screen x,
/// screen y, depth towards the viewer).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum View {
    /// 60° from the stretch axis' normal plane (the stretching shapes).
    Oblique,
    /// A tube along z seen from the side, 20° from above: the flow runs left to right.
    TubeSide,
}

impl View {
    fn project(self, p: DVec3) -> DVec3 {
        match self {
            View::Oblique => {
                let (s, c) = 60f64.to_radians().sin_cos();
                DVec3::new(p.x, p.y * c - p.z * s, p.y * s + p.z * c)
            }
            View::TubeSide => {
                let (s, c) = 20f64.to_radians().sin_cos();
                DVec3::new(p.z, p.x * c - p.y * s, p.x * s + p.y * c)
            }
        }
    }
}

/// Renders shapes in a grid (`columns` per row), all at one scale, viewed obliquely (60° from
/// the stretch axis' normal plane) with Lambert shading and the triangulation drawn.
pub fn render_shapes(path: &Path, shapes: &[Shape], columns: usize, draw_edges: bool) -> Result<(), String> {
    render_shapes_view(path, shapes, columns, draw_edges, View::Oblique)
}

/// As [`render_shapes`], with the given [`View`].
pub fn render_shapes_view(
    path: &Path,
    shapes: &[Shape],
    columns: usize,
    draw_edges: bool,
    view_kind: View,
) -> Result<(), String> {
    let columns = columns.max(1);
    let rows = shapes.len().div_ceil(columns).max(1);
    let (pw, ph) = (420u32, 300u32);
    let root = BitMapBackend::new(path, (pw * columns as u32, ph * rows as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let panels = root.split_evenly((rows, columns));
    let view = |p: DVec3| view_kind.project(p); // (screen x, screen y, depth)
    let light = DVec3::new(-0.3, 0.5, 1.0).normalize();
    // one scale for all: the largest extent of any shape about its own centroid
    let extent = shapes
        .iter()
        .flat_map(|sh| {
            let c = sh.positions.iter().copied().sum::<DVec3>() / sh.positions.len().max(1) as f64;
            sh.positions.iter().map(move |p| *p - c)
        })
        .map(|p| p.x.abs().max(p.y.abs()).max(p.z.abs()))
        .fold(1e-12, f64::max);
    let scale = 0.44 * pw.min(ph) as f64 / extent;
    for (shape, panel) in shapes.iter().zip(panels.iter()) {
        let centre = shape.positions.iter().copied().sum::<DVec3>() / shape.positions.len().max(1) as f64;
        let pts: Vec<DVec3> = shape.positions.iter().map(|&p| view(p - centre)).collect();
        let mut order: Vec<usize> = (0..shape.triangles.len()).collect();
        let depth = |t: &[u32; 3]| pts[t[0] as usize].z + pts[t[1] as usize].z + pts[t[2] as usize].z;
        order.sort_by(|&a, &b| depth(&shape.triangles[a]).total_cmp(&depth(&shape.triangles[b])));
        let to_px = |p: DVec3| {
            (
                (pw as f64 / 2.0 + p.x * scale) as i32,
                (ph as f64 / 2.0 + 12.0 - p.y * scale) as i32,
            )
        };
        for &k in &order {
            let t = shape.triangles[k];
            let (a, b, cc) = (pts[t[0] as usize], pts[t[1] as usize], pts[t[2] as usize]);
            let n = (b - a).cross(cc - a).normalize_or_zero();
            let lum = 0.25 + 0.75 * n.dot(light).abs();
            let col = RGBColor((200.0 * lum) as u8, (60.0 * lum) as u8, (55.0 * lum) as u8);
            let poly = vec![to_px(a), to_px(b), to_px(cc)];
            panel
                .draw(&Polygon::new(poly.clone(), col.filled()))
                .map_err(|e| e.to_string())?;
            if draw_edges {
                let mut closed = poly;
                closed.push(closed[0]);
                panel
                    .draw(&PathElement::new(closed, RGBColor(70, 20, 20).stroke_width(1)))
                    .map_err(|e| e.to_string())?;
            }
        }
        panel
            .draw(&Text::new(shape.title.clone(), (10, 8), ("sans-serif", 18).into_font()))
            .map_err(|e| e.to_string())?;
    }
    root.present().map_err(|e| e.to_string())
}
