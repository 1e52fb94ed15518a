//! `hemodpd sweep`, `sweep-task` and `sweep-collect`: parallel points equal serial ones, an
//! interrupted sweep (SIGKILL of the whole process group, or Ctrl-C) continues to the table of an
//! uninterrupted one, a changed scenario or grid is refused, bad grids fail before any work, and
//! the Slurm path (script, per-task runs, collect) gives the local table. The real-Slurm check is
//! scripts/slurm_test.sh.

use serde_json::Value;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_hemodpd")
}

fn hemodpd(args: &[&str]) -> Output {
    Command::new(bin()).args(args).output().unwrap()
}

fn scenario(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenarios")
        .join(name)
        .to_string_lossy()
        .into_owned()
}

fn read_json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// Asserts that two sweep tables hold the same points with identical results: index, label,
/// values, status `done`, and every figure that is not a timing, compared exactly.
fn assert_same_results(a: &Value, b: &Value) {
    let timing: Vec<&str> = a["timing_columns"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert!(timing.contains(&"wall_time_s"));
    assert_eq!(a["columns"], b["columns"]);
    let (ra, rb) = (a["runs"].as_array().unwrap(), b["runs"].as_array().unwrap());
    assert_eq!(ra.len(), rb.len());
    assert!(!ra.is_empty());
    let mut compared = 0;
    for (x, y) in ra.iter().zip(rb) {
        for k in ["index", "label", "values", "overrides", "status", "point_dir"] {
            assert_eq!(x[k], y[k], "{k}: {x} vs {y}");
        }
        assert_eq!(x["status"], "done", "{x}");
        for c in a["columns"].as_array().unwrap() {
            let c = c.as_str().unwrap();
            if timing.contains(&c) {
                continue;
            }
            assert!(!x["metrics"][c].is_null(), "{c} missing in {x}");
            assert_eq!(x["metrics"][c], y["metrics"][c], "{}: {c}", x["label"]);
            compared += 1;
        }
    }
    assert!(compared >= ra.len(), "no figures compared");
}

const STRETCH_GRID: [&str; 6] = [
    "--vary",
    "membrane.vertices=100,162",
    "--vary",
    "stretching.forces_pn=[0.0, 50.0],[0.0, 100.0]",
    "--threads-per-job",
    "1",
];

/// `--jobs 2` gives the same table as `--jobs 1`, point by point, and each point's figures are
/// the ones `hemodpd run` writes for the same overrides. The table is written as CSV (a header
/// and one line per point, one column per varied key) and JSON, and printed.
#[test]
fn parallel_sweep_equals_serial_sweep() {
    let tmp = tempfile::tempdir().unwrap();
    let scen = scenario("stretching.toml");
    let mut tables = Vec::new();
    for jobs in ["1", "2"] {
        let out = tmp.path().join(format!("jobs{jobs}"));
        let mut args = vec![
            "sweep",
            &scen,
            "--jobs",
            jobs,
            "--quiet",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend(STRETCH_GRID);
        let o = hemodpd(&args);
        assert!(o.status.success(), "{}", text(&o));
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(
            stdout.contains("RMS D_A (um)")
                && stdout.contains("membrane.vertices=162,stretching.forces_pn=[0.0, 100.0]"),
            "{stdout}"
        );
        let csv = std::fs::read_to_string(out.join("sweep.csv")).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 5, "{csv}");
        assert!(lines[0].starts_with("index,label,membrane.vertices,stretching.forces_pn,status,"));
        assert!(
            lines[4].starts_with(
                "3,\"membrane.vertices=162,stretching.forces_pn=[0.0, 100.0]\",162,\"[0.0, 100.0]\",done,"
            ),
            "{csv}"
        );
        tables.push(read_json(&out.join("sweep.json")));
    }
    assert_same_results(&tables[0], &tables[1]);
    let runs = tables[0]["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 4);
    // the RMS deviation grows with the larger force range: real, distinct results per point
    assert_ne!(runs[0]["metrics"]["RMS D_A (um)"], runs[1]["metrics"]["RMS D_A (um)"]);

    let single = tmp.path().join("single");
    let o = hemodpd(&[
        "run",
        &scen,
        "--set",
        "membrane.vertices=162",
        "--set",
        "stretching.forces_pn=[0.0, 100.0]",
        "--out",
        single.to_str().unwrap(),
        "--quiet",
        "--threads",
        "1",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let s = read_json(&single.join("summary.json"));
    assert_eq!(
        runs[3]["metrics"]["RMS D_A (um)"],
        s["results"]["mills2004"]["rms_axial_um"]
    );
    assert_eq!(
        runs[3]["metrics"]["RMS D_T (um)"],
        s["results"]["mills2004"]["rms_transverse_um"]
    );
}

/// A tiny shear grid (two shear stresses, N = 100 in a 10 µm box, 0.5 strain units: seconds):
/// the table has the shear columns, one row per point, each with the stress it was given.
#[test]
fn tiny_shear_sweep_tabulates_the_motion() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("shear");
    let scen = scenario("shear-sweep.toml");
    let o = hemodpd(&[
        "sweep",
        &scen,
        "--jobs",
        "2",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
        "--set",
        "cell.vertices=100",
        "--set",
        "shear.box_um=[10.0, 10.0, 10.0]",
        "--set",
        "shear.duration_strain=0.5",
        "--set",
        "shear.analysis_start_strain=0.1",
        "--set",
        "output.frame_every_strain=0",
        "--vary",
        "shear.shear_stress_pa=0.1,0.5",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("TTF/rate") && stdout.contains("class"), "{stdout}");
    let t = read_json(&out.join("sweep.json"));
    let runs = t["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 2);
    for (r, stress) in runs.iter().zip([0.1, 0.5]) {
        assert_eq!(r["status"], "done", "{r}");
        let got = r["metrics"]["stress (Pa)"].as_f64().unwrap();
        assert!((got / stress - 1.0).abs() < 1e-12, "{r}");
        // too short to classify: said so, not guessed
        assert_eq!(r["metrics"]["class"], "Undetermined", "{r}");
    }
}

/// A dpd-fluid grid of three seeds whose points take a few seconds each, with a checkpoint
/// every 1000 steps.
fn fluid_sweep(out: &Path, jobs: &str) -> Command {
    let mut c = Command::new(bin());
    c.arg("sweep")
        .arg(scenario("dpd-fluid.toml"))
        .args([
            "--vary",
            "seed=1,2,3",
            "--set",
            "fluid.box_size=[6.0, 6.0, 6.0]",
            "--set",
            "run.equilibration_steps=200",
            "--set",
            "run.steps=10000",
            "--set",
            "output.trajectory_every_steps=1000",
            "--set",
            "output.checkpoint_every_steps=1000",
            "--threads-per-job",
            "1",
            "--jobs",
            jobs,
            "--out",
        ])
        .arg(out);
    c
}

fn point_dirs(out: &Path) -> Vec<PathBuf> {
    ["seed=1", "seed=2", "seed=3"].iter().map(|d| out.join(d)).collect()
}

/// Starts the serial fluid sweep in its own process group and waits until point 0 has finished
/// and point 1 has written a checkpoint (it is running, far from its end).
fn start_and_wait_mid_sweep(out: &Path) -> std::process::Child {
    let mut child = fluid_sweep(out, "1")
        .process_group(0)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let dirs = point_dirs(out);
    let t0 = std::time::Instant::now();
    loop {
        if dirs[0].join("summary.json").exists()
            && hemodpd_io::checkpoint::Checkpoint::load(dirs[1].join("checkpoint.h5")).is_ok()
        {
            break;
        }
        assert!(
            child.try_wait().unwrap().is_none(),
            "the sweep ended before point 1 was under way"
        );
        assert!(t0.elapsed().as_secs() < 300, "point 1 not under way after 300 s");
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    child
}

/// A sweep interrupted mid-way continues where it stopped: once by SIGKILL of its whole process
/// group (a killed job; nothing gets to clean up), once by SIGINT to the sweep alone (Ctrl-C: the
/// running point checkpoints, exit status 130). Rerun with the same arguments, the finished point
/// is not redone (its summary.json is byte-identical with the same modification time), the
/// interrupted one resumes from its checkpoint, and the final table equals the table of an
/// uninterrupted `--jobs 2` sweep point by point (kBT, pressure and the final-state fingerprint,
/// exactly).
#[test]
fn interrupted_sweeps_resume_to_the_uninterrupted_table() {
    let tmp = tempfile::tempdir().unwrap();
    let reference = tmp.path().join("reference");
    let o = fluid_sweep(&reference, "2").arg("--quiet").output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let reference = read_json(&reference.join("sweep.json"));

    for how in ["SIGKILL to the process group", "SIGINT to the sweep"] {
        let out = tmp
            .path()
            .join(if how.starts_with("SIGKILL") { "killed" } else { "ctrl-c" });
        let mut child = start_and_wait_mid_sweep(&out);
        let dirs = point_dirs(&out);
        let pid = child.id().to_string();
        if how.starts_with("SIGKILL") {
            let st = Command::new("kill")
                .args(["-KILL", "--", &format!("-{pid}")])
                .status()
                .unwrap();
            assert!(st.success());
            let st = child.wait().unwrap();
            assert_eq!(st.code(), None, "{how}: the sweep was not killed");
        } else {
            let st = Command::new("kill").args(["-INT", &pid]).status().unwrap();
            assert!(st.success());
            let o = child.wait_with_output().unwrap();
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(130), "{how}: {err}");
            assert!(err.contains("sweep interrupted: 1 of 3 points done"), "{err}");
            let status = read_json(&dirs[1].join("sweep-status.json"));
            assert_eq!(status["state"], "interrupted", "{status}");
            // the table written on the way out shows the state of every point
            let partial = read_json(&out.join("sweep.json"));
            let st: Vec<&str> = partial["runs"]
                .as_array()
                .unwrap()
                .iter()
                .map(|r| r["status"].as_str().unwrap())
                .collect();
            assert_eq!(st, ["done", "interrupted", "not run"]);
        }
        // the state on disk: point 0 done, point 1 half done with a checkpoint, point 2 not run
        assert!(dirs[0].join("summary.json").exists());
        assert!(
            !dirs[1].join("summary.json").exists(),
            "{how}: point 1 finished before the interrupt reached it"
        );
        let ck = hemodpd_io::checkpoint::Checkpoint::load(dirs[1].join("checkpoint.h5")).unwrap();
        assert!(ck.step > 0 && ck.step < 10_200, "checkpoint at step {}", ck.step);
        assert!(!dirs[2].join("summary.json").exists());
        let before = std::fs::read(dirs[0].join("summary.json")).unwrap();
        let before_mtime = std::fs::metadata(dirs[0].join("summary.json"))
            .unwrap()
            .modified()
            .unwrap();

        let o = fluid_sweep(&out, "1").output().unwrap();
        assert!(o.status.success(), "{how}: rerun: {}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("continuing: 1 done before, 2 to run"), "{err}");
        assert_eq!(std::fs::read(dirs[0].join("summary.json")).unwrap(), before);
        assert_eq!(
            std::fs::metadata(dirs[0].join("summary.json"))
                .unwrap()
                .modified()
                .unwrap(),
            before_mtime,
            "{how}: the finished point was redone"
        );
        let resumed = read_json(&dirs[1].join("summary.json"));
        let from = resumed["results"]["resumed_from_step"].as_u64();
        assert!(
            from.is_some_and(|s| s >= ck.step),
            "{how}: point 1 did not resume from its checkpoint (step {}): {}",
            ck.step,
            resumed["results"]["resumed_from_step"]
        );
        let table = read_json(&out.join("sweep.json"));
        assert_eq!(table["runs"][1]["resumed_from_step"].as_u64(), from);
        assert_same_results(&reference, &table);
    }
}

/// Reusing a sweep directory with another scenario content, other --set overrides, another grid
/// or --zip is refused before any work, naming what changed; nothing in the directory changes.
/// `sweep-task` refuses to run a point when the scenario file changed.
#[test]
fn a_changed_scenario_or_grid_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let scen = tmp.path().join("s.toml");
    std::fs::copy(scenario("stretching.toml"), &scen).unwrap();
    let out = tmp.path().join("sweep");
    let base = |extra: &[&str]| {
        let mut a: Vec<String> = vec!["sweep".into(), scen.to_string_lossy().into_owned()];
        a.extend(
            [
                "--vary",
                "membrane.vertices=100,162",
                "--set",
                "stretching.forces_pn=[0.0, 50.0]",
                "--quiet",
                "--out",
            ]
            .iter()
            .map(|s| s.to_string()),
        );
        a.push(out.to_string_lossy().into_owned());
        a.extend(extra.iter().map(|s| s.to_string()));
        let a: Vec<&str> = a.iter().map(|s| s.as_str()).collect();
        hemodpd(&a)
    };
    let o = base(&[]);
    assert!(o.status.success(), "{}", text(&o));
    let snapshot = || {
        let mut v: Vec<(PathBuf, std::time::SystemTime)> = walk(&out)
            .into_iter()
            .map(|p| {
                let m = std::fs::metadata(&p).unwrap().modified().unwrap();
                (p, m)
            })
            .collect();
        v.sort();
        v
    };
    let before = snapshot();
    let refused = |o: Output, needles: &[&str]| {
        assert_eq!(o.status.code(), Some(1), "{}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        for n in needles {
            assert!(err.contains(n), "`{n}` not in: {err}");
        }
        assert!(err.contains("choose a new --out"), "{err}");
    };
    refused(
        base(&["--vary", "seed=1,2"]),
        &["the grid changed", "--vary membrane.vertices=100,162 --vary seed=1,2"],
    );
    refused(
        base(&["--set", "membrane.temperature_k=310.0"]),
        &["the --set overrides changed", "membrane.temperature_k=310.0"],
    );
    refused(base(&["--zip"]), &["the combination mode changed"]);
    // the same grid, the scenario edited
    let edited = std::fs::read_to_string(&scen)
        .unwrap()
        .replace("temperature_k = 300.0", "temperature_k = 310.0");
    std::fs::write(&scen, edited).unwrap();
    refused(base(&[]), &["the scenario file's content changed", "s.toml"]);
    assert_eq!(before, snapshot(), "a refused sweep changed its directory");
    let o = hemodpd(&["sweep-task", out.to_str().unwrap(), "0"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("changed since the sweep"),
        "{}",
        text(&o)
    );
    // an existing directory that is not a sweep is not used either
    let other = tmp.path().join("other");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("notes.txt"), "mine").unwrap();
    let o = hemodpd(&[
        "sweep",
        &scenario("stretching.toml"),
        "--vary",
        "membrane.vertices=100",
        "--out",
        other.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("is not a sweep directory"));
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        }
        out.push(p);
    }
    out
}

/// Bad grids fail with exit status 1 before any work (the output directory is never created),
/// each with a message naming the key and the value: an unknown key, a value out of range, an
/// empty grid, a grid of more than 100 points without --yes, --zip with unequal axes, a key both
/// set and varied, a bad --jobs and a bad Slurm option.
#[test]
fn bad_grids_fail_before_any_work() {
    let tmp = tempfile::tempdir().unwrap();
    let scen = scenario("stretching.toml");
    let out = tmp.path().join("never");
    let many: Vec<String> = (0..11).map(|i| (100 + i).to_string()).collect();
    let many = format!("membrane.vertices={}", many.join(","));
    let cases: Vec<(Vec<&str>, Vec<&str>)> = vec![
        (
            vec!["--vary", "membrane.stiffness=1,2"],
            vec!["membrane.stiffness=1", "unknown field `stiffness`"],
        ),
        (
            vec!["--vary", "membrane.vertices=500,50"],
            vec![
                "membrane.vertices=50",
                "key `membrane.vertices` = 50 is not allowed",
                "100",
            ],
        ),
        (
            vec!["--vary", "membrane.vertices="],
            vec!["--vary membrane.vertices=", "no values", "empty"],
        ),
        (
            vec!["--vary", &many, "--vary", "seed=1,2,3,4,5,6,7,8,9,10"],
            vec![
                "110 points",
                "membrane.vertices with 11 values",
                "seed with 10 values",
                "--yes",
            ],
        ),
        (
            vec!["--vary", "membrane.vertices=100,162", "--vary", "seed=1,2,3", "--zip"],
            vec!["membrane.vertices has 2", "seed has 3"],
        ),
        (
            vec!["--vary", "seed=1,2", "--set", "seed=3"],
            vec!["`seed`", "--set seed=3"],
        ),
        (
            vec!["--vary", "seed=1,2", "--jobs", "0"],
            vec!["--jobs 0", "at least 1"],
        ),
    ];
    for (args, needles) in cases {
        let mut a = vec!["sweep", scen.as_str(), "--out", out.to_str().unwrap()];
        a.extend(&args);
        let o = hemodpd(&a);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        for n in needles {
            assert!(err.contains(n), "{args:?}: `{n}` not in: {err}");
        }
        assert!(!out.exists(), "{args:?}: the sweep created its directory");
    }
    let slurm_dir = tmp.path().join("slurm-never");
    let o = hemodpd(&[
        "sweep",
        &scen,
        "--vary",
        "seed=1,2",
        "--emit-slurm",
        slurm_dir.to_str().unwrap(),
        "--slurm-time",
        "2 hours",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("--slurm-time 2 hours"),
        "{}",
        text(&o)
    );
    assert!(!slurm_dir.exists());
    // the large grid runs with --yes (checked here up to its validation only: --emit-slurm
    // writes the script and runs nothing)
    let o = hemodpd(&[
        "sweep",
        &scen,
        "--vary",
        &many,
        "--vary",
        "seed=1,2,3,4,5,6,7,8,9,10",
        "--yes",
        "--emit-slurm",
        slurm_dir.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let script = std::fs::read_to_string(slurm_dir.join("sweep.sbatch")).unwrap();
    assert!(script.contains("#SBATCH --array=0-109\n"), "{script}");
}

/// The Slurm path without Slurm: `--emit-slurm` writes an array script with the resources as
/// options; `sweep-collect` before any task lists every point and the `sbatch --array=` command
/// (exit status 2); running `sweep-task DIR i` for each index as the array tasks do (twice for
/// one: the second run skips the finished point) gives, through `sweep-collect`, the table of a
/// local sweep of the same grid. An index outside the grid is an error naming it.
#[test]
fn slurm_tasks_and_collect_give_the_local_table() {
    let tmp = tempfile::tempdir().unwrap();
    let scen = scenario("stretching.toml");
    let dir = tmp.path().join("cluster");
    let grid = [
        "--vary",
        "membrane.vertices=100,162",
        "--set",
        "stretching.forces_pn=[0.0, 80.0]",
    ];
    let mut a = vec!["sweep", scen.as_str()];
    a.extend(grid);
    a.extend([
        "--emit-slurm",
        dir.to_str().unwrap(),
        "--slurm-time",
        "0-02:00",
        "--slurm-mem",
        "2G",
        "--slurm-partition",
        "short",
        "--slurm-cpus",
        "3",
    ]);
    let o = hemodpd(&a);
    assert!(o.status.success(), "{}", text(&o));
    let script = std::fs::read_to_string(dir.join("sweep.sbatch")).unwrap();
    for line in [
        "#SBATCH --array=0-1\n",
        "#SBATCH --cpus-per-task=3\n",
        "#SBATCH --time=0-02:00\n",
        "#SBATCH --mem=2G\n",
        "#SBATCH --partition=short\n",
        "sweep-task",
        "$SLURM_ARRAY_TASK_ID",
    ] {
        assert!(script.contains(line), "`{line}` not in:\n{script}");
    }
    assert!(dir.join("slurm").is_dir());
    let o = hemodpd(&["sweep-collect", dir.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("2 of 2 points are not done") && err.contains("sbatch --array=0,1 "),
        "{err}"
    );
    for i in ["1", "0", "1"] {
        let o = hemodpd(&["sweep-task", dir.to_str().unwrap(), i, "--threads", "1", "--quiet"]);
        assert!(o.status.success(), "{}", text(&o));
    }
    let o = hemodpd(&["sweep-task", dir.to_str().unwrap(), "1"]);
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("has finished"),
        "{}",
        text(&o)
    );
    let o = hemodpd(&["sweep-task", dir.to_str().unwrap(), "2"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("point index 2 is not in the sweep"),
        "{}",
        text(&o)
    );
    let o = hemodpd(&["sweep-collect", dir.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let local = tmp.path().join("local");
    let mut a = vec!["sweep", scen.as_str()];
    a.extend(grid);
    a.extend(["--jobs", "2", "--quiet", "--out", local.to_str().unwrap()]);
    let o = hemodpd(&a);
    assert!(o.status.success(), "{}", text(&o));
    assert_same_results(
        &read_json(&dir.join("sweep.json")),
        &read_json(&local.join("sweep.json")),
    );
}
