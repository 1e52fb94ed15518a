//! What every run shares, at the ground floor of the crate: where and how it runs
//! ([`RunContext`]), how it fails ([`RunError`]) and the flag that asks it to stop.

use std::path::PathBuf;
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
    #[error("{}: the output directory is in use by {holder}. Nothing was changed. Wait for that run to end (or stop it), or choose another --out; if that process is gone, {} is stale and the next run takes it over", dir.display(), lock_file.display())]
    Locked {
        dir: PathBuf,
        lock_file: PathBuf,
        holder: String,
    },
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
