//! The `hemodpd` command line: params, mesh, run -> summary.json.

use std::process::Command;

fn hemodpd(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_hemodpd")).args(args).output().unwrap()
}

/// `params --json` carries the documented keys, with Table I's values for N = 500 and the
/// N-independent moduli of Eqs. 10–11 (8.303 µN/m, 16.61 µN/m, Y = 22.14 µN/m).
#[test]
fn params_json() {
    let out = hemodpd(&["params", "--n", "500", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in [
        "n",
        "l0_m",
        "lmax_m",
        "persistence_length_m",
        "c_j_m2",
        "theta0_deg",
        "k_bend_j",
        "shear_modulus_n_per_m",
        "area_modulus_n_per_m",
        "young_modulus_n_per_m",
        "area0_m2",
        "volume0_m3",
    ] {
        assert!(j[key].is_number(), "missing {key}");
    }
    let get = |k: &str| j[k].as_f64().unwrap();
    assert!((get("l0_m") - 5.18e-7).abs() < 1e-9);
    assert!((get("persistence_length_m") - 1.08e-9).abs() < 1e-11);
    assert!((get("theta0_deg") - 6.90).abs() < 0.01);
    assert!((get("shear_modulus_n_per_m") / 8.3030e-6 - 1.0).abs() < 1e-4);
    assert!((get("young_modulus_n_per_m") / 2.2141e-5 - 1.0).abs() < 1e-4);
    // Evans–Fung with the corrected c0: 134.1 µm², 94.09 µm³
    assert!((get("area0_m2") / 134.1e-12 - 1.0).abs() < 5e-4);
    assert!((get("volume0_m3") / 94.09e-18 - 1.0).abs() < 1e-4);
    let bad = hemodpd(&["params", "--n", "50"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("n = 50"));
}

/// `mesh` writes a closed mesh that reads back with the requested vertex count.
#[test]
fn mesh_command_writes_a_readable_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let off = dir.path().join("cell.off");
    let out = hemodpd(&["mesh", "--n", "300", "--seed", "4", "-o", off.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let m = hemodpd_membrane::meshio::read_mesh(&off).unwrap();
    assert_eq!(m.vertices.len(), 300);
    let q: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(q["quality"]["min_angle_deg"].as_f64().unwrap() > 30.0);
}

/// `run` writes summary.json with the resolved scenario, the seed, versions, wall time and the
/// stretching results (force, D_A, D_T arrays and the RMS deviation from Mills), and the shapes file.
#[test]
fn run_writes_summary_json() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/stretching.toml");
    let out = hemodpd(&[
        "run",
        scenario,
        "--set",
        "stretching.forces_pn=[0.0, 100.0]",
        "--out",
        dir.path().to_str().unwrap(),
        "--quiet",
        "--threads",
        "1",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("summary.json")).unwrap()).unwrap();
    assert_eq!(j["seed"], 1);
    assert_eq!(j["scenario"]["membrane"]["vertices"], 500);
    assert!(j["wall_time_s"].as_f64().unwrap() > 0.0);
    assert!(j["scenario_toml"]
        .as_str()
        .unwrap()
        .contains("forces_pn = [0.0, 100.0]"));
    let r = &j["results"];
    assert_eq!(r["force_pn"].as_array().unwrap().len(), 2);
    let da = r["axial_diameter_um"][1].as_f64().unwrap();
    assert!(da > 11.5 && da < 14.5, "D_A(100 pN) = {da}");
    assert!(r["mills2004"]["rms_axial_um"].as_f64().unwrap() >= 0.0);
    assert!(dir.path().join("shapes.h5").exists() && dir.path().join("shapes.xmf").exists());
}

/// `analyze` reads a run's trajectory after the fact: one CSV row per frame, with the axial
/// diameter equal to the one the run reported (SI metres against µm), and PNGs with --plot;
/// a file that is not a trajectory gives a clear error and exit code 1.
#[test]
fn analyze_a_stretching_trajectory() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/stretching.toml");
    let out = hemodpd(&[
        "run",
        scenario,
        "--set",
        "stretching.forces_pn=[0.0, 150.0]",
        "--out",
        dir.path().to_str().unwrap(),
        "--quiet",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let h5 = dir.path().join("shapes.h5");
    let out = hemodpd(&["analyze", h5.to_str().unwrap(), "--plot"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let adir = dir.path().join("shapes.analysis");
    let csv = std::fs::read_to_string(adir.join("frames.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 3, "header + 2 frames");
    let col = lines[0].split(',').position(|c| c == "axial_diameter_m").unwrap();
    let da_m: f64 = lines[2].split(',').nth(col).unwrap().parse().unwrap();
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("summary.json")).unwrap()).unwrap();
    let da_um = summary["results"]["axial_diameter_um"][1].as_f64().unwrap();
    assert!((da_m * 1e6 - da_um).abs() < 1e-9, "{da_m} m vs {da_um} µm");
    assert!(adir.join("diameters.png").exists());

    let bad = dir.path().join("bad.h5");
    std::fs::write(&bad, b"not hdf5").unwrap();
    let out = hemodpd(&["analyze", bad.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.h5") && !err.contains("panicked"), "{err}");
}

/// `analyze` on a fluid-only trajectory (a `dpd-fluid` run) says so and exits with 1, instead
/// of reporting a missing dataset.
#[test]
fn analyze_refuses_a_fluid_only_trajectory_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let scen = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/dpd-fluid.toml");
    let out_dir = dir.path().join("run");
    let run = hemodpd(&[
        "run",
        scen.to_str().unwrap(),
        "--set",
        "fluid.box_size=[4.0, 4.0, 4.0]",
        "--set",
        "run.equilibration_steps=10",
        "--set",
        "run.steps=20",
        "--set",
        "run.sample_every=10",
        "--set",
        "output.trajectory_every_steps=10",
        "--quiet",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let out = hemodpd(&["analyze", out_dir.join("trajectory.h5").to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("holds no membrane") && err.contains("fluid frames only: 3"),
        "{err}"
    );
}

/// `sweep` runs every combination of the varied values, writes `sweep.json` with the figures of
/// the scenario's kind for each run, and prints them as a table.
#[test]
fn sweep_runs_every_combination_and_tabulates_the_kinds_figures() {
    let dir = tempfile::tempdir().unwrap();
    let scen = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/dpd-fluid.toml");
    let out = hemodpd(&[
        "sweep",
        scen.to_str().unwrap(),
        "--vary",
        "run.timestep=0.01,0.02",
        "--vary",
        "seed=1,2",
        "--set",
        "fluid.box_size=[4.0, 4.0, 4.0]",
        "--set",
        "run.equilibration_steps=20",
        "--set",
        "run.steps=40",
        "--set",
        "run.sample_every=2",
        "--quiet",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("kBT") && table.contains("pressure"), "{table}");
    let sweep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("sweep.json")).unwrap()).unwrap();
    let runs = sweep["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 4);
    for r in runs {
        // a plumbing check that the figure is read back from the run: 40 steps of 192 particles
        // just after the start are far from an equilibrium average (0.87 seen), so only a loose
        // bound; the temperature itself is validated in the engine tests (docs/validation.md §3)
        let t = r["metrics"]["kBT"].as_f64().unwrap();
        assert!(t > 0.5 && t < 1.5, "{r}");
        assert!(std::path::Path::new(r["dir"].as_str().unwrap())
            .join("summary.json")
            .exists());
    }
}

/// Stretching with the spheroidal stress-free reference (`membrane.reference = { spheroid = {
/// reduced_volume = 0.95 } }`, docs/model.md §4) against the resting-cell reference, over Mills
/// 2004's forces: the summary names the reference; at rest the cell keeps its diameter (within
/// 2 %: the spheroid's rest shape is 0.06 µm RMS from Evans–Fung, the resting-cell
/// reference's 0.08 µm); the RMS deviation from Mills (D_A and D_T together) is 0.887 µm with
/// either reference (measured), asserted within 0.05 µm of each other and below 1 µm.
#[test]
fn stretching_with_a_spheroidal_reference() {
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/stretching.toml");
    let run = |reference: &str| {
        let dir = tempfile::tempdir().unwrap();
        let set = format!("membrane.reference={reference}");
        let out = hemodpd(&[
            "run",
            scenario,
            "--set",
            &set,
            "--out",
            dir.path().to_str().unwrap(),
            "--quiet",
        ]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let j: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join("summary.json")).unwrap()).unwrap();
        j
    };
    let (plain, sph) = (run("\"stress-free\""), run("{spheroid={reduced_volume=0.95}}"));
    assert_eq!(
        sph["scenario"]["membrane"]["reference"]["spheroid"]["reduced_volume"],
        0.95
    );
    let f = |j: &serde_json::Value, p: &str| j["results"].pointer(p).and_then(|v| v.as_f64()).unwrap();
    let (d0, d1) = (f(&plain, "/axial_diameter_um/0"), f(&sph, "/axial_diameter_um/0"));
    assert!((d1 / d0 - 1.0).abs() < 0.02, "rest D_A {d1} µm against {d0} µm");
    let (r0, r1) = (f(&plain, "/mills2004/rms_both_um"), f(&sph, "/mills2004/rms_both_um"));
    assert!(
        (r1 - r0).abs() < 0.05 && r1 < 1.0,
        "RMS from Mills {r1} µm against {r0} µm"
    );
}

/// Runs a short scenario through the CLI into `out`, with `sets` as `--set` overrides.
fn run_short(scenario: &str, sets: &[&str], out: &std::path::Path) {
    let scen = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(scenario);
    let mut args = vec!["run", scen.to_str().unwrap()];
    for s in sets {
        args.extend(["--set", s]);
    }
    args.extend(["--quiet", "--out", out.to_str().unwrap()]);
    let run = hemodpd(&args);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
}

/// Decodes a GIF: (frame count, width, height, delay of the first frame in 1/100 s).
fn decode_gif(path: &std::path::Path) -> (usize, u16, u16, u16) {
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::RGBA);
    let mut dec = opts.read_info(std::fs::File::open(path).unwrap()).unwrap();
    let (w, h) = (dec.width(), dec.height());
    let (mut n, mut delay) = (0, 0);
    while let Some(frame) = dec.read_next_frame().unwrap() {
        assert_eq!((frame.width, frame.height), (w, h), "every frame covers the canvas");
        // A frame that is one colour drew nothing.
        let first = &frame.buffer[..4];
        assert!(frame.buffer.chunks(4).any(|p| p != first), "frame {n} is blank");
        if n == 0 {
            delay = frame.delay;
        }
        n += 1;
    }
    (n, w, h, delay)
}

/// `render --movie` turns a capillary run (side view, tube drawn) and a shear run (along the
/// vorticity) into GIFs: one frame per stored membrane frame (or per `--frames` entry), the size
/// of the view, the delay from `--fps`; `.mp4` without ffmpeg on the PATH fails with a message
/// that says so, and an unknown colouring names the allowed ones.
#[test]
fn movies_of_a_capillary_and_a_shear_run() {
    let dir = tempfile::tempdir().unwrap();
    let cap = dir.path().join("cap");
    run_short(
        "scenarios/capillary.toml",
        &[
            "tube.length_um=20.0",
            "stage.0.duration_s=0.0002",
            "stage.1.duration_s=0.0006",
            "stage.2.duration_s=0.0004",
            "output.frame_every_s=0.0002",
        ],
        &cap,
    );
    let shear = dir.path().join("shear");
    run_short(
        "scenarios/shear.toml",
        &[
            "shear.duration_strain=0.4",
            "output.sample_every_strain=0.05",
            "output.frame_every_strain=0.1",
            "cell.vertices=100",
            "shear.box_um=[12.0,12.0,10.0]",
        ],
        &shear,
    );
    let stored = |run: &std::path::Path| {
        let reader = hemodpd_io::TrajectoryReader::open(run.join("trajectory.h5")).unwrap();
        reader.membrane_frames().unwrap()
    };
    let (cap_frames, shear_frames) = (stored(&cap), stored(&shear));
    // each run leaves the ParaView view script beside its trajectory
    for run in [&cap, &shear] {
        let script = std::fs::read_to_string(run.join("view_in_paraview.py")).unwrap();
        assert_eq!(script, hemodpd_scenario::run_dir::PARAVIEW_VIEW_SCRIPT);
    }
    assert!(cap_frames >= 5 && shear_frames >= 4, "{cap_frames} {shear_frames}");

    let movie = |run: &std::path::Path, name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let traj = run.join("trajectory.h5");
        let mut args = vec!["render", traj.to_str().unwrap(), "--movie", out.to_str().unwrap()];
        args.extend(extra);
        let r = hemodpd(&args);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        (out, String::from_utf8_lossy(&r.stderr).into_owned())
    };
    let (gif, msg) = movie(&cap, "cap.gif", &["--color-by", "area-strain"]);
    assert!(msg.contains("side view, tube walls"), "{msg}");
    assert_eq!(decode_gif(&gif), (cap_frames, 640, 320, 10));
    let (gif, msg) = movie(&shear, "shear.gif", &["--color-by", "speed", "--fps", "4"]);
    assert!(msg.contains("along the vorticity"), "{msg}");
    assert_eq!(decode_gif(&gif), (shear_frames, 480, 480, 25));
    let (gif, _) = movie(&cap, "two.gif", &["--frames", "0,2"]);
    assert_eq!(decode_gif(&gif).0, 2);

    let traj = cap.join("trajectory.h5");
    let mp4 = dir.path().join("cap.mp4");
    let r = Command::new(env!("CARGO_BIN_EXE_hemodpd"))
        .args(["render", traj.to_str().unwrap(), "--movie", mp4.to_str().unwrap()])
        .env("PATH", "")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        !r.status.success() && err.contains("ffmpeg") && err.contains(".gif"),
        "{err}"
    );
    assert!(!mp4.exists(), "nothing written when ffmpeg is missing");
    let r = hemodpd(&[
        "render",
        traj.to_str().unwrap(),
        "--movie",
        "x.gif",
        "--color-by",
        "pressure",
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        !r.status.success() && err.contains("shading") && err.contains("area-strain"),
        "{err}"
    );
}
