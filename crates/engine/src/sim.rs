//! The stepper: Groot–Warren modified velocity-Verlet with extension hooks.
//!
//! One step (n → n + 1), with λ from [`SimConfig::lambda`]:
//! 1. v ← v + ½Δt f/m; x ← x + Δt v (mobile types only: not frozen, not
//!    [`crate::TypeSpec::integrated_by_extension`]); wrap into the box; stability check.
//! 2. [`Extension::after_position_update`] (bounce-back goes here).
//! 3. Predicted velocity ṽ = v + (λ − ½)Δt f/m (= v_old + λΔt f/m); pair forces f(x, ṽ) with the
//!    noise of force evaluation n + 1; + body forces; [`Extension::add_forces`].
//! 4. v ← v + ½Δt f/m; stability check; step counter n + 1; [`Extension::end_of_step`].
//!
//! The forces of the last evaluation are kept in [`Particles::force`]; they are part of the
//! checkpoint ([`SimState`]) so that a restart continues bit-identically.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use glam::{DMat3, DVec3};
use rayon::prelude::*;

use crate::cells::{CellGrid, CellList, AHEAD, MIN_LEN};
use crate::error::{CAUSE_DT, CAUSE_FAST};
use crate::kernel::DpdTable;
use crate::rng::step_key;
use crate::shared;
use crate::{pairs, EngineError, ForceField, Particles, PeriodicBox, Real, SimConfig, SimState, StateMut};

/// Hooks called by [`Simulation::step`]. Every method has a do-nothing default, and `()`
/// implements the trait, so a plain fluid pays nothing (the calls are statically dispatched and
/// inlined away). Walls (bounce-back, adaptive wall force), membranes (vertex forces, bounce-back
/// on triangles) and position-dependent driving forces are written as extensions.
pub trait Extension {
    /// After the drift: positions at t + Δt (wrapped into the box), velocities half-kicked
    /// (v + ½Δt f/m). Reflect particles at walls/membranes here. Keep positions inside the box.
    fn after_position_update(&mut self, _state: &mut StateMut<'_>) -> Result<(), EngineError> {
        Ok(())
    }

    /// After the pair and body forces of the new positions: add forces to `state.force`.
    fn add_forces(&mut self, _state: &mut StateMut<'_>) -> Result<(), EngineError> {
        Ok(())
    }

    /// After the final half-kick: positions and velocities at t + Δt. Sample, control.
    fn end_of_step(&mut self, _state: &mut StateMut<'_>) -> Result<(), EngineError> {
        Ok(())
    }

    /// Whether the engine may reorder the particles in storage ([`SimConfig::sort_every`]).
    /// False by default: an extension that refers to particles by storage index (a membrane's
    /// vertex range, per-particle state) must not see them move.
    fn allows_reordering(&self) -> bool {
        false
    }

    /// Whether [`Extension::add_forces`] may change anything. True by default; an extension
    /// that says false is not called there, and the engine then does the second half-kick in
    /// the same pass as the forces' return to storage order (one pass over the particles less).
    fn adds_forces(&self) -> bool {
        true
    }
}

impl Extension for () {
    fn allows_reordering(&self) -> bool {
        true
    }

    fn adds_forces(&self) -> bool {
        false
    }
}

/// Two extensions composed: each hook runs the first, then the second (walls, then a membrane;
/// nest pairs for more: `(Walls, (Cell, Drive))`). No combinator per pair of extension kinds.
impl<A: Extension, B: Extension> Extension for (A, B) {
    #[inline]
    fn after_position_update(&mut self, state: &mut StateMut<'_>) -> Result<(), EngineError> {
        self.0.after_position_update(state)?;
        self.1.after_position_update(state)
    }

    #[inline]
    fn add_forces(&mut self, state: &mut StateMut<'_>) -> Result<(), EngineError> {
        self.0.add_forces(state)?;
        self.1.add_forces(state)
    }

    #[inline]
    fn end_of_step(&mut self, state: &mut StateMut<'_>) -> Result<(), EngineError> {
        self.0.end_of_step(state)?;
        self.1.end_of_step(state)
    }

    fn allows_reordering(&self) -> bool {
        self.0.allows_reordering() && self.1.allows_reordering()
    }

    fn adds_forces(&self) -> bool {
        self.0.adds_forces() || self.1.adds_forces()
    }
}

/// An optional extension: `None` does nothing (a scene without walls runs no wall code).
impl<E: Extension> Extension for Option<E> {
    #[inline]
    fn after_position_update(&mut self, state: &mut StateMut<'_>) -> Result<(), EngineError> {
        match self {
            Some(e) => e.after_position_update(state),
            None => Ok(()),
        }
    }

    #[inline]
    fn add_forces(&mut self, state: &mut StateMut<'_>) -> Result<(), EngineError> {
        match self {
            Some(e) => e.add_forces(state),
            None => Ok(()),
        }
    }

    #[inline]
    fn end_of_step(&mut self, state: &mut StateMut<'_>) -> Result<(), EngineError> {
        match self {
            Some(e) => e.end_of_step(state),
            None => Ok(()),
        }
    }

    fn allows_reordering(&self) -> bool {
        self.as_ref().is_none_or(|e| e.allows_reordering())
    }

    fn adds_forces(&self) -> bool {
        self.as_ref().is_some_and(|e| e.adds_forces())
    }
}

/// An extension with a stopwatch: the wall-clock seconds spent in its hooks (for the share of a
/// step each part takes; the state is untouched, so the trajectory does not change).
#[derive(Debug, Clone, Default)]
pub struct Timed<E> {
    /// The wrapped extension.
    pub inner: E,
    /// Seconds spent in its hooks so far.
    pub seconds: f64,
}

impl<E> Timed<E> {
    /// Wraps `inner` with a zeroed stopwatch.
    pub fn new(inner: E) -> Self {
        Timed { inner, seconds: 0.0 }
    }
}

impl<E: Extension> Extension for Timed<E> {
    fn after_position_update(&mut self, state: &mut StateMut<'_>) -> Result<(), EngineError> {
        let t = std::time::Instant::now();
        let r = self.inner.after_position_update(state);
        self.seconds += t.elapsed().as_secs_f64();
        r
    }

    fn add_forces(&mut self, state: &mut StateMut<'_>) -> Result<(), EngineError> {
        let t = std::time::Instant::now();
        let r = self.inner.add_forces(state);
        self.seconds += t.elapsed().as_secs_f64();
        r
    }

    fn end_of_step(&mut self, state: &mut StateMut<'_>) -> Result<(), EngineError> {
        let t = std::time::Instant::now();
        let r = self.inner.end_of_step(state);
        self.seconds += t.elapsed().as_secs_f64();
        r
    }

    fn allows_reordering(&self) -> bool {
        self.inner.allows_reordering()
    }

    fn adds_forces(&self) -> bool {
        self.inner.adds_forces()
    }
}

/// A DPD simulation, generic over its [`Extension`] (default `()`: a plain fluid).
#[derive(Debug)]
pub struct Simulation<E: Extension = ()> {
    config: SimConfig,
    field: ForceField,
    domain: PeriodicBox,
    particles: Particles,
    step: u64,
    ext: E,
    cells: CellList,
    table: DpdTable,
    sforce: Vec<DVec3>,
    inv_mass: Vec<Real>,
    /// Per type: left alone by the integrator (frozen, or integrated by an extension).
    held: Vec<bool>,
    /// Per type: frozen (no body force).
    frozen: Vec<bool>,
    body: Vec<DVec3>,
    any_body: bool,
    /// The storage of the next step while [`Simulation::return_sorted`] writes it in cell order
    /// (on the steps that end with a storage sort); swapped with `particles` afterwards. Its
    /// contents between steps mean nothing; it holds a second copy of the storage's memory.
    spare: Particles,
}

impl Simulation<()> {
    /// A plain fluid. Validates everything, wraps positions into the box and computes the initial
    /// forces (force evaluation 0, with the initial velocities as the predicted velocities).
    pub fn new(config: SimConfig, field: ForceField, particles: Particles) -> Result<Self, EngineError> {
        Self::with_extension(config, field, particles, ())
    }
}

impl<E: Extension> Simulation<E> {
    /// A simulation with an extension. Computes the initial forces, including the extension's.
    pub fn with_extension(
        config: SimConfig,
        field: ForceField,
        mut particles: Particles,
        ext: E,
    ) -> Result<Self, EngineError> {
        particles.validate(&field)?;
        config.validate()?;
        let domain = PeriodicBox::new(config.box_lengths)?.with_shear_rate(config.shear_rate)?;
        let u = domain.shear_velocity();
        for (p, v) in particles.pos.iter_mut().zip(particles.vel.iter_mut()) {
            let (w, k) = domain.wrap_sheared(*p);
            *p = w;
            v.x -= k as Real * u; // Lees–Edwards: the velocity follows the image (U = 0: no-op)
        }
        let mut sim = Self::assemble(config, field, particles, 0, ext)?;
        sim.compute_forces(false)?;
        Ok(sim)
    }

    /// Continues from a saved state (no force recomputation: the saved forces are used, so the
    /// continuation is bit-identical to an uninterrupted run).
    pub fn from_state(state: SimState, ext: E) -> Result<Self, EngineError> {
        state.particles.validate(&state.field)?;
        let domain = PeriodicBox::new(state.config.box_lengths)?
            .with_shear_rate(state.config.shear_rate)?
            .at_time(state.step as Real * state.config.dt);
        if let Some(i) = state.particles.pos.iter().position(|p| domain.wrap(*p) != *p) {
            return Err(EngineError::invalid(
                format!("saved particle {i}"),
                format!("position {} outside the box", state.particles.pos[i]),
            ));
        }
        Self::assemble(state.config, state.field, state.particles, state.step, ext)
    }

    fn assemble(
        config: SimConfig,
        field: ForceField,
        particles: Particles,
        step: u64,
        ext: E,
    ) -> Result<Self, EngineError> {
        config.validate()?;
        field.validate()?;
        let domain = PeriodicBox::new(config.box_lengths)?
            .with_shear_rate(config.shear_rate)?
            .at_time(step as Real * config.dt);
        let grid = CellGrid::new(&domain, field.max_cutoff())?;
        let types = field.types();
        let mut cells = CellList::new(grid);
        cells.single = pairs::reads_single(types.len());
        cells.soa64 = pairs::reads_soa64(types.len(), config.scheme, domain.is_sheared());
        Ok(Self {
            table: DpdTable::new(&field, config.dt),
            inv_mass: types.iter().map(|t| 1.0 / t.mass).collect(),
            held: types.iter().map(|t| t.held()).collect(),
            frozen: types.iter().map(|t| t.frozen).collect(),
            body: types.iter().map(|t| t.body_force).collect(),
            any_body: types.iter().any(|t| t.body_force != DVec3::ZERO && !t.frozen),
            spare: Particles::default(),
            cells,
            sforce: Vec::new(),
            config,
            field,
            domain,
            particles,
            step,
            ext,
        })
    }

    /// A copy of everything needed to restart bit-identically.
    pub fn state(&self) -> SimState {
        SimState {
            config: self.config.clone(),
            field: self.field.clone(),
            particles: self.particles.clone(),
            step: self.step,
        }
    }

    /// Consumes the simulation into its state and extension.
    pub fn into_parts(self) -> (SimState, E) {
        (
            SimState {
                config: self.config,
                field: self.field,
                particles: self.particles,
                step: self.step,
            },
            self.ext,
        )
    }

    /// The particles (storage order is fixed for the life of the simulation).
    pub fn particles(&self) -> &Particles {
        &self.particles
    }

    /// The force field.
    pub fn field(&self) -> &ForceField {
        &self.field
    }

    /// The settings.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// The box.
    pub fn domain(&self) -> &PeriodicBox {
        &self.domain
    }

    /// The cell grid used by the pair loop.
    pub fn grid(&self) -> &CellGrid {
        &self.cells.grid
    }

    /// Completed steps.
    pub fn step_count(&self) -> u64 {
        self.step
    }

    /// Simulated time (steps × Δt).
    pub fn time(&self) -> Real {
        self.step as Real * self.config.dt
    }

    /// The extension.
    pub fn extension(&self) -> &E {
        &self.ext
    }

    /// The extension, mutably.
    pub fn extension_mut(&mut self) -> &mut E {
        &mut self.ext
    }

    /// Changes the body force of type `t` (takes effect from the next force evaluation).
    pub fn set_body_force(&mut self, t: usize, f: DVec3) -> Result<(), EngineError> {
        self.field.set_body_force(t, f)?;
        self.body = self.field.types().iter().map(|t| t.body_force).collect();
        self.any_body = self
            .field
            .types()
            .iter()
            .any(|t| t.body_force != DVec3::ZERO && !t.frozen);
        Ok(())
    }

    /// Advances one step.
    pub fn step(&mut self) -> Result<(), EngineError> {
        self.advance(false).map(|_| ())
    }

    /// Advances one step and returns the pair virial W = Σ_pairs r_ij ⊗ f_ij of its force
    /// evaluation (conservative + dissipative + random); see [`crate::observe::pressure_tensor`].
    pub fn step_with_virial(&mut self) -> Result<DMat3, EngineError> {
        self.advance(true)
    }

    /// Advances `n` steps.
    pub fn run(&mut self, n: u64) -> Result<(), EngineError> {
        for _ in 0..n {
            self.advance(false)?;
        }
        Ok(())
    }

    /// Recomputes the forces at the current positions, with the current velocities as predicted
    /// velocities and the noise of evaluation `step`, and returns the pair virial. Not part of
    /// time stepping (it replaces the saved forces, so the trajectory changes): for benchmarks
    /// and diagnostics.
    pub fn recompute_forces(&mut self) -> Result<DMat3, EngineError> {
        self.compute_forces(true)
    }

    fn state_mut(&mut self) -> (StateMut<'_>, &mut E) {
        let p = &mut self.particles;
        (
            StateMut {
                pos: &mut p.pos,
                vel: &mut p.vel,
                force: &mut p.force,
                ptype: &p.ptype,
                id: &p.id,
                domain: &self.domain,
                field: &self.field,
                dt: self.config.dt,
                step: self.step,
            },
            &mut self.ext,
        )
    }

    /// Pair forces at the current positions with ṽ = v + c·f/m (c = (λ − ½)Δt during a step,
    /// 0 for the initial evaluation), noise of evaluation `self.step` (+1 during a step, via
    /// `key_step`), plus body forces and the extension's forces. With `kick = Some(h)` (an
    /// extension that adds no forces) the second half-kick v += h f/m is done in the same pass
    /// as the return of the forces to storage order, and the first particle whose velocity or
    /// force is not finite is returned (the checks of [`Simulation::advance_step`]'s own kick).
    /// With `reorder` as well, the storage itself is put into the cell order of this evaluation
    /// in that pass ([`Simulation::return_sorted`]), and the index returned is one of the new
    /// order.
    fn forces_at(
        &mut self,
        key_step: u64,
        c: Real,
        virial: bool,
        kick: Option<Real>,
        reorder: bool,
    ) -> Result<(DMat3, Option<usize>), EngineError> {
        let p = &self.particles;
        let (inv_mass, held) = (&self.inv_mass, &self.held);
        let vel_of = |i: usize| {
            let t = p.ptype[i] as usize;
            if held[t] || c == 0.0 {
                p.vel[i]
            } else {
                p.vel[i] + p.force[i] * (c * inv_mass[t])
            }
        };
        let prefetch = |i: usize| {
            shared::prefetch(&p.vel, i);
            shared::prefetch(&p.force, i);
        };
        self.cells.build_prefetching(&p.pos, &p.ptype, &p.id, vel_of, prefetch);
        let key = step_key(self.config.seed, key_step);
        let shear = self.domain.is_sheared().then(|| pairs::ShearImages {
            offset: self.domain.offset(),
            velocity: self.domain.shear_velocity(),
        });
        let (scheme, cells, sforce) = (self.config.scheme, &self.cells, &mut self.sforce);
        let w = pair_forces(&self.table, scheme, cells, key, sforce, virial, shear);
        // Back to storage order (a parallel gather through the inverse permutation), adding the
        // body forces on the way, and kicking if asked to.
        let (sforce, inv) = (&self.sforce, self.cells.inverse());
        let (body, frozen, any_body) = (&self.body, &self.frozen, self.any_body);
        let p = &mut self.particles;
        let force_of = |i: usize, k: u32, t: usize| {
            if let Some(&a) = inv.get(i + AHEAD) {
                shared::prefetch(sforce, a as usize);
            }
            with_body_force(sforce[k as usize], t, body, frozen, any_body)
        };
        if let (Some(h), true) = (kick, reorder) {
            return Ok((w, self.return_sorted(h)));
        }
        let Some(h) = kick else {
            p.force
                .par_iter_mut()
                .zip(inv.par_iter())
                .zip(p.ptype.par_iter())
                .enumerate()
                .with_min_len(MIN_LEN)
                .for_each(|(i, ((f, &k), &t))| *f = force_of(i, k, t as usize));
            return Ok((w, None));
        };
        let bad = p
            .force
            .par_iter_mut()
            .zip(p.vel.par_iter_mut())
            .zip(inv.par_iter())
            .zip(p.ptype.par_iter())
            .enumerate()
            .with_min_len(MIN_LEN)
            .filter_map(|(i, (((f, v), &k), &t))| {
                let t = t as usize;
                *f = force_of(i, k, t);
                kick_and_check(v, f, held[t], h * inv_mass[t]).then_some(i)
            })
            .min();
        Ok((w, bad))
    }

    /// The return of the sorted forces with the second half-kick, writing the whole storage in
    /// the cell order of this evaluation: sorted particle k becomes storage index k, with the
    /// position, type and id of `perm[k]`, its force (plus the body force) and its kicked
    /// velocity. The same operations as the return to storage order followed by
    /// [`Simulation::sort_storage`], in one pass that reads the old storage nearly in sequence
    /// (it was sorted one step before) and writes the new one in sequence. Returns the first new
    /// index whose velocity or force is not finite.
    fn return_sorted(&mut self, h: Real) -> Option<usize> {
        let n = self.particles.len();
        let (p, new) = (&self.particles, &mut self.spare);
        new.pos.resize(n, DVec3::ZERO);
        new.vel.resize(n, DVec3::ZERO);
        new.force.resize(n, DVec3::ZERO);
        new.ptype.resize(n, 0);
        new.id.resize(n, 0);
        let (perm, sforce) = (&self.cells.perm, &self.sforce);
        let (body, frozen, any_body) = (&self.body, &self.frozen, self.any_body);
        let (inv_mass, held) = (&self.inv_mass, &self.held);
        let bad = new
            .pos
            .par_iter_mut()
            .zip(new.vel.par_iter_mut())
            .zip(new.force.par_iter_mut())
            .zip(new.ptype.par_iter_mut())
            .zip(new.id.par_iter_mut())
            .enumerate()
            .with_min_len(MIN_LEN)
            .filter_map(|(k, ((((x, v), f), t), id))| {
                if let Some(&a) = perm.get(k + AHEAD) {
                    let a = a as usize;
                    shared::prefetch(&p.pos, a);
                    shared::prefetch(&p.vel, a);
                }
                let i = perm[k] as usize;
                let ti = p.ptype[i];
                let tu = ti as usize;
                (*x, *v, *t, *id) = (p.pos[i], p.vel[i], ti, p.id[i]);
                *f = with_body_force(sforce[k], tu, body, frozen, any_body);
                kick_and_check(v, f, held[tu], h * inv_mass[tu]).then_some(k)
            })
            .min();
        std::mem::swap(&mut self.particles, &mut self.spare);
        bad
    }

    fn compute_forces(&mut self, virial: bool) -> Result<DMat3, EngineError> {
        let (w, _) = self.forces_at(self.step, 0.0, virial, None, false)?;
        let (mut s, ext) = self.state_mut();
        ext.add_forces(&mut s)?;
        Ok(w)
    }

    /// One step. With two or more threads another worker is kept awake through the step
    /// ([`keep_awake`]), so that the step's parallel regions do not each wait for a sleeping
    /// thread to be woken.
    fn advance(&mut self, virial: bool) -> Result<DMat3, EngineError> {
        if rayon::current_num_threads() < 2 {
            return self.advance_step(virial);
        }
        let done = AtomicBool::new(false);
        let caller = rayon::current_thread_index();
        rayon::in_place_scope(|s| {
            s.spawn(|_| keep_awake(&done, caller));
            let result = self.advance_step(virial);
            done.store(true, Ordering::Release);
            result
        })
    }

    fn advance_step(&mut self, virial: bool) -> Result<DMat3, EngineError> {
        let dt = self.config.dt;
        let h = 0.5 * dt;
        let step = self.step;
        let cell = self.cells.grid.size.min_element();
        let max_d2 = cell * cell;

        // 1. half kick + drift, in parallel; the first offending index (if any) is reported.
        // Lees–Edwards: the offset of the new time; a particle crossing y = 0 or Ly takes the
        // velocity of its new image (v_x ∓ U) at once, before any force sees it.
        self.domain = self.domain.at_time((step + 1) as Real * dt);
        {
            let (inv_mass, held, domain) = (&self.inv_mass, &self.held, &self.domain);
            let u = domain.shear_velocity();
            let p = &mut self.particles;
            let bad = p
                .pos
                .par_iter_mut()
                .zip(p.vel.par_iter_mut())
                .zip(p.force.par_iter())
                .zip(p.ptype.par_iter())
                .enumerate()
                .with_min_len(MIN_LEN)
                .filter_map(|(i, (((x, v), f), &t))| {
                    let t = t as usize;
                    if held[t] {
                        return None;
                    }
                    *v += *f * (h * inv_mass[t]);
                    let d = *v * dt;
                    if d.length_squared() <= max_d2 {
                        let (w, k) = domain.wrap_sheared(*x + d);
                        *x = w;
                        if k != 0 {
                            v.x -= k as Real * u;
                        }
                        None
                    } else {
                        Some(i)
                    }
                })
                .min();
            if let Some(i) = bad {
                return Err(self.instability(i, step, cell));
            }
        }

        // 2. extension: reflections
        {
            let (mut s, ext) = self.state_mut();
            ext.after_position_update(&mut s).map_err(|e| wrap_ext(e, step))?;
        }

        // 3. forces with the predicted velocity, noise of evaluation step + 1; 4. second half
        // kick + finiteness check (in the same pass as the forces' return to storage order if
        // the extension adds no forces)
        let fused = !self.ext.adds_forces();
        // On the steps that end with the storage put into cell order (`sort_every`), that is
        // done in the same pass.
        let every = self.config.sort_every;
        let reorder = fused && every > 0 && (step + 1).is_multiple_of(every) && self.ext.allows_reordering();
        let (w, bad) = self.forces_at(
            step + 1,
            (self.config.lambda - 0.5) * dt,
            virial,
            fused.then_some(h),
            reorder,
        )?;
        let bad = if fused {
            bad
        } else {
            {
                let (mut s, ext) = self.state_mut();
                ext.add_forces(&mut s).map_err(|e| wrap_ext(e, step))?;
            }
            let (inv_mass, held) = (&self.inv_mass, &self.held);
            let p = &mut self.particles;
            p.vel
                .par_iter_mut()
                .zip(p.force.par_iter())
                .zip(p.ptype.par_iter())
                .enumerate()
                .with_min_len(MIN_LEN)
                .filter_map(|(i, ((v, f), &t))| {
                    let t = t as usize;
                    kick_and_check(v, f, held[t], h * inv_mass[t]).then_some(i)
                })
                .min()
        };
        if let Some(i) = bad {
            return Err(self.instability(i, step, cell));
        }
        self.step += 1;
        {
            let (mut s, ext) = self.state_mut();
            ext.end_of_step(&mut s).map_err(|e| wrap_ext(e, step))?;
        }
        if every > 0 && !reorder && self.step.is_multiple_of(every) && self.ext.allows_reordering() {
            self.sort_storage();
        }
        Ok(w)
    }

    /// Puts the particles into the cell order of the last force evaluation (the positions have
    /// not changed since: the extension allows reordering, so it moves nothing by index). The
    /// order is the stable cell sort of the current storage order, a function of the state only.
    fn sort_storage(&mut self) {
        let perm = &self.cells.perm;
        let p = &mut self.particles;
        if perm.len() != p.pos.len() {
            return;
        }
        fn gather<T: Copy + Send + Sync>(v: &mut Vec<T>, perm: &[u32]) {
            let sorted: Vec<T> = perm.par_iter().with_min_len(MIN_LEN).map(|&i| v[i as usize]).collect();
            *v = sorted;
        }
        gather(&mut p.pos, perm);
        gather(&mut p.vel, perm);
        gather(&mut p.force, perm);
        gather(&mut p.ptype, perm);
        gather(&mut p.id, perm);
    }

    fn instability(&self, i: usize, step: u64, cell: Real) -> EngineError {
        let p = &self.particles;
        let (id, ptype) = (p.id[i], p.ptype[i]);
        let (x, v, f) = (p.pos[i], p.vel[i], p.force[i]);
        if !f.is_finite() {
            return EngineError::NonFinite {
                step,
                id,
                index: i,
                ptype,
                quantity: "force",
                value: format!("{f}"),
                cause: CAUSE_DT,
            };
        }
        if !v.is_finite() {
            return EngineError::NonFinite {
                step,
                id,
                index: i,
                ptype,
                quantity: "velocity",
                value: format!("{v}"),
                cause: CAUSE_DT,
            };
        }
        if !x.is_finite() {
            return EngineError::NonFinite {
                step,
                id,
                index: i,
                ptype,
                quantity: "position",
                value: format!("{x}"),
                cause: CAUSE_DT,
            };
        }
        EngineError::TooFast {
            step,
            id,
            index: i,
            ptype,
            displacement: (v * self.config.dt).length(),
            cell,
            velocity: format!("{v}"),
            cause: CAUSE_FAST,
        }
    }
}

fn wrap_ext(e: EngineError, step: u64) -> EngineError {
    match e {
        EngineError::Extension { .. } | EngineError::NonFinite { .. } | EngineError::TooFast { .. } => e,
        other => EngineError::Extension {
            step,
            message: other.to_string(),
        },
    }
}

/// Pair force `f` of a particle of type `t` plus its type's body force (none for a frozen type,
/// nor when no type has one).
#[inline(always)]
fn with_body_force(f: DVec3, t: usize, body: &[DVec3], frozen: &[bool], any_body: bool) -> DVec3 {
    if !any_body || frozen[t] {
        f
    } else {
        f + body[t]
    }
}

/// The second half-kick of one particle, v += f · (½Δt/m) (`h_inv_mass`) unless its type is
/// held; true if its velocity or force is then not finite.
#[inline(always)]
fn kick_and_check(v: &mut DVec3, f: &DVec3, held: bool, h_inv_mass: Real) -> bool {
    if !held {
        *v += *f * h_inv_mass;
    }
    !(v.is_finite() && f.is_finite())
}

/// How long [`keep_awake`] spins without finding work before it lets its thread go to sleep.
const KEEP_AWAKE_IDLE: Duration = Duration::from_micros(200);

/// Runs the pool's pending work on this worker until `done` is set, spinning in between, so that
/// the worker is awake whenever the step on thread `caller` starts a parallel region: rayon puts
/// an idle worker to sleep after a few dozen rounds without work, and waking it costs more on a
/// virtual machine, where the vCPU may have been halted, than the step's short regions are worth
/// (docs/performance.md, "Changes tried"). Returns at once on `caller` itself (the step is
/// over by the time the caller could run this job), and after [`KEEP_AWAKE_IDLE`] without work, so
/// that it can never hold its thread for long: a sequential stretch of the step, or a worker that
/// picked this up while waiting inside other work, goes back to rayon's own scheduling. Which
/// thread runs which job never changes a result (docs/engine.md, "Determinism").
fn keep_awake(done: &AtomicBool, caller: Option<usize>) {
    if rayon::current_thread_index() == caller {
        return;
    }
    let mut idle_since: Option<Instant> = None;
    while !done.load(Ordering::Acquire) {
        if rayon::yield_now() == Some(rayon::Yield::Executed) {
            idle_since = None;
        } else if idle_since.get_or_insert_with(Instant::now).elapsed() > KEEP_AWAKE_IDLE {
            return;
        } else {
            std::hint::spin_loop();
        }
    }
}

/// The pair forces of whichever kernel table the run chose. Not generic, and never inlined:
/// the pair loops are compiled once, in this crate, rather than again in every crate that
/// instantiates a [`Simulation`] with its own [`Extension`] (at opt-level 3 generic code is
/// not shared between crates; the kernels' loops made up most of the build time of each test
/// binary that drives the engine).
#[inline(never)]
fn pair_forces(
    table: &DpdTable,
    scheme: crate::ForceScheme,
    cells: &CellList,
    key: u64,
    sforce: &mut Vec<DVec3>,
    virial: bool,
    shear: Option<pairs::ShearImages>,
) -> DMat3 {
    match table {
        DpdTable::Linear(t) => pairs::compute(scheme, cells, t, key, sforce, virial, shear),
        DpdTable::Quarter(t) => pairs::compute(scheme, cells, t, key, sforce, virial, shear),
        DpdTable::Eighth(t) => pairs::compute(scheme, cells, t, key, sforce, virial, shear),
        DpdTable::General(t) => pairs::compute(scheme, cells, t, key, sforce, virial, shear),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{init, PairParams, TypeSpec};
    use std::sync::atomic::AtomicUsize;

    /// A fluid of two types (the second heavier and pushed by a body force), sorted in storage
    /// every `every` steps.
    fn two_type_fluid(every: u64) -> Simulation {
        let mut config = SimConfig::new(DVec3::splat(6.0), 0.01, 11);
        config.sort_every = every;
        let mut field =
            ForceField::new(vec![TypeSpec::new("a"), TypeSpec::new("b")], PairParams::groot_warren()).unwrap();
        field.type_mut(1).unwrap().mass = 2.0;
        field.set_body_force(1, DVec3::new(0.3, -0.1, 0.05)).unwrap();
        let mut p = init::fluid(&config, &field, &init::FluidSpec::standard(), 5).unwrap();
        for t in p.ptype.iter_mut().step_by(3) {
            *t = 1;
        }
        Simulation::new(config, field, p).unwrap()
    }

    /// The storage sort done in the pass that returns the forces ([`Simulation::return_sorted`],
    /// on the steps that end with a sort) leaves bit for bit the state of the separate return
    /// followed by [`Simulation::sort_storage`], at 1 and 2 threads, with sorts every step and
    /// every third step; and the storage really is reordered.
    #[test]
    fn sorting_in_the_return_pass_equals_a_separate_sort() {
        let bits = |v: &[DVec3]| v.iter().map(|x| x.to_array().map(f64::to_bits)).collect::<Vec<_>>();
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                for every in [1, 3] {
                    let mut fused = two_type_fluid(every);
                    let mut separate = two_type_fluid(0);
                    for _ in 0..20 {
                        fused.step().unwrap();
                        separate.step().unwrap();
                        if separate.step.is_multiple_of(every) {
                            separate.sort_storage();
                        }
                    }
                    let (a, b) = (&fused.particles, &separate.particles);
                    assert!(
                        bits(&a.pos) == bits(&b.pos),
                        "positions differ (every {every}, {threads} threads)"
                    );
                    assert!(
                        bits(&a.vel) == bits(&b.vel),
                        "velocities differ (every {every}, {threads} threads)"
                    );
                    assert!(
                        bits(&a.force) == bits(&b.force),
                        "forces differ (every {every}, {threads} threads)"
                    );
                    assert!(
                        a.ptype == b.ptype && a.id == b.id,
                        "types or ids differ (every {every})"
                    );
                    let moved = a.id.iter().enumerate().filter(|(i, &id)| *i as u32 != id).count();
                    assert!(moved > a.len() / 2, "storage was not reordered ({moved} moved)");
                }
            });
        }
    }

    /// Calls `keep_awake(done, caller)` on a 1-thread pool while one job, which counts its runs,
    /// waits in that thread's deque; returns how often the job had run when `keep_awake`
    /// returned, and how long `keep_awake` took. On one thread nothing else can run the job.
    fn with_one_pending_job(done: bool, caller_is_self: bool) -> (usize, Duration) {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        pool.install(|| {
            let (ran, flag) = (AtomicUsize::new(0), AtomicBool::new(done));
            let caller = if caller_is_self {
                rayon::current_thread_index()
            } else {
                None
            };
            let mut seen = (0, Duration::ZERO);
            rayon::in_place_scope(|s| {
                s.spawn(|_| {
                    ran.fetch_add(1, Ordering::SeqCst);
                });
                let t = Instant::now();
                keep_awake(&flag, caller);
                seen = (ran.load(Ordering::SeqCst), t.elapsed());
            });
            assert_eq!(ran.load(Ordering::SeqCst), 1, "the scope runs the job in the end");
            seen
        })
    }

    #[test]
    fn keep_awake_runs_pending_work_and_stops_when_it_should() {
        // On the stepping thread itself it returns at once: the job has not run.
        assert_eq!(with_one_pending_job(false, true).0, 0);
        // Once the step is done it returns at once, too.
        assert_eq!(with_one_pending_job(true, false).0, 0);
        // Otherwise it runs the pending job, then gives up after the idle limit.
        let (ran, took) = with_one_pending_job(false, false);
        assert_eq!(ran, 1);
        assert!(
            took >= KEEP_AWAKE_IDLE,
            "returned after {took:?}, before the idle limit"
        );
    }
}
