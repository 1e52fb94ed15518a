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
pub mod driver;
pub mod figures;
pub mod file;
pub mod fluid;
pub mod kind;
pub mod mesh_cache;
pub mod run_dir;
pub mod shear;
pub mod stretching;
pub mod units;

pub use file::{load, load_str, ScenarioError, FORMAT_VERSION};
pub use kind::{Kind, Scenario, KIND_NAMES};

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

/// Set (e.g. by a Ctrl-C handler) to ask a running scenario to stop: it writes a checkpoint and
/// a final frame, then returns [`RunError::Interrupted`].
pub static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// Where and how a run happens.
#[derive(Clone, Debug)]
pub struct RunContext {
    /// Output directory (created if missing).
    pub out_dir: PathBuf,
    /// Worker threads (rayon pool size).
    pub threads: usize,
    /// Show progress on stderr.
    pub progress: bool,
    /// Behave as if interrupted when this step is reached (tests of checkpoint/resume).
    pub stop_at_step: Option<u64>,
}

impl RunContext {
    /// A context writing to `out_dir` with `threads` threads, progress on or off.
    pub fn new(out_dir: impl Into<PathBuf>, threads: usize, progress: bool) -> Self {
        Self {
            out_dir: out_dir.into(),
            threads,
            progress,
            stop_at_step: None,
        }
    }

    /// A progress reporter for a stepped run from `start` to `total` steps (a bar on a terminal,
    /// log lines otherwise, nothing when progress is off).
    pub fn progress(&self, total: u64, start: u64) -> hemodpd_io::progress::Progress {
        use hemodpd_io::progress::{Progress, ProgressMode};
        let mode = if self.progress {
            ProgressMode::Auto
        } else {
            ProgressMode::Quiet
        };
        Progress::new(total, start, mode, 1.0, "τ")
    }
}

/// Errors of a run (after the scenario was validated).
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("mesh: {0}")]
    Mesh(#[from] hemodpd_membrane::meshgen::MeshGenError),
    #[error("mesh file: {0}")]
    MeshFile(#[from] hemodpd_membrane::MeshError),
    #[error("membrane model: {0}")]
    Force(#[from] hemodpd_membrane::forces::ForceError),
    #[error("stretching: {0}")]
    Stretch(#[from] hemodpd_membrane::stretch::StretchError),
    #[error("parameters: {0}")]
    Params(#[from] hemodpd_membrane::params::ParamsError),
    #[error("engine: {0}")]
    Engine(String),
    #[error("output: {0}")]
    Output(String),
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("interrupted at step {step}: the state is saved in {}/checkpoint.h5 (and a final frame in the trajectory, if the run writes one); continue with `hemodpd run --resume {}`", dir.display(), dir.display())]
    Interrupted { step: u64, dir: PathBuf },
    /// Another process holds the output directory's lock: nothing was touched.
    #[error("{}: the output directory is in use by {holder}. Nothing was changed. Wait for that run to end (or stop it), or choose another --out; if that process is gone, {} is stale and the next run takes it over", dir.display(), dir.join(run_dir::LOCK_FILE).display())]
    Locked { dir: PathBuf, holder: String },
    #[error("cannot resume from {dir}: {message}")]
    Resume { dir: PathBuf, message: String },
    /// `--resume` on a run whose checkpoint is already at its end: nothing to do, no file is
    /// touched. Not a failure (the CLI exits 0 with this message).
    #[error("{dir}: the run has finished ({done} of {total} {unit} done); nothing to resume. Its results are in {}", dir.join("summary.json").display())]
    Finished {
        dir: PathBuf,
        done: u64,
        total: u64,
        unit: &'static str,
    },
}

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
