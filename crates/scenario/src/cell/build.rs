//! Putting a cell in a fluid: the force field of the four particle types, the membrane model
//! and its dry run, the wall and cell configurations, and the simulation assembled from an
//! equilibrated fluid (with walls or without) and the resting mesh.

use super::section::{cell_mapping, cell_params, resolve_substeps, CellSection, ModelKeys, ViscosityForm};
use super::{INNER, MEMBRANE, OUTER, VERTEX_MASS, WALL};
use crate::context::RunError;
use crate::mesh_cache;
use crate::run_dir::engine_err;
use crate::units::{self, FluidDecision, FluidModel, PhysicalSystem, UnitMapping};
use glam::DVec3;
use hemodpd_engine::walls::{self, Reflection, WallConfig, WallShape, Walls};
use hemodpd_engine::{ForceField, PairParams, Particles, SimConfig, Simulation, Timed, TypeSpec};
use hemodpd_membrane::coupling::{Cell, CellConfig, WallRepulsion};
use hemodpd_membrane::forces::MembraneConstants;
use hemodpd_membrane::viscosity::MembraneViscosity;
use hemodpd_membrane::{MembraneModel, Mesh, ReferenceState};
use serde_json::json;

/// The simulation of a cell-in-flow run: walls (none in unbounded shear) and the cell.
pub type CellSim = Simulation<(Option<Timed<Walls>>, Cell)>;

/// What every cell-in-flow plan holds besides its own geometry and schedule: the physical
/// system, the fluid chosen for it with the unit mapping, the time step and the sub-steps.
#[derive(Clone, Debug)]
pub struct CellSetup {
    pub sys: PhysicalSystem,
    pub map: UnitMapping,
    pub fluid: FluidModel,
    /// Fluid time step, model units (`model.timestep`, or the chosen fluid's default).
    pub dt: f64,
    /// Membrane sub-steps per fluid step (`model.membrane_substeps`, resolved).
    pub substeps: u32,
}

impl CellSetup {
    /// The fluid and unit mapping for `sys` under the `[model]` keys, then the time step and
    /// the membrane sub-steps that follow from them and from the cell's membrane viscosity.
    pub(crate) fn new(sys: PhysicalSystem, keys: ModelKeys<'_>, cell: &CellSection) -> Result<Self, RunError> {
        let FluidDecision { fluid, map, .. } = cell_mapping(&sys, keys)?;
        let dt = keys.timestep.unwrap_or(fluid.default_timestep(&sys, &map));
        let visc = cell_membrane_viscosity(cell, &map);
        let substeps = resolve_substeps(keys.membrane_substeps, visc.as_ref(), dt, VERTEX_MASS);
        Ok(Self {
            sys,
            map,
            fluid,
            dt,
            substeps,
        })
    }

    /// The engine configuration of a run in a box of `box_lengths` (rc).
    pub(crate) fn sim_config(&self, box_lengths: DVec3, seed: u64) -> SimConfig {
        SimConfig::new(box_lengths, self.dt, seed)
    }
}

/// What the family needs from a kind's plan to build, check and restore its cell.
pub(crate) trait CellPlan {
    /// The `[cell]` section.
    fn cell(&self) -> &CellSection;
    /// The shared `[model]` keys.
    fn model_keys(&self) -> ModelKeys<'_>;
    /// The system, fluid, mapping, time step and sub-steps.
    fn setup(&self) -> &CellSetup;
    /// Inner (cytosol) over outer viscosity.
    fn viscosity_ratio(&self) -> f64;
    /// The scenario's seed.
    fn seed(&self) -> u64;
    /// The box, rc.
    fn box_lengths(&self) -> DVec3;
    /// The engine configuration of the run.
    fn sim_config(&self) -> SimConfig;
    /// The walls' shape (None: no walls).
    fn wall_shape(&self) -> Option<WallShape>;

    /// The unit mapping.
    fn map(&self) -> &UnitMapping {
        &self.setup().map
    }
    /// The fluid model (model units).
    fn fluid(&self) -> &FluidModel {
        &self.setup().fluid
    }
    /// Membrane sub-steps per fluid step (resolved).
    fn substeps(&self) -> u32 {
        self.setup().substeps
    }
    /// Fluid time step, model units.
    fn dt(&self) -> f64 {
        self.setup().dt
    }
}

/// The membrane viscosity of a `[cell]` section in model units (None when 0: the paper's model).
pub(crate) fn cell_membrane_viscosity(cell: &CellSection, map: &UnitMapping) -> Option<MembraneViscosity> {
    let eta = cell.membrane_viscosity_pa_s_m;
    (eta > 0.0).then(|| {
        let eta_model = map.membrane_viscosity_to_model(eta);
        match cell.membrane_viscosity_form {
            ViscosityForm::Fedosov => MembraneViscosity::from_eta(eta_model),
            ViscosityForm::Central => MembraneViscosity::central_from_eta(eta_model),
        }
    })
}

/// The force field of a cell in plasma (types [`OUTER`], [`WALL`], [`INNER`], [`MEMBRANE`];
/// see the module docs of [`crate::cell`]): the inner fluid's γ gives it `viscosity_ratio` ×
/// the outer's measured η ([`FluidModel::inner_gamma`]), the membrane's friction with each side gives no slip for that side's
/// viscosity. With `substeps` > 1 the membrane type is integrated by the cell, not the engine.
pub(crate) fn cell_fluid_field(
    fluid: &FluidModel,
    viscosity_ratio: f64,
    vertex_density: f64,
    substeps: u32,
) -> Result<ForceField, RunError> {
    let p = fluid.pair;
    let (eta_o, eta_i) = (fluid.viscosity, fluid.viscosity * viscosity_ratio);
    // inner γ from the fluid's measured η(γ) (docs/units.md, "The cytosol")
    let inner = PairParams {
        gamma: fluid.inner_gamma(viscosity_ratio),
        ..p
    };
    let fsi = |eta: f64| PairParams {
        a: 0.0,
        gamma: units::fsi_friction(eta, fluid.density, vertex_density, p.s, p.rc),
        ..p
    };
    // no interaction and a zero cutoff: the pair loop never lists these pairs (with rc kept,
    // every wall–wall and vertex–vertex pair within rc was evaluated to an exact zero)
    let none = PairParams::none();
    let mut f = ForceField::new(
        vec![
            TypeSpec::new("plasma"),
            TypeSpec::frozen("wall"),
            TypeSpec::new("cytosol"),
            TypeSpec::new("membrane"),
        ],
        p,
    )
    .map_err(engine_err)?;
    let set = |f: &mut ForceField, a: u16, b: u16, q: PairParams| f.set_pair(a as usize, b as usize, q);
    set(&mut f, WALL, WALL, none).map_err(engine_err)?;
    set(&mut f, INNER, INNER, inner).map_err(engine_err)?;
    // the cytosol meets the plasma and the wall only through the membrane: repulsion keeps each
    // side's density, but a friction across the membrane would drag the cell's interior by the
    // fluid outside it (a cell pressed against a tube's wall by the wall at rest)
    let across_membrane = PairParams {
        gamma: 0.0,
        kbt: 0.0,
        ..p
    };
    set(&mut f, INNER, WALL, across_membrane).map_err(engine_err)?;
    set(&mut f, INNER, OUTER, across_membrane).map_err(engine_err)?;
    set(&mut f, MEMBRANE, OUTER, fsi(eta_o)).map_err(engine_err)?;
    set(&mut f, MEMBRANE, WALL, fsi(eta_o)).map_err(engine_err)?;
    set(&mut f, MEMBRANE, INNER, fsi(eta_i)).map_err(engine_err)?;
    set(&mut f, MEMBRANE, MEMBRANE, none).map_err(engine_err)?;
    if let Some(t) = f.type_mut(MEMBRANE as usize) {
        t.mass = VERTEX_MASS;
        t.integrated_by_extension = substeps > 1;
    }
    Ok(f)
}

/// The force field of `plan`'s cell on the resting mesh `rest` (its vertices per area set the
/// membrane–fluid friction).
pub(crate) fn plan_field(plan: &impl CellPlan, rest: &Mesh) -> Result<ForceField, RunError> {
    let vertex_density = rest.vertices.len() as f64 / rest.area();
    cell_fluid_field(plan.fluid(), plan.viscosity_ratio(), vertex_density, plan.substeps())
}

/// The resting mesh of a `[cell]` section in µm (generated and cached, or the user's), on its
/// principal axes (symmetry axis y), and where it came from.
pub(crate) fn cell_mesh_um(
    cell: &CellSection,
    seed: u64,
    base_dir: &std::path::Path,
) -> Result<(Mesh, serde_json::Value), RunError> {
    match &cell.mesh_file {
        Some(f) => {
            let path = base_dir.join(f);
            let (mesh, pose) = mesh_cache::user_mesh(&path)?;
            Ok((mesh, json!({ "source": "file", "path": path, "pose_change": pose })))
        }
        None => {
            let (mesh, origin) = mesh_cache::relaxed_mesh(cell.vertices as usize, seed)?;
            Ok((mesh, json!({ "source": "generated", "origin": origin })))
        }
    }
}

/// The membrane model of a `[cell]` section in model units (`map`) on the resting mesh `rest`
/// (model units).
pub(crate) fn membrane_model(cell: &CellSection, map: &UnitMapping, rest: &Mesh) -> Result<MembraneModel, RunError> {
    let params = cell_params(cell)?;
    let c = MembraneConstants::from_params(
        &params,
        map.length_m,
        map.energy_j,
        cell.area_constraint_n_per_m,
        cell.volume_constraint_n_per_m2,
    );
    let topo = rest.topology()?;
    Ok(match cell.reference {
        ReferenceState::Uniform => MembraneModel::uniform(&topo, &c, rest.area(), rest.volume())?,
        ReferenceState::StressFree => MembraneModel::stress_free(&topo, &rest.vertices, &c)?,
        ReferenceState::Spheroid { reduced_volume } => {
            MembraneModel::spheroidal(&topo, &rest.vertices, &c, reduced_volume)?
        }
    })
}

/// Steps of the membrane's dry run before a run ([`hemodpd_membrane::coupling::dry_run`]).
const DRY_RUN_STEPS: u64 = 400;

/// Checks, before any fluid is built, that `plan`'s time step resolves the membrane `model` on
/// the resting mesh `rest`: a dry run of the membrane alone at the fluid's kBT, taking the
/// membrane's own step Δt/substeps. On failure the error names `model.timestep`, the step the
/// dry run failed at and the largest time step (halving) that passed.
pub(crate) fn check_membrane_timestep(
    plan: &impl CellPlan,
    model: &MembraneModel,
    rest: &Mesh,
) -> Result<(), RunError> {
    let visc = cell_membrane_viscosity(plan.cell(), plan.map());
    let (dt_fluid, kbt, f) = (plan.dt(), plan.fluid().pair.kbt, plan.map().thermal_factor);
    let mass = VERTEX_MASS;
    let k = plan.substeps().max(1);
    let dt0 = dt_fluid / k as f64;
    let dry = |dt: f64| {
        hemodpd_membrane::coupling::dry_run(model, &rest.vertices, dt, kbt, mass, visc.as_ref(), DRY_RUN_STEPS)
    };
    let Some(step) = dry(dt0) else {
        return Ok(());
    };
    if k > 1 {
        return Err(RunError::Output(format!(
            "model.timestep = {dt_fluid} with model.membrane_substeps = {k} is too fast for the membrane: a dry run of the membrane alone (no fluid, thermal velocities) at its inner step {dt0:.3e} became unstable at step {step} of {DRY_RUN_STEPS}; likely cause: the membrane's stiffest mode (its moduli in model units grow as the thermal factor falls: f = {f:.3}); raise model.membrane_substeps or lower model.timestep"
        )));
    }
    let mut dt = dt0;
    let stable = (0..8).find_map(|_| {
        dt *= 0.5;
        dry(dt).is_none().then_some(dt)
    });
    let advice = match stable {
        Some(dt) => format!("set model.timestep ≤ {dt:.2e} (the largest halving of it that passed)"),
        None => "no time step down to 1/256 of it passed: check cell.area_constraint_n_per_m and cell.volume_constraint_n_per_m2".into(),
    };
    Err(RunError::Output(format!(
        "model.timestep = {} is too large for the membrane: a dry run of the membrane alone (no fluid, thermal velocities) became unstable at step {step} of {DRY_RUN_STEPS}; likely cause: the time step cannot resolve the membrane's stiffest mode (its moduli in model units grow as the thermal factor falls: f = {:.3}); {advice}",
        dt0, f
    )))
}

/// The walls' configuration: bounce-back, 5 bins of the wall force, no adaptation.
pub(crate) fn wall_config(fluid: &FluidModel) -> WallConfig {
    WallConfig {
        reflection: Reflection::BounceBack,
        bins: 5,
        rc: fluid.pair.rc,
        adapt: false,
        ..WallConfig::default()
    }
}

/// The walls of `plan` (None without walls).
pub(crate) fn plan_walls(plan: &impl CellPlan) -> Result<Option<Walls>, RunError> {
    plan.wall_shape()
        .map(|shape| Walls::new(shape, wall_config(plan.fluid())).map_err(engine_err))
        .transpose()
}

/// The cell's configuration, its vertices from particle `first` on. With walls, the membrane is
/// repelled from them within `model.wall_repulsion_range_rc`, at contact with a few times the
/// largest force a plasma pair exerts (a).
pub(crate) fn cell_config(plan: &impl CellPlan, first: usize) -> CellConfig {
    let (m, fluid) = (plan.model_keys(), plan.fluid());
    CellConfig {
        first,
        outer_type: OUTER,
        inner_type: INNER,
        check_every: m.crossing_check_every_steps,
        wall: plan.wall_shape().map(|shape| WallRepulsion {
            shape,
            range: m.wall_repulsion_range_rc * fluid.pair.rc,
            strength: 4.0 * fluid.pair.a,
        }),
        reflection: m.membrane_reflection,
        kbt: fluid.pair.kbt,
        seed: plan.seed(),
        viscosity: cell_membrane_viscosity(plan.cell(), plan.map()),
        substeps: plan.substeps(),
        substep_forces: m.membrane_substep_forces,
    }
}

/// Places the cell in an equilibrated fluid `base` (fluid and, with walls, wall particles of
/// [`walls`]' types) and assembles the simulation: the vertices start at `start` (the resting
/// mesh `rest`, or the cell pressed into a narrow tube, [`super::placement`]), fluid inside
/// that surface becomes cytosol, the rest plasma, wall particles [`WALL`], and the vertices
/// follow with the next ids. `streaming` (None: at rest) is the imposed flow's velocity at a point, added to the
/// fluid's and given to the vertices.
pub(crate) fn place_cell(
    plan: &impl CellPlan,
    base: &Particles,
    rest: &Mesh,
    start: &[DVec3],
    model: MembraneModel,
    streaming: Option<&dyn Fn(DVec3) -> DVec3>,
) -> Result<CellSim, RunError> {
    let field = plan_field(plan, rest)?;
    let mut p = Particles::with_capacity(base.len() + rest.vertices.len());
    let mut max_id = 0u32;
    for i in 0..base.len() {
        let x = base.pos[i];
        let (t, v) = if base.ptype[i] == walls::WALL_TYPE {
            (WALL, base.vel[i])
        } else {
            let t = if hemodpd_membrane::mesh::contains(x, start, &rest.triangles) {
                INNER
            } else {
                OUTER
            };
            (t, streaming.map_or(base.vel[i], |u| base.vel[i] + u(x)))
        };
        p.push(x, v, t, base.id[i]);
        max_id = max_id.max(base.id[i]);
    }
    let first = p.len();
    for (k, v) in start.iter().enumerate() {
        let u = streaming.map_or(DVec3::ZERO, |u| u(*v));
        p.push(*v, u, MEMBRANE, max_id + 1 + k as u32);
    }
    let walls_ext = plan_walls(plan)?.map(Timed::new);
    let cell = Cell::new(model, cell_config(plan, first), start.to_vec()).map_err(engine_err)?;
    Simulation::with_extension(plan.sim_config(), field, p, (walls_ext, cell)).map_err(describe_engine_error)
}

/// An engine error with the particle type named (membrane vertex, fluid particle, ...).
pub fn describe_engine_error(e: hemodpd_engine::EngineError) -> RunError {
    use hemodpd_engine::EngineError as E;
    let part = |t: u16| match t {
        OUTER => "a plasma particle",
        INNER => "a cytosol particle",
        MEMBRANE => "a membrane vertex",
        _ => "a wall particle",
    };
    let hint = |t: u16| {
        match t {
        MEMBRANE => "likely cause: the membrane is too stiff for the time step (lower model.timestep) or the drive is beyond the scenario's bounds",
        _ => "likely cause: the drive is too strong for the fluid (Mach number) or the time step is too large",
    }
    };
    match &e {
        E::NonFinite { ptype, .. } | E::TooFast { ptype, .. } => {
            RunError::Engine(format!("{e} — the part is {}; {}", part(*ptype), hint(*ptype)))
        }
        _ => RunError::Engine(e.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cytosol meets the plasma and the wall by repulsion alone (no friction, no noise:
    /// nothing crosses the membrane but pressure); the vertices have each side's friction, the
    /// cytosol its own fluid's.
    #[test]
    fn the_cytosol_has_no_friction_across_the_membrane() {
        let fluid = FluidModel::capillary();
        let f = cell_fluid_field(&fluid, 5.0, 3.7, 1).unwrap();
        for other in [OUTER, WALL] {
            let q = f.pair(INNER as usize, other as usize);
            assert_eq!((q.gamma, q.kbt, q.a), (0.0, 0.0, fluid.pair.a), "cytosol–{other}");
        }
        assert_eq!(f.pair(OUTER as usize, WALL as usize).gamma, fluid.pair.gamma);
        assert_eq!(f.pair(INNER as usize, INNER as usize).gamma, fluid.inner_gamma(5.0));
        assert!(f.pair(MEMBRANE as usize, WALL as usize).gamma > 0.0);
        assert!(f.pair(MEMBRANE as usize, INNER as usize).gamma > f.pair(MEMBRANE as usize, OUTER as usize).gamma);
    }
}
