//! `hemodpd fit`: a toy calibration with a known answer, a fit interrupted and resumed, the
//! shipped Mills experiment, and bad fit files refused before any work.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn hemodpd(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_hemodpd")).args(args).output().unwrap()
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A small dpd-fluid run: 375 particles, `steps` production steps.
fn fluid_sets(steps: u64) -> Vec<String> {
    vec![
        "fluid.box_size=[5.0,5.0,5.0]".into(),
        "run.equilibration_steps=200".into(),
        format!("run.steps={steps}"),
        "run.sample_every=10".into(),
    ]
}

/// The toy: calibrate the conservative amplitude a of the DPD fluid against a pressure
/// measured at a = 25 with the same seed (the known answer), σ = 0.1 (about the run's standard
/// error of the mean pressure).
fn toy_fit_file(dir: &Path, target: f64, steps: u64) -> PathBuf {
    let sets = fluid_sets(steps)
        .iter()
        .map(|s| format!("{s:?}"))
        .collect::<Vec<_>>()
        .join(", ");
    let text = format!(
        r#"format_version = 1

[[parameter]]
name = "a"
lower = 15.0
upper = 35.0
points = 5

[[experiment]]
name = "pressure"
scenario = {scenario:?}
set = [{sets}]
parameters = {{ a = "fluid.a" }}

[[experiment.observable]]
pointer = "/pressure/mean"
target = {target:?}
sigma = 0.1
"#,
        scenario = root().join("scenarios/dpd-fluid.toml").display().to_string()
    );
    let path = dir.join("toy.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn pressure_at_25(dir: &Path, steps: u64) -> f64 {
    let out = dir.join("reference");
    let scen = root().join("scenarios/dpd-fluid.toml");
    let mut args = vec!["run".to_string(), scen.display().to_string()];
    for s in fluid_sets(steps) {
        args.extend(["--set".to_string(), s]);
    }
    args.extend([
        "--set".into(),
        "fluid.a=25.0".into(),
        "--quiet".into(),
        "--out".into(),
        out.display().to_string(),
    ]);
    let r = Command::new(env!("CARGO_BIN_EXE_hemodpd"))
        .args(&args)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let s: Value = serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    s["results"]["pressure"]["mean"].as_f64().unwrap()
}

fn fit_json(out: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("fit.json")).unwrap()).unwrap()
}

/// The known answer a = 25 is recovered within its stated uncertainty (2σ, σ from Δχ² = 1), the
/// uncertainty is small against the bounds, and `run --params` applies the calibrated value.
#[test]
fn toy_fit_recovers_the_known_parameter() {
    let dir = tempfile::tempdir().unwrap();
    let target = pressure_at_25(dir.path(), 1000);
    let file = toy_fit_file(dir.path(), target, 1000);
    let out = dir.path().join("fit");
    let r = hemodpd(&["fit", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let f = fit_json(&out);
    let a = f["parameters"][0]["value"].as_f64().unwrap();
    let sigma = f["parameters"][0]["sigma"].as_f64().unwrap();
    eprintln!("a = {a} ± {sigma} (known: 25); target pressure {target}");
    assert!((a - 25.0).abs() < 2.0 * sigma, "a = {a} ± {sigma}");
    assert!(sigma > 0.0 && sigma < 0.5, "σ = {sigma}");
    assert_eq!(f["constrained"], true);
    assert!(f["experiments"][0]["chi2_at_fit"].as_f64().unwrap() < 1.0);
    let table = String::from_utf8_lossy(&r.stdout);
    assert!(table.contains("| a |") && table.contains("| pressure | 5 |"), "{table}");
    // the calibrated file applies to a dpd-fluid run
    let cal = out.join("calibrated.toml");
    let run_dir = dir.path().join("calibrated-run");
    let r = hemodpd(&[
        "run",
        root().join("scenarios/dpd-fluid.toml").to_str().unwrap(),
        "--params",
        cal.to_str().unwrap(),
        "--set",
        "run.steps=20",
        "--set",
        "run.equilibration_steps=10",
        "--quiet",
        "--out",
        run_dir.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let s: Value = serde_json::from_str(&std::fs::read_to_string(run_dir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["scenario"]["fluid"]["a"].as_f64().unwrap(), a);
    // ... and is refused, naming what it has, for another kind
    let r = hemodpd(&[
        "run",
        root().join("scenarios/capillary.toml").to_str().unwrap(),
        "--params",
        cal.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        !r.status.success() && err.contains("capillary") && err.contains("dpd-fluid"),
        "{err}"
    );
}

/// A fit stopped by Ctrl-C while its design runs, run again, ends as the uninterrupted fit does:
/// the finished points are kept, the interrupted one resumes from its checkpoint, and the
/// calibrated file is the same byte for byte.
#[test]
fn an_interrupted_fit_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let steps = 10_000;
    let file = toy_fit_file(dir.path(), 23.7, steps);
    let whole = dir.path().join("whole");
    let r = hemodpd(&[
        "fit",
        file.to_str().unwrap(),
        "--out",
        whole.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let cut = dir.path().join("cut");
    let child = Command::new(env!("CARGO_BIN_EXE_hemodpd"))
        .args(["fit", file.to_str().unwrap(), "--out", cut.to_str().unwrap(), "--quiet"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // once the first point is done, Ctrl-C (SIGINT to the fit process)
    let t0 = std::time::Instant::now();
    let first_done = || {
        std::fs::read_dir(cut.join("pressure"))
            .map(|d| d.flatten().any(|e| e.path().join("summary.json").exists()))
            .unwrap_or(false)
    };
    while !first_done() {
        assert!(t0.elapsed().as_secs() < 120, "no point finished");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let kill = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let out = child.wait_with_output().unwrap();
    assert!(!out.status.success(), "the fit ran to the end before the interrupt");
    assert!(!cut.join("calibrated.toml").exists());
    let r = hemodpd(&["fit", file.to_str().unwrap(), "--out", cut.to_str().unwrap(), "--quiet"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let a = std::fs::read_to_string(whole.join("calibrated.toml")).unwrap();
    let b = std::fs::read_to_string(cut.join("calibrated.toml")).unwrap();
    // the header names the output directory; the rest is identical
    let body = |s: &str| s.lines().skip(1).map(str::to_string).collect::<Vec<_>>();
    assert_eq!(body(&a), body(&b));
}

/// Runs the shipped fit file `scenarios/fits/NAME` with 3 design points per parameter in `dir`;
/// its `fit.json` and output directory.
fn shipped_fit_on_three_points(dir: &Path, name: &str) -> (Value, PathBuf) {
    let text = std::fs::read_to_string(root().join("scenarios/fits").join(name))
        .unwrap()
        .replace("points = 5", "points = 3");
    let file = dir.join(name);
    std::fs::write(&file, text).unwrap();
    let out = dir.join("fit");
    let r = hemodpd(&["fit", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    (fit_json(&out), out)
}

/// The shipped Mills 2004 experiment on a 3 × 3 design: the fit lies inside the bounds with a
/// finite uncertainty, and its χ² is no worse than the best design point's.
#[test]
fn shipped_mills_experiment_fits() {
    let dir = tempfile::tempdir().unwrap();
    let (f, _) = shipped_fit_on_three_points(dir.path(), "mills.toml");
    let e = &f["experiments"][0];
    assert_eq!(e["runs"], 9);
    assert_eq!(e["observables"].as_array().unwrap().len(), 26);
    assert!(e["chi2_at_fit"].as_f64().unwrap() <= e["best_design_chi2"].as_f64().unwrap() + 1e-9);
    for p in f["parameters"].as_array().unwrap() {
        let (v, lo, hi) = (
            p["value"].as_f64().unwrap(),
            p["lower"].as_f64().unwrap(),
            p["upper"].as_f64().unwrap(),
        );
        assert!(v >= lo && v <= hi, "{p}");
    }
    let v = f["parameters"][0]["sigma"].as_f64().unwrap();
    assert!(v > 0.0 && v < 0.14, "σ of the reduced volume {v}");
}

/// The shipped three-parameter Mills fit (`scenarios/fits/mills-x0.toml`, Lmax/L0 free) on a
/// 3 × 3 × 3 design: it finds the 5 × 5 × 5 design's answer within that fit's σ (docs/fit.md:
/// v = 0.981 ± 0.008, Lmax/L0 = 1.97 ± 0.24; measured here 0.980 and 1.98), and its χ² at the fit
/// is below 5, half the two-parameter fit's 10.0: the third parameter is what closes the gap.
#[test]
fn shipped_mills_x0_fit_finds_the_stiffening_links() {
    let dir = tempfile::tempdir().unwrap();
    let (f, out) = shipped_fit_on_three_points(dir.path(), "mills-x0.toml");
    let e = &f["experiments"][0];
    assert_eq!(e["runs"], 27);
    let chi2 = e["chi2_at_fit"].as_f64().unwrap();
    assert!(chi2 < 5.0, "χ² at the fit {chi2}");
    let value = |k: usize| f["parameters"][k]["value"].as_f64().unwrap();
    assert!((value(0) - 0.981).abs() < 0.008, "reduced volume {}", value(0));
    assert!((value(2) - 1.97).abs() < 0.24, "Lmax/L0 {}", value(2));
    let cal = std::fs::read_to_string(out.join("calibrated.toml")).unwrap();
    assert!(cal.contains("cell.max_extension_ratio="), "{cal}");
}

/// Bad fit files fail before any run, naming the key, the value and what is allowed; nothing is
/// written.
#[test]
fn bad_fit_files_are_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let cases: &[(&str, &[&str])] = &[
        (
            "format_version = 1\n[[parameter]]\nname = \"v\"\nlower = 0.9\n[[experiment]]\nname = \"mills2004\"\n",
            &["parameter[0].upper", "(missing)", "upper bound"],
        ),
        (
            "format_version = 1\n[[parameter]]\nname = \"reduced_volume\"\nlower = 0.9\nupper = 0.95\n[[experiment]]\nname = \"fischer2099\"\n",
            &["experiment[0].name", "\"fischer2099\"", "mills2004"],
        ),
        (
            "format_version = 1\n[[parameter]]\nname = \"reduced_volume\"\nlower = 0.9\nupper = 0.8\n[[experiment]]\nname = \"mills2004\"\n",
            &["parameter[0].upper", "0.8", "above lower = 0.9"],
        ),
        (
            "format_version = 1\n[[parameter]]\nname = \"eta\"\nlower = 0.0\nupper = 1.0\n[[experiment]]\nname = \"mills2004\"\n",
            &["experiment[0].parameters", "declared parameter (eta)", "reduced_volume"],
        ),
        (
            "format_version = 1\n[[parameter]]\nname = \"reduced_volume\"\nlower = 0.5\nupper = 0.95\n[[experiment]]\nname = \"mills2004\"\n",
            &["membrane.reference", "0.5"],
        ),
        (
            "format_version = 1\n[[parameter]]\nname = \"reduced_volume\"\nlower = 0.9\nupper = 0.95\npoints = 2\n[[experiment]]\nname = \"mills2004\"\n",
            &["parameter[0].points", "3–21"],
        ),
        (
            "format_version = 1\n[[parameter]]\nname = \"membrane_viscosity\"\nlower = 4e-7\nupper = 8e-7\npoints = 3\n[[experiment]]\nname = \"ttf\"\nshipped = \"fischer_ttf\"\n",
            &["experiment[0].shear_rate_per_s", "(missing)", "fischer_ttf"],
        ),
        (
            "format_version = 1\n[[parameter]]\nname = \"membrane_viscosity\"\nlower = 4e-7\nupper = 8e-7\npoints = 3\n[[experiment]]\nname = \"x\"\nshipped = \"fischer2099\"\n",
            &["experiment[0].shipped", "\"fischer2099\"", "fischer2015_inclination"],
        ),
        (
            "format_version = 1\n[[parameter]]\nname = \"a\"\nlower = 15.0\nupper = 35.0\n[[experiment]]\nname = \"p\"\nscenario = \"x.toml\"\nshear_rate_per_s = 17.3\n",
            &["experiment[0]", "shipped experiment"],
        ),
    ];
    for (k, (text, wanted)) in cases.iter().enumerate() {
        let file = dir.path().join(format!("bad{k}.toml"));
        std::fs::write(&file, text).unwrap();
        let out = dir.path().join(format!("out{k}"));
        let r = hemodpd(&["fit", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet"]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "case {k} ran");
        for w in *wanted {
            assert!(err.contains(w), "case {k}: {w:?} not in: {err}");
        }
        // no run started: no sweep directory
        let swept = std::fs::read_dir(&out)
            .map(|d| d.flatten().any(|e| e.path().is_dir()))
            .unwrap_or(false);
        assert!(!swept, "case {k}: a sweep directory was made");
    }
}

/// The shipped Hochmuth 1979 experiment calibrates the membrane viscosity alone (N = 200, 0.3 s
/// of recovery, 3 points over 4e-7–1.2e-6 N·s/m, the two-parameter `"calibrated"` membrane the
/// numbers below were measured with): a run at the fitted η_m gives Hochmuth's mean
/// t_c within the observable's σ (one SD of his cells, 0.033 s). It is not closer because the
/// fitted t_c of a fixed window is not linear in η_m (0.076, 0.226, 0.367 s at the three design
/// points), so the quadratic surface misses between them: measured 0.129 s at the fitted
/// 5.87e-7 where the surface predicts 0.147 s. `calibrated.toml` carries the viscosity, with the
/// recovery's central form, to the capillary and shear kinds' `[cell]`.
#[test]
fn shipped_hochmuth_experiment_calibrates_the_membrane_viscosity() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("hochmuth.toml");
    std::fs::write(
        &file,
        "format_version = 1\n[[parameter]]\nname = \"membrane_viscosity\"\nlower = 4e-7\nupper = 1.2e-6\npoints = 3\n[[experiment]]\nname = \"hochmuth1979\"\nset = [\"membrane.parameters=\\\"calibrated\\\"\", \"membrane.vertices=200\", \"recovery.duration_s=0.3\", \"recovery.samples=60\"]\n",
    )
    .unwrap();
    let out = dir.path().join("fit");
    let r = hemodpd(&["fit", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let f = fit_json(&out);
    let eta = f["parameters"][0]["value"].as_f64().unwrap();
    let calibrated = out.join("calibrated.toml");
    let text = std::fs::read_to_string(&calibrated).unwrap();
    for kind in ["capillary", "shear"] {
        let sets = hemodpd::fit::params_sets(&calibrated, kind).unwrap();
        assert!(
            sets.contains(&format!("cell.membrane_viscosity_pa_s_m={eta:?}")),
            "{kind}: {sets:?}"
        );
        assert!(
            sets.contains(&"cell.membrane_viscosity_form=\"central\"".to_string()),
            "{kind}: {sets:?}"
        );
    }
    // the run at the fitted value
    let check = dir.path().join("check");
    let r = hemodpd(&[
        "run",
        root().join("scenarios/recovery.toml").to_str().unwrap(),
        "--params",
        calibrated.to_str().unwrap(),
        "--set",
        "membrane.parameters=\"calibrated\"",
        "--set",
        "membrane.vertices=200",
        "--set",
        "recovery.duration_s=0.3",
        "--set",
        "recovery.samples=60",
        "--set",
        "output.shapes=false",
        "--out",
        check.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(r.status.success(), "{}\n{text}", String::from_utf8_lossy(&r.stderr));
    let s: Value = serde_json::from_str(&std::fs::read_to_string(check.join("summary.json")).unwrap()).unwrap();
    let tc = s["results"]["recovery"]["t_c_s"].as_f64().unwrap();
    let mean = s["results"]["recovery"]["hochmuth1979"]["mean_t_c_s"].as_f64().unwrap();
    eprintln!("η_m = {eta:.4e} N·s/m: t_c {tc:.4} s against {mean:.4} s");
    let sd = s["results"]["recovery"]["hochmuth1979"]["sd_t_c_s"].as_f64().unwrap();
    assert!(
        (tc - mean).abs() < sd,
        "t_c {tc} at the fitted η_m against {mean} ± {sd}"
    );
}

/// A shipped shear experiment through the whole fit, shortened to 0.6 strain units at N = 200 (the
/// plumbing, not the physics: the targets are Fischer's, the runs far too short to match them).
/// The membrane's rotation is defined in every run, so the TTF fit finishes; the inclination is
/// defined only for a classified tank-treading cell, none of these short runs is one, and that
/// fit stops after the runs with how many had a number. `calibrated.toml` carries a cell
/// calibrated in shear to the capillary kind too.
#[test]
fn shipped_shear_experiments_run_through_the_fit() {
    let dir = tempfile::tempdir().unwrap();
    let short = "set = [\"cell.vertices=200\", \"shear.duration_strain=0.6\", \"shear.analysis_start_strain=0.2\"]";
    let head =
        "format_version = 1\n[[parameter]]\nname = \"membrane_viscosity\"\nlower = 4e-7\nupper = 8e-7\npoints = 3\n";
    let ttf = dir.path().join("ttf.toml");
    std::fs::write(
        &ttf,
        format!(
            "{head}[[experiment]]\nname = \"ttf-64\"\nshipped = \"fischer_ttf\"\nshear_rate_per_s = 64.0\n{short}\n"
        ),
    )
    .unwrap();
    let out = dir.path().join("ttf");
    let r = hemodpd(&[
        "fit",
        ttf.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
        "--jobs",
        "2",
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let f = fit_json(&out);
    let e = &f["experiments"][0];
    assert_eq!(e["runs"], 3);
    assert!(
        (e["observables"][0]["target"].as_f64().unwrap() - 0.0287).abs() < 2e-4,
        "{e}"
    );
    assert_eq!(e["observables"][0]["runs_without_a_number"], 0);
    let eta = f["parameters"][0]["value"].as_f64().unwrap();
    assert!((4e-7..=8e-7).contains(&eta), "{eta}");
    for kind in ["shear", "capillary"] {
        let sets = hemodpd::fit::params_sets(&out.join("calibrated.toml"), kind).unwrap();
        assert!(
            sets.contains(&format!("cell.membrane_viscosity_pa_s_m={eta:?}")),
            "{kind}: {sets:?}"
        );
    }
    // the inclination: none of the three short runs defines it
    let incl = dir.path().join("incl.toml");
    std::fs::write(
        &incl,
        format!("{head}[[experiment]]\nname = \"incl\"\nshipped = \"fischer2015_inclination\"\nouter_viscosity_mpa_s = 23.9\nshear_rate_per_s = 64.0\n{short}\n"),
    )
    .unwrap();
    let out = dir.path().join("incl");
    let r = hemodpd(&[
        "fit",
        incl.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
        "--jobs",
        "2",
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success(), "the inclination fit ran to the end");
    assert!(
        err.contains("only 0 of 3 runs have a number at /motion/mean_inclination_deg"),
        "{err}"
    );
}
