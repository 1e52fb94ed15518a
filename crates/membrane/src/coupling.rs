//! The membrane in the flow: one cell whose vertices are particles of the DPD engine
//! (docs/engine.md, "The cell in the fluid").
//!
//! [`Cell`] is an engine [`Extension`]. The fluid and the walls act on the vertices through the
//! ordinary pair forces of their type pairs (the scenario sets a = 0 and the no-slip friction);
//! the cell adds, per step:
//!
//! 1. after the drift, [`Extension::after_position_update`]: the vertices' **unwrapped**
//!    positions are advanced by the minimum image of their wrapped displacement (a vertex moves
//!    far less than half a box per step), so links, area, volume and bounce-back never see the
//!    periodic boundary; then fluid particles that crossed a triangle during the step are
//!    **bounced back** on the moving triangle ([`hemodpd_engine::mesh_bounce`]), and the
//!    impulses go to the triangle's vertices (linear and angular momentum conserved);
//! 2. [`Extension::add_forces`]: the membrane forces of Eq. 1 on the unwrapped positions, and a
//!    short-range repulsion from the wall so that the cell never enters it;
//! 3. [`Extension::end_of_step`]: the membrane viscosity, when there is one
//!    ([`CellConfig::viscosity`]): a Shardlow sweep over the links that updates the vertex
//!    velocities by the exact solution of each link's dissipative and random forces
//!    ([`crate::viscosity`]); then, every `check_every` steps, an inside test (generalised
//!    winding number) of every inner and outer fluid particle near the cell; a particle on the
//!    wrong side is a missed crossing, counted in [`CellStats::misplaced`].
//!
//! **Sub-stepping** ([`CellConfig::substeps`] = k > 1, docs/model.md §7b): the cell integrates
//! its vertices itself by a two-level r-RESPA scheme ([`crate::respa`]), and their particle type
//! must be [`TypeSpec::integrated_by_extension`](hemodpd_engine::TypeSpec) (the engine then
//! only computes their pair forces). The slow force is what the engine leaves in `state.force`
//! of a vertex (the pair forces from the fluid and walls, any wall force, the external forces);
//! the fast ones are the membrane forces, the wall repulsion and the membrane viscosity:
//! 1. [`Extension::after_position_update`]: v += ½Δt F_slow(t)/m; k inner steps of h = Δt/k
//!    (velocity Verlet with the fast forces on the unwrapped positions, then the Shardlow
//!    sweep with step h); the new positions wrapped into `state.pos` (Lees–Edwards: the velocity
//!    follows the image); then the bounce pass over the step as above;
//! 2. [`Extension::add_forces`]: only the external forces are added (the membrane forces are
//!    inner forces; the last inner evaluation's forces and energy are kept);
//! 3. [`Extension::end_of_step`]: v += ½Δt F_slow(t + Δt)/m; the checks.
//!
//! Each pair force reaches both partners as the same two half-kicks, and the fast forces and
//! the sweep conserve momentum, so the total momentum of fluid and cell is conserved to
//! round-off as with k = 1. The fast forces at the end of a step are kept for the next step's
//! first inner half-kick and checkpointed ([`CellState::fast_forces`]).
//!
//! Candidate pairs for bounce-back: a particle can only have crossed a triangle if its segment
//! of the step meets the bounding box of the cell over the step; those few particles (a parallel
//! filter with one box test each) are tested against the triangles of a uniform grid over that
//! box whose cells their segment overlaps. The cost grows with the particles near the membrane,
//! not with particles × triangles. The results are applied in particle order, so the trajectory
//! does not depend on the number of threads.
//!
//! Lengths, velocities and forces are in the engine's model units.

use glam::DVec3;
use hemodpd_engine::mesh_bounce::{self, MovingTriangle};
use hemodpd_engine::{EngineError, Extension, StateMut, WallShape};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

use crate::forces::{ForceError, ForceWorkspace};
use crate::mesh::winding_number;
use crate::respa::{inner_steps, inner_sweeps, InnerSweep};
use crate::viscosity::{shardlow_sweep, MembraneViscosity};
use crate::MembraneModel;

/// Distance off the end-of-step triangle, relative to its longest edge, at which a bounced
/// particle is put back on its side.
const PLACEMENT_OFFSET: f64 = 1e-5;

/// Mixed into the seed of the Maxwell reflections (a stream apart from the pair noise).
const MAXWELL_SALT: u64 = 0x6d65_6d62_7261_6e65;

/// A velocity relative to the wall leaving it along `n` (unit, towards the particle's side):
/// flux-weighted Maxwell–Boltzmann of thermal speed `vth` = √(kBT/m), from the counter-based
/// stream (`key`, particle `id`).
fn maxwell_velocity(key: u64, id: u32, n: DVec3, vth: f64) -> DVec3 {
    use hemodpd_engine::rng::mix64;
    let base = key.wrapping_add((id as u64).wrapping_mul(4).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let u = |k: u64| {
        let h = mix64(base.wrapping_add(k.wrapping_mul(0x9E37_79B9_7F4A_7C15)));
        ((h >> 11) as f64 + 0.5) / (1u64 << 53) as f64 // (0, 1)
    };
    let (u1, u2, u3) = (u(1), u(2), u(3));
    let normal = vth * (-2.0 * u1.ln()).sqrt();
    let r = vth * (-2.0 * u2.ln()).sqrt();
    let phi = std::f64::consts::TAU * u3;
    let t1 = n.any_orthonormal_vector();
    let t2 = n.cross(t1);
    n * normal + t1 * (r * phi.cos()) + t2 * (r * phi.sin())
}

/// Seed of the membrane-viscosity noise in [`dry_run`].
const DRY_RUN_SEED: u64 = 0x2545_f491;

/// Meshes with at least this many vertices use the parallel force evaluation.
const PARALLEL_FORCES_FROM: usize = 4000;

/// Short-range repulsion of the vertices from a wall: a vertex at distance d < `range` from the
/// wall surface (inside the fluid) feels `strength·(1 − d/range)` along the inward normal.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WallRepulsion {
    /// The wall surface (the same signed distance as the walls).
    pub shape: WallShape,
    /// Range (length).
    pub range: f64,
    /// Force at contact (force).
    pub strength: f64,
}

/// How a fluid particle leaves the membrane after it crossed a triangle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MembraneReflection {
    /// v → 2u_w − v (u_w: the velocity of the hit point): no slip, energy-conserving in the
    /// triangle's frame. A particle caught in a sharp crease of a thermally rough membrane is
    /// reflected back and forth between two light triangles and gains energy every step
    /// (seen at κ/kBT ≈ 6 with vertex mass = fluid mass; docs/capillary.md).
    BounceBack,
    /// Diffuse (Maxwell) reflection: v → u_w + c, with c drawn from the flux-weighted
    /// Maxwell–Boltzmann distribution of the fluid's kBT leaving the surface on the particle's
    /// side (normal speed √(kBT/m)·√(−2 ln ξ), tangential components Gaussian of variance
    /// kBT/m). No slip on average, and the particle leaves at the fluid's temperature, so no
    /// energy is pumped in; momentum goes to the vertices as for bounce-back. Counter-based
    /// random numbers of (seed, step, particle id): independent of the thread count.
    #[default]
    Maxwell,
}

impl WallRepulsion {
    /// Energy of a vertex at `p`: strength·range/2·(1 − d/range)² within the range, else 0
    /// (the force is its negative gradient).
    pub fn energy(&self, p: DVec3) -> f64 {
        let d = -self.shape.signed_distance(p);
        if d < self.range {
            let u = 1.0 - d.max(0.0) / self.range;
            0.5 * self.strength * self.range * u * u
        } else {
            0.0
        }
    }

    /// Force on a vertex at `p`: strength·(1 − d/range) along the inward normal within the range.
    pub fn force(&self, p: DVec3) -> DVec3 {
        let d = -self.shape.signed_distance(p);
        if d < self.range {
            -self.shape.normal(p) * (self.strength * (1.0 - d.max(0.0) / self.range))
        } else {
            DVec3::ZERO
        }
    }
}

/// Settings of a [`Cell`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CellConfig {
    /// Storage index of vertex 0; the N vertices occupy `first..first + N`.
    pub first: usize,
    /// Type of the fluid outside the cell.
    pub outer_type: u16,
    /// Type of the fluid inside the cell.
    pub inner_type: u16,
    /// Steps between inside/outside checks (0: never).
    pub check_every: u64,
    /// Repulsion from the wall, if there is one.
    pub wall: Option<WallRepulsion>,
    /// How fluid leaves the membrane after a crossing.
    pub reflection: MembraneReflection,
    /// Thermal energy kBT of the fluid (for [`MembraneReflection::Maxwell`]).
    pub kbt: f64,
    /// Seed of the Maxwell reflections' and the membrane viscosity's random numbers.
    pub seed: u64,
    /// Membrane viscosity (Fedosov's dissipative and random link forces at the fluid's `kbt`),
    /// or `None`: the paper's model, no work done. Applied at the end of every step (k = 1) or
    /// after every inner step (k > 1).
    #[serde(default)]
    pub viscosity: Option<MembraneViscosity>,
    /// Membrane sub-steps k ≥ 1 per fluid step (default 1). 1: the engine integrates the
    /// vertices with the membrane forces added to their pair forces, and the viscosity sweep
    /// runs once per step. k > 1: the cell integrates them by r-RESPA with k inner steps of
    /// Δt/k (module docs), and the vertex type must be integrated by the extension
    /// ([`hemodpd_engine::TypeSpec::integrated_by_extension`]); with k = 1 it must not be.
    #[serde(default = "one_substep")]
    pub substeps: u32,
    /// With k > 1: whether the membrane's elastic forces and the wall repulsion are evaluated
    /// in every inner step ([`SubstepForces::Inner`], r-RESPA) or once per fluid step with the
    /// slow forces ([`SubstepForces::Outer`]: only the drift and the viscosity sweep are
    /// sub-stepped).
    #[serde(default)]
    pub substep_forces: SubstepForces,
}

/// Where the membrane's elastic forces act when the membrane is sub-stepped (k > 1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SubstepForces {
    /// r-RESPA: velocity Verlet with the membrane forces in each of the k inner steps
    /// ([`crate::respa::inner_steps`]); k force evaluations per fluid step.
    #[default]
    Inner,
    /// The membrane forces join the slow forces (two half-kicks of ½Δt per fluid step, as
    /// with k = 1, where they are stable); the inner steps are only drift and sweep
    /// ([`crate::respa::inner_sweeps`]), which is what the viscosity's friction cap needs. One
    /// force evaluation per fluid step; the slow motion feels the same friction as with
    /// `Inner` at the same k.
    Outer,
}

fn one_substep() -> u32 {
    1
}

/// Counters of a [`Cell`] (part of its checkpointed state).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CellStats {
    /// Fluid particles bounced back on a triangle.
    pub bounces: u64,
    /// Inside/outside checks done.
    pub checks: u64,
    /// Fluid particles found on the wrong side, summed over the checks (target: 0).
    pub misplaced: u64,
    /// Particles on the wrong side at the last check.
    pub misplaced_last: u64,
    /// Fluid particles tested in the last check.
    pub checked_last: u64,
}

/// The checkpointed state of a [`Cell`]: the unwrapped vertex positions (which carry the
/// periodic image of every vertex) and the counters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CellState {
    /// Unwrapped vertex positions, `[x, y, z]` (length).
    pub unwrapped: Vec<[f64; 3]>,
    pub stats: CellStats,
    /// With sub-steps (k > 1): the fast forces (membrane + wall repulsion, force) at
    /// `unwrapped`, for the first inner half-kick of the next step. Empty with k = 1 and in
    /// checkpoints written before sub-stepping existed (then recomputed from the positions).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub fast_forces: Vec<[f64; 3]>,
}

/// Wall-clock seconds spent in each part of the cell's work (not checkpointed).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct CellTimers {
    pub bounce_s: f64,
    /// The membrane forces and, with sub-steps, the rest of the inner steps but the sweeps.
    pub membrane_forces_s: f64,
    pub checks_s: f64,
    /// The viscosity sweeps and, with sub-steps and a viscosity, the inner kicks and drifts.
    pub viscosity_s: f64,
}

/// One bounce found in the parallel pass, applied in particle order afterwards.
#[derive(Clone, Copy, Debug)]
struct BounceEvent {
    particle: u32,
    triangle: u32,
    position: DVec3,
    velocity: DVec3,
    vertex_impulse: [DVec3; 3],
}

/// One red blood cell in the engine (see the module docs).
#[derive(Debug)]
pub struct Cell {
    model: MembraneModel,
    config: CellConfig,
    /// Unwrapped vertex positions now, and at the start of the step being taken.
    x: Vec<DVec3>,
    x_prev: Vec<DVec3>,
    forces: Vec<DVec3>,
    workspace: Option<ForceWorkspace>,
    stats: CellStats,
    timers: CellTimers,
    /// Energy terms of the last force evaluation.
    energy: crate::EnergyTerms,
    // reusable buffers of the bounce pass
    candidates: Vec<u32>,
    grid_start: Vec<u32>,
    grid_items: Vec<u32>,
    /// Swept bounding box of each triangle over the step being taken.
    tri_boxes: Vec<(DVec3, DVec3)>,
    /// Fill cursor per grid cell while binning the triangles.
    grid_fill: Vec<u32>,
    /// Mass of each particle type (read from the force field at the first step).
    masses: Vec<f64>,
    /// Mass of each vertex (read from the force field at the first viscosity sweep).
    vertex_masses: Vec<f64>,
    /// Constant external forces on vertices (vertex index, force), e.g. optical tweezers.
    external: Vec<(u32, DVec3)>,
    /// Sub-steps: whether `forces` holds the fast forces at `x` (false until the first
    /// evaluation, or after a restore from a checkpoint without them).
    fast_ready: bool,
    /// Whether the vertex type was checked against `substeps` (at the first hook).
    types_checked: bool,
    /// Sub-steps: the vertex velocities in the frame of the unwrapped positions.
    vel_buf: Vec<DVec3>,
}

/// Bounding box of a set of points.
fn bounds<'a>(points: impl Iterator<Item = &'a DVec3>) -> (DVec3, DVec3) {
    points.fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    )
}

/// A conservative first test for [`segment_meets_box`] on a particle's wrapped position: per
/// periodic axis, whether any image of the end point lies within the step's displacement of the
/// (unwrapped) box [lo, hi]. No division and no minimum image; false only if no image of the
/// segment can meet the box. With Lees–Edwards the x images also shift by the offset, so x is
/// not tested there.
struct NearBox {
    /// `lo` wrapped into [0, L) per axis.
    lo: DVec3,
    /// hi − lo.
    width: DVec3,
    lengths: DVec3,
    /// Per axis: whether to test it (box narrower than the period; x not under shear).
    test: [bool; 3],
}

impl NearBox {
    fn new(domain: &hemodpd_engine::PeriodicBox, lo: DVec3, hi: DVec3) -> Self {
        let l = domain.lengths();
        let width = hi - lo;
        let mut test = [0, 1, 2].map(|a| width[a].is_finite() && width[a] < 0.5 * l[a]);
        test[0] &= !domain.is_sheared();
        let lo = DVec3::from_array([0, 1, 2].map(|a| if test[a] { lo[a].rem_euclid(l[a]) } else { 0.0 }));
        Self {
            lo,
            width,
            lengths: l,
            test,
        }
    }

    /// Whether a segment ending at `p` (inside the box [0, L)) after a displacement `d` may meet
    /// the box. The margins (|d| per axis, plus 1e-9 L for the rounding of the wrapped `lo`)
    /// keep it conservative.
    #[inline(always)]
    fn may_meet(&self, p: DVec3, d: DVec3) -> bool {
        for a in 0..3 {
            if !self.test[a] {
                continue;
            }
            let (l, m) = (self.lengths[a], d[a].abs() + 1e-9 * self.lengths[a]);
            // offset of p past (lo − m), brought into [0, L): p and lo are in [0, L), m ≪ L
            let mut q = p[a] - self.lo[a] + m;
            if q < 0.0 {
                q += l;
            } else if q >= l {
                q -= l;
            }
            if !(0.0..l).contains(&q) {
                q = q.rem_euclid(l); // far out (not reached with |d| ≤ a cell); NaN stays NaN
            }
            // (NaN passes on to the exact test)
            if q > self.width[a] + 2.0 * m {
                return false;
            }
        }
        true
    }
}

/// Whether the segment from `a` to `b` meets the box [lo, hi] (slab test).
#[inline]
fn segment_meets_box(a: DVec3, b: DVec3, lo: DVec3, hi: DVec3) -> bool {
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    let d = b - a;
    for k in 0..3 {
        if d[k] == 0.0 {
            if a[k] < lo[k] || a[k] > hi[k] {
                return false;
            }
        } else {
            let (u, v) = ((lo[k] - a[k]) / d[k], (hi[k] - a[k]) / d[k]);
            let (u, v) = if u <= v { (u, v) } else { (v, u) };
            t0 = t0.max(u);
            t1 = t1.min(v);
            if t0 > t1 {
                return false;
            }
        }
    }
    true
}

/// A uniform grid over a box, for the triangle lookup of the bounce pass.
#[derive(Clone, Copy, Debug)]
struct Grid {
    lo: DVec3,
    h: f64,
    n: [usize; 3],
}

impl Grid {
    fn new(lo: DVec3, hi: DVec3, h: f64) -> Self {
        let span = hi - lo;
        let n = [0, 1, 2].map(|k| ((span[k] / h).floor() as usize + 1).clamp(1, 256));
        Grid { lo, h, n }
    }
    fn len(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }
    /// Cell index range along each axis covering [a, b].
    fn range(&self, a: DVec3, b: DVec3) -> [(usize, usize); 3] {
        [0, 1, 2].map(|k| {
            let f = |x: f64| (((x - self.lo[k]) / self.h).floor().max(0.0) as usize).min(self.n[k] - 1);
            (f(a[k]), f(b[k]))
        })
    }
    fn index(&self, i: usize, j: usize, k: usize) -> usize {
        (k * self.n[1] + j) * self.n[0] + i
    }
}

/// The fast forces of the sub-stepped scheme at the unwrapped positions `x`, written into `f`:
/// the membrane forces of `model` (in parallel with `ws`, when given) plus the wall repulsion at
/// the positions wrapped into `domain`. Returns the membrane's energy terms.
fn fast_forces(
    model: &MembraneModel,
    ws: Option<&mut ForceWorkspace>,
    wall: Option<&WallRepulsion>,
    domain: &hemodpd_engine::PeriodicBox,
    x: &[DVec3],
    f: &mut [DVec3],
) -> Result<crate::EnergyTerms, ForceError> {
    f.iter_mut().for_each(|fk| *fk = DVec3::ZERO);
    let energy = match ws {
        Some(ws) => model.add_forces_parallel(x, f, ws)?,
        None => model.add_forces(x, f)?,
    };
    if let Some(w) = wall {
        for (fk, xk) in f.iter_mut().zip(x) {
            *fk += w.force(domain.wrap(*xk));
        }
    }
    Ok(energy)
}

impl Cell {
    /// A cell with the given model (in model units) whose vertices are at the unwrapped
    /// positions `unwrapped` (the particles at `config.first..` must hold the same positions,
    /// wrapped into the box).
    pub fn new(model: MembraneModel, config: CellConfig, unwrapped: Vec<DVec3>) -> Result<Self, EngineError> {
        if unwrapped.len() != model.n_vertices() {
            return Err(EngineError::invalid(
                "cell vertices",
                format!(
                    "{} positions for a model of {} vertices",
                    unwrapped.len(),
                    model.n_vertices()
                ),
            ));
        }
        if let Some(w) = &config.wall {
            if !(w.range > 0.0 && w.range.is_finite() && w.strength >= 0.0 && w.strength.is_finite()) {
                return Err(EngineError::invalid(
                    "cell wall repulsion",
                    format!(
                        "range {} and strength {} (need range > 0, strength ≥ 0)",
                        w.range, w.strength
                    ),
                ));
            }
        }
        if let Some(v) = &config.viscosity {
            if !(v.is_valid() && config.kbt.is_finite() && config.kbt >= 0.0) {
                return Err(EngineError::invalid(
                    "cell membrane viscosity",
                    format!(
                        "gamma_t {}, gamma_c {} and kbt {} (need all finite and ≥ 0)",
                        v.gamma_t, v.gamma_c, config.kbt
                    ),
                ));
            }
        }
        if config.substeps == 0 {
            return Err(EngineError::invalid(
                "cell membrane substeps",
                "0 (need k ≥ 1; 1: no sub-stepping)",
            ));
        }
        let n = unwrapped.len();
        let workspace = (n >= PARALLEL_FORCES_FROM).then(|| model.workspace());
        Ok(Cell {
            model,
            config,
            x_prev: unwrapped.clone(),
            x: unwrapped,
            forces: vec![DVec3::ZERO; n],
            workspace,
            stats: CellStats::default(),
            timers: CellTimers::default(),
            energy: Default::default(),
            candidates: Vec::new(),
            grid_start: Vec::new(),
            grid_items: Vec::new(),
            tri_boxes: Vec::new(),
            grid_fill: Vec::new(),
            masses: Vec::new(),
            vertex_masses: Vec::new(),
            external: Vec::new(),
            fast_ready: false,
            types_checked: false,
            vel_buf: Vec::new(),
        })
    }

    /// Restores the state saved by [`Cell::state`].
    pub fn with_state(mut self, state: CellState) -> Result<Self, EngineError> {
        if state.unwrapped.len() != self.x.len() {
            return Err(EngineError::invalid(
                "saved cell state",
                format!("{} vertices for a model of {}", state.unwrapped.len(), self.x.len()),
            ));
        }
        if !state.fast_forces.is_empty() && state.fast_forces.len() != self.x.len() {
            return Err(EngineError::invalid(
                "saved cell state",
                format!(
                    "{} fast forces for a model of {} vertices",
                    state.fast_forces.len(),
                    self.x.len()
                ),
            ));
        }
        self.x = state.unwrapped.iter().map(|v| DVec3::from_array(*v)).collect();
        self.x_prev = self.x.clone();
        self.stats = state.stats;
        if self.inner_forces() && !state.fast_forces.is_empty() {
            self.forces = state.fast_forces.iter().map(|v| DVec3::from_array(*v)).collect();
            self.fast_ready = true;
        }
        Ok(self)
    }

    /// The state to checkpoint.
    pub fn state(&self) -> CellState {
        CellState {
            unwrapped: self.x.iter().map(|v| v.to_array()).collect(),
            stats: self.stats.clone(),
            fast_forces: if self.inner_forces() && self.fast_ready {
                self.forces.iter().map(|v| v.to_array()).collect()
            } else {
                Vec::new()
            },
        }
    }

    /// Sets constant external forces on vertices (vertex index, force), added to the membrane
    /// forces at every step until changed (empty: none). Not part of [`CellState`]: the caller
    /// sets them from its own schedule (a stage) after a restart. Indices must be < N.
    pub fn set_external_forces(&mut self, forces: Vec<(u32, DVec3)>) -> Result<(), EngineError> {
        if let Some((k, f)) = forces
            .iter()
            .find(|(k, f)| *k as usize >= self.x.len() || !f.is_finite())
        {
            return Err(EngineError::invalid(
                "cell external forces",
                format!(
                    "vertex {k} with force {f} (need an index < {} and a finite force)",
                    self.x.len()
                ),
            ));
        }
        self.external = forces;
        Ok(())
    }

    /// The constant external forces on vertices.
    pub fn external_forces(&self) -> &[(u32, DVec3)] {
        &self.external
    }

    /// The membrane model.
    pub fn model(&self) -> &MembraneModel {
        &self.model
    }

    /// The settings.
    pub fn config(&self) -> &CellConfig {
        &self.config
    }

    /// Unwrapped vertex positions (length).
    pub fn vertices(&self) -> &[DVec3] {
        &self.x
    }

    /// Counters.
    pub fn stats(&self) -> &CellStats {
        &self.stats
    }

    /// Time spent per part.
    pub fn timers(&self) -> CellTimers {
        self.timers
    }

    /// Energy terms of the last force evaluation.
    pub fn energy(&self) -> crate::EnergyTerms {
        self.energy
    }

    /// Storage indices of the vertices.
    pub fn vertex_range(&self) -> std::ops::Range<usize> {
        self.config.first..self.config.first + self.x.len()
    }

    /// Tests the inner and outer fluid particles near the cell (positions wrapped into `domain`
    /// in `pos`) and returns (tested, on the wrong side).
    pub fn count_misplaced(&self, pos: &[DVec3], ptype: &[u16], domain: &hemodpd_engine::PeriodicBox) -> (u64, u64) {
        let (lo, hi) = bounds(self.x.iter());
        let c = 0.5 * (lo + hi);
        let (inner, outer) = (self.config.inner_type, self.config.outer_type);
        let tris = self.model.triangles();
        let x = &self.x;
        let vr = self.vertex_range();
        let (tested, wrong) = pos
            .par_iter()
            .zip(ptype.par_iter())
            .enumerate()
            .with_min_len(1024)
            .filter_map(|(i, (p, &t))| {
                if (t != inner && t != outer) || vr.contains(&i) {
                    return None;
                }
                let q = c + domain.min_image(*p, c);
                let inside_box = q.cmpge(lo).all() && q.cmple(hi).all();
                let is_inside = inside_box && winding_number(q, x, tris) > 0.5;
                if !inside_box && t == outer {
                    return None; // outside the box: trivially on the right side if outer
                }
                Some((1u64, ((t == inner) != is_inside) as u64))
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        (tested, wrong)
    }

    /// The engine error of a failed membrane force evaluation at `step`.
    fn force_error(&self, e: ForceError, step: u64) -> EngineError {
        // before any step has completed the state is the initial one: blame the shape first
        let cause = if step == 0 {
            "the initial vertex positions are too far from the resting mesh (a perturbed or badly placed shape), or a time step too large for the membrane's stiffness"
        } else {
            "a time step too large for the membrane's stiffness or a flow far beyond the scenario's stated bounds"
        };
        EngineError::Extension {
            step,
            message: format!(
                "membrane: {e} (membrane vertices, storage indices {}..{}); likely cause: {cause}",
                self.config.first,
                self.config.first + self.x.len()
            ),
        }
    }

    /// Checks, once, that the vertices are in storage and that their type is integrated by this
    /// extension exactly when sub-stepping (and is not frozen then).
    fn check_types(&mut self, s: &StateMut<'_>) -> Result<(), EngineError> {
        if self.types_checked {
            return Ok(());
        }
        let range = self.vertex_range();
        if range.end > s.ptype.len() {
            return Err(EngineError::invalid(
                "cell vertices",
                format!(
                    "storage indices {}..{} beyond the {} particles",
                    range.start,
                    range.end,
                    s.ptype.len()
                ),
            ));
        }
        let k = self.config.substeps;
        let want = k > 1;
        let types = s.field.types();
        if let Some(i) = range.clone().find(|&i| {
            let t = &types[s.ptype[i] as usize];
            t.integrated_by_extension != want || (want && t.frozen)
        }) {
            let t = &types[s.ptype[i] as usize];
            let need = if want {
                "integrated by the extension (TypeSpec::integrated_by_extension = true) and not frozen"
            } else {
                "integrated by the engine (TypeSpec::integrated_by_extension = false)"
            };
            return Err(EngineError::invalid(
                "cell vertex type",
                format!(
                    "type {} \"{}\" of the vertex at storage index {i} has integrated_by_extension = {} and frozen = {}; with membrane substeps = {k} it must be {need}",
                    s.ptype[i], t.name, t.integrated_by_extension, t.frozen
                ),
            ));
        }
        self.types_checked = true;
        Ok(())
    }

    /// Whether the membrane forces are inner forces (sub-stepped with them, r-RESPA).
    fn inner_forces(&self) -> bool {
        self.config.substeps > 1 && self.config.substep_forces == SubstepForces::Inner
    }

    /// Reads the vertex masses from the force field (once).
    fn load_vertex_masses(&mut self, s: &StateMut<'_>) {
        if self.vertex_masses.len() != self.x.len() {
            let types = s.field.types();
            self.vertex_masses = s.ptype[self.vertex_range()]
                .iter()
                .map(|&t| types[t as usize].mass)
                .collect();
        }
    }

    /// Sub-stepping: the fast forces at the current unwrapped positions into `forces` (when they
    /// are not there yet).
    fn ensure_fast_forces(&mut self, s: &StateMut<'_>) -> Result<(), EngineError> {
        if self.fast_ready {
            return Ok(());
        }
        let t0 = Instant::now();
        let r = fast_forces(
            &self.model,
            self.workspace.as_mut(),
            self.config.wall.as_ref(),
            s.domain,
            &self.x,
            &mut self.forces,
        );
        self.energy = r.map_err(|e| self.force_error(e, s.step))?;
        self.fast_ready = true;
        self.timers.membrane_forces_s += t0.elapsed().as_secs_f64();
        Ok(())
    }

    /// Sub-stepping, after the fluid's drift: the slow half-kick, the k inner steps, the new
    /// positions written back wrapped (module docs). Leaves `x_prev`/`x` at the start and end of
    /// the step for the bounce pass.
    fn substep(&mut self, s: &mut StateMut<'_>) -> Result<(), EngineError> {
        self.load_vertex_masses(s);
        let inner_forces = self.inner_forces();
        if inner_forces {
            self.ensure_fast_forces(s)?;
        }
        let t0 = Instant::now();
        let range = self.vertex_range();
        let k = self.config.substeps;
        let (dt, h) = (s.dt, s.dt / k as f64);
        let domain = *s.domain;
        // Lees–Edwards: a vertex whose wrapped image is j periods below its unwrapped position
        // moves, in the unwrapped frame, j U faster along x (U = 0: no change)
        let (u, ly) = (domain.shear_velocity(), domain.lengths().y);
        self.vel_buf.clear();
        for (j, i) in range.clone().enumerate() {
            s.vel[i] += s.force[i] * (0.5 * dt / self.vertex_masses[j]);
            let mut v = s.vel[i];
            if u != 0.0 {
                v += DVec3::X * (u * ((self.x[j].y - s.pos[i].y) / ly).round());
            }
            self.vel_buf.push(v);
        }
        self.x_prev.copy_from_slice(&self.x);
        let sweep = self.config.viscosity.as_ref().map(|visc| InnerSweep {
            links: self.model.links(),
            viscosity: visc,
            kbt: self.config.kbt,
            seed: self.config.seed,
            first_key: s.step.wrapping_mul(k as u64),
        });
        let (model, wall) = (&self.model, self.config.wall.as_ref());
        let (ws, energy) = (&mut self.workspace, &mut self.energy);
        let mut force_s = 0.0;
        let result = if inner_forces {
            inner_steps(
                &mut self.x,
                &mut self.vel_buf,
                &mut self.forces,
                &self.vertex_masses,
                k,
                h,
                sweep,
                |x, f| {
                    let t = Instant::now();
                    let r = fast_forces(model, ws.as_mut(), wall, &domain, x, f);
                    force_s += t.elapsed().as_secs_f64();
                    *energy = r?;
                    Ok(())
                },
            )
        } else {
            inner_sweeps(&mut self.x, &mut self.vel_buf, &self.vertex_masses, k, h, sweep);
            Ok(())
        };
        if let Err(e) = result {
            self.fast_ready = false;
            return Err(self.force_error(e, s.step));
        }
        for (j, i) in range.enumerate() {
            let (w, images) = domain.wrap_sheared(self.x[j]);
            s.pos[i] = w;
            s.vel[i] = if u != 0.0 {
                self.vel_buf[j] - DVec3::X * (images as f64 * u)
            } else {
                self.vel_buf[j]
            };
        }
        let total = t0.elapsed().as_secs_f64();
        if self.config.viscosity.is_some() {
            self.timers.membrane_forces_s += force_s;
            self.timers.viscosity_s += total - force_s;
        } else {
            self.timers.membrane_forces_s += total;
        }
        Ok(())
    }

    /// Advances the unwrapped positions to the vertices' new wrapped positions. With
    /// Lees–Edwards boundaries the nearest image carries the x shift of its y period at the
    /// current offset, so a cell straddling the shear plane stays whole.
    fn unwrap(&mut self, s: &StateMut<'_>) {
        std::mem::swap(&mut self.x, &mut self.x_prev);
        let first = self.config.first;
        for (k, (x, xp)) in self.x.iter_mut().zip(self.x_prev.iter()).enumerate() {
            *x = *xp + s.domain.min_image(s.pos[first + k], *xp);
        }
    }

    /// The bounce pass (see the module docs). Returns the number of bounces.
    fn bounce(&mut self, s: &mut StateMut<'_>) -> Result<u64, EngineError> {
        let dt = s.dt;
        let (lo, hi) = bounds(self.x.iter().chain(self.x_prev.iter()));
        let centre = 0.5 * (lo + hi);
        let (inner, outer) = (self.config.inner_type, self.config.outer_type);
        let domain = *s.domain;
        // Lees–Edwards: a particle's image next to the cell moves with v − k U x̂ (k from
        // `min_image_sheared`); the bounce works in the cell's frame (U = 0: no change)
        let shear_u = domain.shear_velocity();
        let framed = |p: DVec3, v: DVec3| {
            let (d, k) = domain.min_image_sheared(p, centre);
            (centre + d, v - DVec3::X * (k as f64 * shear_u))
        };
        let vr = self.vertex_range();
        let near = NearBox::new(&domain, lo, hi);
        // 1. particles whose segment of the step meets the cell's box (most of the box's
        // particles are rejected by `near` without a minimum image)
        self.candidates.clear();
        {
            let (pos, vel, ptype) = (&*s.pos, &*s.vel, s.ptype);
            self.candidates
                .par_extend((0..pos.len() as u32).into_par_iter().with_min_len(4096).filter(|&i| {
                    let i = i as usize;
                    let t = ptype[i];
                    if (t != inner && t != outer) || vr.contains(&i) || !near.may_meet(pos[i], vel[i] * dt) {
                        return false;
                    }
                    let (p1, v) = framed(pos[i], vel[i]);
                    segment_meets_box(p1 - v * dt, p1, lo, hi)
                }));
        }
        if self.candidates.is_empty() {
            return Ok(0);
        }
        // 2. triangles binned by their swept boxes
        let tris = self.model.triangles();
        // cells of ½ (rc = 1 in the scenarios): ~5 triangle boxes per cell at N = 500, against
        // ~20 with cells of 1, for the few cells a step's segment touches
        let grid = Grid::new(lo, hi, 0.5_f64.max((hi - lo).max_element() / 64.0));
        self.grid_start.clear();
        self.grid_start.resize(grid.len() + 1, 0);
        let (x0, x1) = (&self.x_prev, &self.x);
        let swept = |t: &[u32; 3]| {
            let p = [0, 1, 2].map(|k| x0[t[k] as usize]);
            let q = [0, 1, 2].map(|k| x1[t[k] as usize]);
            bounds(p.iter().chain(q.iter()))
        };
        self.tri_boxes.clear();
        self.tri_boxes.extend(tris.iter().map(swept));
        for &(a, b) in &self.tri_boxes {
            let r = grid.range(a, b);
            for k in r[2].0..=r[2].1 {
                for j in r[1].0..=r[1].1 {
                    for i in r[0].0..=r[0].1 {
                        self.grid_start[grid.index(i, j, k) + 1] += 1;
                    }
                }
            }
        }
        for c in 0..grid.len() {
            self.grid_start[c + 1] += self.grid_start[c];
        }
        self.grid_items.clear();
        self.grid_items.resize(self.grid_start[grid.len()] as usize, 0);
        self.grid_fill.clear();
        self.grid_fill.extend_from_slice(&self.grid_start[..grid.len()]);
        let fill = &mut self.grid_fill;
        for (ti, &(a, b)) in self.tri_boxes.iter().enumerate() {
            let r = grid.range(a, b);
            for k in r[2].0..=r[2].1 {
                for j in r[1].0..=r[1].1 {
                    for i in r[0].0..=r[0].1 {
                        let c = grid.index(i, j, k);
                        self.grid_items[fill[c] as usize] = ti as u32;
                        fill[c] += 1;
                    }
                }
            }
        }
        // 3. the earliest crossing of each candidate, in parallel; applied in particle order
        let (start, items, boxes) = (&self.grid_start, &self.grid_items, &self.tri_boxes);
        let (pos, vel, ptype) = (&*s.pos, &*s.vel, s.ptype);
        if self.masses.len() != s.field.ntypes() {
            self.masses = s.field.types().iter().map(|t| t.mass).collect();
        }
        let mass = &self.masses;
        let (reflection, kbt, ids) = (self.config.reflection, self.config.kbt, s.id);
        let key = hemodpd_engine::rng::step_key(self.config.seed ^ MAXWELL_SALT, s.step);
        // triangle `ti` over the step, from the unwrapped vertex positions
        let moving = |ti: u32| {
            let t = &tris[ti as usize];
            MovingTriangle {
                a0: x0[t[0] as usize],
                b0: x0[t[1] as usize],
                c0: x0[t[2] as usize],
                a1: x1[t[0] as usize],
                b1: x1[t[1] as usize],
                c1: x1[t[2] as usize],
            }
        };
        let events: Vec<BounceEvent> = self
            .candidates
            .par_iter()
            .with_min_len(64)
            .filter_map(|&i| {
                let iu = i as usize;
                let (p1, v) = framed(pos[iu], vel[iu]);
                let p0 = p1 - v * dt;
                let (plo, phi) = (p0.min(p1), p0.max(p1));
                let r = grid.range(plo, phi);
                let mut best: Option<(f64, u32)> = None;
                for k in r[2].0..=r[2].1 {
                    for j in r[1].0..=r[1].1 {
                        for ii in r[0].0..=r[0].1 {
                            let c = grid.index(ii, j, k);
                            for &ti in &items[start[c] as usize..start[c + 1] as usize] {
                                if best.is_some_and(|b| b.1 == ti) {
                                    continue;
                                }
                                // the segment's box must meet the triangle's swept box (a
                                // crossing point lies in both); most pairs end here
                                let (blo, bhi) = boxes[ti as usize];
                                if plo.cmpgt(bhi).any() || phi.cmplt(blo).any() {
                                    continue;
                                }
                                if let Some(cr) = mesh_bounce::crossing(p0, p1, &moving(ti)) {
                                    if best.is_none_or(|b| cr.t < b.0) {
                                        best = Some((cr.t, ti));
                                    }
                                }
                            }
                        }
                    }
                }
                let (_, ti) = best?;
                let mt = moving(ti);
                let m = mass[ptype[iu] as usize];
                let b = mesh_bounce::bounce(p0, v, m, dt, &mt)?;
                // Not advanced for the rest of the step (a reflected path may meet a neighbouring
                // triangle where the membrane is concave): put at the hit point's place on the
                // end-of-step triangle, just off it on the side it came from.
                let w = b.crossing.weights;
                let end = [mt.a1, mt.b1, mt.c1];
                let n1 = (end[1] - end[0]).cross(end[2] - end[0]);
                if n1.length_squared() == 0.0 {
                    return Some(BounceEvent {
                        particle: i,
                        triangle: ti,
                        position: b.position,
                        velocity: b.velocity,
                        vertex_impulse: b.vertex_impulse,
                    });
                }
                let n_hat = n1.normalize() * b.crossing.side;
                let scale = (end[1] - end[0]).length().max((end[2] - end[0]).length());
                let position = end[0] * w[0] + end[1] * w[1] + end[2] * w[2] + n_hat * (PLACEMENT_OFFSET * scale);
                let (velocity, vertex_impulse) = match reflection {
                    MembraneReflection::BounceBack => (b.velocity, b.vertex_impulse),
                    MembraneReflection::Maxwell => {
                        let u_w = (b.velocity + v) * 0.5; // bounce-back's v_new = 2u_w − v
                        let c = maxwell_velocity(key, ids[iu], n_hat, (kbt / m).sqrt());
                        let v_new = u_w + c;
                        let j = (v - v_new) * m;
                        (v_new, [j * w[0], j * w[1], j * w[2]])
                    }
                };
                Some(BounceEvent {
                    particle: i,
                    triangle: ti,
                    position,
                    velocity,
                    vertex_impulse,
                })
            })
            .collect();
        let first = self.config.first;
        for e in &events {
            let i = e.particle as usize;
            let (w, k) = domain.wrap_sheared(e.position);
            s.pos[i] = w;
            s.vel[i] = e.velocity - DVec3::X * (k as f64 * shear_u);
            let t = tris[e.triangle as usize];
            for k in 0..3 {
                let vi = first + t[k] as usize;
                let m = mass[s.ptype[vi] as usize];
                s.vel[vi] += e.vertex_impulse[k] / m;
            }
        }
        Ok(events.len() as u64)
    }
}

impl Extension for Cell {
    fn after_position_update(&mut self, s: &mut StateMut<'_>) -> Result<(), EngineError> {
        self.check_types(s)?;
        if self.config.substeps > 1 {
            self.substep(s)?;
        }
        let t0 = Instant::now();
        if self.config.substeps == 1 {
            self.unwrap(s);
        }
        let n = self.bounce(s)?;
        self.stats.bounces += n;
        self.timers.bounce_s += t0.elapsed().as_secs_f64();
        Ok(())
    }

    fn add_forces(&mut self, s: &mut StateMut<'_>) -> Result<(), EngineError> {
        self.check_types(s)?;
        if self.inner_forces() {
            // the membrane forces and the wall repulsion are inner forces; only the external
            // ones join the slow force (the first call, at the initial force evaluation,
            // computes the fast forces for the first step)
            self.ensure_fast_forces(s)?;
            let first = self.config.first;
            for &(k, f) in &self.external {
                s.force[first + k as usize] += f;
            }
            return Ok(());
        }
        let t0 = Instant::now();
        self.forces.iter_mut().for_each(|f| *f = DVec3::ZERO);
        let result = match self.workspace.as_mut() {
            Some(ws) => self.model.add_forces_parallel(&self.x, &mut self.forces, ws),
            None => self.model.add_forces(&self.x, &mut self.forces),
        };
        self.energy = result.map_err(|e| self.force_error(e, s.step))?;
        let first = self.config.first;
        for (k, f) in self.forces.iter().enumerate() {
            s.force[first + k] += *f;
        }
        for &(k, f) in &self.external {
            s.force[first + k as usize] += f;
        }
        if let Some(w) = self.config.wall {
            for k in 0..self.x.len() {
                s.force[first + k] += w.force(s.pos[first + k]);
            }
        }
        self.timers.membrane_forces_s += t0.elapsed().as_secs_f64();
        Ok(())
    }

    fn end_of_step(&mut self, s: &mut StateMut<'_>) -> Result<(), EngineError> {
        if self.config.substeps > 1 {
            // the second slow half-kick, with the pair forces of the new positions
            self.load_vertex_masses(s);
            let h = 0.5 * s.dt;
            for (j, i) in self.vertex_range().enumerate() {
                s.vel[i] += s.force[i] * (h / self.vertex_masses[j]);
            }
        } else if let Some(visc) = self.config.viscosity {
            let t0 = Instant::now();
            let range = self.vertex_range();
            self.load_vertex_masses(s);
            // Lees–Edwards: a vertex whose wrapped image is k periods below its unwrapped
            // position moves, in the cell's frame, k U faster along x; the sweep works there
            let (u, ly) = (s.domain.shear_velocity(), s.domain.lengths().y);
            let shift = |k: usize, x: &[DVec3], pos: &[DVec3]| DVec3::X * (u * ((x[k].y - pos[k].y) / ly).round());
            if u != 0.0 {
                for (k, v) in s.vel[range.clone()].iter_mut().enumerate() {
                    *v += shift(k, &self.x, &s.pos[range.clone()]);
                }
            }
            shardlow_sweep(
                self.model.links(),
                &self.x,
                &mut s.vel[range.clone()],
                &self.vertex_masses,
                &visc,
                self.config.kbt,
                s.dt,
                self.config.seed,
                s.step,
            );
            if u != 0.0 {
                for (k, v) in s.vel[range.clone()].iter_mut().enumerate() {
                    *v -= shift(k, &self.x, &s.pos[range.clone()]);
                }
            }
            self.timers.viscosity_s += t0.elapsed().as_secs_f64();
        }
        let every = self.config.check_every;
        if every > 0 && s.step.is_multiple_of(every) {
            let t0 = Instant::now();
            let (tested, wrong) = self.count_misplaced(s.pos, s.ptype, s.domain);
            self.stats.checks += 1;
            self.stats.misplaced += wrong;
            self.stats.misplaced_last = wrong;
            self.stats.checked_last = tested;
            self.timers.checks_s += t0.elapsed().as_secs_f64();
        }
        Ok(())
    }
}

/// A dry run of the membrane alone (no fluid, no damping but the membrane viscosity): the
/// vertices start at `rest` with thermal velocities of `kbt`/`mass` (a fixed stream, so the
/// answer is reproducible) and are integrated by velocity Verlet for `steps` steps of `dt`,
/// each followed by the Shardlow sweep of `viscosity` when there is one (as in the run). Returns the step at which it failed
/// (a force error such as a link reaching Lmax, or the kinetic energy growing 100-fold), or
/// `None` if it stayed stable. Velocity Verlet is stable for dt·ω_max < 2, so a failure here
/// means the time step cannot resolve the membrane's stiffest mode, whatever the fluid adds.
pub fn dry_run(
    model: &MembraneModel,
    rest: &[DVec3],
    dt: f64,
    kbt: f64,
    mass: f64,
    viscosity: Option<&MembraneViscosity>,
    steps: u64,
) -> Option<u64> {
    let n = rest.len();
    let mut x = rest.to_vec();
    let mut v = vec![DVec3::ZERO; n];
    let sd = (kbt / mass).sqrt();
    let mut z = 0x2545_f491_4f6c_dd1du64;
    let mut gauss = || {
        let mut u = || {
            z = hemodpd_engine::rng::mix64(z.wrapping_add(0x9E37_79B9_7F4A_7C15));
            ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (a, b) = (u(), u());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    };
    for vi in v.iter_mut() {
        *vi = DVec3::new(gauss(), gauss(), gauss()) * sd;
    }
    let mean = v.iter().fold(DVec3::ZERO, |a, b| a + *b) / n.max(1) as f64;
    v.iter_mut().for_each(|vi| *vi -= mean);
    let kinetic = |v: &[DVec3]| v.iter().map(|u| u.length_squared()).sum::<f64>();
    let k0 = kinetic(&v).max(1e-300);
    let mut f = vec![DVec3::ZERO; n];
    if model.add_forces(&x, &mut f).is_err() {
        return Some(0);
    }
    let h = 0.5 * dt / mass;
    let masses = vec![mass; n];
    for step in 1..=steps {
        for k in 0..n {
            v[k] += f[k] * h;
            x[k] += v[k] * dt;
        }
        f.iter_mut().for_each(|fk| *fk = DVec3::ZERO);
        if model.add_forces(&x, &mut f).is_err() {
            return Some(step);
        }
        for k in 0..n {
            v[k] += f[k] * h;
        }
        if let Some(visc) = viscosity {
            shardlow_sweep(model.links(), &x, &mut v, &masses, visc, kbt, dt, DRY_RUN_SEED, step);
        }
        let k = kinetic(&v);
        if !k.is_finite() || k > 100.0 * k0 {
            return Some(step);
        }
    }
    None
}

#[cfg(test)]
mod tests;
