//! Sweeps: `hemodpd sweep` (a grid of points, run in parallel as child processes, resumable),
//! `hemodpd sweep-task DIR INDEX` (one point, resume-aware: what each child and each Slurm array
//! task runs) and `hemodpd sweep-collect DIR` (the table of a sweep directory). docs/sweeps.md
//! describes the layout and the workflow.

pub mod grid;
pub mod manifest;
pub mod slurm;

use anyhow::{bail, Context, Result};
use grid::Point;
use manifest::Manifest;
use serde_json::{json, Value};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// Each point's state as its own process saw it: `running`, `done`, `failed` (with the error)
/// or `interrupted`, in `POINT/sweep-status.json`.
pub const STATUS_FILE: &str = "sweep-status.json";
/// The children's stdout and stderr in a local sweep, one file per point.
pub const LOG_DIR: &str = "logs";
pub const TABLE_JSON: &str = "sweep.json";
pub const TABLE_CSV: &str = "sweep.csv";

/// An error that ends the program with a given exit status (the message is printed as is).
#[derive(Debug, thiserror::Error)]
#[error("{message}")]
pub struct ExitWith {
    pub code: i32,
    pub message: String,
}

/// The arguments of `hemodpd sweep`.
pub struct SweepArgs {
    pub scenario: PathBuf,
    pub vary: Vec<String>,
    pub sets: Vec<String>,
    pub zip: bool,
    pub jobs: usize,
    pub threads_per_job: Option<usize>,
    pub yes: bool,
    pub out: Option<PathBuf>,
    pub quiet: bool,
    pub emit_slurm: Option<PathBuf>,
    pub slurm: slurm::SlurmOptions,
}

/// The figures a sweep tabulates for each scenario kind: (column, JSON pointer into `results`,
/// whether it is a timing that differs from run to run); each kind declares its own
/// ([`hemodpd_scenario::Kind::SWEEP_COLUMNS`]).
pub fn columns(kind: &str) -> &'static [(&'static str, &'static str, bool)] {
    hemodpd_scenario::sweep_columns(kind)
}

fn available_threads() -> usize {
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

/// `hemodpd sweep`: checks everything, writes the manifest, then runs the points locally or
/// writes the Slurm script.
pub fn sweep(a: SweepArgs) -> Result<()> {
    // 1. everything that needs no file
    if a.jobs == 0 {
        bail!("--jobs 0: allowed: an integer of at least 1 (points run at once)");
    }
    if a.threads_per_job == Some(0) {
        bail!("--threads-per-job 0: allowed: an integer of at least 1");
    }
    if a.emit_slurm.is_some() {
        a.slurm.validate()?;
    }
    let axes = grid::parse_axes(&a.vary, &a.sets)?;
    let points = grid::points(&axes, a.zip, a.yes)?;
    // 2. the scenario, with every point's overrides, validated before any work
    let content = std::fs::read_to_string(&a.scenario)
        .with_context(|| format!("reading the scenario file {}", a.scenario.display()))?;
    let scenario_file = std::fs::canonicalize(&a.scenario)
        .with_context(|| format!("resolving the scenario file {}", a.scenario.display()))?;
    let mut kind = String::new();
    for p in &points {
        let sc = hemodpd_scenario::load(&a.scenario, &p.overrides(&a.sets)).with_context(|| {
            format!(
                "point {} of {} of the grid, {}: not a valid scenario",
                p.index + 1,
                points.len(),
                p.label
            )
        })?;
        if kind.is_empty() {
            kind = sc.kind().to_string();
        }
    }
    let out = match (&a.emit_slurm, &a.out) {
        (Some(d), _) => d.clone(),
        (None, Some(d)) => d.clone(),
        (None, None) => {
            let stem = a
                .scenario
                .file_stem()
                .map(|s| s.to_string_lossy().to_string())
                .unwrap_or_else(|| "run".into());
            PathBuf::from("runs").join(format!("{stem}-sweep"))
        }
    };
    if a.emit_slurm.is_some() {
        slurm::check_dir(&out)?;
    }
    let m = Manifest::new(scenario_file, content, kind, a.sets.clone(), axes, a.zip, points);
    // 3. the directory: new, or the same sweep continued
    let continued = manifest::open_or_create(&out, &m)?;
    match &a.emit_slurm {
        Some(_) => emit_slurm(&out, &m, &a.slurm, continued),
        None => {
            let threads = a
                .threads_per_job
                .unwrap_or_else(|| (available_threads() / a.jobs).max(1));
            run_local(&out, &m, a.jobs, threads, a.quiet, continued)
        }
    }
}

fn emit_slurm(dir: &Path, m: &Manifest, opts: &slurm::SlurmOptions, continued: bool) -> Result<()> {
    let abs = std::fs::canonicalize(dir).with_context(|| format!("resolving {}", dir.display()))?;
    slurm::check_dir(&abs)?;
    let exe = std::env::current_exe().context("finding the hemodpd binary for the Slurm script")?;
    std::fs::create_dir_all(abs.join(slurm::LOG_DIR))
        .with_context(|| format!("creating {}", abs.join(slurm::LOG_DIR).display()))?;
    let script = slurm::script(&abs, &exe, m, opts);
    let path = abs.join(slurm::SCRIPT_FILE);
    write_text_atomic(&path, &script)?;
    let done = m
        .points
        .iter()
        .filter(|p| abs.join(&p.dir).join("summary.json").exists())
        .count();
    println!(
        "wrote {}: a job array of {} tasks, one per point{}",
        path.display(),
        m.points.len(),
        if continued {
            format!(" ({done} already done; their tasks will skip them)")
        } else {
            String::new()
        }
    );
    println!("  submit:   sbatch {}", path.display());
    println!("  watch:    squeue --me");
    println!("  collect:  hemodpd sweep-collect {}", abs.display());
    if m.points.len() > 1001 {
        println!(
            "  note: {} tasks exceed Slurm's default MaxArraySize (1001); ask your cluster's limit, or submit in parts with --array=",
            m.points.len()
        );
    }
    Ok(())
}

fn write_text_atomic(path: &Path, text: &str) -> Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

fn write_status(pdir: &Path, state: &str, error: Option<String>) {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .unwrap_or_default();
    let v = json!({
        "state": state,
        "error": error,
        "host": host,
        "pid": std::process::id(),
        "slurm_job": std::env::var("SLURM_JOB_ID").ok(),
        "slurm_array_job": std::env::var("SLURM_ARRAY_JOB_ID").ok(),
        "slurm_array_task": std::env::var("SLURM_ARRAY_TASK_ID").ok(),
    });
    // the status is a report, never a reason to fail the point
    let _ = hemodpd_io::summary::write_json_atomic(pdir.join(STATUS_FILE), &v);
}

/// Removes everything in a point's directory (before it runs from the start) but its lock.
fn clear_dir(dir: &Path) -> Result<()> {
    if dir.exists() {
        for e in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
            let p = e.with_context(|| format!("reading {}", dir.display()))?.path();
            if p.file_name().is_some_and(|n| n == hemodpd_scenario::run_dir::LOCK_FILE) {
                continue;
            }
            if p.is_dir() {
                std::fs::remove_dir_all(&p)
            } else {
                std::fs::remove_file(&p)
            }
            .with_context(|| format!("removing {}", p.display()))?;
        }
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))
}

/// `hemodpd sweep-task DIR INDEX`: runs one point. A finished point (summary.json) is left alone;
/// one with a checkpoint resumes from it; any other (or one whose checkpoint cannot be resumed)
/// runs from the start in an emptied directory.
pub fn task(dir: &Path, index: usize, threads: Option<usize>, quiet: bool) -> Result<()> {
    let m = Manifest::read(dir)?;
    let Some(point) = m.points.get(index) else {
        bail!(
            "point index {index} is not in the sweep {}: it has {} points, indices 0 to {}",
            dir.display(),
            m.points.len(),
            m.points.len().saturating_sub(1)
        );
    };
    let now = std::fs::read_to_string(&m.scenario_file).with_context(|| {
        format!(
            "reading the sweep's scenario file {} (recorded in {})",
            m.scenario_file.display(),
            dir.join(manifest::MANIFEST_FILE).display()
        )
    })?;
    if now != m.scenario_content {
        bail!(
            "the scenario file {} changed since the sweep in {} began (hash {}, now {:016x}); its points would not match the finished ones. Restore the file, or start a new sweep in a new directory",
            m.scenario_file.display(),
            dir.display(),
            m.scenario_fnv1a64,
            grid::fnv1a64(now.as_bytes())
        );
    }
    let threads = threads.unwrap_or_else(available_threads);
    if threads == 0 {
        bail!("--threads 0: allowed: an integer of at least 1");
    }
    let pdir = dir.join(&point.dir);
    if pdir.join("summary.json").exists() {
        eprintln!(
            "point {index} ({}) has finished; its results are in {}",
            point.label,
            pdir.join("summary.json").display()
        );
        return Ok(());
    }
    // the point's directory belongs to this task until it ends: a second task on the same point
    // (a resubmission while the first still runs, a requeue) stops here and changes nothing
    let _lock = hemodpd_scenario::lock_out_dir(&pdir, quiet).map_err(anyhow::Error::new)?;
    if pdir.join("summary.json").exists() {
        eprintln!(
            "point {index} ({}) has been finished meanwhile by another task; its results are in {}",
            point.label,
            pdir.join("summary.json").display()
        );
        return Ok(());
    }
    write_status(&pdir, "running", None);
    let result = run_point(&m, point, &pdir, threads, quiet);
    match &result {
        Ok(()) => write_status(&pdir, "done", None),
        Err(e) => match e.downcast_ref::<hemodpd_scenario::RunError>() {
            Some(hemodpd_scenario::RunError::Interrupted { .. }) => write_status(&pdir, "interrupted", None),
            _ => write_status(&pdir, "failed", Some(format!("{e:#}"))),
        },
    }
    result
}

fn run_point(m: &Manifest, point: &Point, pdir: &Path, threads: usize, quiet: bool) -> Result<()> {
    use hemodpd_scenario::RunError;
    if pdir.join(hemodpd_scenario::run_dir::CHECKPOINT_FILE).exists() {
        if !quiet {
            eprintln!("point {} ({}): resuming from its checkpoint", point.index, point.label);
        }
        match crate::run::resume_run(pdir, Some(threads), quiet) {
            Ok(()) => return Ok(()),
            Err(e) => match e.downcast_ref::<RunError>() {
                Some(RunError::Interrupted { .. }) => return Err(e),
                Some(RunError::Finished { .. }) if pdir.join("summary.json").exists() => return Ok(()),
                // e.g. a checkpoint at the end whose summary was never written, or files cut
                // short by a power cut: the point runs again from the start
                _ => eprintln!(
                    "point {} ({}): cannot resume ({e:#}); running it again from the start",
                    point.index, point.label
                ),
            },
        }
    }
    clear_dir(pdir)?;
    write_status(pdir, "running", None);
    crate::run::run_one(
        &m.scenario_file,
        &point.overrides(&m.sets),
        Some(pdir.to_path_buf()),
        Some(threads),
        quiet,
    )
    .map(|_| ())
}

/// Progress of a local sweep: a bar on a terminal, a line per event otherwise, nothing with
/// --quiet. Shows the points done, running and left, and an ETA from the points finished so far.
struct SweepProgress {
    bar: Option<indicatif::ProgressBar>,
    log: bool,
    total: usize,
    jobs: usize,
    started: Instant,
    finished_walls: Vec<f64>,
}

fn fmt_secs(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    if s >= 3600 {
        format!("{}h{:02}m", s / 3600, (s % 3600) / 60)
    } else if s >= 60 {
        format!("{}m{:02}s", s / 60, s % 60)
    } else {
        format!("{s}s")
    }
}

impl SweepProgress {
    fn new(total: usize, done: usize, jobs: usize, quiet: bool) -> Self {
        let tty = std::io::stderr().is_terminal();
        let bar = (!quiet && tty).then(|| {
            let pb =
                indicatif::ProgressBar::with_draw_target(Some(total as u64), indicatif::ProgressDrawTarget::stderr());
            let style = indicatif::ProgressStyle::with_template("{bar:30.cyan/blue} {pos}/{len} points  {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
            pb.set_style(style);
            pb.set_position(done as u64);
            pb.enable_steady_tick(Duration::from_millis(500));
            pb
        });
        SweepProgress {
            log: !quiet && !tty,
            bar,
            total,
            jobs,
            started: Instant::now(),
            finished_walls: Vec::new(),
        }
    }

    fn counts(&self, done: usize, running: usize) -> String {
        let left = self.total.saturating_sub(done + running);
        let eta = if self.finished_walls.is_empty() {
            "?".to_string()
        } else {
            let mean = self.finished_walls.iter().sum::<f64>() / self.finished_walls.len() as f64;
            let remaining = left + running;
            let waves = remaining.div_ceil(self.jobs.max(1)).max(usize::from(remaining > 0));
            fmt_secs(mean * waves as f64)
        };
        format!(
            "done {done}, running {running}, left {left}, elapsed {}, ETA {eta}",
            fmt_secs(self.started.elapsed().as_secs_f64())
        )
    }

    fn event(&mut self, line: &str, done: usize, running: usize) {
        let counts = self.counts(done, running);
        if let Some(bar) = &self.bar {
            bar.set_position(done as u64);
            bar.set_message(counts);
            bar.println(line);
        } else if self.log {
            eprintln!("sweep: {line} [{counts}]");
        }
    }

    fn tick(&self, done: usize, running: usize) {
        if let Some(bar) = &self.bar {
            bar.set_message(self.counts(done, running));
        }
    }

    fn finish(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}

struct Running {
    point: usize,
    child: Child,
    /// Closing it (end of file in the child) asks the child to checkpoint and stop.
    stdin: Option<ChildStdin>,
    started: Instant,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Outcome {
    Done,
    Interrupted,
    Failed,
}

fn last_error_line(log: &Path) -> Option<String> {
    let text = std::fs::read_to_string(log).ok()?;
    text.lines()
        .rev()
        .find(|l| l.starts_with("error:"))
        .map(|l| l.trim_start_matches("error:").trim().to_string())
}

fn run_local(dir: &Path, m: &Manifest, jobs: usize, threads: usize, quiet: bool, continued: bool) -> Result<()> {
    let n = m.points.len();
    let is_done = |p: &Point| dir.join(&p.dir).join("summary.json").exists();
    let pending: Vec<usize> = m.points.iter().filter(|p| !is_done(p)).map(|p| p.index).collect();
    let mut done = n - pending.len();
    if !quiet {
        eprintln!(
            "hemodpd {}: sweep of {} ({} kind), {n} points -> {}{}; {} at a time, {threads} threads each",
            env!("CARGO_PKG_VERSION"),
            m.scenario_file.display(),
            m.scenario_kind,
            dir.display(),
            if continued {
                format!(" (continuing: {done} done before, {} to run)", pending.len())
            } else {
                String::new()
            },
            jobs.min(pending.len().max(1))
        );
    }
    let exe = std::env::current_exe().context("finding the hemodpd binary to run the points")?;
    let logs = dir.join(LOG_DIR);
    std::fs::create_dir_all(&logs).with_context(|| format!("creating {}", logs.display()))?;
    let mut progress = SweepProgress::new(n, done, jobs, quiet);
    let mut next = 0usize;
    let mut running: Vec<Running> = Vec::new();
    let mut outcomes: Vec<(usize, Outcome, String)> = Vec::new();
    let mut stop_sent = false;
    loop {
        // reap finished children
        let mut i = 0;
        while i < running.len() {
            let status = running[i]
                .child
                .try_wait()
                .with_context(|| format!("waiting for point {}", running[i].point))?;
            let Some(status) = status else {
                i += 1;
                continue;
            };
            let r = running.swap_remove(i);
            let p = &m.points[r.point];
            let wall = r.started.elapsed().as_secs_f64();
            let log = logs.join(format!("{}.log", p.dir));
            let (outcome, what) = match status.code() {
                Some(0) if is_done(p) => (Outcome::Done, format!("done in {wall:.1} s")),
                Some(0) => (Outcome::Failed, "ended without writing summary.json".to_string()),
                Some(130) => (Outcome::Interrupted, "stopped with a checkpoint".to_string()),
                Some(c) => (
                    Outcome::Failed,
                    format!(
                        "failed (exit status {c}): {}",
                        last_error_line(&log).unwrap_or_else(|| "see the log".into())
                    ),
                ),
                None => {
                    use std::os::unix::process::ExitStatusExt;
                    (
                        Outcome::Failed,
                        format!("killed by signal {}", status.signal().unwrap_or(0)),
                    )
                }
            };
            if outcome == Outcome::Done {
                done += 1;
                progress.finished_walls.push(wall);
            }
            progress.event(&format!("point {} ({}) {what}", p.index, p.label), done, running.len());
            outcomes.push((r.point, outcome, what));
        }
        let interrupted = hemodpd_scenario::INTERRUPTED.load(Ordering::SeqCst);
        if interrupted && !stop_sent {
            // end of file on their stdin: each child checkpoints and exits with 130
            for r in &mut running {
                r.stdin = None;
            }
            stop_sent = true;
            progress.event(
                "interrupted: the running points are writing their checkpoints",
                done,
                running.len(),
            );
        }
        while !interrupted && running.len() < jobs && next < pending.len() {
            let p = &m.points[pending[next]];
            next += 1;
            let log_path = logs.join(format!("{}.log", p.dir));
            let log = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(&log_path)
                .with_context(|| format!("opening {}", log_path.display()))?;
            let log2 = log
                .try_clone()
                .with_context(|| format!("opening {}", log_path.display()))?;
            let mut child = Command::new(&exe)
                .arg("sweep-task")
                .arg(dir)
                .arg(p.index.to_string())
                .arg("--threads")
                .arg(threads.to_string())
                .arg("--watch-stdin")
                .stdin(Stdio::piped())
                .stdout(log)
                .stderr(log2)
                .spawn()
                .with_context(|| format!("starting {} for point {}", exe.display(), p.index))?;
            let stdin = child.stdin.take();
            running.push(Running {
                point: p.index,
                child,
                stdin,
                started: Instant::now(),
            });
            progress.event(&format!("point {} ({}) started", p.index, p.label), done, running.len());
        }
        if running.is_empty() && (interrupted || next >= pending.len()) {
            break;
        }
        progress.tick(done, running.len());
        std::thread::sleep(Duration::from_millis(50));
    }
    progress.finish();
    let table = Table::collect(dir, m)?;
    table.write(dir)?;
    table.print();
    let interrupted = hemodpd_scenario::INTERRUPTED.load(Ordering::SeqCst);
    let failed: Vec<&(usize, Outcome, String)> = outcomes.iter().filter(|o| o.1 == Outcome::Failed).collect();
    let stopped = outcomes.iter().filter(|o| o.1 == Outcome::Interrupted).count();
    if interrupted {
        return Err(ExitWith {
            code: 130,
            message: format!(
                "sweep interrupted: {done} of {n} points done, {stopped} stopped with a checkpoint; run the same command again to continue (finished points are not redone)"
            ),
        }
        .into());
    }
    if !failed.is_empty() || stopped > 0 {
        let list = failed
            .iter()
            .map(|(i, _, what)| {
                format!(
                    "point {i} ({}) {what}; log: {}",
                    m.points[*i].label,
                    logs.join(format!("{}.log", m.points[*i].dir)).display()
                )
            })
            .collect::<Vec<_>>()
            .join("\n  ");
        return Err(ExitWith {
            code: 1,
            message: format!(
                "error: {} of {n} points did not finish ({} failed, {stopped} stopped by a signal):\n  {list}\nrun the same command again to retry them (finished points are not redone)",
                n - done,
                failed.len()
            ),
        }
        .into());
    }
    if !quiet {
        eprintln!(
            "sweep done: {n} points; table: {} and {}",
            dir.join(TABLE_CSV).display(),
            dir.join(TABLE_JSON).display()
        );
    }
    Ok(())
}

/// `hemodpd sweep-collect DIR`: the table of the points finished so far; exit status 2 and the
/// command to resubmit the missing ones when some are not done.
pub fn collect(dir: &Path) -> Result<()> {
    let m = Manifest::read(dir)?;
    let table = Table::collect(dir, &m)?;
    table.write(dir)?;
    table.print();
    let missing: Vec<&Row> = table.rows.iter().filter(|r| r.status != "done").collect();
    if missing.is_empty() {
        eprintln!(
            "{} points, all done; table: {} and {}",
            table.rows.len(),
            dir.join(TABLE_CSV).display(),
            dir.join(TABLE_JSON).display()
        );
        return Ok(());
    }
    let list = missing
        .iter()
        .map(|r| {
            format!(
                "  {} ({}): {}{}",
                r.index,
                r.label,
                r.status,
                r.error.as_deref().map(|e| format!(": {e}")).unwrap_or_default()
            )
        })
        .collect::<Vec<_>>()
        .join("\n");
    let indices = missing
        .iter()
        .map(|r| r.index.to_string())
        .collect::<Vec<_>>()
        .join(",");
    let script = dir.join(slurm::SCRIPT_FILE);
    let how = if script.exists() {
        format!(
            "resubmit only these (finished points are skipped, checkpointed ones resume): sbatch --array={indices} {}",
            script.display()
        )
    } else {
        "run the same `hemodpd sweep` command again to finish them".to_string()
    };
    Err(ExitWith {
        code: 2,
        message: format!(
            "{} of {} points are not done (a task still running shows as `running`):\n{list}\n{how}",
            missing.len(),
            table.rows.len()
        ),
    }
    .into())
}

/// The table of the sweep directory `dir` as `sweep.json` holds it, collected now (the points
/// finished so far; nothing is written).
pub fn table_json(dir: &Path) -> Result<Value> {
    let m = Manifest::read(dir)?;
    Ok(Table::collect(dir, &m)?.to_json())
}

/// One row of the sweep table.
pub struct Row {
    pub index: usize,
    pub label: String,
    pub values: Vec<(String, String)>,
    pub dir: String,
    /// `done`, `failed`, `running` (started, no result yet: still running, or stopped without a
    /// checkpoint), `interrupted` (has a checkpoint to resume) or `not run`.
    pub status: &'static str,
    pub error: Option<String>,
    pub wall_time_s: Option<f64>,
    pub resumed_from: Option<Value>,
    pub metrics: serde_json::Map<String, Value>,
}

/// The table of a sweep directory, in grid order.
pub struct Table {
    /// The sweep directory as given (the `dir` of each run is inside it).
    pub dir: PathBuf,
    pub kind: String,
    pub manifest: Manifest,
    pub rows: Vec<Row>,
}

impl Table {
    pub fn collect(dir: &Path, m: &Manifest) -> Result<Table> {
        let cols = columns(&m.scenario_kind);
        let mut rows = Vec::new();
        for p in &m.points {
            let pdir = dir.join(&p.dir);
            let status_file: Option<Value> = std::fs::read_to_string(pdir.join(STATUS_FILE))
                .ok()
                .and_then(|t| serde_json::from_str(&t).ok());
            let mut row = Row {
                index: p.index,
                label: p.label.clone(),
                values: p.values.clone(),
                dir: p.dir.clone(),
                status: "not run",
                error: None,
                wall_time_s: None,
                resumed_from: None,
                metrics: serde_json::Map::new(),
            };
            if pdir.join("summary.json").exists() {
                let s = hemodpd_io::summary::read_summary_json(&pdir)
                    .with_context(|| format!("reading {}", pdir.join("summary.json").display()))?;
                let results = &s["results"];
                row.status = "done";
                row.wall_time_s = s["wall_time_s"].as_f64();
                row.resumed_from = Some(results["resumed_from_step"].clone()).filter(|v| !v.is_null());
                for (name, pointer, _) in cols {
                    row.metrics.insert(
                        name.to_string(),
                        results.pointer(pointer).cloned().unwrap_or(Value::Null),
                    );
                }
            } else {
                let state = status_file.as_ref().and_then(|s| s["state"].as_str()).unwrap_or("");
                if state == "failed" {
                    row.status = "failed";
                    row.error = status_file
                        .as_ref()
                        .and_then(|s| s["error"].as_str())
                        .map(str::to_string);
                } else if pdir.join(hemodpd_scenario::run_dir::CHECKPOINT_FILE).exists() {
                    row.status = "interrupted";
                } else if pdir.exists() {
                    row.status = "running";
                }
            }
            rows.push(row);
        }
        Ok(Table {
            dir: dir.to_path_buf(),
            kind: m.scenario_kind.clone(),
            manifest: m.clone(),
            rows,
        })
    }

    /// The table as JSON (`sweep.json`; `hemodpd plot` reads its `runs`).
    pub fn to_json(&self) -> Value {
        let cols = columns(&self.kind);
        let runs: Vec<Value> = self
            .rows
            .iter()
            .map(|r| {
                let values: serde_json::Map<String, Value> =
                    r.values.iter().map(|(k, v)| (k.clone(), json!(v))).collect();
                let overrides: Vec<String> = self.manifest.points[r.index].overrides(&self.manifest.sets);
                let mut run = json!({
                    "index": r.index, "label": r.label, "values": values, "overrides": overrides,
                    "dir": self.dir.join(&r.dir), "point_dir": r.dir, "status": r.status, "error": r.error, "wall_time_s": r.wall_time_s,
                    "resumed_from_step": r.resumed_from, "scenario_kind": self.kind, "metrics": r.metrics,
                });
                if self.kind == "stretching" {
                    run["rms_axial_um"] = r.metrics.get("RMS D_A (um)").cloned().unwrap_or_default();
                    run["rms_transverse_um"] = r.metrics.get("RMS D_T (um)").cloned().unwrap_or_default();
                }
                run
            })
            .collect();
        json!({
            "scenario_file": self.manifest.scenario_file,
            "scenario_fnv1a64": self.manifest.scenario_fnv1a64,
            "scenario_kind": self.kind,
            "sets": self.manifest.sets,
            "axes": self.manifest.axes,
            "zip": self.manifest.zip,
            "points": self.rows.len(),
            "done": self.rows.iter().filter(|r| r.status == "done").count(),
            "columns": cols.iter().map(|c| c.0).collect::<Vec<_>>(),
            "timing_columns": std::iter::once("wall_time_s").chain(cols.iter().filter(|c| c.2).map(|c| c.0)).collect::<Vec<_>>(),
            "runs": runs,
        })
    }

    /// The table as CSV: index, label, one column per varied key, status, the kind's figures,
    /// wall time, directory.
    pub fn to_csv(&self) -> String {
        let cols = columns(&self.kind);
        let mut header: Vec<String> = vec!["index".into(), "label".into()];
        header.extend(self.manifest.axes.iter().map(|a| a.key.clone()));
        header.push("status".into());
        header.extend(cols.iter().map(|c| c.0.to_string()));
        header.extend(["wall_time_s".to_string(), "point_dir".to_string()]);
        let mut out = header.iter().map(|h| csv_field(h)).collect::<Vec<_>>().join(",");
        out.push('\n');
        for r in &self.rows {
            let mut f: Vec<String> = vec![r.index.to_string(), csv_field(&r.label)];
            f.extend(r.values.iter().map(|(_, v)| csv_field(v)));
            f.push(r.status.to_string());
            for c in cols {
                f.push(match r.metrics.get(c.0) {
                    Some(Value::String(s)) => csv_field(s),
                    Some(Value::Null) | None => String::new(),
                    Some(v) => v.to_string(),
                });
            }
            f.push(r.wall_time_s.map(|w| w.to_string()).unwrap_or_default());
            f.push(csv_field(&r.dir));
            out.push_str(&f.join(","));
            out.push('\n');
        }
        out
    }

    pub fn write(&self, dir: &Path) -> Result<()> {
        hemodpd_io::summary::write_json_atomic(dir.join(TABLE_JSON), &self.to_json())
            .with_context(|| format!("writing {}", dir.join(TABLE_JSON).display()))?;
        write_text_atomic(&dir.join(TABLE_CSV), &self.to_csv())
    }

    /// Prints the table for people (stdout).
    pub fn print(&self) {
        let cols = columns(&self.kind);
        let lw = self.rows.iter().map(|r| r.label.len()).max().unwrap_or(0).max(5);
        let mut line = format!("{:>5}  {:<lw$}  {:<11}", "#", "point", "status");
        let widths: Vec<usize> = cols.iter().map(|c| c.0.len().max(12)).collect();
        for (c, w) in cols.iter().zip(&widths) {
            line.push_str(&format!(" {:>w$}", c.0));
        }
        line.push_str(&format!(" {:>10}", "wall (s)"));
        println!("{}", line.trim_end());
        for r in &self.rows {
            let mut line = format!("{:>5}  {:<lw$}  {:<11}", r.index, r.label, r.status);
            for (c, w) in cols.iter().zip(&widths) {
                let v = match r.metrics.get(c.0) {
                    Some(Value::Number(x)) => {
                        let x = x.as_f64().unwrap_or(f64::NAN);
                        if x != 0.0 && (x.abs() >= 1e5 || x.abs() < 1e-3) {
                            format!("{x:.4e}")
                        } else {
                            format!("{x:.4}")
                        }
                    }
                    Some(Value::String(s)) => s.clone(),
                    _ => "-".into(),
                };
                line.push_str(&format!(" {v:>w$}"));
            }
            line.push_str(&format!(
                " {:>10}",
                r.wall_time_s.map_or("-".into(), |w| format!("{w:.3}"))
            ));
            println!("{line}");
        }
    }
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}
