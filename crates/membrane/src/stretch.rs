//! Optical-tweezers stretching at static equilibrium (SPEC §2, Fig. 1 of the paper).
//!
//! The cell rests with its large diameter in the xz plane. The 5 % of vertices with the largest
//! x at rest carry +F/(0.05 N) each along x, the 5 % with the smallest x carry −F/(0.05 N).
//! For each force the equilibrium shape minimises `F_membrane(x) − Σ f_ext · x`, found by
//! L-BFGS from the previous equilibria (continuation with a linear predictor in the force,
//! see [`stretch_from`]). Converged when the largest
//! net force on any vertex is below `tolerance` (in the caller's force unit).
//! D_A = max x − min x, D_T = 2 max √(y² + z²).

use crate::forces::{EnergyTerms, ForceError, MembraneModel};
use crate::mesh::{area_of, volume_of};
use crate::precondition::Preconditioner;
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
    /// The solver's initial inverse Hessian.
    pub preconditioning: Preconditioning,
}

/// The stretching solver's initial inverse Hessian (the L-BFGS "H0").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Preconditioning {
    /// P⁻¹, P the sparse Gauss–Newton Hessian of the membrane plus the global area and volume
    /// terms ([`Preconditioner`]), factorised once per force: 15–80× fewer iterations
    /// (docs/performance.md, "Membrane stretching"); the factor takes ~120 MB at N = 23867.
    #[default]
    GaussNewton,
    /// γ I, γ = s·y / y·y (plain L-BFGS): no factorisation, O(N) memory, iterations ∝ N^0.85.
    None,
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
    /// Whether the solver used the Gauss–Newton preconditioner at this force.
    #[serde(default)]
    pub preconditioned: bool,
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
    stretch_from(model, rest, &[], opts, || false, observer)
}

/// An equilibrium already reached, to continue from: its force and its shape.
#[derive(Clone, Copy, Debug)]
pub struct Equilibrium<'a> {
    pub force: f64,
    pub positions: &'a [DVec3],
}

/// The start of the solver at `force`: the last equilibrium, or the straight line through the
/// last two extrapolated to `force` (a predictor in the force).
fn predict(before: &[Equilibrium], force: f64, out: &mut [DVec3]) -> bool {
    let [.., a, b] = before else {
        return false;
    };
    let span = b.force - a.force;
    if span <= 0.0 || !span.is_finite() {
        return false;
    }
    let w = (force - b.force) / span;
    for ((o, xa), xb) in out.iter_mut().zip(a.positions).zip(b.positions) {
        *o = *xb + (*xb - *xa) * w;
    }
    true
}

/// Like [`stretch`], but continuing from `before`: the last one or two equilibria reached
/// (oldest first; empty to start from `rest`), and polling `stop` once per solver iteration.
/// When `stop` returns true the force in progress is abandoned and the equilibria reached so far
/// are returned (fewer than `opts.forces`). Each force starts from the line through the last two
/// equilibria extrapolated to it (or from the last equilibrium when only one is known, or when
/// the extrapolated shape has the higher energy or is invalid). The loaded vertices and the
/// solver's first step come from `rest`, and the solver's memory starts empty at every force, so
/// a run split into parts, each given the last two equilibria, gives the same equilibria, bit
/// for bit, as one run. Forces are evaluated in parallel ([`MembraneModel::add_forces_parallel`]):
/// the result does not depend on the number of threads.
pub fn stretch_from(
    model: &MembraneModel,
    rest: &[DVec3],
    before: &[Equilibrium],
    opts: &StretchOptions,
    stop: impl Fn() -> bool,
    mut observer: impl FnMut(&StretchPoint),
) -> Result<Vec<StretchPoint>, StretchError> {
    if !(opts.end_fraction > 0.0 && opts.end_fraction < 0.5) {
        return Err(StretchError::BadFraction(opts.end_fraction));
    }
    if let Some(e) = before.iter().find(|e| e.positions.len() != rest.len()) {
        return Err(StretchError::StartLength {
            start: e.positions.len(),
            rest: rest.len(),
        });
    }
    let (high, low) = loaded_vertices(rest, opts.end_fraction);
    // the last two equilibria (oldest first), owned
    let mut history: Vec<(f64, Vec<DVec3>)> = before
        .iter()
        .rev()
        .take(2)
        .rev()
        .map(|e| (e.force, e.positions.to_vec()))
        .collect();
    let mut x = history.last().map_or_else(|| rest.to_vec(), |h| h.1.clone());
    let mut x_pred = vec![DVec3::ZERO; rest.len()];
    let mut out = Vec::with_capacity(opts.forces.len());
    let (d0, _) = diameters(rest);
    // the first step of a fresh L-BFGS memory moves no vertex more than 1e-4 cell diameters
    let mut solver = Lbfgs::new(rest.len(), 10, 1e-4 * d0);
    if opts.preconditioning == Preconditioning::GaussNewton {
        // a failure here (it should not happen) leaves the plain L-BFGS, and the points say so
        solver.precondition = Preconditioner::new(model).ok();
    }
    let mut ws = model.workspace();
    let mut ext = vec![DVec3::ZERO; rest.len()];
    for &force in &opts.forces {
        if stop() {
            // also between forces: a force already in equilibrium takes no solver iteration
            return Ok(out);
        }
        let per_vertex = force / high.len() as f64;
        ext.iter_mut().for_each(|e| *e = DVec3::ZERO);
        for &i in &high {
            ext[i].x += per_vertex;
        }
        for &i in &low {
            ext[i].x -= per_vertex;
        }
        let ext = &ext;
        let mut objective = |x: &[DVec3], g: &mut [DVec3]| -> Result<f64, ForceError> {
            g.iter_mut().zip(ext).for_each(|(gi, e)| *gi = *e);
            let e = model.add_forces_parallel(x, g, &mut ws)?;
            let work: f64 = x.iter().zip(ext).map(|(xi, ei)| xi.dot(*ei)).sum();
            // gradient = −(membrane force + external force)
            g.iter_mut().for_each(|gi| *gi = -*gi);
            Ok(e.total() - work)
        };
        let views: Vec<Equilibrium> = history
            .iter()
            .map(|(f, p)| Equilibrium {
                force: *f,
                positions: p,
            })
            .collect();
        if predict(&views, force, &mut x_pred) {
            // keep the prediction only where it lowers the energy (the gradient is recomputed)
            let g = &mut solver.g;
            let e_last = objective(&x, g).map_err(|source| StretchError::Force { force, source })?;
            if let Ok(e_pred) = objective(&x_pred, g) {
                if e_pred < e_last {
                    x.copy_from_slice(&x_pred);
                }
            }
        }
        // P from the start shape, once per force; if it cannot be built there (a link at its
        // limit, say) this force runs unpreconditioned
        let preconditioned = solver
            .precondition
            .as_mut()
            .is_some_and(|p| p.update(model, &x).is_ok());
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
            preconditioned,
            positions: x.clone(),
        };
        observer(&point);
        out.push(point);
        if history.len() == 2 {
            let (_, mut oldest) = history.remove(0);
            oldest.copy_from_slice(&x);
            history.push((force, oldest));
        } else {
            history.push((force, x.clone()));
        }
    }
    Ok(out)
}

/// Limited-memory BFGS with a backtracking (Armijo) line search, on vectors of `DVec3`.
/// A trial step that overstretches a link (the WLC energy is infinite there) is shortened.
struct Lbfgs {
    memory: usize,
    /// The (s, y) pairs, oldest first, with ρ = 1/(s·y) and y·y.
    pairs: VecDeque<Pair>,
    g: Vec<DVec3>,
    g_new: Vec<DVec3>,
    d: Vec<DVec3>,
    x_new: Vec<DVec3>,
    first_step: f64,
    /// Dropped pairs, reused: no allocation per iteration.
    spare: Vec<Pair>,
    alphas: Vec<f64>,
    /// P⁻¹ as the initial inverse Hessian (instead of γ I) when present and factorised.
    precondition: Option<Preconditioner>,
}

struct Pair {
    s: Vec<DVec3>,
    y: Vec<DVec3>,
    rho: f64,
    yy: f64,
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
            pairs: VecDeque::new(),
            g: z.clone(),
            g_new: z.clone(),
            d: z.clone(),
            x_new: z,
            first_step,
            spare: Vec::new(),
            alphas: Vec::new(),
            precondition: None,
        }
    }

    fn preconditioned(&self) -> bool {
        self.precondition.as_ref().is_some_and(|p| p.is_factored())
    }

    /// Empties the memory (its buffers go to `spare`).
    fn forget(&mut self) {
        self.spare.extend(self.pairs.drain(..));
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
        self.forget();
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
                self.forget();
                self.direction();
                gd = dot(&self.g, &self.d);
            }
            // first step of a fresh memory: limit the largest move
            let mut alpha = if self.pairs.is_empty() && !self.preconditioned() {
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
                        self.remember(alpha);
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
                self.forget();
                if stalls > 5 {
                    return Ok(Some((it, max_norm(&self.g))));
                }
            } else {
                stalls = 0;
            }
        }
        Ok(Some((max_iter, max_norm(&self.g))))
    }

    /// Stores the pair s = alpha d, y = g_new − g if s·y > 0 (dropping the oldest when full).
    fn remember(&mut self, alpha: f64) {
        let n = self.g.len();
        let mut p = self.spare.pop().unwrap_or_else(|| Pair {
            s: vec![DVec3::ZERO; n],
            y: vec![DVec3::ZERO; n],
            rho: 0.0,
            yy: 0.0,
        });
        let (mut sy, mut yy) = (0.0, 0.0);
        for (((s, y), d), (gn, g)) in
            p.s.iter_mut()
                .zip(&mut p.y)
                .zip(&self.d)
                .zip(self.g_new.iter().zip(&self.g))
        {
            *s = *d * alpha;
            *y = *gn - *g;
            sy += s.dot(*y);
            yy += y.dot(*y);
        }
        if sy > 1e-300 {
            (p.rho, p.yy) = (1.0 / sy, yy);
            if self.pairs.len() == self.memory {
                self.spare.extend(self.pairs.pop_front());
            }
            self.pairs.push_back(p);
        } else {
            self.spare.push(p);
        }
    }

    /// Two-loop recursion: d = −H g. Each pass over the vectors also computes the dot product
    /// the next step needs.
    fn direction(&mut self) {
        let k = self.pairs.len();
        let d = &mut self.d;
        if k == 0 {
            d.iter_mut().zip(&self.g).for_each(|(d, g)| *d = -*g);
            if let Some(p) = &mut self.precondition {
                p.apply(d);
            }
            return;
        }
        let alphas = &mut self.alphas;
        alphas.clear();
        alphas.resize(k, 0.0);
        d.copy_from_slice(&self.g);
        // newest to oldest: α_i = ρ_i s_i·d, d −= α_i y_i
        let mut sd = dot(&self.pairs[k - 1].s, d);
        for i in (0..k).rev() {
            let a = self.pairs[i].rho * sd;
            alphas[i] = a;
            let y = &self.pairs[i].y;
            sd = 0.0;
            if i > 0 {
                for ((dj, yj), sj) in d.iter_mut().zip(y).zip(&self.pairs[i - 1].s) {
                    *dj -= *yj * a;
                    sd += sj.dot(*dj);
                }
            } else {
                d.iter_mut().zip(y).for_each(|(dj, yj)| *dj -= *yj * a);
            }
        }
        // initial inverse Hessian P⁻¹, or γ I with γ = s·y / y·y of the newest pair
        // (the γ pass also computes the dot product the next pass needs)
        let mut yd = 0.0;
        if self.precondition.as_mut().is_some_and(|p| p.apply(d)) {
            yd = dot(&self.pairs[0].y, d);
        } else {
            let last = &self.pairs[k - 1];
            let gamma = 1.0 / (last.rho * last.yy);
            for (dj, yj) in d.iter_mut().zip(&self.pairs[0].y) {
                *dj *= gamma;
                yd += yj.dot(*dj);
            }
        }
        // oldest to newest: β = ρ_i y_i·d, d += (α_i − β) s_i; the last pass also negates d
        for i in 0..k {
            let c = alphas[i] - self.pairs[i].rho * yd;
            let s = &self.pairs[i].s;
            yd = 0.0;
            if i + 1 < k {
                for ((dj, sj), yj) in d.iter_mut().zip(s).zip(&self.pairs[i + 1].y) {
                    *dj += *sj * c;
                    yd += yj.dot(*dj);
                }
            } else {
                d.iter_mut().zip(s).for_each(|(dj, sj)| *dj = -(*dj + *sj * c));
            }
        }
    }
}
