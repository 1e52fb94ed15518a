//! Scenario files and the drivers that run them.
//!
//! A scenario is a versioned TOML file in SI units (the unit is in each key's name, e.g.
//! `temperature_k`, `forces_pn`). [`load`] parses it, applies `--set key=value` overrides and
//! validates every value *before* any work starts; an error names the file, the key, the value
//! and what is allowed. [`run`] executes it and returns the results that go into
//! `summary.json`.

pub mod capillary;
pub mod cell;
pub mod channel;
pub mod context;
pub mod driver;
pub mod figures;
pub mod file;
pub mod fluid;
pub mod fluid_choice;
pub mod kind;
pub mod mesh_cache;
pub mod movie;
pub mod parameter_sets;
pub mod registry;
pub mod run_dir;
pub mod shear;
pub mod stretching;
pub mod units;

pub use context::{RunContext, RunError, INTERRUPTED};
pub use file::{ScenarioError, FORMAT_VERSION};
pub use kind::Kind;
pub use registry::{load, load_str, sweep_columns, Scenario, KIND_NAMES};

use std::path::{Path, PathBuf};

/// Resumes the run whose checkpoint is in `dir` (written by an earlier run into the same
/// directory); returns the scenario it holds and the results. The output continues in `dir`.
pub fn resume(dir: &Path, ctx: &RunContext) -> Result<(Scenario, serde_json::Value), RunError> {
    let _lock = lock_out_dir(dir, !ctx.progress)?;
    let err = |message: String| RunError::Resume {
        dir: dir.to_path_buf(),
        message,
    };
    let loaded = run_dir::load_checkpoint(dir)?;
    if let Some(w) = &loaded.warning {
        eprintln!("warning: {w}");
    }
    let ck = loaded.checkpoint;
    let path = ck.source.clone().unwrap_or_else(|| dir.join(run_dir::CHECKPOINT_FILE));
    let mut scenario =
        load_str(&ck.scenario_toml, &format!("{} (scenario)", path.display()), &[]).map_err(|e| err(e.to_string()))?;
    // files named in the scenario (a mesh, a wall force profile) are relative to its directory
    if let Ok(dir) = ck.scalar_str("base_dir").map(PathBuf::from) {
        scenario.set_base_dir(dir);
    }
    // the checkpoint must be one of its own scenario's kind (a file renamed or copied from
    // another run would otherwise fail later, or worse, run)
    match ck.scalar_str("scenario_kind") {
        Ok(kind) if kind == scenario.kind() => {}
        Ok(kind) => {
            return Err(err(format!(
                "the checkpoint is marked as a {kind} run, but its scenario is a {} scenario",
                scenario.kind()
            )))
        }
        Err(e) => return Err(err(format!("the checkpoint does not name its kind: {e}"))),
    }
    if scenario.seed() != ck.seed {
        return Err(err(format!(
            "checkpoint seed {} differs from its scenario's seed {}",
            ck.seed,
            scenario.seed()
        )));
    }
    // a finished run: say so and touch nothing (appending to its files would repeat the end)
    let (total, unit) = scenario.schedule_end();
    // stages that end when steady finish before their longest duration: the checkpoint says so
    let marked = ck.scalar_str("finished").map(|f| f == "yes").unwrap_or(false);
    if ck.step >= total || marked {
        return Err(RunError::Finished {
            dir: dir.to_path_buf(),
            done: ck.step,
            total,
            unit,
        });
    }
    let ctx = RunContext {
        out_dir: dir.to_path_buf(),
        ..ctx.clone()
    };
    let results = scenario.run_from(&ctx, Some(&ck))?;
    Ok((scenario, results))
}

/// Runs a validated scenario; returns its results (the `results` object of `summary.json`).
pub fn run(scenario: &Scenario, ctx: &RunContext) -> Result<serde_json::Value, RunError> {
    let _lock = lock_out_dir(&ctx.out_dir, !ctx.progress)?;
    scenario.run_from(ctx, None)
}

/// Locks a run's output directory (see [`run_dir::DirLock`]); says so on stderr, unless `quiet`,
/// when a stale lock is taken over. Re-entrant within a process.
pub fn lock_out_dir(dir: &Path, quiet: bool) -> Result<run_dir::DirLock, RunError> {
    let lock = run_dir::DirLock::acquire(dir)?;
    if let (Some(old), false) = (lock.took_over(), quiet) {
        eprintln!(
            "note: {} was left by {old}, which has ended; taking it over",
            dir.join(run_dir::LOCK_FILE).display()
        );
    }
    Ok(lock)
}
