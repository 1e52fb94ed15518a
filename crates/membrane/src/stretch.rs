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
use crate::lbfgs::Lbfgs;
use crate::mesh::{area_of, volume_of};
use crate::precondition::Preconditioner;
use glam::DVec3;

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
