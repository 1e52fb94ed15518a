//! Motion of one cell in linear shear flow u = γ̇ y x̂ (flow x, gradient y, vorticity z):
//! tumbling, tank-treading, swinging or intermittent, from a time series of membrane frames.
//! Geometry only; any consistent length and time units.
//!
//! Definitions (angles are mathematical, counter-clockwise about +z; the vorticity of this flow
//! is −γ̇ ẑ, so the flow turns bodies and membranes *clockwise* and θ, Φ decrease):
//! * **Inclination θ**: angle from x to the long in-plane axis, the major eigenvector of the
//!   x–y block of the vertices' gyration tensor. For a disc whose symmetry axis (smallest
//!   eigenvalue) lies in the shear plane, as in tumbling and swinging, this is the in-plane
//!   diameter, perpendicular to that axis; for an elongated cell it is the largest-eigenvalue
//!   axis projected on x–y. θ is defined modulo 180° and unwrapped frame to frame, so a
//!   tumbling body accumulates angle; frames must be close enough that θ turns < 90° between
//!   them ([`MotionThresholds::max_strain_per_frame`]).
//! * **Tank-treading phase Φ**: vertices are taken to the cell's own frame (centroid at the
//!   origin, rotated by −θ, axes scaled by the in-plane semi-axes √λ₁, √λ₂, so a point moving
//!   along an elliptic contour turns at a uniform rate); each vertex's angle change between
//!   frames is averaged with weight ρ·ρ' (its normalised distance from the axis in both frames,
//!   so vertices near the vorticity axis count little) and the increments are summed. Φ = 0 in
//!   the resting configuration, which acts as frame −1 (its offset is meaningful only when the
//!   rest positions have frame 0's orientation up to a turn about z; rates never depend on it).
//! * **Episodes**: the series is cut into consecutive episodes, each closed at the first frame
//!   where the body has turned by 180° (a *flip*: |Δθ| ≥ 180°) or the membrane by half a
//!   revolution (|ΔΦ| ≥ 180°), labelled tumbling or tank-treading by the larger of the two.
//!   The trailing, incomplete episode is not labelled.
//! * **Classes**: only tumbling episodes ⇒ [`MotionClass::Tumbling`]; only tank-treading
//!   episodes ⇒ [`MotionClass::TankTreading`], or [`MotionClass::Swinging`] when θ oscillates
//!   with amplitude ≥ `min_swing_amplitude_deg` at twice the TT frequency (± `swing_ratio_tolerance`);
//!   both kinds ⇒ [`MotionClass::Intermittent`]; no complete episode (less than half a turn of
//!   either kind), a face-on cell or too coarse sampling ⇒ [`MotionClass::Undetermined`].
//! * **Rates** (positive in the vorticity sense): tumbling rate = net body rotation over the
//!   tumbling episodes / their duration / 180° (flips per time unit; a Jeffery period is two
//!   flips); TT frequency = net membrane rotation over the TT episodes / their duration / 360°
//!   (revolutions per time unit). The swinging amplitude (half peak-to-peak), mean inclination
//!   and θ frequency come from a least-squares fit θ ≈ θ₀ + A sin(ωt + φ) over the longest run of
//!   TT episodes, with ω scanned from half a cycle per run to min(Nyquist, 6 × TT frequency).

use std::cmp::Ordering::Greater;
use std::f64::consts::{PI, TAU};

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Bad input to the motion analysis.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MotionError {
    #[error("no frames to analyse (need at least 2)")]
    TooFewFrames,
    #[error("the rest shape has {0} vertices; a cell needs at least 3")]
    TooFewVertices(usize),
    #[error("{times} times for {frames} frames")]
    LengthMismatch { times: usize, frames: usize },
    #[error("frame {frame} has {found} vertices, the rest shape has {expected}")]
    VertexCount {
        frame: usize,
        expected: usize,
        found: usize,
    },
    #[error("vertex {vertex} of frame {frame} is not finite")]
    NonFinite { frame: usize, vertex: usize },
    #[error("vertex {0} of the rest shape is not finite")]
    NonFiniteRest(usize),
    #[error("time of frame {frame} is {value}: times must be finite and strictly increasing")]
    BadTime { frame: usize, value: f64 },
    #[error("shear rate must be finite and > 0, got {0}")]
    BadShearRate(f64),
    #[error("motion threshold {0} is out of range")]
    BadThreshold(&'static str),
}

/// The kind of motion over the analysed window.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum MotionClass {
    Tumbling,
    TankTreading,
    Swinging,
    Intermittent,
    #[default]
    Undetermined,
}

/// Why a window was not classified.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum UndeterminedReason {
    /// Neither a flip (180° of θ) nor half a TT revolution (180° of Φ) in the window.
    WindowTooShort,
    /// The median in-plane anisotropy is below `min_in_plane_anisotropy` (a cell seen face-on,
    /// e.g. rolling with its axis along z): θ is not defined.
    NoInPlaneAxis,
    /// Some frames are more than `max_strain_per_frame` apart, so unwrapping is ambiguous.
    Undersampled,
}

/// Thresholds of the classifier (dimensionless or degrees), with their defaults.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MotionThresholds {
    /// Least θ oscillation amplitude (half peak-to-peak, degrees) called swinging. Default 1.0°.
    pub min_swing_amplitude_deg: f64,
    /// Largest |f_θ / f_TT − 2| still called swinging. Default 0.5.
    pub swing_ratio_tolerance: f64,
    /// Least median (λ₁ − λ₂)/(λ₁ + λ₂) of the in-plane gyration tensor. Default 0.05.
    pub min_in_plane_anisotropy: f64,
    /// Largest γ̇ Δt between frames (radians of strain; bodies turn at most γ̇ Δt and θ can be
    /// unwrapped below 90° ≈ 1.57). Default 1.0.
    pub max_strain_per_frame: f64,
}

impl Default for MotionThresholds {
    fn default() -> Self {
        Self {
            min_swing_amplitude_deg: 1.0,
            swing_ratio_tolerance: 0.5,
            min_in_plane_anisotropy: 0.05,
            max_strain_per_frame: 1.0,
        }
    }
}

/// Per-frame motion measures (for a CSV row), from [`MotionTracker::push`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameMotion {
    /// Time of the frame (caller's unit).
    pub time: f64,
    /// Centroid of the vertices (caller's length unit).
    pub centroid: [f64; 3],
    /// Unwrapped inclination θ (degrees; within ±90° of the rest shape's at frame 0).
    pub inclination_deg: f64,
    /// (λ₁ − λ₂)/(λ₁ + λ₂) of the in-plane gyration tensor, in [0, 1]; 0 = no in-plane axis.
    pub in_plane_anisotropy: f64,
    /// Unwrapped tank-treading phase Φ (radians, counter-clockwise; 0 at rest).
    pub tt_phase_rad: f64,
}

/// Result of [`classify`]: rates in the caller's time unit, angles in degrees.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MotionAnalysis {
    pub class: MotionClass,
    /// Set when `class` is `Undetermined`.
    pub undetermined_reason: Option<UndeterminedReason>,
    /// Total strain γ̇ (t_last − t_first) of the window.
    pub strain: f64,
    /// Complete tumbling episodes (flips).
    pub flips: usize,
    /// Complete tank-treading episodes (half revolutions).
    pub tt_half_revolutions: usize,
    /// Fraction of the labelled time spent tumbling, in [0, 1].
    pub tumbling_fraction: f64,
    /// Flips (180° turns of the body) per time unit, positive in the vorticity sense.
    pub tumbling_rate: Option<f64>,
    /// Membrane revolutions per time unit, positive in the vorticity sense.
    pub tank_treading_frequency: Option<f64>,
    /// Mean inclination θ₀ over the longest TT run, in (−90°, 90°].
    pub mean_inclination_deg: Option<f64>,
    /// θ oscillation amplitude A (half peak-to-peak) over the longest TT run.
    pub inclination_amplitude_deg: Option<f64>,
    /// θ oscillation frequency (cycles per time unit), when A ≥ `min_swing_amplitude_deg`.
    pub swing_frequency: Option<f64>,
    /// swing_frequency / tank_treading_frequency (≈ 2 for swinging).
    pub swing_to_tt_ratio: Option<f64>,
}

/// Wraps `a` into [−period/2, period/2].
fn wrap(a: f64, period: f64) -> f64 {
    a - period * (a / period).round()
}

/// The in-plane pose of one frame and its vertices' angles in the cell's own frame.
struct Pose {
    centroid: DVec3,
    /// Unwrapped inclination (radians).
    theta: f64,
    anisotropy: f64,
    /// Normalised body-frame angle and radius of each vertex.
    psi: Vec<f64>,
    rho: Vec<f64>,
}

/// The pose of `x`, its θ unwrapped to lie within 90° of `hint` (radians).
fn pose(x: &[DVec3], hint: f64) -> Pose {
    let (centroid, g) = gyration(x);
    let raw = 0.5 * (2.0 * g[1]).atan2(g[0] - g[2]);
    pose_at(x, centroid, g, hint + wrap(raw - hint, PI))
}

/// Centroid and in-plane gyration tensor (xx, xy, yy) of `x`.
fn gyration(x: &[DVec3]) -> (DVec3, [f64; 3]) {
    let n = x.len() as f64;
    let centroid = x.iter().copied().sum::<DVec3>() / n;
    let (mut gxx, mut gxy, mut gyy) = (0.0, 0.0, 0.0);
    for p in x {
        let d = *p - centroid;
        gxx += d.x * d.x / n;
        gxy += d.x * d.y / n;
        gyy += d.y * d.y / n;
    }
    (centroid, [gxx, gxy, gyy])
}

/// The pose of `x` with a given (unwrapped) inclination `theta` (radians); `g` is the in-plane
/// gyration tensor (xx, xy, yy) about `centroid`.
fn pose_at(x: &[DVec3], centroid: DVec3, g: [f64; 3], theta: f64) -> Pose {
    let [gxx, gxy, gyy] = g;
    let mean = 0.5 * (gxx + gyy);
    let dev = (0.25 * (gxx - gyy).powi(2) + gxy * gxy).sqrt();
    let anisotropy = if mean > 0.0 { (dev / mean).min(1.0) } else { 0.0 };
    let tiny = 1e-24 * mean.max(f64::MIN_POSITIVE);
    let (a, b) = ((mean + dev).max(tiny).sqrt(), (mean - dev).max(tiny).sqrt());
    let (s, c) = theta.sin_cos();
    let (psi, rho) = x
        .iter()
        .map(|p| {
            let d = *p - centroid;
            let (u, v) = ((d.x * c + d.y * s) / a, (d.y * c - d.x * s) / b);
            (v.atan2(u), u.hypot(v))
        })
        .unzip();
    Pose {
        centroid,
        theta,
        anisotropy,
        psi,
        rho,
    }
}

/// Weighted mean body-frame angle change of the vertices from `from` to `to` (radians).
fn phase_step(from: &Pose, to: &Pose) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..from.psi.len() {
        let w = from.rho[i] * to.rho[i];
        num += w * wrap(to.psi[i] - from.psi[i], TAU);
        den += w;
    }
    if den > 0.0 {
        num / den
    } else {
        0.0
    }
}

/// Inclination θ of one frame in degrees, in [−90°, 90°] (not unwrapped); NaN for an empty frame.
pub fn inclination_deg(frame: &[DVec3]) -> f64 {
    if frame.is_empty() {
        return f64::NAN;
    }
    pose(frame, 0.0).theta.to_degrees()
}

/// Tank-treading phase of `frame` relative to `reference` (same material points), radians in
/// [−π, π]: the weighted mean body-frame angle change of the vertices (see the module docs).
pub fn tt_phase(frame: &[DVec3], reference: &[DVec3]) -> Result<f64, MotionError> {
    check_rest(reference)?;
    check_frame(0, frame, reference.len())?;
    let r = pose(reference, 0.0);
    Ok(phase_step(&r, &pose(frame, r.theta)))
}

fn check_rest(rest: &[DVec3]) -> Result<(), MotionError> {
    if rest.len() < 3 {
        return Err(MotionError::TooFewVertices(rest.len()));
    }
    match rest.iter().position(|p| !p.is_finite()) {
        Some(v) => Err(MotionError::NonFiniteRest(v)),
        None => Ok(()),
    }
}

fn check_frame(frame: usize, x: &[DVec3], expected: usize) -> Result<(), MotionError> {
    if x.len() != expected {
        return Err(MotionError::VertexCount {
            frame,
            expected,
            found: x.len(),
        });
    }
    match x.iter().position(|p| !p.is_finite()) {
        Some(vertex) => Err(MotionError::NonFinite { frame, vertex }),
        None => Ok(()),
    }
}

/// Follows θ and Φ frame by frame (for writing per-frame rows while a run goes on).
pub struct MotionTracker {
    last: Pose,
    last_time: Option<f64>,
    phase: f64,
    frames: usize,
}

impl MotionTracker {
    /// Starts from the resting vertex positions (the material reference, frame −1).
    pub fn new(rest: &[DVec3]) -> Result<Self, MotionError> {
        check_rest(rest)?;
        Ok(Self {
            last: pose(rest, 0.0),
            last_time: None,
            phase: 0.0,
            frames: 0,
        })
    }

    /// Adds the next frame (unwrapped vertices in the rest order) at `time` (> the previous).
    pub fn push(&mut self, time: f64, frame: &[DVec3]) -> Result<FrameMotion, MotionError> {
        let k = self.frames;
        if !time.is_finite() || self.last_time.is_some_and(|t| time <= t) {
            return Err(MotionError::BadTime { frame: k, value: time });
        }
        check_frame(k, frame, self.last.psi.len())?;
        let p = pose(frame, self.last.theta);
        self.phase += phase_step(&self.last, &p);
        let out = FrameMotion {
            time,
            centroid: p.centroid.to_array(),
            inclination_deg: p.theta.to_degrees(),
            in_plane_anisotropy: p.anisotropy,
            tt_phase_rad: self.phase,
        };
        (self.last, self.last_time, self.frames) = (p, Some(time), k + 1);
        Ok(out)
    }
}

/// What a [`MotionTracker`] needs to continue after a restart, besides the positions of its
/// last frame: the exact unwrapped angles and counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrackerSnapshot {
    /// Unwrapped inclination of the last frame (radians).
    pub theta_rad: f64,
    /// Unwrapped tank-treading phase (radians).
    pub phase_rad: f64,
    /// Time of the last frame (None before the first).
    pub last_time: Option<f64>,
    /// Frames pushed so far.
    pub frames: usize,
}

impl MotionTracker {
    /// The tracker's state, for a checkpoint (with the positions of its last frame, or of the
    /// rest shape before the first).
    pub fn snapshot(&self) -> TrackerSnapshot {
        TrackerSnapshot {
            theta_rad: self.last.theta,
            phase_rad: self.phase,
            last_time: self.last_time,
            frames: self.frames,
        }
    }

    /// Continues from `snap`, whose last frame had the vertex positions `last_frame`; the frames
    /// pushed next are measured exactly as they would have been without the restart.
    pub fn resume(last_frame: &[DVec3], snap: &TrackerSnapshot) -> Result<Self, MotionError> {
        check_rest(last_frame)?;
        let (centroid, g) = gyration(last_frame);
        Ok(Self {
            last: pose_at(last_frame, centroid, g, snap.theta_rad),
            last_time: snap.last_time,
            phase: snap.phase_rad,
            frames: snap.frames,
        })
    }
}

/// Per-frame measures of a whole series (`times[k]` is the time of `frames[k]`).
pub fn motion_series<F: AsRef<[DVec3]>>(
    times: &[f64],
    frames: &[F],
    rest: &[DVec3],
) -> Result<Vec<FrameMotion>, MotionError> {
    if times.len() != frames.len() {
        return Err(MotionError::LengthMismatch {
            times: times.len(),
            frames: frames.len(),
        });
    }
    let mut tracker = MotionTracker::new(rest)?;
    times
        .iter()
        .zip(frames)
        .map(|(&t, f)| tracker.push(t, f.as_ref()))
        .collect()
}

/// Classifies the motion of a series and measures its rates (see the module docs).
pub fn analyze<F: AsRef<[DVec3]>>(
    times: &[f64],
    frames: &[F],
    rest: &[DVec3],
    shear_rate: f64,
    thresholds: &MotionThresholds,
) -> Result<MotionAnalysis, MotionError> {
    check_inputs(frames.len(), shear_rate, thresholds)?;
    classify(&motion_series(times, frames, rest)?, shear_rate, thresholds)
}

fn check_inputs(n: usize, shear_rate: f64, th: &MotionThresholds) -> Result<(), MotionError> {
    if !(shear_rate.is_finite() && shear_rate > 0.0) {
        return Err(MotionError::BadShearRate(shear_rate));
    }
    let in_range = |v: f64, lo: f64, hi: f64| v.is_finite() && v >= lo && v <= hi;
    for (name, ok) in [
        (
            "min_swing_amplitude_deg",
            in_range(th.min_swing_amplitude_deg, 0.0, 90.0),
        ),
        ("swing_ratio_tolerance", in_range(th.swing_ratio_tolerance, 0.0, 2.0)),
        (
            "min_in_plane_anisotropy",
            in_range(th.min_in_plane_anisotropy, 0.0, 1.0),
        ),
        (
            "max_strain_per_frame",
            in_range(th.max_strain_per_frame, 1e-300, f64::MAX),
        ),
    ] {
        if !ok {
            return Err(MotionError::BadThreshold(name));
        }
    }
    if n < 2 {
        Err(MotionError::TooFewFrames)
    } else {
        Ok(())
    }
}

/// One complete episode: frames `start..=end`, body and membrane rotation (degrees, + = vorticity sense).
struct Episode {
    start: usize,
    end: usize,
    tumbling: bool,
    body: f64,
    membrane: f64,
}

/// Classifies a series from [`motion_series`] or [`MotionTracker`]; `shear_rate` γ̇ in 1/time.
pub fn classify(s: &[FrameMotion], shear_rate: f64, th: &MotionThresholds) -> Result<MotionAnalysis, MotionError> {
    check_inputs(s.len(), shear_rate, th)?;
    if let Some(k) = (1..s.len()).find(|&k| s[k].time.partial_cmp(&s[k - 1].time) != Some(Greater)) {
        return Err(MotionError::BadTime {
            frame: k,
            value: s[k].time,
        });
    }
    let strain = shear_rate * (s[s.len() - 1].time - s[0].time);
    let mut out = MotionAnalysis {
        strain,
        ..Default::default()
    };
    let max_gap = s.windows(2).map(|w| w[1].time - w[0].time).fold(0.0, f64::max);
    let mut aniso: Vec<f64> = s.iter().map(|f| f.in_plane_anisotropy).collect();
    aniso.sort_by(f64::total_cmp);
    out.undetermined_reason = if shear_rate * max_gap > th.max_strain_per_frame {
        Some(UndeterminedReason::Undersampled)
    } else if aniso[aniso.len() / 2] < th.min_in_plane_anisotropy {
        Some(UndeterminedReason::NoInPlaneAxis)
    } else {
        None
    };
    if out.undetermined_reason.is_some() {
        return Ok(out);
    }
    let mut episodes = Vec::new();
    let mut start = 0;
    for k in 1..s.len() {
        let body = s[start].inclination_deg - s[k].inclination_deg;
        let membrane = (s[start].tt_phase_rad - s[k].tt_phase_rad).to_degrees();
        if body.abs() >= 180.0 || membrane.abs() >= 180.0 {
            let tumbling = body.abs() >= membrane.abs();
            episodes.push(Episode {
                start,
                end: k,
                tumbling,
                body,
                membrane,
            });
            start = k;
        }
    }
    if episodes.is_empty() {
        out.undetermined_reason = Some(UndeterminedReason::WindowTooShort);
        return Ok(out);
    }
    let span = |e: &Episode| s[e.end].time - s[e.start].time;
    let (tu, tt): (Vec<&Episode>, Vec<&Episode>) = episodes.iter().partition(|e| e.tumbling);
    let (t_tu, t_tt) = (
        tu.iter().map(|e| span(e)).sum::<f64>(),
        tt.iter().map(|e| span(e)).sum::<f64>(),
    );
    out.flips = tu.len();
    out.tt_half_revolutions = tt.len();
    out.tumbling_fraction = t_tu / (t_tu + t_tt) + 0.0; // + 0.0: never -0
    if !tu.is_empty() {
        out.tumbling_rate = Some(tu.iter().map(|e| e.body).sum::<f64>() / t_tu / 180.0);
    }
    out.class = match (tu.is_empty(), tt.is_empty()) {
        (false, true) => MotionClass::Tumbling,
        (false, false) => MotionClass::Intermittent,
        _ => MotionClass::TankTreading,
    };
    if tt.is_empty() {
        return Ok(out);
    }
    let f_tt = tt.iter().map(|e| e.membrane).sum::<f64>() / t_tt / 360.0;
    out.tank_treading_frequency = Some(f_tt);
    // The longest run of consecutive TT episodes, extended to the end of the series if it is
    // last; an episode next to a tumbling one is dropped while others remain (it holds the
    // end of the flip).
    let (mut best, mut first) = ((0, 0, 0.0), 0);
    for run in episodes.chunk_by(|a, b| a.tumbling == b.tumbling) {
        let (last, next) = (first + run.len() - 1, first + run.len());
        if !run[0].tumbling {
            let a = if first > 0 && last > first { first + 1 } else { first };
            let b = if next < episodes.len() && last > a {
                last - 1
            } else {
                last
            };
            let fb = if next == episodes.len() {
                s.len() - 1
            } else {
                episodes[b].end
            };
            let (fa, span) = (episodes[a].start, s[fb].time - s[episodes[a].start].time);
            if span > best.2 {
                best = (fa, fb, span);
            }
        }
        first = next;
    }
    let run = &s[best.0..=best.1];
    let t: Vec<f64> = run.iter().map(|f| f.time).collect();
    let mean = run.iter().map(|f| f.inclination_deg).sum::<f64>() / run.len() as f64;
    let shift = 180.0 * ((mean - 90.0) / 180.0).ceil(); // puts the run's mean in (−90, 90]
    let y: Vec<f64> = run.iter().map(|f| f.inclination_deg - shift).collect();
    let dt_med = {
        let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
        d.sort_by(f64::total_cmp);
        d[d.len() / 2]
    };
    let (w_lo, w_hi) = (PI / best.2, (PI / dt_med).min(TAU * 6.0 * f_tt.abs()));
    match fit_sinusoid(&t, &y, w_lo, w_hi) {
        Some((w, c, amp)) => {
            out.mean_inclination_deg = Some(c);
            out.inclination_amplitude_deg = Some(amp);
            if amp >= th.min_swing_amplitude_deg {
                let ratio = w / TAU / f_tt.abs();
                out.swing_frequency = Some(w / TAU);
                out.swing_to_tt_ratio = Some(ratio);
                if tu.is_empty() && (ratio - 2.0).abs() <= th.swing_ratio_tolerance {
                    out.class = MotionClass::Swinging;
                }
            }
        }
        None => out.mean_inclination_deg = Some(y.iter().sum::<f64>() / y.len() as f64),
    }
    Ok(out)
}

fn det3(m: [[f64; 3]; 3]) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

/// Least squares y ≈ c₀ + c₁ cos ωt + c₂ sin ωt (t centred); returns (c, residual sum of squares).
fn fit_at(t: &[f64], y: &[f64], w: f64) -> Option<([f64; 3], f64)> {
    let (mut m, mut r, mut yy) = ([[0.0; 3]; 3], [0.0; 3], 0.0);
    for (&ti, &yi) in t.iter().zip(y) {
        let (sn, cs) = (w * ti).sin_cos();
        let b = [1.0, cs, sn];
        for i in 0..3 {
            r[i] += b[i] * yi;
            for j in 0..3 {
                m[i][j] += b[i] * b[j];
            }
        }
        yy += yi * yi;
    }
    let d = det3(m);
    if !d.is_finite() || d.abs() <= 1e-12 * (t.len() as f64).powi(3) {
        return None;
    }
    let mut c = [0.0; 3];
    for k in 0..3 {
        let mut mk = m;
        (0..3).for_each(|i| mk[i][k] = r[i]);
        c[k] = det3(mk) / d;
    }
    Some((c, (yy - c[0] * r[0] - c[1] * r[1] - c[2] * r[2]).max(0.0)))
}

/// Best single sinusoid over ω ∈ [w_lo, w_hi] (grid, then golden section): (ω, mean, amplitude).
fn fit_sinusoid(t: &[f64], y: &[f64], w_lo: f64, w_hi: f64) -> Option<(f64, f64, f64)> {
    if t.len() < 4 || w_hi.partial_cmp(&w_lo) != Some(Greater) {
        return None;
    }
    let tm = t.iter().sum::<f64>() / t.len() as f64;
    let t: Vec<f64> = t.iter().map(|v| v - tm).collect();
    let rss = |w: f64| fit_at(&t, y, w).map_or(f64::INFINITY, |f| f.1);
    let n = (((w_hi - w_lo) * 8.0 / (2.0 * w_lo)).ceil() as usize).clamp(16, 4000);
    let dw = (w_hi - w_lo) / n as f64;
    let k = (0..=n)
        .map(|k| (k, rss(w_lo + k as f64 * dw)))
        .min_by(|a, b| a.1.total_cmp(&b.1))?
        .0;
    let (mut a, mut b) = (
        (w_lo + (k as f64 - 1.0) * dw).max(w_lo),
        (w_lo + (k as f64 + 1.0) * dw).min(w_hi),
    );
    let g = 0.5 * (5f64.sqrt() - 1.0);
    for _ in 0..60 {
        let (x1, x2) = (b - g * (b - a), a + g * (b - a));
        if rss(x1) < rss(x2) {
            b = x2
        } else {
            a = x1
        }
    }
    let w = 0.5 * (a + b);
    let (c, _) = fit_at(&t, y, w)?;
    Some((w, c[0], c[1].hypot(c[2])))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shape::EvansFung;
    use rand::{Rng, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// `n` nearly uniform points on the unit sphere (Fibonacci spiral).
    fn sphere(n: usize) -> Vec<DVec3> {
        let ga = PI * (3.0 - 5f64.sqrt());
        (0..n)
            .map(|i| {
                let z = 1.0 - (2 * i + 1) as f64 / n as f64;
                let (s, c) = (ga * i as f64).sin_cos();
                let r = (1.0 - z * z).sqrt();
                DVec3::new(r * c, r * s, z)
            })
            .collect()
    }

    fn rot_z(p: DVec3, a: f64) -> DVec3 {
        let (s, c) = a.sin_cos();
        DVec3::new(c * p.x - s * p.y, s * p.x + c * p.y, p.z)
    }

    /// Frames at `times`: material points `u` turned by `tt(t)` about z, mapped by `shape`, the
    /// body turned by `theta(t)` about z and advected with the flow (γ̇ = 1, centre at y = 2).
    fn frames(
        times: &[f64],
        u: &[DVec3],
        shape: impl Fn(DVec3) -> DVec3,
        theta: impl Fn(f64) -> f64,
        tt: impl Fn(f64) -> f64,
    ) -> Vec<Vec<DVec3>> {
        let c = |t: f64| DVec3::new(2.0 * t, 2.0, 0.5);
        times
            .iter()
            .map(|&t| {
                u.iter()
                    .map(|&p| rot_z(shape(rot_z(p, tt(t))), theta(t)) + c(t))
                    .collect()
            })
            .collect()
    }

    fn times(dt: f64, t_end: f64) -> Vec<f64> {
        (0..=(t_end / dt).round() as usize).map(|k| k as f64 * dt).collect()
    }

    fn ellipsoid(p: DVec3) -> DVec3 {
        DVec3::new(1.4 * p.x, 0.7 * p.y, 1.0 * p.z)
    }

    fn run(ts: &[f64], fr: &[Vec<DVec3>], rest: &[DVec3]) -> MotionAnalysis {
        analyze(ts, fr, rest, 1.0, &MotionThresholds::default()).unwrap()
    }

    fn close(a: Option<f64>, b: f64, tol: f64) -> bool {
        a.is_some_and(|a| (a - b).abs() <= tol)
    }

    #[test]
    fn tumbling_rate_recovered() {
        let ef = EvansFung::healthy_um();
        let u = sphere(500);
        let rest: Vec<DVec3> = u.iter().map(|&p| ef.from_sphere(p)).collect();
        let ts = times(0.05, 20.0);
        let fr = frames(&ts, &u, |p| ef.from_sphere(p), |t| 0.3 - 0.5 * t, |_| 0.0);
        let m = run(&ts, &fr, &rest);
        assert_eq!(m.class, MotionClass::Tumbling, "{m:?}");
        assert!(close(m.tumbling_rate, 0.5 / PI, 0.01 * 0.5 / PI), "{m:?}");
        assert_eq!(m.flips, 3);
        assert!(m.tank_treading_frequency.is_none());
        // the per-frame helpers: the unwrapped inclination keeps decreasing
        let s = motion_series(&ts, &fr, &rest).unwrap();
        assert!((s[400].inclination_deg - s[0].inclination_deg + 10f64.to_degrees()).abs() < 1e-6);
        assert!(s.iter().all(|f| f.tt_phase_rad.abs() < 1e-9));
    }

    #[test]
    fn jeffery_orbit_flip_rate_recovered() {
        // a rigid ellipse of aspect r in shear: tan θ = r tan(−γ̇ t r/(r² + 1)), two flips per
        // Jeffery period 2π (r + 1/r)/γ̇; the non-uniform rotation averages out over whole flips
        let (u, r) = (sphere(400), 2.0);
        let rest: Vec<DVec3> = u.iter().map(|&p| ellipsoid(p)).collect();
        let ts = times(0.05, 50.0);
        let theta = |t: f64| {
            let a = -t * r / (r * r + 1.0);
            (r * a.tan()).atan() + PI * (a / PI).round()
        };
        let fr = frames(&ts, &u, ellipsoid, theta, |_| 0.0);
        let m = run(&ts, &fr, &rest);
        let rate = 2.0 / (TAU * (r + 1.0 / r));
        assert_eq!(m.class, MotionClass::Tumbling, "{m:?}");
        assert!(close(m.tumbling_rate, rate, 0.01 * rate), "{m:?} vs {rate}");
    }

    #[test]
    fn tank_treading_frequency_and_inclination_recovered() {
        let u = sphere(600);
        let rest: Vec<DVec3> = u.iter().map(|&p| ellipsoid(p)).collect();
        let (f, th0) = (0.04, 25f64.to_radians());
        let ts = times(0.1, 60.0);
        let fr = frames(&ts, &u, ellipsoid, |_| th0, |t| -TAU * f * t);
        let m = run(&ts, &fr, &rest);
        assert_eq!(m.class, MotionClass::TankTreading, "{m:?}");
        assert!(close(m.tank_treading_frequency, f, 0.01 * f), "{m:?}");
        assert!(close(m.mean_inclination_deg, 25.0, 0.5), "{m:?}");
        assert!(m.inclination_amplitude_deg.unwrap() < 0.5, "{m:?}");
        assert_eq!((m.flips, m.tt_half_revolutions), (0, 4));
        assert!((inclination_deg(&fr[7]) - 25.0).abs() < 0.5);
        // tt_phase of one frame against the rest shape: −2π f t, here at t = 3
        assert!((tt_phase(&fr[30], &rest).unwrap() + TAU * f * 3.0).abs() < 0.01);
    }

    #[test]
    fn swinging_amplitude_mean_and_ratio_recovered() {
        let u = sphere(600);
        let rest: Vec<DVec3> = u.iter().map(|&p| ellipsoid(p)).collect();
        let (f, th0, amp) = (0.04, 20.0, 6.0);
        let ts = times(0.1, 75.0);
        let theta = |t: f64| (th0 + amp * (2.0 * TAU * f * t).sin()).to_radians();
        let fr = frames(&ts, &u, ellipsoid, theta, |t| -TAU * f * t);
        let m = run(&ts, &fr, &rest);
        assert_eq!(m.class, MotionClass::Swinging, "{m:?}");
        assert!(close(m.inclination_amplitude_deg, amp, 0.3), "{m:?}");
        assert!(close(m.mean_inclination_deg, th0, 0.5), "{m:?}");
        assert!(close(m.swing_to_tt_ratio, 2.0, 0.05), "{m:?}");
        assert!(close(m.tank_treading_frequency, f, 0.01 * f), "{m:?}");
    }

    #[test]
    fn tumbling_then_tank_treading_is_intermittent() {
        let u = sphere(500);
        let rest: Vec<DVec3> = u.iter().map(|&p| ellipsoid(p)).collect();
        let (w, t1, f) = (0.5, 2.1 * PI / 0.5, 0.05); // 2.1 flips, then 2.1 TT revolutions
        let ts = times(0.05, t1 + 42.0);
        let fr = frames(
            &ts,
            &u,
            ellipsoid,
            |t| 0.4 - w * t.min(t1),
            |t| -TAU * f * (t - t1).max(0.0),
        );
        let m = run(&ts, &fr, &rest);
        assert_eq!(m.class, MotionClass::Intermittent, "{m:?}");
        assert_eq!((m.flips, m.tt_half_revolutions), (2, 4), "{m:?}");
        assert!(close(m.tumbling_rate, w / PI, 0.03 * w / PI), "{m:?}");
        assert!(close(m.tank_treading_frequency, f, 0.03 * f), "{m:?}");
        assert!(close(m.mean_inclination_deg, 0.4f64.to_degrees() - 18.0, 0.5), "{m:?}"); // −2.1 flips
        assert!((0.2..0.3).contains(&m.tumbling_fraction), "{m:?}");
    }

    #[test]
    fn short_face_on_or_coarse_windows_are_undetermined() {
        let u = sphere(400);
        let rest: Vec<DVec3> = u.iter().map(|&p| ellipsoid(p)).collect();
        let ts = times(0.1, 5.0); // 0.2 of a TT revolution, 0.15 of a flip
        let fr = frames(&ts, &u, ellipsoid, |t| 0.3 - 0.1 * t, |t| -0.25 * t);
        let m = run(&ts, &fr, &rest);
        assert_eq!(m.class, MotionClass::Undetermined);
        assert_eq!(m.undetermined_reason, Some(UndeterminedReason::WindowTooShort));
        assert!(m.tumbling_rate.is_none() && m.tank_treading_frequency.is_none());
        // a sphere has no in-plane axis
        let ts = times(0.1, 50.0);
        let fr = frames(&ts, &u, |p| p, |t| -0.5 * t, |_| 0.0);
        let m = run(&ts, &fr, &u);
        assert_eq!(m.undetermined_reason, Some(UndeterminedReason::NoInPlaneAxis));
        let ts = times(2.0, 50.0);
        let fr = frames(&ts, &u, ellipsoid, |t| -0.5 * t, |_| 0.0);
        let m = run(&ts, &fr, &rest);
        assert_eq!(m.undetermined_reason, Some(UndeterminedReason::Undersampled));
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        use MotionError::*;
        let (rest, th) = (sphere(10), MotionThresholds::default());
        let err = |t: &[f64], f: &[Vec<DVec3>], r: &[DVec3], g: f64| analyze(t, f, r, g, &th).unwrap_err();
        let two = [rest.clone(), rest.clone()];
        let mut nan = two.clone();
        nan[1][4].y = f64::NAN;
        let (t2, short) = ([0.0, 1.0], [rest.clone(), rest[..9].to_vec()]);
        assert_eq!(err(&[], &[], &rest, 1.0), TooFewFrames);
        assert_eq!(err(&t2, &two, &rest[..2], 1.0), TooFewVertices(2));
        assert_eq!(err(&[0.0], &two, &rest, 1.0), LengthMismatch { times: 1, frames: 2 });
        let found = VertexCount {
            frame: 1,
            expected: 10,
            found: 9,
        };
        assert_eq!(err(&t2, &short, &rest, 1.0), found);
        assert_eq!(err(&t2, &nan, &rest, 1.0), NonFinite { frame: 1, vertex: 4 });
        assert_eq!(err(&t2, &two, &nan[1], 1.0), NonFiniteRest(4));
        assert!(matches!(err(&[0.0, 0.0], &two, &rest, 1.0), BadTime { frame: 1, .. }));
        assert!(matches!(
            err(&[0.0, f64::NAN], &two, &rest, 1.0),
            BadTime { frame: 1, .. }
        ));
        for g in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(err(&t2, &two, &rest, g), BadShearRate(_)));
        }
        let bad = MotionThresholds {
            max_strain_per_frame: 0.0,
            ..th
        };
        assert_eq!(
            analyze(&t2, &two, &rest, 1.0, &bad),
            Err(BadThreshold("max_strain_per_frame"))
        );
        assert!(tt_phase(&rest[..9], &rest).is_err());
        assert!(inclination_deg(&[]).is_nan());
    }

    #[test]
    fn thermal_jitter_does_not_change_the_class() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(12);
        let mut jitter = |fr: &mut Vec<Vec<DVec3>>, sigma: f64| {
            for p in fr.iter_mut().flatten() {
                *p += DVec3::new(rng.random(), rng.random(), rng.random()) * (2.0 * sigma) - sigma;
            }
        };
        let u = sphere(600);
        let rest: Vec<DVec3> = u.iter().map(|&p| ellipsoid(p)).collect();
        let ts = times(0.1, 60.0);
        let f = 0.04;
        let mut fr = frames(&ts, &u, ellipsoid, |_| 0.35, |t| -TAU * f * t);
        jitter(&mut fr, 0.04); // 4 % of the mean radius 1
        let m = run(&ts, &fr, &rest);
        assert_eq!(m.class, MotionClass::TankTreading, "{m:?}");
        assert!(close(m.tank_treading_frequency, f, 0.02 * f), "{m:?}");
        assert!(close(m.mean_inclination_deg, 0.35f64.to_degrees(), 0.5), "{m:?}");
        let ef = EvansFung::healthy_um();
        let rest: Vec<DVec3> = u.iter().map(|&p| ef.from_sphere(p)).collect();
        let mut fr = frames(&ts, &u, |p| ef.from_sphere(p), |t| -0.3 * t, |_| 0.0);
        jitter(&mut fr, 0.1); // 2.6 % of R = 3.91
        let m = run(&ts, &fr, &rest);
        assert_eq!(m.class, MotionClass::Tumbling, "{m:?}");
        assert!(close(m.tumbling_rate, 0.3 / PI, 0.01 * 0.3 / PI), "{m:?}");
    }

    /// A tracker resumed from its snapshot and last frame measures the next frames bit for bit
    /// as the uninterrupted one.
    #[test]
    fn resumed_tracker_continues_exactly() {
        let rest: Vec<DVec3> = (0..60)
            .map(|k| {
                let t = k as f64 * 0.7;
                DVec3::new(3.0 * t.cos(), 1.2 * t.sin(), 0.4 * (2.0 * t).sin())
            })
            .collect();
        let frame = |k: usize| -> Vec<DVec3> {
            let a = -0.13 * k as f64;
            let (s, c) = a.sin_cos();
            rest.iter()
                .map(|p| DVec3::new(c * p.x - s * p.y, s * p.x + c * p.y, p.z))
                .collect()
        };
        let mut a = MotionTracker::new(&rest).unwrap();
        for k in 0..7 {
            a.push(k as f64, &frame(k)).unwrap();
        }
        let mut b = MotionTracker::resume(&frame(6), &a.snapshot()).unwrap();
        for k in 7..20 {
            let (fa, fb) = (
                a.push(k as f64, &frame(k)).unwrap(),
                b.push(k as f64, &frame(k)).unwrap(),
            );
            assert_eq!(fa, fb);
        }
        assert!(MotionTracker::resume(&frame(6)[..2], &a.snapshot()).is_err());
    }
}
