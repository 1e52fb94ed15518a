//! Saving and restoring a cell-in-flow run, and creating its trajectory.
//!
//! A checkpoint holds, in this order: the kind and the scenario's directory (and, for kinds that
//! end early, whether the run has finished), the particles, the walls' state (with walls), the
//! kind's own progress (JSON), the cell's state, the resting mesh it was built on and where the
//! mesh came from.

use super::build::{cell_config, membrane_model, plan_field, plan_walls, CellPlan, CellSim};
use super::MEMBRANE;
use crate::context::{RunContext, RunError};
use crate::run_dir::{self, engine_err, particles_from_checkpoint, particles_into_checkpoint};
use hemodpd_engine::walls::WallsState;
use hemodpd_engine::{PeriodicBox, SimState, Simulation, Timed};
use hemodpd_io::checkpoint::{Checkpoint, ScalarValue};
use hemodpd_io::{RunMetadata, TrajectoryWriter};
use hemodpd_membrane::coupling::{Cell, CellState};
use hemodpd_membrane::Mesh;
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::path::Path;

/// What a kind writes at the head of its checkpoint.
pub(crate) struct CheckpointHead<'a> {
    /// The kind (`scenario_kind`), checked on restore.
    pub kind: &'static str,
    pub seed: u64,
    /// The resolved scenario, TOML.
    pub toml: &'a str,
    /// Directory of the scenario file (files it names are relative to it).
    pub base_dir: &'a Path,
    /// Whether the run has finished, for kinds that can end before their last step (None: not
    /// written).
    pub finished: Option<bool>,
}

/// Writes the checkpoint of a cell-in-flow run: `head`, the particles, the walls' state, the
/// kind's `progress`, the cell's state, the resting mesh `rest` and `mesh_info`.
pub(crate) fn save_cell_run(
    sim: &CellSim,
    head: &CheckpointHead,
    progress: &impl Serialize,
    rest: &Mesh,
    mesh_info: &serde_json::Value,
    ctx: &RunContext,
) -> Result<(), RunError> {
    let mut ck = Checkpoint::new(sim.step_count(), sim.time(), head.seed, head.toml.to_owned());
    ck.set_scalar("scenario_kind", ScalarValue::Str(head.kind.into()));
    ck.set_scalar(
        "base_dir",
        ScalarValue::Str(head.base_dir.to_string_lossy().into_owned()),
    );
    if let Some(finished) = head.finished {
        ck.set_scalar("finished", ScalarValue::Str(if finished { "yes" } else { "no" }.into()));
    }
    particles_into_checkpoint(&mut ck, sim.particles());
    let (walls_ext, cell) = sim.extension();
    if let Some(w) = walls_ext {
        run_dir::json_into_checkpoint(&mut ck, "walls_state_json", &w.inner.state())?;
    }
    run_dir::json_into_checkpoint(&mut ck, "progress_json", progress)?;
    cell_into_checkpoint(&mut ck, cell, rest, mesh_info)?;
    run_dir::save_checkpoint(&ck, ctx)
}

/// Saves what a cell-in-flow run needs to rebuild its cell: the cell's state, the resting mesh
/// it was built on (topology and reference state) and where the mesh came from.
fn cell_into_checkpoint(
    ck: &mut Checkpoint,
    cell: &Cell,
    rest: &Mesh,
    mesh_info: &serde_json::Value,
) -> Result<(), RunError> {
    run_dir::json_into_checkpoint(ck, "cell_state_json", &cell.state())?;
    ck.insert_vec3("membrane_rest_vertices", &rest.vertices);
    ck.insert_u32("membrane_triangles", rest.triangles.iter().flatten().copied().collect());
    run_dir::json_into_checkpoint(ck, "mesh_info_json", mesh_info)
}

/// The resting mesh saved by [`cell_into_checkpoint`].
fn rest_mesh_from_checkpoint(ck: &Checkpoint) -> Result<Mesh, RunError> {
    let bad = |e: hemodpd_io::IoError| RunError::Output(format!("checkpoint: {e}"));
    let verts = ck.vec3s("membrane_rest_vertices", None).map_err(bad)?;
    let tri_flat = ck.u32s("membrane_triangles").map_err(bad)?;
    let triangles: Vec<[u32; 3]> = tri_flat.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
    Ok(Mesh::new(verts, triangles)?)
}

/// A cell-in-flow run restored from a checkpoint: the simulation, the resting mesh, the kind's
/// progress and where the mesh came from.
pub(crate) struct Restored<P> {
    pub sim: CellSim,
    pub rest: Mesh,
    pub progress: P,
    pub mesh_info: serde_json::Value,
}

/// Restores the run that [`save_cell_run`] saved, after checking that the checkpoint is of
/// `kind`: the cell is rebuilt on the saved resting mesh with `plan`'s membrane model, then
/// given its saved state; the walls likewise.
pub(crate) fn restore_cell_run<P: DeserializeOwned>(
    plan: &impl CellPlan,
    kind: &str,
    ck: &Checkpoint,
) -> Result<Restored<P>, RunError> {
    let bad = |e: hemodpd_io::IoError| RunError::Output(format!("checkpoint: {e}"));
    let saved_kind = ck.scalar_str("scenario_kind").map_err(bad)?;
    if saved_kind != kind {
        return Err(RunError::Output(format!(
            "checkpoint of a {saved_kind} run, not {kind}"
        )));
    }
    let particles = particles_from_checkpoint(ck)?;
    let rest = rest_mesh_from_checkpoint(ck)?;
    let model = membrane_model(plan.cell(), plan.map(), &rest)?;
    let field = plan_field(plan, &rest)?;
    let first = particles
        .ptype
        .iter()
        .position(|&t| t == MEMBRANE)
        .ok_or_else(|| RunError::Output("checkpoint: no membrane vertices".into()))?;
    let cs: CellState = run_dir::json_from_checkpoint(ck, "cell_state_json")?;
    let cell = Cell::new(model, cell_config(plan, first), rest.vertices.clone())
        .and_then(|c| c.with_state(cs))
        .map_err(engine_err)?;
    let walls_ext = match plan_walls(plan)? {
        Some(walls) => {
            let ws: WallsState = run_dir::json_from_checkpoint(ck, "walls_state_json")?;
            let domain = PeriodicBox::new(plan.box_lengths()).map_err(engine_err)?;
            Some(Timed::new(walls.with_state(ws, &domain).map_err(engine_err)?))
        }
        None => None,
    };
    let state = SimState {
        config: plan.sim_config(),
        field,
        particles,
        step: ck.step,
    };
    let sim = Simulation::from_state(state, (walls_ext, cell)).map_err(engine_err)?;
    let progress: P = run_dir::json_from_checkpoint(ck, "progress_json")?;
    let mesh_info: serde_json::Value = run_dir::json_from_checkpoint(ck, "mesh_info_json")?;
    Ok(Restored {
        sim,
        rest,
        progress,
        mesh_info,
    })
}

/// Opens the trajectory of a cell-in-flow run that writes a frame every `frame_every` steps
/// (the reopen rule of [`run_dir::open_trajectory`] on resume); a new file gets `meta`, the
/// membrane's triangles and its reference area and volume.
pub(crate) fn open_cell_trajectory(
    ctx: &RunContext,
    checkpoint: Option<&Checkpoint>,
    frame_every: u64,
    meta: impl FnOnce() -> RunMetadata,
    sim: &CellSim,
    rest: &Mesh,
) -> Result<TrajectoryWriter, RunError> {
    let last_frame = checkpoint.and_then(|ck| run_dir::last_scheduled_frame(ck.step, 0, frame_every));
    run_dir::open_trajectory(ctx, checkpoint.is_some(), last_frame, |path| {
        let mut w = TrajectoryWriter::create(path, &meta())?;
        w.write_mesh(&rest.triangles)?;
        let cell = &sim.extension().1;
        w.set_membrane_reference(cell.model().area0(), cell.model().volume0())?;
        Ok(w)
    })
}
