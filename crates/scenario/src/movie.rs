//! Movies of a run's membrane frames (`hemodpd render TRAJ --movie out.gif`): a capillary run
//! seen from the side with the tube's walls drawn and the camera following the cell, a shear
//! run seen along the vorticity with the flow marked, any other run (stretching shapes)
//! obliquely. The cell is shaded, or coloured by a per-vertex field ([`ColorBy`]) on one scale
//! for the whole movie. Frames are rendered in parallel (rayon) and written as an animated GIF,
//! or, when `ffmpeg` is on the PATH, as an H.264 `.mp4` (raw frames piped to it).

use glam::DVec3;
use hemodpd_io::TrajectoryReader;
use plotters::prelude::*;
use rayon::prelude::*;
use std::io::Write;
use std::path::{Path, PathBuf};

/// What colours the cell.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ColorBy {
    /// One colour, Lambert-shaded (default).
    #[default]
    Shading,
    /// |v − v̄|: each vertex's speed relative to the cell's mean velocity (needs frames with
    /// velocities, as capillary and shear runs write them).
    Speed,
    /// Local area strain: a vertex's area (a third of its triangles') over its area in the
    /// first frame rendered, minus 1.
    AreaStrain,
}

impl std::str::FromStr for ColorBy {
    type Err = MovieError;
    fn from_str(s: &str) -> Result<Self, MovieError> {
        match s {
            "shading" => Ok(Self::Shading),
            "speed" => Ok(Self::Speed),
            "area-strain" => Ok(Self::AreaStrain),
            other => Err(MovieError::BadOption(format!(
                "--color-by {other}: use \"shading\", \"speed\" or \"area-strain\""
            ))),
        }
    }
}

/// Options of [`write_movie`].
#[derive(Clone, Debug)]
pub struct MovieOptions {
    /// Frame indices (empty: all).
    pub frames: Vec<usize>,
    /// Frames per second of the movie.
    pub fps: f64,
    pub color_by: ColorBy,
}

impl Default for MovieOptions {
    fn default() -> Self {
        Self {
            frames: Vec::new(),
            fps: 10.0,
            color_by: ColorBy::Shading,
        }
    }
}

/// What [`write_movie`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct MovieReport {
    pub path: PathBuf,
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    /// "capillary (side view, tube walls)", "shear (along the vorticity)" or "oblique".
    pub view: String,
}

/// Why a movie could not be made.
#[derive(Debug, thiserror::Error)]
pub enum MovieError {
    #[error("{0}")]
    BadOption(String),
    #[error("reading {path}: {source}")]
    Read { path: PathBuf, source: hemodpd_io::IoError },
    #[error("{path}: {msg}")]
    Trajectory { path: PathBuf, msg: String },
    #[error("drawing frame {frame}: {msg}")]
    Draw { frame: usize, msg: String },
    #[error("writing {path}: {msg}")]
    Write { path: PathBuf, msg: String },
    #[error(
        "writing an .mp4 needs ffmpeg on the PATH, and it was not found ({0}); write a .gif instead (--movie out.gif), or install ffmpeg (e.g. apt-get install ffmpeg)"
    )]
    NoFfmpeg(String),
}

/// How a movie frame is viewed.
#[derive(Clone, Copy, Debug, PartialEq)]
enum MovieView {
    /// A tube along z seen from the side (screen x = z, screen y = x), walls at ±`radius` (µm)
    /// about the axis at (x, y) = `axis`; the camera follows the cell along z.
    Tube { radius: f64, axis: [f64; 2] },
    /// Seen along the vorticity z (screen x = x, y = y), centred on the cell.
    Shear,
    /// 60° from the xz plane, centred on the cell.
    Oblique,
}

impl MovieView {
    fn size(self) -> (u32, u32) {
        match self {
            MovieView::Tube { .. } => (640, 320),
            MovieView::Shear => (480, 480),
            MovieView::Oblique => (480, 360),
        }
    }

    /// (screen x, screen y, depth towards the viewer) of `p` (µm) relative to `c`.
    fn project(self, p: DVec3, c: DVec3) -> DVec3 {
        match self {
            MovieView::Tube { axis, .. } => DVec3::new(p.z - c.z, p.x - axis[0], p.y - axis[1]),
            MovieView::Shear => DVec3::new(p.x - c.x, p.y - c.y, p.z - c.z),
            MovieView::Oblique => {
                let d = p - c;
                let (s, co) = 60f64.to_radians().sin_cos();
                DVec3::new(d.x, d.y * co - d.z * s, d.y * s + d.z * co)
            }
        }
    }

    fn describe(self) -> &'static str {
        match self {
            MovieView::Tube { .. } => "capillary (side view, tube walls)",
            MovieView::Shear => "shear (along the vorticity)",
            MovieView::Oblique => "oblique",
        }
    }
}

/// One frame's data, µm and µm/s.
struct FrameData {
    time_s: f64,
    x: Vec<DVec3>,
    v: Option<Vec<DVec3>>,
}

/// Per-vertex area: a third of each adjacent triangle's.
fn vertex_areas(x: &[DVec3], triangles: &[[u32; 3]]) -> Vec<f64> {
    let mut a = vec![0.0; x.len()];
    for t in triangles {
        let [p, q, r] = t.map(|k| x[k as usize]);
        let third = (q - p).cross(r - p).length() / 6.0;
        for k in t {
            a[*k as usize] += third;
        }
    }
    a
}

/// Renders the membrane frames of `trajectory` into a movie at `output` (`.gif`, or `.mp4`
/// through ffmpeg).
pub fn write_movie(trajectory: &Path, output: &Path, opts: &MovieOptions) -> Result<MovieReport, MovieError> {
    let ext = output
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    if ext != "gif" && ext != "mp4" {
        return Err(MovieError::BadOption(format!(
            "--movie {}: the file must end in .gif or .mp4",
            output.display()
        )));
    }
    if ext == "mp4" {
        // Found out before any frame is drawn.
        std::process::Command::new("ffmpeg")
            .arg("-version")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .status()
            .map_err(|e| MovieError::NoFfmpeg(e.to_string()))?;
    }
    if !(opts.fps > 0.0 && opts.fps <= 100.0) {
        return Err(MovieError::BadOption(format!("--fps {}: use 0 < fps ≤ 100", opts.fps)));
    }
    let read = |source| MovieError::Read {
        path: trajectory.to_path_buf(),
        source,
    };
    let reader = TrajectoryReader::open(trajectory).map_err(read)?;
    let n = reader.membrane_frames().map_err(read)?;
    if n == 0 {
        return Err(MovieError::Trajectory {
            path: trajectory.to_path_buf(),
            msg: "no membrane frames (a fluid-only trajectory?)".into(),
        });
    }
    let indices: Vec<usize> = if opts.frames.is_empty() {
        (0..n).collect()
    } else {
        opts.frames.clone()
    };
    if let Some(&bad) = indices.iter().find(|&&i| i >= n) {
        return Err(MovieError::BadOption(format!(
            "--frames: frame {bad} requested, {} has {n} frames",
            trajectory.display()
        )));
    }
    let triangles = reader.triangles().map_err(read)?;
    let mut frames = Vec::with_capacity(indices.len());
    for &i in &indices {
        let f = reader.membrane_frame(i).map_err(read)?;
        frames.push(FrameData {
            time_s: f.time,
            x: f.positions.iter().map(|p| *p * 1e6).collect(),
            v: f.velocities.map(|v| v.iter().map(|u| *u * 1e6).collect()),
        });
    }
    let meta = reader.metadata();
    let view = match meta.scenario_name.as_str() {
        "capillary" => {
            let scenario: toml::Value = toml::from_str(&meta.scenario_toml).map_err(|e| MovieError::Trajectory {
                path: trajectory.to_path_buf(),
                msg: format!("its scenario text does not parse: {e}"),
            })?;
            let d = scenario
                .get("tube")
                .and_then(|t| t.get("diameter_um"))
                .and_then(|d| d.as_float())
                .ok_or_else(|| MovieError::Trajectory {
                    path: trajectory.to_path_buf(),
                    msg: "a capillary trajectory without tube.diameter_um in its scenario".into(),
                })?;
            // the cell starts on the axis
            let c0 = frames[0].x.iter().copied().sum::<DVec3>() / frames[0].x.len() as f64;
            MovieView::Tube {
                radius: 0.5 * d,
                axis: [c0.x, c0.y],
            }
        }
        "shear" => MovieView::Shear,
        _ => MovieView::Oblique,
    };
    // the per-vertex field and its range over the whole movie
    let field: Option<Vec<Vec<f64>>> = match opts.color_by {
        ColorBy::Shading => None,
        ColorBy::Speed => {
            let mut out = Vec::with_capacity(frames.len());
            for (k, f) in frames.iter().enumerate() {
                let v = f.v.as_ref().ok_or_else(|| MovieError::Trajectory {
                    path: trajectory.to_path_buf(),
                    msg: format!("frame {} has no vertex velocities for --color-by speed", indices[k]),
                })?;
                let mean = v.iter().copied().sum::<DVec3>() / v.len().max(1) as f64;
                out.push(v.iter().map(|u| (*u - mean).length()).collect());
            }
            Some(out)
        }
        ColorBy::AreaStrain => {
            let a0 = vertex_areas(&frames[0].x, &triangles);
            Some(
                frames
                    .iter()
                    .map(|f| {
                        vertex_areas(&f.x, &triangles)
                            .iter()
                            .zip(&a0)
                            .map(|(a, b)| a / b - 1.0)
                            .collect()
                    })
                    .collect(),
            )
        }
    };
    let range = field.as_ref().map(|fs| {
        let hi = fs.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-12);
        match opts.color_by {
            ColorBy::AreaStrain => (-hi, hi),
            _ => (0.0, hi),
        }
    });
    // one scale for the whole movie: the largest extent of any frame about its centroid
    let extent = frames
        .iter()
        .flat_map(|f| {
            let c = f.x.iter().copied().sum::<DVec3>() / f.x.len() as f64;
            f.x.iter().map(move |p| view.project(*p, c))
        })
        .map(|p| p.x.abs().max(p.y.abs()))
        .fold(1e-12, f64::max);
    let (w, h) = view.size();
    let buffers: Vec<Vec<u8>> = frames
        .par_iter()
        .enumerate()
        .map(|(k, f)| {
            let colours = field.as_ref().map(|fs| (&fs[k][..], range.unwrap_or((0.0, 1.0))));
            draw_frame(view, (w, h), extent, f, &triangles, colours, opts.color_by)
                .map_err(|msg| MovieError::Draw { frame: indices[k], msg })
        })
        .collect::<Result<_, _>>()?;
    match ext.as_str() {
        "gif" => write_gif(output, (w, h), opts.fps, &buffers)?,
        _ => write_mp4(output, (w, h), opts.fps, &buffers)?,
    }
    Ok(MovieReport {
        path: output.to_path_buf(),
        frames: buffers.len(),
        width: w,
        height: h,
        view: view.describe().into(),
    })
}

/// Draws one frame into an RGB buffer of `w × h` pixels.
fn draw_frame(
    view: MovieView,
    (w, h): (u32, u32),
    extent: f64,
    f: &FrameData,
    triangles: &[[u32; 3]],
    colours: Option<(&[f64], (f64, f64))>,
    color_by: ColorBy,
) -> Result<Vec<u8>, String> {
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let centre = f.x.iter().copied().sum::<DVec3>() / f.x.len() as f64;
        let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
        // the tube view is sized by the tube, the others by the cell
        let scale = match view {
            MovieView::Tube { radius, .. } => 0.42 * h as f64 / radius.max(extent),
            _ => 0.40 * w.min(h) as f64 / extent,
        };
        let to_px = |p: DVec3| ((cx + p.x * scale) as i32, (cy - p.y * scale) as i32);
        let grey = RGBColor(150, 150, 150);
        match view {
            MovieView::Tube { radius, .. } => {
                // the walls, shaded beyond them
                let (top, bottom) = ((cy - radius * scale) as i32, (cy + radius * scale) as i32);
                let wall = RGBColor(225, 225, 225);
                root.draw(&Rectangle::new([(0, 0), (w as i32, top)], wall.filled()))
                    .map_err(|e| e.to_string())?;
                root.draw(&Rectangle::new([(0, bottom), (w as i32, h as i32)], wall.filled()))
                    .map_err(|e| e.to_string())?;
                for y in [top, bottom] {
                    root.draw(&PathElement::new(vec![(0, y), (w as i32, y)], grey.stroke_width(2)))
                        .map_err(|e| e.to_string())?;
                }
                // a tick every 5 µm along the tube, moving with the tube (the camera follows the cell)
                let first = ((centre.z - cx / scale) / 5.0).floor() as i64;
                let last = ((centre.z + cx / scale) / 5.0).ceil() as i64;
                for k in first..=last {
                    let x = (cx + (k as f64 * 5.0 - centre.z) * scale) as i32;
                    root.draw(&PathElement::new(
                        vec![(x, bottom), (x, bottom + 8)],
                        grey.stroke_width(1),
                    ))
                    .map_err(|e| e.to_string())?;
                }
                root.draw(&Text::new(
                    "flow →",
                    (w as i32 - 90, h as i32 - 22),
                    ("sans-serif", 16).into_font(),
                ))
                .map_err(|e| e.to_string())?;
            }
            MovieView::Shear => {
                // the flow: +x above the cell, −x below
                let arrow = |y: i32, dir: i32| {
                    let (x0, x1) = (cx as i32 - 60 * dir, cx as i32 + 60 * dir);
                    vec![
                        PathElement::new(vec![(x0, y), (x1, y)], grey.stroke_width(2)),
                        PathElement::new(
                            vec![(x1 - 10 * dir, y - 6), (x1, y), (x1 - 10 * dir, y + 6)],
                            grey.stroke_width(2),
                        ),
                    ]
                };
                for e in arrow(28, 1).into_iter().chain(arrow(h as i32 - 28, -1)) {
                    root.draw(&e).map_err(|e| e.to_string())?;
                }
                root.draw(&Text::new("flow", (cx as i32 + 70, 20), ("sans-serif", 16).into_font()))
                    .map_err(|e| e.to_string())?;
            }
            MovieView::Oblique => {}
        }
        let pts: Vec<DVec3> = f.x.iter().map(|p| view.project(*p, centre)).collect();
        let mut order: Vec<usize> = (0..triangles.len()).collect();
        let depth = |t: &[u32; 3]| pts[t[0] as usize].z + pts[t[1] as usize].z + pts[t[2] as usize].z;
        order.sort_by(|&a, &b| depth(&triangles[a]).total_cmp(&depth(&triangles[b])));
        let light = DVec3::new(-0.3, 0.5, 1.0).normalize();
        for &k in &order {
            let t = triangles[k];
            let [a, b, c] = t.map(|i| pts[i as usize]);
            let n = (b - a).cross(c - a).normalize_or_zero();
            let lum = 0.35 + 0.65 * n.dot(light).abs();
            let base = match colours {
                None => (200.0, 60.0, 55.0),
                Some((values, (lo, hi))) => {
                    let v = t.iter().map(|&i| values[i as usize]).sum::<f64>() / 3.0;
                    let RGBColor(r, g, b) = ViridisRGB::get_color_normalized(v, lo, hi);
                    (r as f64, g as f64, b as f64)
                }
            };
            let col = RGBColor((base.0 * lum) as u8, (base.1 * lum) as u8, (base.2 * lum) as u8);
            root.draw(&Polygon::new(vec![to_px(a), to_px(b), to_px(c)], col.filled()))
                .map_err(|e| e.to_string())?;
        }
        let mut label = format!("t = {:.2} ms", f.time_s * 1e3);
        if let Some((_, (lo, hi))) = colours {
            let (name, unit, k) = match color_by {
                ColorBy::Speed => ("|v − v_cell|", "mm/s", 1e-3),
                _ => ("area strain", "", 1.0),
            };
            label += &format!("   {name}: {:.3}…{:.3} {unit} (viridis)", lo * k, hi * k);
        }
        root.draw(&Text::new(label, (10, 8), ("sans-serif", 16).into_font()))
            .map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(buf)
}

/// Writes the frames as an animated GIF (looping), each quantised to its own palette in parallel.
fn write_gif(path: &Path, (w, h): (u32, u32), fps: f64, frames: &[Vec<u8>]) -> Result<(), MovieError> {
    let err = |msg: String| MovieError::Write {
        path: path.to_path_buf(),
        msg,
    };
    let (w16, h16) = (w as u16, h as u16);
    let delay = (100.0 / fps).round().max(1.0) as u16; // centiseconds
    let encoded: Vec<gif::Frame<'static>> = frames
        .par_iter()
        .map(|rgb| {
            let mut f = gif::Frame::from_rgb_speed(w16, h16, rgb, 10);
            f.delay = delay;
            f
        })
        .collect();
    let file = std::fs::File::create(path).map_err(|e| err(e.to_string()))?;
    let mut enc = gif::Encoder::new(std::io::BufWriter::new(file), w16, h16, &[]).map_err(|e| err(e.to_string()))?;
    enc.set_repeat(gif::Repeat::Infinite).map_err(|e| err(e.to_string()))?;
    for f in &encoded {
        enc.write_frame(f).map_err(|e| err(e.to_string()))?;
    }
    enc.into_inner()
        .map_err(|e| err(e.to_string()))?
        .flush()
        .map_err(|e| err(e.to_string()))
}

/// Writes the frames as an H.264 `.mp4` by piping them, raw, to `ffmpeg`.
fn write_mp4(path: &Path, (w, h): (u32, u32), fps: f64, frames: &[Vec<u8>]) -> Result<(), MovieError> {
    use std::process::{Command, Stdio};
    let err = |msg: String| MovieError::Write {
        path: path.to_path_buf(),
        msg,
    };
    let mut child = Command::new("ffmpeg")
        .args(["-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s"])
        .arg(format!("{w}x{h}"))
        .arg("-r")
        .arg(format!("{fps}"))
        .args(["-i", "-", "-c:v", "libx264", "-pix_fmt", "yuv420p"])
        .arg(path)
        .stdin(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| MovieError::NoFfmpeg(e.to_string()))?;
    {
        let mut stdin = child.stdin.take().ok_or_else(|| err("no pipe to ffmpeg".into()))?;
        for f in frames {
            stdin
                .write_all(f)
                .map_err(|e| err(format!("piping frames to ffmpeg: {e}")))?;
        }
    }
    let out = child.wait_with_output().map_err(|e| err(e.to_string()))?;
    if !out.status.success() {
        return Err(err(format!(
            "ffmpeg failed: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    Ok(())
}
