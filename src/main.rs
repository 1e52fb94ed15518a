//! `hemodpd`: red blood cells in DPD flow. Runs scenario files (SI in, SI out), prints the
//! coarse-grained parameters, makes meshes, and analyses trajectories.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use hemodpd_membrane::params::ModelParams;
use hemodpd_scenario::{mesh_cache, RunContext};
use serde_json::json;
use std::path::{Path, PathBuf};

#[derive(Parser)]
#[command(name = "hemodpd", version, about = "Red blood cells in dissipative particle dynamics flow (Pivkin & Karniadakis 2008 model)")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scenario file; writes DIR/summary.json and the scenario's output files.
    Run {
        /// Scenario file (TOML, SI units).
        scenario: PathBuf,
        /// Override a key, e.g. --set membrane.vertices=1000 (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
        /// Output directory (default: runs/<scenario name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// No progress output.
        #[arg(long)]
        quiet: bool,
    },
    /// Validate scenario files without running them.
    Check {
        scenarios: Vec<PathBuf>,
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
    },
    /// Print the coarse-grained model parameters (SI) for N vertices.
    Params {
        /// Number of vertices (>= 100).
        #[arg(long)]
        n: usize,
        /// Temperature, K.
        #[arg(long, default_value_t = 300.0)]
        temperature_k: f64,
        /// Machine-readable JSON.
        #[arg(long)]
        json: bool,
    },
    /// Generate the relaxed Evans–Fung mesh with N vertices and write it (OFF, PLY or CSV by extension; µm).
    Mesh {
        #[arg(long)]
        n: usize,
        /// Output file: .off, .ply or .csv (NAME.vertices.csv + NAME.triangles.csv).
        #[arg(short = 'o', long)]
        output: PathBuf,
        /// Seed of the point distribution.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Regenerate even if the mesh is cached.
        #[arg(long)]
        no_cache: bool,
    },
}

fn main() {
    let cli = Cli::parse();
    if let Err(e) = dispatch(cli) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn dispatch(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Run { scenario, sets, out, threads, quiet } => run(&scenario, &sets, out, threads, quiet),
        Command::Check { scenarios, sets } => {
            if scenarios.is_empty() {
                bail!("no scenario files given");
            }
            for s in &scenarios {
                let sc = hemodpd_scenario::load(s, &sets)?;
                println!("{}: ok ({})", s.display(), sc.kind());
            }
            Ok(())
        }
        Command::Params { n, temperature_k, json } => params(n, temperature_k, json),
        Command::Mesh { n, output, seed, no_cache } => mesh(n, &output, seed, no_cache),
    }
}

fn run(path: &Path, sets: &[String], out: Option<PathBuf>, threads: Option<usize>, quiet: bool) -> Result<()> {
    let scenario = hemodpd_scenario::load(path, sets)?;
    let threads = threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    if threads == 0 {
        bail!("--threads must be at least 1");
    }
    let stem = path.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or_else(|| "run".into());
    let out_dir = out.unwrap_or_else(|| PathBuf::from("runs").join(stem));
    let ctx = RunContext { out_dir: out_dir.clone(), threads, progress: !quiet };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().context("starting the thread pool")?;
    if !quiet {
        eprintln!("hemodpd {}: {} scenario {} -> {}", env!("CARGO_PKG_VERSION"), scenario.kind(), path.display(), out_dir.display());
    }
    let t0 = std::time::Instant::now();
    let results = pool.install(|| hemodpd_scenario::run(&scenario, &ctx)).with_context(|| format!("running {}", path.display()))?;
    let wall = t0.elapsed().as_secs_f64();
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
    hemodpd_io::summary::write_summary_json(&out_dir, &summary).context("writing summary.json")?;
    if !quiet {
        eprintln!("done in {wall:.2} s; summary: {}", out_dir.join("summary.json").display());
    }
    Ok(())
}

fn params(n: usize, temperature_k: f64, as_json: bool) -> Result<()> {
    let p = ModelParams::coarse_grained(n, temperature_k).context("--n / --temperature-k")?;
    let shape = hemodpd_membrane::shape::EvansFung::healthy_um();
    let (a0_um2, v0_um3) = shape.area_and_volume();
    let j = json!({
        "n": p.n,
        "temperature_k": p.temperature_k,
        "kbt_j": p.kbt_j,
        "l0_m": p.l0_m,
        "lmax_m": p.lmax_m,
        "persistence_length_m": p.persistence_length_m,
        "c_j_m2": p.c_j_m2,
        "theta0_deg": p.theta0_deg,
        "k_bend_j": p.k_bend_j,
        "shear_modulus_n_per_m": p.shear_modulus_n_per_m,
        "area_modulus_n_per_m": p.area_modulus_n_per_m,
        "young_modulus_n_per_m": p.young_modulus_n_per_m,
        "area0_m2": a0_um2 * 1e-12,
        "volume0_m3": v0_um3 * 1e-18,
    });
    if as_json {
        println!("{}", serde_json::to_string_pretty(&j)?);
    } else {
        println!("Coarse-grained RBC model, N = {} vertices, T = {} K (Pivkin & Karniadakis 2008)", p.n, p.temperature_k);
        println!("  kBT                 {:.6e} J", p.kbt_j);
        println!("  L0      (Eq. 8)     {:.6e} m", p.l0_m);
        println!("  Lmax    (3.17 L0)   {:.6e} m", p.lmax_m);
        println!("  p       (Eq. 12)    {:.6e} m", p.persistence_length_m);
        println!("  C       (Eq. 4)     {:.6e} J m^2   (Table I prints ~4x this: see docs/model.md)", p.c_j_m2);
        println!("  theta0  (Eq. 9)     {:.4} deg", p.theta0_deg);
        println!("  k_bend  (200 kBT)   {:.6e} J", p.k_bend_j);
        println!("  mu0     (Eq. 10)    {:.6e} N/m", p.shear_modulus_n_per_m);
        println!("  K       (Eq. 11)    {:.6e} N/m", p.area_modulus_n_per_m);
        println!("  Y = 4K mu0/(K+mu0)  {:.6e} N/m", p.young_modulus_n_per_m);
        println!("  A0 (Evans-Fung)     {:.6e} m^2", a0_um2 * 1e-12);
        println!("  V0 (Evans-Fung)     {:.6e} m^3", v0_um3 * 1e-18);
    }
    Ok(())
}

fn mesh(n: usize, output: &Path, seed: u64, no_cache: bool) -> Result<()> {
    ModelParams::coarse_grained(n, 300.0).context("--n")?;
    let t0 = std::time::Instant::now();
    let (mesh, origin) = if no_cache {
        let (m, report) = mesh_cache::generate(n, seed)?;
        (m, json!({ "from_cache": false, "relax": report }))
    } else {
        let (m, o) = mesh_cache::relaxed_mesh(n, seed)?;
        (m, json!(o))
    };
    let files = if output.extension().is_some_and(|e| e == "h5") {
        // the same layout as every trajectory: the triangles once and one frame of positions
        let meta = hemodpd_io::RunMetadata::new("mesh", format!("n = {n}\nseed = {seed}\n"), seed, hemodpd_scenario::stretching::stretching_units());
        let write = || -> hemodpd_io::Result<()> {
            let mut w = hemodpd_io::TrajectoryWriter::create(output, &meta)?;
            w.write_mesh(&mesh.triangles)?;
            w.set_membrane_reference(mesh.area(), mesh.volume())?;
            w.append_membrane_frame(0, 0.0, &mesh.vertices, None, &[])?;
            w.close()
        };
        write().with_context(|| format!("writing {}", output.display()))?;
        vec![output.to_path_buf()]
    } else {
        hemodpd_membrane::meshio::write_mesh(&mesh, output)?
    };
    let q = mesh.quality()?;
    eprintln!("mesh N = {n}, seed {seed}: {:.2} s ({})", t0.elapsed().as_secs_f64(), origin);
    println!("{}", serde_json::to_string_pretty(&json!({ "files": files, "quality": q }))?);
    Ok(())
}
