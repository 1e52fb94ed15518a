//! Running one scenario from the command line: the output directory's lock, the thread pool,
//! the run or its resume, and `summary.json`. `hemodpd run` and each sweep point go through here.

use anyhow::{bail, Context, Result};
use hemodpd_scenario::RunContext;
use serde_json::json;
use std::path::{Path, PathBuf};

/// Where a run of the scenario file `path` writes when no directory is given: `runs/STEM`.
pub fn default_out_dir(path: &Path) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "run".into());
    PathBuf::from("runs").join(stem)
}

/// Runs one scenario and writes its summary; returns the summary.
pub fn run_one(
    path: &Path,
    sets: &[String],
    out: Option<PathBuf>,
    threads: Option<usize>,
    quiet: bool,
) -> Result<serde_json::Value> {
    let scenario = hemodpd_scenario::load(path, sets)?;
    let threads = threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    if threads == 0 {
        bail!("--threads must be at least 1");
    }
    let out_dir = out.unwrap_or_else(|| default_out_dir(path));
    // the directory is this run's until the summary is written (the run itself takes the lock
    // again, re-entrantly; a second process stops here having changed nothing)
    let _lock = hemodpd_scenario::lock_out_dir(&out_dir, quiet).map_err(anyhow::Error::new)?;
    let ctx = RunContext::new(out_dir.clone(), threads, !quiet);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("starting the thread pool")?;
    if !quiet {
        eprintln!(
            "hemodpd {}: {} scenario {} -> {}",
            env!("CARGO_PKG_VERSION"),
            scenario.kind(),
            path.display(),
            out_dir.display()
        );
    }
    let t0 = std::time::Instant::now();
    let results = pool
        .install(|| hemodpd_scenario::run(&scenario, &ctx))
        .map_err(anyhow::Error::new)?;
    let wall = t0.elapsed().as_secs_f64();
    write_summary(path, &scenario, sets, threads, wall, results, &out_dir, quiet)
}

pub fn resume_run(dir: &Path, threads: Option<usize>, quiet: bool) -> Result<()> {
    let threads = threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    if !dir.is_dir() {
        bail!("--resume {}: no such run directory", dir.display());
    }
    let _lock = hemodpd_scenario::lock_out_dir(dir, quiet).map_err(anyhow::Error::new)?;
    let ctx = RunContext::new(dir.to_path_buf(), threads, !quiet);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("starting the thread pool")?;
    if !quiet {
        eprintln!("hemodpd {}: resuming {}", env!("CARGO_PKG_VERSION"), dir.display());
    }
    let t0 = std::time::Instant::now();
    let (scenario, results) = pool
        .install(|| hemodpd_scenario::resume(dir, &ctx))
        .map_err(anyhow::Error::new)?;
    let wall = t0.elapsed().as_secs_f64();
    let ck = dir.join(hemodpd_scenario::run_dir::CHECKPOINT_FILE);
    write_summary(&ck, &scenario, &[], threads, wall, results, dir, quiet)?;
    Ok(())
}

/// Writes DIR/summary.json: the resolved scenario, seed, versions, wall time and results.
#[allow(clippy::too_many_arguments)]
fn write_summary(
    path: &Path,
    scenario: &hemodpd_scenario::Scenario,
    sets: &[String],
    threads: usize,
    wall: f64,
    results: serde_json::Value,
    out_dir: &Path,
    quiet: bool,
) -> Result<serde_json::Value> {
    let summary = json!({
        "hemodpd_version": env!("CARGO_PKG_VERSION"),
        "versions": { "hemodpd": env!("CARGO_PKG_VERSION"), "scenario_format": hemodpd_scenario::FORMAT_VERSION, "trajectory_format": hemodpd_io::trajectory::TRAJECTORY_VERSION },
        "scenario_file": path,
        "scenario_kind": scenario.kind(),
        "scenario": scenario,
        "scenario_toml": scenario.to_toml(),
        "overrides": sets,
        "seed": scenario.seed(),
        "threads": threads,
        "wall_time_s": wall,
        "results": results,
    });
    hemodpd_io::summary::write_summary_json(out_dir, &summary).context("writing summary.json")?;
    if !quiet {
        eprintln!(
            "done in {wall:.2} s; summary: {}",
            out_dir.join("summary.json").display()
        );
    }
    Ok(summary)
}
