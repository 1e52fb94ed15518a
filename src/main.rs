//! `hemodpd`: red blood cells in DPD flow. Runs scenario files (SI in, SI out), prints the
//! coarse-grained parameters, makes meshes, and analyses trajectories.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use hemodpd_membrane::params::ModelParams;
use hemodpd_scenario::mesh_cache;
use serde_json::json;
use std::path::{Path, PathBuf};

use hemodpd::run::{resume_run, run_one};
use hemodpd::sweep;

/// mimalloc: faster allocation, and on Linux it asks for transparent huge pages
/// (`madvise(MADV_HUGEPAGE)`) for its large regions, which holds the engine's particle arrays in
/// fewer TLB entries (docs/performance.md, "Changes tried").
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[derive(Parser)]
#[command(
    name = "hemodpd",
    version,
    about = "Red blood cells in dissipative particle dynamics flow (Pivkin & Karniadakis 2008 model)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scenario file; writes DIR/summary.json and the scenario's output files.
    /// Ctrl-C writes a checkpoint and a final frame; `--resume DIR` continues from it.
    Run {
        /// Scenario file (TOML, SI units).
        #[arg(required_unless_present = "resume")]
        scenario: Option<PathBuf>,
        /// Continue the interrupted run in DIR from its checkpoint (bit-identical to an
        /// uninterrupted run); the output continues in DIR.
        #[arg(long, value_name = "DIR", conflicts_with_all = ["scenario", "sets", "out"])]
        resume: Option<PathBuf>,
        /// Override a key, e.g. --set membrane.vertices=1000 (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
        /// Output directory (default: the scenario's name, under runs/).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// No progress output.
        #[arg(long)]
        quiet: bool,
        /// Print how SI maps onto model units (every scale, every dimensionless group in both
        /// systems, the time step in seconds) and exit without running (capillary and shear scenarios).
        #[arg(long, conflicts_with = "resume")]
        explain_units: bool,
        /// Calibrated parameters from `hemodpd fit` (its calibrated.toml): the overrides for
        /// this scenario's kind, applied before any --set.
        #[arg(long, value_name = "CALIBRATED.toml", conflicts_with = "resume")]
        params: Option<PathBuf>,
    },
    /// Calibrate parameters against experiments (docs/fit.md): a grid design run through
    /// `hemodpd sweep` per experiment (resumable; --emit-slurm for a cluster), a quadratic
    /// response surface of χ², the minimum with its Δχ² = 1 uncertainties; writes
    /// OUT/calibrated.toml (for `hemodpd run --params`) and OUT/fit.json.
    Fit {
        /// The fit file (TOML: [[parameter]] name/lower/upper/points, [[experiment]] by name or
        /// with a scenario, parameter keys and observables).
        file: PathBuf,
        /// Output directory (default: runs/STEM).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Runs at once.
        #[arg(long, default_value_t = 1)]
        jobs: usize,
        /// Worker threads of each run (default: the cores divided by --jobs).
        #[arg(long)]
        threads_per_job: Option<usize>,
        /// No progress output.
        #[arg(long)]
        quiet: bool,
        /// Write one Slurm job array per experiment into OUT/<experiment> instead of running;
        /// run the same command without it after the jobs to fit.
        #[arg(long)]
        emit_slurm: bool,
        #[command(flatten)]
        slurm: SlurmArgs,
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
    /// Run a scenario for every point of a grid: --vary membrane.vertices=100,500,5000.
    /// Each point goes to DIR/<key=value,...>/; DIR/sweep.csv and DIR/sweep.json tabulate them.
    /// Points run in parallel (--jobs) as child processes; run the same command again to
    /// continue an interrupted sweep. --emit-slurm writes a Slurm job-array script instead
    /// (docs/sweeps.md).
    Sweep {
        scenario: PathBuf,
        /// KEY=V1,V2,... (repeatable: the points are the cartesian product, first axis slowest).
        #[arg(long = "vary", value_name = "KEY=V1,V2,...", required = true)]
        vary: Vec<String>,
        /// Pair the i-th values of every --vary instead of combining them all (equal lengths).
        #[arg(long)]
        zip: bool,
        /// Override a key in every run (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
        /// Output directory (default: the scenario's name followed by -sweep, under runs/).
        #[arg(long, conflicts_with = "emit_slurm")]
        out: Option<PathBuf>,
        /// Points run at once.
        #[arg(long, default_value_t = 1, conflicts_with = "emit_slurm")]
        jobs: usize,
        /// Worker threads of each point (default: the cores divided by --jobs).
        #[arg(long = "threads-per-job", alias = "threads", value_name = "T")]
        threads_per_job: Option<usize>,
        /// Allow a grid of more than 100 points.
        #[arg(long)]
        yes: bool,
        #[arg(long)]
        quiet: bool,
        /// Write DIR/sweep.sbatch, a Slurm job array with one task per point, instead of running
        /// (DIR is the sweep directory; collect with `hemodpd sweep-collect DIR`).
        #[arg(long, value_name = "DIR")]
        emit_slurm: Option<PathBuf>,
        #[command(flatten)]
        slurm: SlurmArgs,
    },
    /// Run one point of a sweep directory (what each Slurm array task runs): a finished point is
    /// skipped, one with a checkpoint resumes, any other runs from the start.
    SweepTask {
        /// The sweep directory (with sweep-manifest.json).
        dir: PathBuf,
        /// The point's index (0-based, the Slurm array task id).
        index: usize,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        #[arg(long)]
        quiet: bool,
        /// Checkpoint and stop when standard input closes (used by a local sweep for its children).
        #[arg(long, hide = true)]
        watch_stdin: bool,
    },
    /// Gather the table (sweep.csv, sweep.json) of a sweep directory, e.g. after a Slurm job
    /// array; lists the points not done and the command to resubmit only those (exit status 2).
    SweepCollect {
        /// The sweep directory (with sweep-manifest.json).
        dir: PathBuf,
    },
    /// Plot stretching curves (D_A, D_T vs force) of runs or sweeps against Mills et al. 2004.
    Plot {
        /// Run directories (with summary.json) or sweep.json files.
        inputs: Vec<PathBuf>,
        /// Output PNG.
        #[arg(short = 'o', long)]
        output: PathBuf,
        #[arg(long, default_value = "RBC stretching")]
        title: String,
    },
    /// Render membrane shapes from a trajectory (e.g. shapes.h5) as a PNG of panels, or as a movie (--movie out.gif).
    Render {
        trajectory: PathBuf,
        /// Frame indices (default: all).
        #[arg(long, value_delimiter = ',')]
        frames: Vec<usize>,
        /// Panels per row.
        #[arg(long, default_value_t = 3)]
        columns: usize,
        /// Draw the triangulation.
        #[arg(long)]
        edges: bool,
        /// The view: "oblique" (stretching shapes) or "tube-side" (a capillary run: the tube
        /// along z seen from the side, the flow left to right). Default: tube-side for capillary
        /// trajectories, oblique otherwise.
        #[arg(long)]
        view: Option<String>,
        /// The PNG of panels.
        #[arg(short = 'o', long, required_unless_present = "movie")]
        output: Option<PathBuf>,
        /// A movie of the frames instead (.gif, or .mp4 when ffmpeg is installed): a capillary
        /// run from the side with the tube drawn, following the cell; a shear run along the
        /// vorticity with the flow marked; others obliquely (docs/output.md, "Movies").
        #[arg(long, conflicts_with = "output")]
        movie: Option<PathBuf>,
        /// Movie frames per second.
        #[arg(long, default_value_t = 10.0)]
        fps: f64,
        /// What colours the cell in a movie: "shading", "speed" (|v − v_cell| per vertex) or
        /// "area-strain" (local area against the first frame).
        #[arg(long, default_value = "shading")]
        color_by: String,
    },
    /// Analyse the membrane frames of a trajectory after the fact (CSV + JSON, PNGs with --plot).
    ///
    /// Which files get which metrics:
    ///
    /// - Any trajectory with a membrane (today: a stretching run's shapes.h5, one frame per
    ///   force; `hemodpd mesh -o FILE.h5`): per frame the centroid, the velocity (stored vertex
    ///   velocities, else the centroid's finite difference over the frames' times; a stretching
    ///   run's frame time is the frame index, so its "velocity" is per frame, not physical), the
    ///   axial (x) and transverse diameters, the surface gyration tensor's eigenvalues and axes,
    ///   the inclination in the x-y plane, the asphericity, the deformation index and L/B, and
    ///   the area and volume with their deviation from /membrane@reference_area/_volume (else
    ///   frame 0).
    ///
    /// - Shear runs only (the file's /extra@flow = "shear", or a scenario name containing
    ///   "shear"; no shipped scenario writes one yet): also the tumbling and tank-treading rates
    ///   and frequencies and the inclination's mean and amplitude. They need several frames
    ///   closer than a quarter turn.
    ///
    /// - Fluid-only trajectories (dpd-fluid, poiseuille-tube, couette) hold no membrane and are
    ///   refused: their results are in summary.json and velocity_profile.csv; open the .xmf in
    ///   ParaView or the .h5 with h5py (docs/output.md).
    #[command(verbatim_doc_comment)]
    Analyze {
        trajectory: PathBuf,
        /// Output directory (default: beside the trajectory, NAME.analysis/).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Also write PNG time series.
        #[arg(long)]
        plot: bool,
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

/// The Slurm options of `sweep --emit-slurm` and `fit --emit-slurm`.
#[derive(clap::Args, Debug)]
struct SlurmArgs {
    /// Slurm time limit of each task (--time).
    #[arg(long, value_name = "TIME", default_value = "01:00:00", requires = "emit_slurm")]
    slurm_time: String,
    /// Slurm memory of each task (--mem, e.g. 4G; default: the cluster's).
    #[arg(long, value_name = "SIZE", requires = "emit_slurm")]
    slurm_mem: Option<String>,
    /// Slurm partition (default: the cluster's).
    #[arg(long, value_name = "NAME", requires = "emit_slurm")]
    slurm_partition: Option<String>,
    /// Slurm account (default: yours).
    #[arg(long, value_name = "NAME", requires = "emit_slurm")]
    slurm_account: Option<String>,
    /// CPUs of each task (--cpus-per-task), also its threads.
    #[arg(long, value_name = "N", default_value_t = 1, requires = "emit_slurm")]
    slurm_cpus: usize,
}

impl SlurmArgs {
    fn options(self) -> sweep::slurm::SlurmOptions {
        sweep::slurm::SlurmOptions {
            time: self.slurm_time,
            mem: self.slurm_mem,
            partition: self.slurm_partition,
            account: self.slurm_account,
            cpus: self.slurm_cpus,
        }
    }
}

/// Ctrl-C / SIGTERM deliveries so far: the first asks the run to checkpoint and stop, a second
/// exits at once. (Counted apart from INTERRUPTED, which a sweep's child also sets when its
/// parent closes its stdin.)
static SIGNALS: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);

fn main() {
    let cli = Cli::parse();
    // First Ctrl-C (or SIGTERM, as Slurm sends at a time limit): ask the run to checkpoint and
    // stop; a second one exits at once.
    let _ = ctrlc::set_handler(|| {
        hemodpd_scenario::INTERRUPTED.store(true, std::sync::atomic::Ordering::SeqCst);
        if SIGNALS.fetch_add(1, std::sync::atomic::Ordering::SeqCst) > 0 {
            std::process::exit(130);
        }
    });
    if let Err(e) = dispatch(cli) {
        if let Some(x) = e.downcast_ref::<sweep::ExitWith>() {
            eprintln!("{}", x.message);
            std::process::exit(x.code);
        }
        match e.downcast_ref::<hemodpd_scenario::RunError>() {
            Some(hemodpd_scenario::RunError::Interrupted { .. }) => {
                eprintln!("{e}");
                std::process::exit(130);
            }
            // `--resume` on a finished run: nothing to do, nothing written
            Some(hemodpd_scenario::RunError::Finished { .. }) => {
                println!("{e}");
                std::process::exit(0);
            }
            _ => {}
        }
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn dispatch(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Run {
            scenario,
            resume,
            sets,
            out,
            threads,
            quiet,
            explain_units,
            params,
        } => {
            let sets = match (&params, &scenario) {
                (Some(p), Some(s)) => {
                    let kind = hemodpd_scenario::load(s, &sets)?.kind().to_string();
                    let mut all = hemodpd::fit::params_sets(p, &kind)?;
                    all.extend(sets);
                    all
                }
                _ => sets,
            };
            match (scenario, resume) {
                (Some(scenario), None) if explain_units => explain(&scenario, &sets),
                (_, Some(dir)) => resume_run(&dir, threads, quiet),
                (Some(scenario), None) => run(&scenario, &sets, out, threads, quiet),
                (None, None) => bail!("give a scenario file or --resume DIR"),
            }
        }
        Command::Fit {
            file,
            out,
            jobs,
            threads_per_job,
            quiet,
            emit_slurm,
            slurm,
        } => hemodpd::fit::fit(hemodpd::fit::FitArgs {
            file,
            out,
            jobs,
            threads_per_job,
            quiet,
            emit_slurm,
            slurm: slurm.options(),
        })
        .map(|_| ()),
        Command::Analyze { trajectory, out, plot } => analyze(&trajectory, out, plot),
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
        Command::Sweep {
            scenario,
            vary,
            zip,
            sets,
            out,
            jobs,
            threads_per_job,
            yes,
            quiet,
            emit_slurm,
            slurm,
        } => sweep::sweep(sweep::SweepArgs {
            scenario,
            vary,
            sets,
            zip,
            jobs,
            threads_per_job,
            yes,
            out,
            quiet,
            emit_slurm,
            slurm: slurm.options(),
        }),
        Command::SweepTask {
            dir,
            index,
            threads,
            quiet,
            watch_stdin,
        } => {
            if watch_stdin {
                // the parent sweep closes our stdin (or dies) to ask for a checkpoint and a stop
                std::thread::spawn(|| {
                    let _ = std::io::copy(&mut std::io::stdin(), &mut std::io::sink());
                    hemodpd_scenario::INTERRUPTED.store(true, std::sync::atomic::Ordering::SeqCst);
                });
            }
            sweep::task(&dir, index, threads, quiet)
        }
        Command::SweepCollect { dir } => sweep::collect(&dir),
        Command::Plot { inputs, output, title } => plot(&inputs, &output, &title),
        Command::Render {
            trajectory,
            frames,
            columns,
            edges,
            view,
            output,
            movie,
            fps,
            color_by,
        } => match (movie, output) {
            (Some(movie), _) => {
                let opts = hemodpd_scenario::movie::MovieOptions {
                    frames,
                    fps,
                    color_by: color_by.parse()?,
                };
                let r = hemodpd_scenario::movie::write_movie(&trajectory, &movie, &opts)
                    .with_context(|| format!("rendering {} into {}", trajectory.display(), movie.display()))?;
                eprintln!(
                    "wrote {}: {} frames of {}×{}, {} view",
                    r.path.display(),
                    r.frames,
                    r.width,
                    r.height,
                    r.view
                );
                Ok(())
            }
            (None, Some(output)) => render(&trajectory, &frames, columns, edges, view.as_deref(), &output),
            (None, None) => bail!("give --output FILE.png or --movie FILE.gif"),
        },
        Command::Mesh {
            n,
            output,
            seed,
            no_cache,
        } => mesh(n, &output, seed, no_cache),
    }
}

fn run(path: &Path, sets: &[String], out: Option<PathBuf>, threads: Option<usize>, quiet: bool) -> Result<()> {
    run_one(path, sets, out, threads, quiet).map(|_| ())
}

/// `run --explain-units`: the unit mapping of a scenario in SI.
fn explain(path: &Path, sets: &[String]) -> Result<()> {
    let sc = hemodpd_scenario::load(path, sets)?;
    match sc.explain_units() {
        Some(text) => {
            print!("{}", text?);
            Ok(())
        }
        None => bail!(
            "--explain-units: {} is a {} scenario, written in model units already; only the kinds in SI (capillary, shear) map SI onto the model",
            path.display(),
            sc.kind()
        ),
    }
}

fn read_json(path: &Path) -> Result<serde_json::Value> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{} is not JSON", path.display()))
}

fn plot(inputs: &[PathBuf], output: &Path, title: &str) -> Result<()> {
    use hemodpd_scenario::figures::{stretching_chart, Curve};
    let mut curves = Vec::new();
    for input in inputs {
        let label_dirs: Vec<(String, PathBuf)> =
            if input.is_file() && input.file_name().is_some_and(|n| n == "sweep.json") {
                let sw = read_json(input)?;
                // `dir` is the sweep directory as given to `sweep` joined with the point's
                // directory; `point_dir` is the point's directory inside the sweep directory
                let base = input.parent().unwrap_or(Path::new("."));
                sw["runs"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .filter(|r| r["status"].as_str().is_none_or(|s| s == "done"))
                    .map(|r| {
                        let dir = PathBuf::from(r["dir"].as_str().unwrap_or(""));
                        let in_sweep = base.join(r["point_dir"].as_str().unwrap_or(""));
                        (
                            r["label"].as_str().unwrap_or("").to_string(),
                            if r["point_dir"].is_string() && in_sweep.exists() {
                                in_sweep
                            } else {
                                dir
                            },
                        )
                    })
                    .collect()
            } else {
                vec![(
                    input
                        .file_name()
                        .map(|n| n.to_string_lossy().to_string())
                        .unwrap_or_default(),
                    input.clone(),
                )]
            };
        for (label, dir) in label_dirs {
            let summary = read_json(&dir.join("summary.json"))?;
            let curve = Curve::from_summary(&label, &summary)
                .with_context(|| format!("{}: not a stretching run", dir.display()))?;
            curves.push(Curve {
                label: curve.label.replace("membrane.", "").replace("stretching.", ""),
                ..curve
            });
        }
    }
    if curves.is_empty() {
        bail!("no runs to plot");
    }
    stretching_chart(output, title, &curves)?;
    eprintln!("wrote {}", output.display());
    Ok(())
}

fn render(
    trajectory: &Path,
    frames: &[usize],
    columns: usize,
    edges: bool,
    view: Option<&str>,
    output: &Path,
) -> Result<()> {
    use hemodpd_scenario::figures::View;
    let reader = hemodpd_io::TrajectoryReader::open(trajectory)?;
    let view = match view {
        Some("oblique") => View::Oblique,
        Some("tube-side") => View::TubeSide,
        Some(other) => bail!("--view {other}: use \"oblique\" or \"tube-side\""),
        None if reader.metadata().scenario_name == "capillary" => View::TubeSide,
        None => View::Oblique,
    };
    let triangles = reader.triangles()?;
    let n = reader.membrane_frames()?;
    let frames: Vec<usize> = if frames.is_empty() {
        (0..n).collect()
    } else {
        frames.to_vec()
    };
    let forces = reader.membrane_scalar("force").ok();
    let mut data = Vec::new();
    for &i in &frames {
        if i >= n {
            bail!("{}: frame {i} requested, the file has {n} frames", trajectory.display());
        }
        let f = reader.membrane_frame(i)?;
        let um: Vec<glam::DVec3> = f.positions.iter().map(|p| *p * 1e6).collect();
        let title = match &forces {
            Some(fs) => format!("{:.0} pN", fs[i] * 1e12),
            None => format!("t = {:.1} ms", f.time * 1e3),
        };
        data.push((title, um));
    }
    let shapes: Vec<hemodpd_scenario::figures::Shape> = data
        .iter()
        .map(|(t, p)| hemodpd_scenario::figures::Shape {
            title: t.clone(),
            positions: p,
            triangles: &triangles,
        })
        .collect();
    hemodpd_scenario::figures::render_shapes_view(output, &shapes, columns, edges, view)
        .map_err(|e| anyhow::anyhow!("rendering {}: {e}", output.display()))?;
    eprintln!("wrote {}", output.display());
    Ok(())
}

fn analyze(trajectory: &Path, out: Option<PathBuf>, plot: bool) -> Result<()> {
    use hemodpd_io::analysis;
    // a fluid-only file (dpd-fluid, the wall scenarios) has nothing for this command
    if let Ok(r) = hemodpd_io::TrajectoryReader::open(trajectory) {
        if !r.has_membrane() {
            bail!(
                "{} holds no membrane (fluid frames only: {}); `hemodpd analyze` measures cell shapes. Open fluid trajectories in ParaView (the .xmf beside the file) or with h5py (docs/output.md)",
                trajectory.display(),
                r.fluid_frames().unwrap_or(0)
            );
        }
    }
    let a = analysis::analyze_file(trajectory, &analysis::AnalysisOptions::default())?;
    let out = out.unwrap_or_else(|| {
        let stem = trajectory
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_default();
        trajectory.with_file_name(format!("{stem}.analysis"))
    });
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    analysis::write_csv(out.join("frames.csv"), &a.frames)?;
    // a capillary run: its own measures (tube along z), as in the run's cell.csv
    let kind = hemodpd_io::TrajectoryReader::open(trajectory)
        .map(|r| r.metadata().scenario_name.clone())
        .unwrap_or_default();
    if kind == "capillary" {
        let rows = hemodpd_scenario::capillary::analyze_trajectory(trajectory)?;
        hemodpd_scenario::capillary::write_measures_csv(&out.join("capillary.csv"), &rows)?;
        eprintln!(
            "capillary measures of {} frames -> {}",
            rows.len(),
            out.join("capillary.csv").display()
        );
    }
    // a shear run: the motion of the cell and its class
    if kind == "shear" {
        let (rows, class) = hemodpd_scenario::shear::analyze_trajectory(trajectory, None)?;
        hemodpd_scenario::shear::write_motion_csv(&out.join("motion.csv"), &rows)?;
        let path = out.join("shear.json");
        std::fs::write(&path, serde_json::to_string_pretty(&class)?)
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!(
            "shear motion of {} frames: {} -> {}",
            rows.len(),
            class["class"],
            path.display()
        );
    }
    analysis::write_json(out.join("analysis.json"), &a)?;
    if plot {
        analysis::plot_time_series(&out, &a)?;
    }
    eprintln!("{} frames analysed -> {}", a.frames.len(), out.display());
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
        println!(
            "Coarse-grained RBC model, N = {} vertices, T = {} K (Pivkin & Karniadakis 2008)",
            p.n, p.temperature_k
        );
        println!("  kBT                 {:.6e} J", p.kbt_j);
        println!("  L0      (Eq. 8)     {:.6e} m", p.l0_m);
        println!("  Lmax    (3.17 L0)   {:.6e} m", p.lmax_m);
        println!("  p       (Eq. 12)    {:.6e} m", p.persistence_length_m);
        println!(
            "  C       (Eq. 4)     {:.6e} J m^2   (Table I prints ~4x this: see docs/model.md)",
            p.c_j_m2
        );
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
        let meta = hemodpd_io::RunMetadata::new(
            "mesh",
            format!("n = {n}\nseed = {seed}\n"),
            seed,
            hemodpd_scenario::stretching::stretching_units(),
        );
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
    eprintln!(
        "mesh N = {n}, seed {seed}: {:.2} s ({})",
        t0.elapsed().as_secs_f64(),
        origin
    );
    println!(
        "{}",
        serde_json::to_string_pretty(&json!({ "files": files, "quality": q }))?
    );
    Ok(())
}
