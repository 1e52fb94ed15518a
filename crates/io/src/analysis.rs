//! Cell shape and motion metrics, computed from a trajectory after the fact.
//!
//! Conventions (also in `docs/output.md`): the flow direction is x and the shear plane is x–y
//! (velocity along x varying along y, vorticity along z). All values are SI, as in the file.
//!
//! Per frame ([`FrameMetrics`]):
//! - `centroid`: mean of the vertex positions (material points, so its time derivative is the
//!   mean vertex velocity);
//! - `velocity`: mean vertex velocity when the file stores velocities, else the centroid's finite
//!   difference over time (central inside, one-sided at the ends);
//! - `axial_diameter`: extent of the vertices along x; `transverse_diameter`: twice the largest
//!   distance of a vertex from the line through the centroid along x;
//! - `gyration_eigenvalues`, `principal_axes`: eigen-decomposition of the surface gyration tensor
//!   `G = (1/A) ∫ (r − c_A)(r − c_A)ᵀ dA` of the triangulated surface (area-weighted, exact for
//!   flat triangles, so it does not depend on how evenly the mesh is refined), largest first;
//!   each axis is a unit vector whose largest component is positive;
//! - `inclination_angle`: angle in (−π/2, π/2] from x to the major axis of the x–y block of `G`
//!   (the cell's long axis in the shear plane), counter-clockwise about z;
//! - `asphericity`: `((λ1−λ2)² + (λ2−λ3)² + (λ3−λ1)²) / (2 (λ1+λ2+λ3)²)`, 0 for a sphere, 1 for a
//!   rod, 1/4 for a flat disc;
//! - `length`, `width`: extents of the vertices along the in-plane major and minor axes;
//!   `deformation_index` = (L − B)/(L + B); `length_over_width` = L/B (both reported; Taylor's
//!   deformation parameter is the former);
//! - `area`, `volume`: of the closed triangulated surface (volume by the divergence theorem);
//!   `area_deviation`, `volume_deviation`: relative to the reference stored in the file
//!   (`/membrane@reference_area`, `@reference_volume`), or to frame 0 when absent.
//!
//! For shear runs ([`RotationMetrics`]): the tumbling rate is the least-squares slope of the
//! unwrapped inclination angle; the tank-treading rate is the mean least-squares slope of the
//! unwrapped angle, about the centroid in the x–y plane, of a few tracked membrane vertices
//! *relative to the inclination*, so a rigidly tumbling cell has zero tank-treading and a cell
//! whose shape is still while its membrane rotates has zero tumbling. Frequencies are rate/2π.
//! Unwrapping needs frames closer than half a turn of the membrane (and a quarter turn of the
//! shape); over a non-integer number of turns a non-circular orbit biases the slope slightly.

use std::io::Write;
use std::path::Path;

use glam::DVec3;
use serde::Serialize;

use crate::error::{IoError, Result};
use crate::trajectory::{MetaValue, TrajectoryReader};

/// Metrics of one membrane frame, SI.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FrameMetrics {
    pub step: u64,
    /// s
    pub time: f64,
    /// m
    pub centroid: [f64; 3],
    /// m/s
    pub velocity: [f64; 3],
    /// m
    pub axial_diameter: f64,
    /// m
    pub transverse_diameter: f64,
    /// m², largest first
    pub gyration_eigenvalues: [f64; 3],
    /// Unit vectors, same order as the eigenvalues.
    pub principal_axes: [[f64; 3]; 3],
    /// rad
    pub inclination_angle: f64,
    pub asphericity: f64,
    pub deformation_index: f64,
    /// m
    pub length: f64,
    /// m
    pub width: f64,
    pub length_over_width: f64,
    /// m²
    pub area: f64,
    /// m³
    pub volume: f64,
    /// (A − A_ref)/A_ref
    pub area_deviation: f64,
    /// (V − V_ref)/V_ref
    pub volume_deviation: f64,
}

/// Rotation of a cell in shear flow (signed rates about +z: shear flow v_x = γ̇ y turns cells
/// clockwise, i.e. negative).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RotationMetrics {
    /// rad/s, mean over tracked vertices.
    pub tank_treading_rate: f64,
    /// Hz, |rate|/2π.
    pub tank_treading_frequency: f64,
    /// rad/s, spread of the per-vertex rates (standard deviation).
    pub tank_treading_rate_std: f64,
    /// rad/s, slope of the unwrapped inclination angle.
    pub tumbling_rate: f64,
    /// Hz, |rate|/2π.
    pub tumbling_frequency: f64,
    /// rad, mean of the unwrapped inclination angle.
    pub mean_inclination: f64,
    /// rad, half the peak-to-peak range of the inclination after removing the fitted trend
    /// (the swinging amplitude for a tank-treading cell).
    pub inclination_amplitude: f64,
    /// Vertex indices that were tracked.
    pub tracked_vertices: Vec<u32>,
}

/// Result of [`analyze_file`] / [`analyze_frames`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Analysis {
    pub frames: Vec<FrameMetrics>,
    pub rotation: Option<RotationMetrics>,
}

/// When to compute [`RotationMetrics`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RotationMode {
    /// When the file says the run is a shear run (`/extra@flow = "shear"`, or a scenario name
    /// containing `shear`).
    Auto,
    Always,
    Never,
}

/// Analysis options.
#[derive(Clone, Debug)]
pub struct AnalysisOptions {
    pub rotation: RotationMode,
    /// How many membrane vertices to track for the tank-treading rate.
    pub tracked_vertices: usize,
}

impl Default for AnalysisOptions {
    fn default() -> Self {
        AnalysisOptions {
            rotation: RotationMode::Auto,
            tracked_vertices: 16,
        }
    }
}

/// Eigenvalues (descending) and unit eigenvectors (`vectors[i]` belongs to `values[i]`) of a
/// symmetric 3×3 matrix, by cyclic Jacobi rotations. Each eigenvector is signed so that its
/// largest-magnitude component is positive.
pub fn symmetric_eigen3(m: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut a = m;
    // v: columns are the eigenvectors.
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _sweep in 0..64 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        let scale = a[0][0].abs() + a[1][1].abs() + a[2][2].abs();
        if off <= f64::EPSILON * scale * 1e-3 || off == 0.0 {
            break;
        }
        for (p, q) in [(0usize, 1usize), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // A' = Jᵀ A J with J the rotation in the (p, q) plane.
            for k in 0..3 {
                let akp = a[k][p];
                let akq = a[k][q];
                a[k][p] = c * akp - s * akq;
                a[k][q] = s * akp + c * akq;
            }
            for k in 0..3 {
                let apk = a[p][k];
                let aqk = a[q][k];
                a[p][k] = c * apk - s * aqk;
                a[q][k] = s * apk + c * aqk;
            }
            for k in 0..3 {
                let vkp = v[k][p];
                let vkq = v[k][q];
                v[k][p] = c * vkp - s * vkq;
                v[k][q] = s * vkp + c * vkq;
            }
        }
    }
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&i, &j| a[j][j].total_cmp(&a[i][i]));
    let mut values = [0.0; 3];
    let mut vectors = [[0.0; 3]; 3];
    for (out, &i) in idx.iter().enumerate() {
        values[out] = a[i][i];
        let mut e = [v[0][i], v[1][i], v[2][i]];
        let big = e
            .iter()
            .copied()
            .max_by(|x, y| x.abs().total_cmp(&y.abs()))
            .unwrap_or(1.0);
        if big < 0.0 {
            e = [-e[0], -e[1], -e[2]];
        }
        vectors[out] = e;
    }
    (values, vectors)
}

/// Relative shape anisotropy of gyration eigenvalues: 0 sphere, 1/4 disc, 1 rod.
pub fn asphericity(l: [f64; 3]) -> f64 {
    let tr = l[0] + l[1] + l[2];
    if tr <= 0.0 {
        return 0.0;
    }
    ((l[0] - l[1]).powi(2) + (l[1] - l[2]).powi(2) + (l[2] - l[0]).powi(2)) / (2.0 * tr * tr)
}

fn check_triangles(path: &Path, triangles: &[[u32; 3]], n: usize) -> Result<()> {
    if triangles.is_empty() {
        return Err(IoError::invalid(path, "membrane has no triangles"));
    }
    if let Some(t) = triangles.iter().find(|t| t.iter().any(|&i| i as usize >= n)) {
        return Err(IoError::invalid(
            path,
            format!("/membrane/triangles: triangle {t:?} refers past the {n} vertices"),
        ));
    }
    Ok(())
}

/// Area and enclosed volume of a closed triangulated surface (volume positive for outward
/// normals; its absolute value is returned). Indices must be in range.
pub fn area_volume(positions: &[DVec3], triangles: &[[u32; 3]]) -> (f64, f64) {
    let mut area = 0.0;
    let mut vol = 0.0;
    for t in triangles {
        let (a, b, c) = (
            positions[t[0] as usize],
            positions[t[1] as usize],
            positions[t[2] as usize],
        );
        area += 0.5 * (b - a).cross(c - a).length();
        vol += a.dot(b.cross(c)) / 6.0;
    }
    (area, vol.abs())
}

/// Area-weighted centroid and gyration tensor of a triangulated surface.
pub fn surface_gyration(positions: &[DVec3], triangles: &[[u32; 3]]) -> (DVec3, [[f64; 3]; 3]) {
    // Shift by the vertex mean first for round-off.
    let shift = positions.iter().copied().sum::<DVec3>() / positions.len().max(1) as f64;
    let mut area = 0.0;
    let mut first = DVec3::ZERO;
    let mut second = [[0.0; 3]; 3];
    for t in triangles {
        let p = [
            positions[t[0] as usize] - shift,
            positions[t[1] as usize] - shift,
            positions[t[2] as usize] - shift,
        ];
        let a = 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length();
        let s = p[0] + p[1] + p[2];
        area += a;
        first += a * s / 3.0;
        // ∫ x xᵀ dA over a flat triangle = A/12 (Σ pᵢpᵢᵀ + s sᵀ).
        for i in 0..3 {
            for j in 0..3 {
                let mut sum = s[i] * s[j];
                for v in &p {
                    sum += v[i] * v[j];
                }
                second[i][j] += a / 12.0 * sum;
            }
        }
    }
    if area <= 0.0 {
        return (shift, [[0.0; 3]; 3]);
    }
    let c = first / area;
    let mut g = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            g[i][j] = second[i][j] / area - c[i] * c[j];
        }
    }
    (c + shift, g)
}

/// In-plane (x–y) major-axis angle of a gyration tensor, in (−π/2, π/2].
fn inplane_angle(g: &[[f64; 3]; 3]) -> f64 {
    let th = 0.5 * (2.0 * g[0][1]).atan2(g[0][0] - g[1][1]);
    if th <= -std::f64::consts::FRAC_PI_2 {
        th + std::f64::consts::PI
    } else {
        th
    }
}

/// Shape metrics of one frame (velocity, deviations and time left for the caller).
fn shape_metrics(positions: &[DVec3], triangles: &[[u32; 3]]) -> FrameMetrics {
    let n = positions.len().max(1) as f64;
    let centroid = positions.iter().copied().sum::<DVec3>() / n;
    let (mut xmin, mut xmax, mut rmax) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
    for p in positions {
        xmin = xmin.min(p.x);
        xmax = xmax.max(p.x);
        let d = *p - centroid;
        rmax = rmax.max((d.y * d.y + d.z * d.z).sqrt());
    }
    let (_, g) = surface_gyration(positions, triangles);
    let (values, vectors) = symmetric_eigen3(g);
    let theta = inplane_angle(&g);
    let (e1, e2) = (
        DVec3::new(theta.cos(), theta.sin(), 0.0),
        DVec3::new(-theta.sin(), theta.cos(), 0.0),
    );
    let extent = |e: DVec3| {
        let (lo, hi) = positions
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                let s = p.dot(e);
                (lo.min(s), hi.max(s))
            });
        hi - lo
    };
    let (l, b) = (extent(e1), extent(e2));
    let (area, volume) = area_volume(positions, triangles);
    FrameMetrics {
        step: 0,
        time: 0.0,
        centroid: centroid.to_array(),
        velocity: [0.0; 3],
        axial_diameter: xmax - xmin,
        transverse_diameter: 2.0 * rmax,
        gyration_eigenvalues: values,
        principal_axes: vectors,
        inclination_angle: theta,
        asphericity: asphericity(values),
        deformation_index: if l + b > 0.0 { (l - b) / (l + b) } else { 0.0 },
        length: l,
        width: b,
        length_over_width: if b > 0.0 { l / b } else { f64::INFINITY },
        area,
        volume,
        area_deviation: 0.0,
        volume_deviation: 0.0,
    }
}

/// Least-squares slope of y(t).
fn slope(t: &[f64], y: &[f64]) -> f64 {
    let n = t.len() as f64;
    let tm = t.iter().sum::<f64>() / n;
    let ym = y.iter().sum::<f64>() / n;
    let (mut num, mut den) = (0.0, 0.0);
    for (ti, yi) in t.iter().zip(y) {
        num += (ti - tm) * (yi - ym);
        den += (ti - tm) * (ti - tm);
    }
    if den > 0.0 {
        num / den
    } else {
        0.0
    }
}

/// Unwraps a sequence of angles defined modulo `period`.
fn unwrap(angles: &[f64], period: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(angles.len());
    let mut offset = 0.0;
    for (i, &a) in angles.iter().enumerate() {
        if i > 0 {
            let prev = angles[i - 1];
            let d = a - prev;
            offset -= period * (d / period).round();
        }
        out.push(a + offset);
    }
    out
}

/// Input for [`analyze_frames`]: one membrane frame, SI.
pub struct FrameInput<'a> {
    pub step: u64,
    pub time: f64,
    pub positions: &'a [DVec3],
    pub velocities: Option<&'a [DVec3]>,
}

/// Computes the metrics of a sequence of frames of one mesh. `reference` is (area, volume) for
/// the deviations (frame 0 when `None`). `path` only names the source in errors.
pub fn analyze_frames(
    path: &Path,
    triangles: &[[u32; 3]],
    frames: &[FrameInput],
    reference: Option<(f64, f64)>,
    rotation: bool,
    tracked_vertices: usize,
) -> Result<Analysis> {
    let Some(first) = frames.first() else {
        return Ok(Analysis {
            frames: Vec::new(),
            rotation: None,
        });
    };
    let n = first.positions.len();
    check_triangles(path, triangles, n)?;
    for f in frames {
        if f.positions.len() != n || f.velocities.is_some_and(|v| v.len() != n) {
            return Err(IoError::invalid(
                path,
                format!("frame at step {} has another vertex count than frame 0 ({n})", f.step),
            ));
        }
    }
    let mut out: Vec<FrameMetrics> = frames
        .iter()
        .map(|f| {
            let mut m = shape_metrics(f.positions, triangles);
            m.step = f.step;
            m.time = f.time;
            if let Some(v) = f.velocities {
                m.velocity = (v.iter().copied().sum::<DVec3>() / n as f64).to_array();
            }
            m
        })
        .collect();
    let (a0, v0) = reference.unwrap_or((out[0].area, out[0].volume));
    let has_vel = frames.iter().all(|f| f.velocities.is_some());
    let k = out.len();
    for i in 0..k {
        out[i].area_deviation = (out[i].area - a0) / a0;
        out[i].volume_deviation = (out[i].volume - v0) / v0;
        if !has_vel && k > 1 {
            let (lo, hi) = (i.saturating_sub(1), (i + 1).min(k - 1));
            let dt = out[hi].time - out[lo].time;
            if dt > 0.0 {
                let c = |j: usize| DVec3::from_array(out[j].centroid);
                out[i].velocity = ((c(hi) - c(lo)) / dt).to_array();
            }
        }
    }
    let rotation = if rotation && k >= 3 {
        Some(rotation_metrics(frames, &out, tracked_vertices))
    } else {
        None
    };
    Ok(Analysis { frames: out, rotation })
}

fn rotation_metrics(frames: &[FrameInput], metrics: &[FrameMetrics], tracked: usize) -> RotationMetrics {
    use std::f64::consts::PI;
    let t: Vec<f64> = metrics.iter().map(|m| m.time).collect();
    let incl = unwrap(&metrics.iter().map(|m| m.inclination_angle).collect::<Vec<_>>(), PI);
    let tumbling = slope(&t, &incl);
    let tm = t.iter().sum::<f64>() / t.len() as f64;
    let im = incl.iter().sum::<f64>() / incl.len() as f64;
    let detrended: Vec<f64> = t
        .iter()
        .zip(&incl)
        .map(|(ti, a)| a - im - tumbling * (ti - tm))
        .collect();
    let amp = 0.5
        * (detrended.iter().copied().fold(f64::NEG_INFINITY, f64::max)
            - detrended.iter().copied().fold(f64::INFINITY, f64::min));

    // Tracked vertices: far from the vorticity axis and near the shear plane at frame 0, spread
    // evenly in angle.
    let c0 = DVec3::from_array(metrics[0].centroid);
    let p0 = frames[0].positions;
    let rad = |p: &DVec3| {
        let d = *p - c0;
        (d.x * d.x + d.y * d.y).sqrt()
    };
    let rmax = p0.iter().map(rad).fold(0.0, f64::max);
    let zmax = p0.iter().map(|p| (p.z - c0.z).abs()).fold(0.0, f64::max);
    let mut cand: Vec<(f64, u32)> = p0
        .iter()
        .enumerate()
        .filter(|(_, p)| rad(p) >= 0.5 * rmax && (p.z - c0.z).abs() <= 0.5 * zmax + 1e-300)
        .map(|(i, p)| ((p.y - c0.y).atan2(p.x - c0.x), i as u32))
        .collect();
    if cand.is_empty() {
        cand = p0
            .iter()
            .enumerate()
            .map(|(i, p)| ((p.y - c0.y).atan2(p.x - c0.x), i as u32))
            .collect();
    }
    cand.sort_by(|a, b| a.0.total_cmp(&b.0));
    let want = tracked.clamp(1, cand.len());
    let picked: Vec<u32> = (0..want).map(|j| cand[j * cand.len() / want].1).collect();
    let rates: Vec<f64> = picked
        .iter()
        .map(|&vi| {
            let rel: Vec<f64> = frames
                .iter()
                .zip(metrics)
                .zip(&incl)
                .map(|((f, m), th)| {
                    let d = f.positions[vi as usize] - DVec3::from_array(m.centroid);
                    d.y.atan2(d.x) - th
                })
                .collect();
            slope(&t, &unwrap(&rel, 2.0 * PI))
        })
        .collect();
    let mean = rates.iter().sum::<f64>() / rates.len() as f64;
    let std = (rates.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / rates.len() as f64).sqrt();
    RotationMetrics {
        tank_treading_rate: mean,
        tank_treading_frequency: mean.abs() / (2.0 * PI),
        tank_treading_rate_std: std,
        tumbling_rate: tumbling,
        tumbling_frequency: tumbling.abs() / (2.0 * PI),
        mean_inclination: im,
        inclination_amplitude: amp,
        tracked_vertices: picked,
    }
}

/// Whether a trajectory's metadata marks it as a shear run.
pub fn is_shear_run(reader: &TrajectoryReader) -> bool {
    let meta = reader.metadata();
    matches!(meta.extra("flow"), Some(MetaValue::Str(s)) if s.eq_ignore_ascii_case("shear"))
        || meta.scenario_name.to_ascii_lowercase().contains("shear")
}

/// Reads a trajectory and computes the metrics of every membrane frame.
pub fn analyze_file(path: impl AsRef<Path>, options: &AnalysisOptions) -> Result<Analysis> {
    let path = path.as_ref();
    let reader = TrajectoryReader::open(path)?;
    if !reader.has_membrane() {
        return Err(IoError::MissingDataset {
            path: path.to_path_buf(),
            dataset: "/membrane/triangles".to_string(),
        });
    }
    let triangles = reader.triangles()?;
    let n = reader.membrane_frames()?;
    let raw: Vec<_> = (0..n).map(|i| reader.membrane_frame(i)).collect::<Result<_>>()?;
    let inputs: Vec<FrameInput> = raw
        .iter()
        .map(|f| FrameInput {
            step: f.step,
            time: f.time,
            positions: &f.positions,
            velocities: f.velocities.as_deref(),
        })
        .collect();
    let rotation = match options.rotation {
        RotationMode::Always => true,
        RotationMode::Never => false,
        RotationMode::Auto => is_shear_run(&reader),
    };
    analyze_frames(
        path,
        &triangles,
        &inputs,
        reader.membrane_reference()?,
        rotation,
        options.tracked_vertices,
    )
}

/// CSV header matching [`write_csv`] rows.
pub const CSV_HEADER: &str = "step,time_s,centroid_x_m,centroid_y_m,centroid_z_m,\
velocity_x_m_per_s,velocity_y_m_per_s,velocity_z_m_per_s,axial_diameter_m,transverse_diameter_m,\
gyration_l1_m2,gyration_l2_m2,gyration_l3_m2,axis1_x,axis1_y,axis1_z,axis2_x,axis2_y,axis2_z,\
axis3_x,axis3_y,axis3_z,inclination_angle_rad,asphericity,deformation_index,length_m,width_m,\
length_over_width,area_m2,volume_m3,area_deviation,volume_deviation";

/// Writes one CSV row per frame (full precision, header [`CSV_HEADER`]).
pub fn write_csv(path: impl AsRef<Path>, frames: &[FrameMetrics]) -> Result<()> {
    let path = path.as_ref();
    let mut s = String::with_capacity(64 + frames.len() * 512);
    s.push_str(CSV_HEADER);
    s.push('\n');
    for m in frames {
        let mut cols: Vec<String> = vec![m.step.to_string(), m.time.to_string()];
        let mut push = |v: f64| cols.push(format!("{v:e}"));
        m.centroid.iter().for_each(|&v| push(v));
        m.velocity.iter().for_each(|&v| push(v));
        push(m.axial_diameter);
        push(m.transverse_diameter);
        m.gyration_eigenvalues.iter().for_each(|&v| push(v));
        m.principal_axes.iter().flatten().for_each(|&v| push(v));
        for v in [
            m.inclination_angle,
            m.asphericity,
            m.deformation_index,
            m.length,
            m.width,
            m.length_over_width,
            m.area,
            m.volume,
            m.area_deviation,
            m.volume_deviation,
        ] {
            push(v);
        }
        s.push_str(&cols.join(","));
        s.push('\n');
    }
    let mut f = std::fs::File::create(path).map_err(|e| IoError::fs(path, e))?;
    f.write_all(s.as_bytes()).map_err(|e| IoError::fs(path, e))
}

/// Writes the analysis as pretty JSON.
pub fn write_json(path: impl AsRef<Path>, analysis: &Analysis) -> Result<()> {
    let path = path.as_ref();
    let text = serde_json::to_string_pretty(analysis).map_err(|source| IoError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    std::fs::write(path, text).map_err(|e| IoError::fs(path, e))
}

/// Writes PNG time series of the main metrics into `dir` (`diameters.png`, `shape.png`,
/// `inclination.png`, `area_volume.png`, `velocity.png`); returns the files written.
pub fn plot_time_series(dir: impl AsRef<Path>, analysis: &Analysis) -> Result<Vec<std::path::PathBuf>> {
    use crate::plot::{line_chart, Series};
    let dir = dir.as_ref();
    std::fs::create_dir_all(dir).map_err(|e| IoError::fs(dir, e))?;
    let f = &analysis.frames;
    let series = |name: &str, get: &dyn Fn(&FrameMetrics) -> f64| {
        Series::line(name, f.iter().map(|m| (m.time, get(m))).collect())
    };
    let mut out = Vec::new();
    let mut chart = |file: &str, title: &str, y: &str, s: Vec<Series>| -> Result<()> {
        let p = dir.join(file);
        line_chart(&p, title, "time (s)", y, &s)?;
        out.push(p);
        Ok(())
    };
    chart(
        "diameters.png",
        "Cell diameters",
        "diameter (µm)",
        vec![
            series("axial", &|m| m.axial_diameter * 1e6),
            series("transverse", &|m| m.transverse_diameter * 1e6),
            series("length (shear plane)", &|m| m.length * 1e6),
            series("width (shear plane)", &|m| m.width * 1e6),
        ],
    )?;
    chart(
        "shape.png",
        "Shape",
        "dimensionless",
        vec![
            series("deformation index", &|m| m.deformation_index),
            series("asphericity", &|m| m.asphericity),
        ],
    )?;
    chart(
        "inclination.png",
        "Inclination angle",
        "angle (degrees)",
        vec![series("inclination", &|m| m.inclination_angle.to_degrees())],
    )?;
    chart(
        "area_volume.png",
        "Area and volume deviation",
        "relative deviation (%)",
        vec![
            series("area", &|m| m.area_deviation * 100.0),
            series("volume", &|m| m.volume_deviation * 100.0),
        ],
    )?;
    chart(
        "velocity.png",
        "Centroid velocity",
        "velocity (mm/s)",
        vec![
            series("v_x", &|m| m.velocity[0] * 1e3),
            series("v_y", &|m| m.velocity[1] * 1e3),
            series("v_z", &|m| m.velocity[2] * 1e3),
        ],
    )?;
    Ok(out)
}
