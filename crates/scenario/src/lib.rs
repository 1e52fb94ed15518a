//! Scenario files and the drivers that run them.
//!
//! A scenario is a versioned TOML file in SI units (the unit is in each key's name, e.g.
//! `temperature_k`, `forces_pn`). [`load`] parses it, applies `--set key=value` overrides and
//! validates every value *before* any work starts; an error names the file, the key, the value
//! and what is allowed. [`run`] executes it and returns the results that go into
//! `summary.json`.

pub mod figures;
pub mod file;
pub mod fluid;
pub mod mesh_cache;
pub mod stretching;

pub use file::{load, load_str, Scenario, ScenarioError};

use std::path::PathBuf;

/// Version of the scenario file format this build reads.
pub const FORMAT_VERSION: u32 = 1;

/// Where and how a run happens.
#[derive(Clone, Debug)]
pub struct RunContext {
    /// Output directory (created if missing).
    pub out_dir: PathBuf,
    /// Worker threads (rayon pool size).
    pub threads: usize,
    /// Show progress on stderr.
    pub progress: bool,
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
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// Runs a validated scenario; returns its results (the `results` object of `summary.json`).
pub fn run(scenario: &Scenario, ctx: &RunContext) -> Result<serde_json::Value, RunError> {
    std::fs::create_dir_all(&ctx.out_dir).map_err(|source| RunError::Io {
        path: ctx.out_dir.clone(),
        source,
    })?;
    match scenario {
        Scenario::Stretching(s) => stretching::run(s, ctx),
        Scenario::DpdFluid(s) => fluid::run(s, ctx),
    }
}
