//! Checkpoints and restarts: a run interrupted and resumed ends bit-identical to the
//! uninterrupted run, with the same trajectory frames (none lost, none duplicated); Ctrl-C on
//! the CLI writes a checkpoint and exits cleanly; bad checkpoints give clear errors.

use hemodpd_io::TrajectoryReader;
use hemodpd_scenario::{RunContext, RunError, Scenario};
use std::path::{Path, PathBuf};
use std::process::Command;

fn scenario_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/dpd-fluid.toml")
}

fn small(sets: &[&str]) -> Scenario {
    let mut all = vec![
        "fluid.box_size=[5.0, 5.0, 5.0]",
        "run.equilibration_steps=100",
        "run.steps=600",
        "run.sample_every=10",
        "output.trajectory_every_steps=50",
        "output.checkpoint_every_steps=100",
        "output.field_bins=5",
    ];
    all.extend_from_slice(sets);
    hemodpd_scenario::load(&scenario_path(), &all.iter().map(|s| s.to_string()).collect::<Vec<_>>()).unwrap()
}

fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

fn final_arrays(dir: &Path) -> (Vec<glam::DVec3>, Vec<glam::DVec3>) {
    let ck = hemodpd_io::checkpoint::Checkpoint::load(dir.join("checkpoint.h5")).unwrap();
    (
        ck.vec3s("positions", None).unwrap(),
        ck.vec3s("velocities", None).unwrap(),
    )
}

fn frames(dir: &Path) -> (Vec<u64>, usize) {
    let r = TrajectoryReader::open(dir.join("trajectory.h5")).unwrap();
    let steps: Vec<u64> = (0..r.fluid_frames().unwrap())
        .map(|i| r.fluid_frame(i).unwrap().step)
        .collect();
    (steps, r.field_info("density").map(|i| i.frames).unwrap_or(0))
}

/// Every file under `dir`: relative path -> (bytes, modification time). Equal snapshots mean
/// nothing was written, created, removed or touched.
fn snapshot(dir: &Path) -> std::collections::BTreeMap<PathBuf, (Vec<u8>, std::time::SystemTime)> {
    let mut out = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let meta = std::fs::metadata(&p).unwrap();
                let rel = p.strip_prefix(dir).unwrap().to_path_buf();
                out.insert(rel, (std::fs::read(&p).unwrap(), meta.modified().unwrap()));
            }
        }
    }
    out
}

/// Interrupt at step 337 (off every schedule), resume on 2 threads; compare with an
/// uninterrupted 1-thread run: final positions and velocities bit for bit, the sampled
/// temperature and pressure means exactly, and the trajectory's frame steps.
#[test]
fn resumed_run_is_bit_identical() {
    let s = small(&[]);
    let a = tempfile::tempdir().unwrap();
    let full = in_pool(1, || hemodpd_scenario::run(&s, &RunContext::new(a.path(), 1, false))).unwrap();

    let b = tempfile::tempdir().unwrap();
    let mut ctx = RunContext::new(b.path(), 1, false);
    ctx.stop_at_step = Some(337);
    match in_pool(1, || hemodpd_scenario::run(&s, &ctx)) {
        Err(RunError::Interrupted { step: 337, .. }) => {}
        other => panic!("expected an interrupt at step 337, got {other:?}"),
    }
    // the interrupted file ends with the final frame at step 337
    assert_eq!(*frames(b.path()).0.last().unwrap(), 337);
    let (_, resumed) = in_pool(2, || {
        hemodpd_scenario::resume(b.path(), &RunContext::new(b.path(), 2, false))
    })
    .unwrap();
    assert_eq!(resumed["resumed_from_step"], 337);

    assert_eq!(full["final_state_fingerprint"], resumed["final_state_fingerprint"]);
    for k in ["temperature", "pressure"] {
        assert_eq!(
            full[k]["mean"].as_f64().unwrap().to_bits(),
            resumed[k]["mean"].as_f64().unwrap().to_bits(),
            "{k}"
        );
        assert_eq!(full[k]["samples"], resumed[k]["samples"]);
    }
    let (pa, va) = final_arrays(a.path());
    let (pb, vb) = final_arrays(b.path());
    assert!(pa == pb && va == vb, "final state differs");
    let (fa, na) = frames(a.path());
    let (fb, nb) = frames(b.path());
    let expected: Vec<u64> = (0..=12).map(|k| 100 + 50 * k).collect();
    assert_eq!(fa, expected);
    assert_eq!(fb, expected, "frames lost or duplicated by the resume");
    assert_eq!((na, nb), (13, 13));
}

/// `--resume` on a directory whose checkpoint is garbage, truncated, or missing: a clear
/// error naming the directory, exit code 1, no panic.
#[test]
fn bad_checkpoints_are_clear_errors() {
    let d = tempfile::tempdir().unwrap();
    let run = |dir: &Path| {
        Command::new(env!("CARGO_BIN_EXE_hemodpd"))
            .args(["run", "--resume", dir.to_str().unwrap(), "--quiet"])
            .output()
            .unwrap()
    };
    let out = run(d.path());
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no checkpoint.h5"));
    std::fs::write(d.path().join("checkpoint.h5"), b"this is not an HDF5 file at all").unwrap();
    let out = run(d.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("cannot resume") && err.contains("checkpoint.h5") && !err.contains("panicked"),
        "{err}"
    );
}

/// A fluid run long enough (20,200 steps on 1 thread) to be signalled or raced while it steps:
/// frames every 500 steps from step 200, a checkpoint every 1000.
const LONG_RUN: [&str; 13] = [
    "--set",
    "fluid.box_size=[6.0, 6.0, 6.0]",
    "--set",
    "run.equilibration_steps=200",
    "--set",
    "run.steps=20000",
    "--set",
    "output.trajectory_every_steps=500",
    "--set",
    "output.checkpoint_every_steps=1000",
    "--quiet",
    "--threads",
    "1",
];

/// Ctrl-C (SIGINT) on a running `hemodpd run`: exit code 130, a checkpoint and the trajectory
/// are on disk, and `--resume` finishes the run with the same final state as an uninterrupted one.
///
/// The signal must arrive while the run is stepping, far from its end: the test waits for the
/// first periodic checkpoint (step 1000 of 20200), reads its step, and only then sends SIGINT.
/// A run that finishes anyway (exit 0, or a checkpoint at the last step) fails the test.
#[test]
fn ctrl_c_checkpoints_and_resumes() {
    const TOTAL: u64 = 200 + 20_000;
    let sets = LONG_RUN;
    let bin = env!("CARGO_BIN_EXE_hemodpd");
    let scen = scenario_path();
    let b = tempfile::tempdir().unwrap();
    let mut child = Command::new(bin)
        .arg("run")
        .arg(&scen)
        .args(sets)
        .arg("--out")
        .arg(b.path())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // wait until the run is under way: its first periodic checkpoint (written atomically, so it
    // can be read while the run goes on) is on disk
    let ck_path = b.path().join("checkpoint.h5");
    let t0 = std::time::Instant::now();
    let first = loop {
        if let Ok(ck) = hemodpd_io::checkpoint::Checkpoint::load(&ck_path) {
            break ck.step;
        }
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before its first checkpoint"
        );
        assert!(t0.elapsed().as_secs() < 120, "no checkpoint after 120 s");
        std::thread::sleep(std::time::Duration::from_millis(10));
    };
    assert!(
        first < TOTAL / 2,
        "the first checkpoint seen is at step {first} of {TOTAL}: too close to the end to interrupt reliably"
    );
    Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.code(),
        Some(130),
        "SIGINT was sent at step >= {first} of {TOTAL}; the run did not stop with status 130 (did it finish first?): {stderr}"
    );
    assert!(stderr.contains("interrupted at step"), "{stderr}");
    let ck = hemodpd_io::checkpoint::Checkpoint::load(&ck_path).unwrap();
    assert!(
        ck.step >= first && ck.step < TOTAL,
        "the interrupt checkpoint is at step {}, expected between {first} and {TOTAL}",
        ck.step
    );
    assert!(
        !b.path().join("summary.json").exists(),
        "an interrupted run wrote summary.json"
    );
    let resumed = Command::new(bin)
        .args([
            "run",
            "--resume",
            b.path().to_str().unwrap(),
            "--quiet",
            "--threads",
            "2",
        ])
        .output()
        .unwrap();
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    // the uninterrupted run, for comparison
    let a = tempfile::tempdir().unwrap();
    let full = Command::new(bin)
        .arg("run")
        .arg(&scen)
        .args(sets)
        .arg("--out")
        .arg(a.path())
        .output()
        .unwrap();
    assert!(full.status.success(), "{}", String::from_utf8_lossy(&full.stderr));
    let sa: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(a.path().join("summary.json")).unwrap()).unwrap();
    let sb: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(b.path().join("summary.json")).unwrap()).unwrap();
    assert_eq!(
        sa["results"]["final_state_fingerprint"],
        sb["results"]["final_state_fingerprint"]
    );
    assert_eq!(sb["results"]["resumed_from_step"].as_u64(), Some(ck.step));
    assert_eq!(frames(a.path()).0, frames(b.path()).0);
}

/// `hemodpd run --resume DIR` on a finished run of each scenario kind says that it has finished,
/// exits with 0, and leaves every file in DIR byte-identical with the same modification time.
#[test]
fn resume_of_a_finished_run_says_so_and_touches_nothing() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let walls_small = [
        "walls.update_every=50",
        "walls.adapt_iterations=1",
        "run.equilibration_steps=20",
        "run.flow_steps=20",
        "run.steps=40",
        "run.sample_every=5",
        "run.measure_overhead=false",
        "output.trajectory_every_steps=20",
    ];
    let cases: Vec<(&str, Vec<&str>, &str)> = vec![
        (
            "stretching.toml",
            vec!["membrane.vertices=100", "stretching.forces_pn=[0.0, 20.0]"],
            "2 of 2 forces done",
        ),
        (
            "dpd-fluid.toml",
            vec![
                "fluid.box_size=[4.0, 4.0, 4.0]",
                "run.equilibration_steps=10",
                "run.steps=20",
                "run.sample_every=10",
                "output.trajectory_every_steps=10",
            ],
            "30 of 30 steps done",
        ),
        (
            "poiseuille-tube.toml",
            [&walls_small[..], &["tube.radius=2.5", "tube.length=4.0"]].concat(),
            "110 of 110 steps done",
        ),
        (
            "couette.toml",
            [&walls_small[..], &["plates.gap=4.0", "plates.width=[4.0, 4.0]"]].concat(),
            "110 of 110 steps done",
        ),
    ];
    for (file, sets, done) in cases {
        let dir = tempfile::tempdir().unwrap();
        let mut args: Vec<String> = vec!["run".into(), root.join(file).to_str().unwrap().into()];
        for s in sets.iter().copied() {
            args.push("--set".into());
            args.push(s.into());
        }
        let out_dir = dir.path().join("run");
        args.extend(["--out".into(), out_dir.to_str().unwrap().into(), "--quiet".into()]);
        let run = Command::new(env!("CARGO_BIN_EXE_hemodpd"))
            .args(&args)
            .output()
            .unwrap();
        assert!(run.status.success(), "{file}: {}", String::from_utf8_lossy(&run.stderr));
        assert!(out_dir.join("summary.json").exists(), "{file}");
        let before = snapshot(&out_dir);
        // mtimes have a coarse resolution on some file systems: let a rewrite show
        std::thread::sleep(std::time::Duration::from_millis(20));
        let again = Command::new(env!("CARGO_BIN_EXE_hemodpd"))
            .args(["run", "--resume", out_dir.to_str().unwrap(), "--quiet"])
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&again.stdout);
        let stderr = String::from_utf8_lossy(&again.stderr);
        assert_eq!(again.status.code(), Some(0), "{file}: {stdout}{stderr}");
        assert!(
            stdout.contains("the run has finished") && stdout.contains(done) && stdout.contains("nothing to resume"),
            "{file}: {stdout}{stderr}"
        );
        assert_eq!(before, snapshot(&out_dir), "{file}: files changed");
    }
}

/// A small wall scenario.
fn small_walled(file: &str, sets: &[&str]) -> Scenario {
    let mut all = vec![
        "walls.update_every=50",
        "walls.adapt_iterations=2",
        "run.equilibration_steps=50",
        "run.flow_steps=50",
        "run.steps=200",
        "run.sample_every=5",
        "run.measure_overhead=false",
        "output.trajectory_every_steps=50",
        "output.checkpoint_every_steps=60",
    ];
    all.extend_from_slice(sets);
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(file);
    hemodpd_scenario::load(&path, &all.iter().map(|s| s.to_string()).collect::<Vec<_>>()).unwrap()
}

/// Wall scenarios resume bit-identically: a tube run with the flow controller, interrupted in
/// the adaptation phase (step 73) and again while sampling (step 237), resumed each time on
/// another thread count, ends with the uninterrupted run's particles, wall forces, adaptation
/// history, controller history, profile and viscosity to the last bit, and the same trajectory frames; a Couette run interrupted while
/// sampling gives the same wall stress and viscosity.
#[test]
fn wall_scenarios_resume_bit_identically() {
    let cases: [(&str, &[&str], &[u64], &str); 2] = [
        (
            "poiseuille-tube.toml",
            // the flow controller's state goes through the checkpoints too
            &[
                "tube.radius=2.5",
                "tube.length=4.0",
                "tube.mean_velocity=0.3",
                "tube.flow_control_every=20",
            ],
            &[73, 237],
            "viscosity",
        ),
        (
            "couette.toml",
            &["plates.gap=4.0", "plates.width=[4.0, 4.0]", "plates.wall_speed=1.0"],
            &[211],
            "viscosity",
        ),
    ];
    for (file, sets, stops, key) in cases {
        let a = tempfile::tempdir().unwrap();
        let s = small_walled(file, sets);
        let full = in_pool(1, || hemodpd_scenario::run(&s, &RunContext::new(a.path(), 1, false))).unwrap();
        let b = tempfile::tempdir().unwrap();
        let s = small_walled(file, sets);
        let mut ctx = RunContext::new(b.path(), 1, false);
        ctx.stop_at_step = Some(stops[0]);
        match in_pool(1, || hemodpd_scenario::run(&s, &ctx)) {
            Err(RunError::Interrupted { step, .. }) if step == stops[0] => {}
            other => panic!("{file}: expected an interrupt at step {}, got {other:?}", stops[0]),
        }
        let mut resumed = None;
        for (k, &stop) in stops.iter().enumerate() {
            let mut ctx = RunContext::new(b.path(), 2 - k % 2, false);
            ctx.stop_at_step = stops.get(k + 1).copied();
            match in_pool(2 - k % 2, || hemodpd_scenario::resume(b.path(), &ctx)) {
                Ok((_, r)) => resumed = Some(r),
                Err(RunError::Interrupted { step, .. }) if Some(step) == ctx.stop_at_step => {}
                Err(e) => panic!("{file}: resume from {stop}: {e}"),
            }
        }
        let resumed = resumed.unwrap();
        assert_eq!(resumed["resumed_from_step"].as_u64(), stops.last().copied());
        // (the whole entries: the viscosity of these small runs may be null, with a note)
        assert_eq!(full[key], resumed[key], "{file}: {key}");
        assert_eq!(
            full["viscosity_profile"], resumed["viscosity_profile"],
            "{file}: η profile"
        );
        assert_eq!(full["temperature"], resumed["temperature"], "{file}: temperature");
        assert_eq!(full["adaptation"], resumed["adaptation"], "{file}: adaptation history");
        assert_eq!(full["profile"], resumed["profile"], "{file}: sampled profile");
        assert_eq!(full["near_wall"], resumed["near_wall"], "{file}: near-wall density");
        assert_eq!(full["reflections"], resumed["reflections"], "{file}: reflections");
        assert_eq!(full["flow_control"], resumed["flow_control"], "{file}: flow controller");
        assert!(full["reflections"].as_u64().unwrap() > 0);
        let (pa, va) = final_arrays(a.path());
        let (pb, vb) = final_arrays(b.path());
        assert!(pa == pb && va == vb, "{file}: final state differs");
        let expected: Vec<u64> = (0..=7).map(|k| 50 * k).collect();
        assert_eq!(frames(a.path()).0, expected, "{file}");
        assert_eq!(
            frames(b.path()).0,
            expected,
            "{file}: frames lost or duplicated by the resume"
        );
        // resuming a finished run (its checkpoint is at the last step) is refused as finished,
        // and touches nothing
        let before = snapshot(b.path());
        match in_pool(1, || {
            hemodpd_scenario::resume(b.path(), &RunContext::new(b.path(), 1, false))
        }) {
            Err(RunError::Finished { done, total, .. }) => {
                assert_eq!((done, total), (350, 350), "{file}: 2 x 50 adapt + 50 flow + 200 steps");
            }
            other => panic!("{file}: resuming a finished run gave {other:?}"),
        }
        assert_eq!(
            before,
            snapshot(b.path()),
            "{file}: files changed by a resume of a finished run"
        );
        // the force profile was written after adaptation, into each run's own directory
        assert!(a.path().join("wall_force.csv").exists());
        assert!(b.path().join("wall_force.csv").exists());
    }
}

/// The `--set` arguments of [`small`] for the CLI.
fn small_cli_sets() -> Vec<String> {
    [
        "fluid.box_size=[5.0, 5.0, 5.0]",
        "run.equilibration_steps=100",
        "run.steps=600",
        "run.sample_every=10",
        "output.trajectory_every_steps=50",
        "output.checkpoint_every_steps=100",
        "output.field_bins=5",
    ]
    .iter()
    .flat_map(|s| ["--set".to_string(), s.to_string()])
    .collect()
}

fn summary(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
}

/// A run killed while it writes a checkpoint (fault injection: the process aborts with the
/// new checkpoint half written) leaves the previous checkpoint intact and a stale lock: the
/// resume takes the lock over and ends bit-identical to an uninterrupted run. A checkpoint cut
/// short afterwards (truncated) is reported as damaged and the previous one is used, with the
/// same result; with both damaged the resume fails and says so.
#[test]
fn killed_while_checkpointing_and_truncated_checkpoints_resume_from_the_previous_one() {
    let bin = env!("CARGO_BIN_EXE_hemodpd");
    let scen = scenario_path();
    let sets = small_cli_sets();
    let reference = tempfile::tempdir().unwrap();
    let full = Command::new(bin)
        .arg("run")
        .arg(&scen)
        .args(&sets)
        .args(["--quiet", "--threads", "1", "--out"])
        .arg(reference.path())
        .output()
        .unwrap();
    assert!(full.status.success(), "{}", String::from_utf8_lossy(&full.stderr));
    let fingerprint = summary(reference.path())["results"]["final_state_fingerprint"].clone();
    let resume = |dir: &Path| {
        Command::new(bin)
            .args(["run", "--resume", dir.to_str().unwrap(), "--threads", "2"])
            .output()
            .unwrap()
    };
    // the run aborts while writing its `k`-th checkpoint (steps 100, 200, ... are the 1st, 2nd, ...)
    let killed_at_checkpoint = |k: u32| {
        let d = tempfile::tempdir().unwrap();
        let out = Command::new(bin)
            .arg("run")
            .arg(&scen)
            .args(&sets)
            .args(["--quiet", "--threads", "1", "--out"])
            .arg(d.path())
            .env("HEMODPD_FAULT_CHECKPOINT_ABORT", k.to_string())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(
            !out.status.success() && out.status.code().is_none(),
            "the run was not killed: {err}"
        );
        assert!(err.contains(&format!("aborting while writing checkpoint {k}")), "{err}");
        for f in [
            "checkpoint.h5",
            "checkpoint.prev.h5",
            "checkpoint.h5.tmp",
            "hemodpd.lock",
        ] {
            assert!(d.path().join(f).exists(), "{f} missing after the kill");
        }
        let ck = hemodpd_io::checkpoint::Checkpoint::load(d.path().join("checkpoint.h5")).unwrap();
        assert_eq!(ck.step, 100 * (k as u64 - 1), "the last complete checkpoint");
        d
    };

    // killed in the middle of a checkpoint write: the last complete one is used
    let d = killed_at_checkpoint(3);
    let out = resume(d.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("has ended; taking it over"),
        "the stale lock is not reported: {err}"
    );
    let s = summary(d.path());
    assert_eq!(s["results"]["final_state_fingerprint"], fingerprint);
    assert_eq!(s["results"]["resumed_from_step"].as_u64(), Some(200));
    assert_eq!(frames(d.path()).0, frames(reference.path()).0);
    assert!(!d.path().join("hemodpd.lock").exists(), "the lock outlived the run");

    // the newest checkpoint truncated: reported as damaged, the previous one is used
    let d = killed_at_checkpoint(4);
    let path = d.path().join("checkpoint.h5");
    let len = std::fs::metadata(&path).unwrap().len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&path)
        .unwrap()
        .set_len(len / 2)
        .unwrap();
    let out = resume(d.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("checkpoint.h5 is damaged") && err.contains("checkpoint.prev.h5 (step 200)"),
        "{err}"
    );
    let s = summary(d.path());
    assert_eq!(s["results"]["final_state_fingerprint"], fingerprint);
    assert_eq!(s["results"]["resumed_from_step"].as_u64(), Some(200));
    assert_eq!(frames(d.path()).0, frames(reference.path()).0);

    // both damaged: a clear error, no panic
    let d = killed_at_checkpoint(4);
    for f in ["checkpoint.h5", "checkpoint.prev.h5"] {
        std::fs::write(d.path().join(f), b"not a checkpoint").unwrap();
    }
    let out = resume(d.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("checkpoint.prev.h5 is damaged too") && !err.contains("panicked"),
        "{err}"
    );
}

/// A second `hemodpd run` or `--resume` on the output directory of a run that is going stops at
/// once, names the process that holds it and changes nothing: the first run goes on, is
/// interrupted and resumed, and its trajectory is whole.
#[test]
fn a_running_runs_directory_is_refused_to_a_second_process() {
    let bin = env!("CARGO_BIN_EXE_hemodpd");
    let scen = scenario_path();
    let sets = LONG_RUN;
    let d = tempfile::tempdir().unwrap();
    let mut first = Command::new(bin)
        .arg("run")
        .arg(&scen)
        .args(sets)
        .arg("--out")
        .arg(d.path())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // wait for the first run's lock and its first checkpoint (its files exist and are in use)
    let t0 = std::time::Instant::now();
    loop {
        let lock: Option<serde_json::Value> = std::fs::read_to_string(d.path().join("hemodpd.lock"))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok());
        let holds = lock.is_some_and(|v| v["pid"].as_u64() == Some(first.id() as u64));
        if holds && hemodpd_io::checkpoint::Checkpoint::load(d.path().join("checkpoint.h5")).is_ok() {
            break;
        }
        assert!(first.try_wait().unwrap().is_none(), "the first run ended early");
        assert!(t0.elapsed().as_secs() < 120, "no lock and checkpoint after 120 s");
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let trajectory = d.path().join("trajectory.h5");
    let before = std::fs::metadata(&trajectory).unwrap().len();
    let second = Command::new(bin)
        .arg("run")
        .arg(&scen)
        .args(sets)
        .arg("--out")
        .arg(d.path())
        .output()
        .unwrap();
    let third = Command::new(bin)
        .args(["run", "--resume", d.path().to_str().unwrap(), "--quiet"])
        .output()
        .unwrap();
    for out in [&second, &third] {
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(
            err.contains(&format!("in use by process {} on host", first.id())) && err.contains("Nothing was changed"),
            "{err}"
        );
    }
    // the first run's trajectory was not cut (it only grows while the run goes on)
    assert!(std::fs::metadata(&trajectory).unwrap().len() >= before);
    assert!(first.try_wait().unwrap().is_none(), "the first run ended early");
    Command::new("kill")
        .args(["-INT", &first.id().to_string()])
        .status()
        .unwrap();
    let out = first.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(130), "{}", String::from_utf8_lossy(&out.stderr));
    let resumed = Command::new(bin)
        .args([
            "run",
            "--resume",
            d.path().to_str().unwrap(),
            "--quiet",
            "--threads",
            "2",
        ])
        .output()
        .unwrap();
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    let (steps, _) = frames(d.path());
    let expected: Vec<u64> = (0..=40).map(|k| 200 + 500 * k).collect();
    assert_eq!(steps, expected, "the trajectory lost or repeated frames");
}
