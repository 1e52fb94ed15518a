//! Optical-tweezers stretching at static equilibrium (SPEC §2, Fig. 1 of the paper).
//!
//! The cell rests with its large diameter in the xz plane. The 5 % of vertices with the largest
//! x at rest carry +F/(0.05 N) each along x, the 5 % with the smallest x carry −F/(0.05 N).
//! For each force the equilibrium shape minimises `F_membrane(x) − Σ f_ext · x`, found by
//! L-BFGS from the previous force's equilibrium (continuation). Converged when the largest
//! net force on any vertex is below `tolerance` (in the caller's force unit).
//! D_A = max x − min x, D_T = 2 max √(y² + z²).

use crate::forces::{EnergyTerms, ForceError, MembraneModel};
use crate::mesh::{area_of, volume_of};
use glam::DVec3;
use std::collections::VecDeque;

/// Options of the stretching solver (forces and tolerance in the caller's force unit).
#[derive(Clone, Debug)]
pub struct StretchOptions {
    /// Total stretching forces, in increasing order (continuation).
    pub forces: Vec<f64>,
    /// Fraction of vertices loaded at each end (the paper: 0.05).
    pub end_fraction: f64,
    /// Converged when max_n |f_n| < tolerance.
    pub tolerance: f64,
    /// Iteration cap per force; reaching it is an error (not a silent result).
    pub max_iterations: usize,
}

/// Equilibrium at one force.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StretchPoint {
    pub force: f64,
    pub axial_diameter: f64,
    pub transverse_diameter: f64,
    pub iterations: usize,
    /// Largest net vertex force at the end.
    pub residual: f64,
    /// (A − A0)/A0 and (V − V0)/V0.
    pub area_deviation: f64,
    pub volume_deviation: f64,
    pub energy: EnergyTerms,
    /// Vertex positions at equilibrium (not serialised).
    #[serde(skip)]
    pub positions: Vec<DVec3>,
}

/// Errors of the stretching solver.
#[derive(Debug, thiserror::Error)]
pub enum StretchError {
    #[error("end_fraction = {0} must be in (0, 0.5)")]
    BadFraction(f64),
    #[error("force {force} did not converge in {iterations} iterations (largest residual force {residual:.3e}, tolerance {tolerance:.1e}); raise max_iterations or the tolerance")]
    NotConverged {
        force: f64,
        iterations: usize,
        residual: f64,
        tolerance: f64,
    },
    #[error("at force {force}: {source}")]
    Force { force: f64, source: ForceError },
    #[error("the start shape has {start} vertices, the rest shape {rest}")]
    StartLength { start: usize, rest: usize },
}

/// Indices of the loaded vertices: (the `fraction` with the largest x, the `fraction` with the smallest x).
pub fn loaded_vertices(rest: &[DVec3], fraction: f64) -> (Vec<usize>, Vec<usize>) {
    let n = rest.len();
    let count = ((fraction * n as f64).round() as usize).max(1);
    let mut idx: Vec<usize> = (0..n).collect();
    // total order with index tie-break: deterministic
    idx.sort_by(|&a, &b| rest[a].x.total_cmp(&rest[b].x).then(a.cmp(&b)));
    let low = idx[..count].to_vec();
    let high = idx[n - count..].to_vec();
    (high, low)
}

/// Axial and transverse diameters of a shape stretched along x.
pub fn diameters(x: &[DVec3]) -> (f64, f64) {
    let (mut lo, mut hi, mut rmax) = (f64::MAX, f64::MIN, 0.0f64);
    for p in x {
        lo = lo.min(p.x);
        hi = hi.max(p.x);
        rmax = rmax.max((p.y * p.y + p.z * p.z).sqrt());
    }
    (hi - lo, 2.0 * rmax)
}

/// Runs the stretching protocol from the resting positions `rest`. `observer` sees each
/// equilibrium as it is reached (to write shapes as the run goes).
pub fn stretch(
    model: &MembraneModel,
    rest: &[DVec3],
    opts: &StretchOptions,
    observer: impl FnMut(&StretchPoint),
) -> Result<Vec<StretchPoint>, StretchError> {
    stretch_from(model, rest, rest, opts, || false, observer)
}

/// Like [`stretch`], but starting from `start` (the rest shape, or the equilibrium of the force
/// before `opts.forces[0]` when a run continues) and polling `stop` once per solver iteration.
/// When `stop` returns true the force in progress is abandoned and the equilibria reached so far
/// are returned (fewer than `opts.forces`). The loaded vertices and the solver's first step come
/// from `rest`, and the solver's memory starts empty at every force, so a run split into parts
/// gives the same equilibria, bit for bit, as one run.
pub fn stretch_from(
    model: &MembraneModel,
    rest: &[DVec3],
    start: &[DVec3],
    opts: &StretchOptions,
    stop: impl Fn() -> bool,
    mut observer: impl FnMut(&StretchPoint),
) -> Result<Vec<StretchPoint>, StretchError> {
    if !(opts.end_fraction > 0.0 && opts.end_fraction < 0.5) {
        return Err(StretchError::BadFraction(opts.end_fraction));
    }
    if start.len() != rest.len() {
        return Err(StretchError::StartLength {
            start: start.len(),
            rest: rest.len(),
        });
    }
    let (high, low) = loaded_vertices(rest, opts.end_fraction);
    let mut x = start.to_vec();
    let mut out = Vec::with_capacity(opts.forces.len());
    let (d0, _) = diameters(rest);
    // the first step of a fresh L-BFGS memory moves no vertex more than 1e-4 cell diameters
    let mut solver = Lbfgs::new(rest.len(), 10, 1e-4 * d0);
    for &force in &opts.forces {
        if stop() {
            // also between forces: a force already in equilibrium takes no solver iteration
            return Ok(out);
        }
        let per_vertex = force / high.len() as f64;
        let mut ext = vec![DVec3::ZERO; rest.len()];
        for &i in &high {
            ext[i].x += per_vertex;
        }
        for &i in &low {
            ext[i].x -= per_vertex;
        }
        let objective = |x: &[DVec3], g: &mut [DVec3]| -> Result<f64, ForceError> {
            g.iter_mut().zip(&ext).for_each(|(gi, e)| *gi = *e);
            let e = model.add_forces(x, g)?;
            let work: f64 = x.iter().zip(&ext).map(|(xi, ei)| xi.dot(*ei)).sum();
            // gradient = −(membrane force + external force)
            g.iter_mut().for_each(|gi| *gi = -*gi);
            Ok(e.total() - work)
        };
        let Some((iterations, residual)) = solver
            .minimize(&mut x, objective, opts.tolerance, opts.max_iterations, &stop)
            .map_err(|source| StretchError::Force { force, source })?
        else {
            return Ok(out);
        };
        if residual >= opts.tolerance {
            return Err(StretchError::NotConverged {
                force,
                iterations,
                residual,
                tolerance: opts.tolerance,
            });
        }
        let (da, dt) = diameters(&x);
        let energy = model
            .energy(&x)
            .map_err(|source| StretchError::Force { force, source })?;
        let (a, v) = (area_of(&x, model.triangles()), volume_of(&x, model.triangles()));
        let point = StretchPoint {
            force,
            axial_diameter: da,
            transverse_diameter: dt,
            iterations,
            residual,
            area_deviation: a / model.area0() - 1.0,
            volume_deviation: v / model.volume0() - 1.0,
            energy,
            positions: x.clone(),
        };
        observer(&point);
        out.push(point);
    }
    Ok(out)
}

/// Limited-memory BFGS with a backtracking (Armijo) line search, on vectors of `DVec3`.
/// A trial step that overstretches a link (the WLC energy is infinite there) is shortened.
struct Lbfgs {
    memory: usize,
    s: VecDeque<Vec<DVec3>>,
    y: VecDeque<Vec<DVec3>>,
    g: Vec<DVec3>,
    g_new: Vec<DVec3>,
    d: Vec<DVec3>,
    x_new: Vec<DVec3>,
    first_step: f64,
}

fn dot(a: &[DVec3], b: &[DVec3]) -> f64 {
    a.iter().zip(b).map(|(p, q)| p.dot(*q)).sum()
}

fn max_norm(a: &[DVec3]) -> f64 {
    a.iter().map(|v| v.length()).fold(0.0, f64::max)
}

impl Lbfgs {
    fn new(n: usize, memory: usize, first_step: f64) -> Self {
        let z = vec![DVec3::ZERO; n];
        Self {
            memory,
            s: VecDeque::new(),
            y: VecDeque::new(),
            g: z.clone(),
            g_new: z.clone(),
            d: z.clone(),
            x_new: z,
            first_step,
        }
    }

    /// Minimises from `x` until max |g| < tol. Returns (iterations, final max |g|), or None
    /// when `stop` returned true (checked once per iteration; `x` is then partly relaxed).
    fn minimize(
        &mut self,
        x: &mut [DVec3],
        mut f: impl FnMut(&[DVec3], &mut [DVec3]) -> Result<f64, ForceError>,
        tol: f64,
        max_iter: usize,
        stop: &impl Fn() -> bool,
    ) -> Result<Option<(usize, f64)>, ForceError> {
        self.s.clear();
        self.y.clear();
        let mut e = f(x, &mut self.g)?;
        let mut stalls = 0;
        for it in 0..max_iter {
            let gmax = max_norm(&self.g);
            if gmax < tol {
                return Ok(Some((it, gmax)));
            }
            if stop() {
                return Ok(None);
            }
            self.direction();
            let mut gd = dot(&self.g, &self.d);
            if gd >= 0.0 {
                // not a descent direction: restart with steepest descent
                self.s.clear();
                self.y.clear();
                self.direction();
                gd = dot(&self.g, &self.d);
            }
            // first step of a fresh memory: limit the largest move
            let mut alpha = if self.s.is_empty() {
                (self.first_step / max_norm(&self.d).max(1e-300)).min(1.0)
            } else {
                1.0
            };
            let mut accepted = false;
            for _ in 0..60 {
                for ((xn, xi), di) in self.x_new.iter_mut().zip(x.iter()).zip(&self.d) {
                    *xn = *xi + *di * alpha;
                }
                match f(&self.x_new, &mut self.g_new) {
                    Ok(e_new)
                        if e_new <= e + 1e-4 * alpha * gd
                            || (e_new - e).abs() <= 1e-14 * e.abs().max(1.0)
                                && dot(&self.g_new, &self.d) < 0.9 * gd.abs() =>
                    {
                        let s: Vec<DVec3> = self.d.iter().map(|d| *d * alpha).collect();
                        let y: Vec<DVec3> = self.g_new.iter().zip(&self.g).map(|(a, b)| *a - *b).collect();
                        if dot(&s, &y) > 1e-300 {
                            if self.s.len() == self.memory {
                                self.s.pop_front();
                                self.y.pop_front();
                            }
                            self.s.push_back(s);
                            self.y.push_back(y);
                        }
                        x.copy_from_slice(&self.x_new);
                        std::mem::swap(&mut self.g, &mut self.g_new);
                        e = e_new;
                        accepted = true;
                        break;
                    }
                    Ok(_) | Err(ForceError::LinkOverstretched { .. }) => alpha *= 0.5,
                    Err(other) => return Err(other),
                }
            }
            if !accepted {
                // line search failed (round-off floor): restart the memory, try again a few times
                stalls += 1;
                self.s.clear();
                self.y.clear();
                if stalls > 5 {
                    return Ok(Some((it, max_norm(&self.g))));
                }
            } else {
                stalls = 0;
            }
        }
        Ok(Some((max_iter, max_norm(&self.g))))
    }

    /// Two-loop recursion: d = −H g.
    fn direction(&mut self) {
        self.d.copy_from_slice(&self.g);
        let k = self.s.len();
        let mut alphas = vec![0.0; k];
        for i in (0..k).rev() {
            let rho = 1.0 / dot(&self.y[i], &self.s[i]);
            alphas[i] = rho * dot(&self.s[i], &self.d);
            for (d, y) in self.d.iter_mut().zip(&self.y[i]) {
                *d -= *y * alphas[i];
            }
        }
        if k > 0 {
            let gamma = dot(&self.s[k - 1], &self.y[k - 1]) / dot(&self.y[k - 1], &self.y[k - 1]);
            self.d.iter_mut().for_each(|d| *d *= gamma);
        }
        for i in 0..k {
            let rho = 1.0 / dot(&self.y[i], &self.s[i]);
            let beta = rho * dot(&self.y[i], &self.d);
            for (d, s) in self.d.iter_mut().zip(&self.s[i]) {
                *d += *s * (alphas[i] - beta);
            }
        }
        self.d.iter_mut().for_each(|d| *d = -*d);
    }
}
