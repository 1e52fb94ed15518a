//! End-to-end tests of the shear scenario (docs/shear.md): one cell in simple shear by
//! Lees–Edwards boundaries or sliding plates, SI in and out, the motion classified.
//! Measured values are in the comments; tolerances say why.

use hemodpd_scenario::{load, run, RunContext, RunError, Scenario};
use serde_json::Value;
use std::path::{Path, PathBuf};

fn scenario_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/shear.toml")
}

/// The shipped scenario with a small cell (N = 100) in a small box (14 × 12 × 12 µm: ~6000
/// particles), then `sets`.
fn small(sets: &[&str]) -> Scenario {
    let mut all: Vec<String> = vec![
        "cell.vertices=100".into(),
        "shear.box_um=[14.0, 12.0, 12.0]".into(),
        "output.frame_every_strain=0".into(),
    ];
    all.extend(sets.iter().map(|s| s.to_string()));
    load(&scenario_path(), &all).unwrap()
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

/// A short run (3 strain units at 32 1/s, Lees–Edwards and plates):
/// - the fluid carries the imposed shear rate: the plasma's mean slope dv_x/dy within 5 % (the
///   cell slows the fluid around it; measured −0.4 % (LE) and −2.6 % (plates));
/// - area and volume within 2 % (the constraints hold them to ~0.5 %);
/// - no fluid particle on the wrong side of the membrane (checked every 100 steps);
/// - the cell does not migrate across the flow by more than 0.5 µm (unbounded shear has no
///   lift; measured < 0.1 µm);
/// - the capillary number is the same in SI and in the model.
#[test]
fn cell_in_shear_keeps_its_volume_and_the_fluid_its_shear_rate() {
    for driver in ["lees-edwards", "plates"] {
        let dir = tempfile::tempdir().unwrap();
        let s = small(&[
            &format!("shear.driver=\"{driver}\""),
            "shear.duration_strain=3",
            "shear.analysis_start_strain=0.5",
            "model.crossing_check_every_steps=100",
        ]);
        let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
        let sh = &r["shear"];
        let measured = f(&sh["measured_fluid_shear_rate_per_s"]);
        eprintln!(
            "{driver}: shear rate {measured:.3} for {}; cell {}; crossings {}; {:.0} steps/s",
            sh["shear_rate_per_s"],
            r["cell"],
            r["crossings"],
            f(&r["performance"]["steps_per_second"])
        );
        assert!(
            (measured / 32.0 - 1.0).abs() < 0.05,
            "{driver}: fluid shear rate {measured}"
        );
        assert!(f(&r["cell"]["max_abs_area_deviation"]) < 0.02);
        assert!(f(&r["cell"]["max_abs_volume_deviation"]) < 0.02);
        assert!(f(&r["cell"]["centroid_drift_y_um"]).abs() < 0.5);
        assert_eq!(r["crossings"]["misplaced_total"], 0, "{driver}: {}", r["crossings"]);
        assert!(r["crossings"]["checks"].as_u64().unwrap() >= 40);
        let (ca_si, ca_m) = (
            f(&r["groups_si"]["capillary_number"]),
            f(&r["groups_model"]["capillary_number"]),
        );
        assert!((ca_si / ca_m - 1.0).abs() < 1e-9, "Ca {ca_si} vs {ca_m}");
        let csv = std::fs::read_to_string(dir.path().join("motion.csv")).unwrap();
        assert!(csv.lines().count() > 50, "motion.csv has {} lines", csv.lines().count());
    }
}

/// Interrupted twice (on 2 threads) and resumed, a run ends bit-identical to one uninterrupted
/// run on 1 thread: the same motion series and the same particle state.
#[test]
fn shear_resumes_bit_identically_on_any_thread_count() {
    let s = small(&["shear.duration_strain=1", "output.frame_every_strain=0.25"]);
    let pool = |n: usize| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
    let whole = tempfile::tempdir().unwrap();
    pool(1)
        .install(|| run(&s, &RunContext::new(whole.path(), 1, false)))
        .unwrap();
    let parts = tempfile::tempdir().unwrap();
    let mut ctx = RunContext::new(parts.path(), 2, false);
    pool(2).install(|| {
        ctx.stop_at_step = Some(333);
        assert!(matches!(run(&s, &ctx), Err(RunError::Interrupted { step: 333, .. })));
        ctx.stop_at_step = Some(1001);
        assert!(matches!(
            hemodpd_scenario::resume(parts.path(), &ctx),
            Err(RunError::Interrupted { step: 1001, .. })
        ));
        ctx.stop_at_step = None;
        hemodpd_scenario::resume(parts.path(), &ctx).unwrap();
    });
    let a = std::fs::read_to_string(whole.path().join("motion.csv")).unwrap();
    let b = std::fs::read_to_string(parts.path().join("motion.csv")).unwrap();
    assert_eq!(a, b, "motion series differ");
    let ck = |d: &Path| hemodpd_io::checkpoint::Checkpoint::load(d.join("checkpoint.h5")).unwrap();
    let (ca, cb) = (ck(whole.path()), ck(parts.path()));
    assert_eq!(ca.step, cb.step);
    assert_eq!(
        ca.vec3s("positions", None).unwrap(),
        cb.vec3s("positions", None).unwrap()
    );
    assert_eq!(
        ca.vec3s("velocities", None).unwrap(),
        cb.vec3s("velocities", None).unwrap()
    );
    let t = hemodpd_io::TrajectoryReader::open(parts.path().join("trajectory.h5")).unwrap();
    let u = hemodpd_io::TrajectoryReader::open(whole.path().join("trajectory.h5")).unwrap();
    assert_eq!(t.membrane_steps().unwrap(), u.membrane_steps().unwrap());
}

/// Bad input fails before any work, naming the key, the value and what is allowed.
#[test]
fn bad_shear_input_names_the_key() {
    let err = |sets: &[&str]| {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        load(&scenario_path(), &sets).unwrap_err().to_string()
    };
    let e = err(&["shear.shear_stress_pa=0.5"]);
    assert!(e.contains("shear.shear_rate_per_s") && e.contains("exactly one"), "{e}");
    let e = err(&["shear.box_um=[24.0, 8.0, 16.0]"]);
    assert!(e.contains("shear.box_um[1]") && e.contains('8'), "{e}");
    let e = err(&["shear.initial_inclination_deg=120"]);
    assert!(e.contains("initial_inclination_deg") && e.contains("120"), "{e}");
    let e = err(&["shear.driver=\"walls\""]);
    assert!(e.contains("walls"), "{e}");
    let e = err(&["fluid.outer_viscosity_pa_s=-1"]);
    assert!(e.contains("fluid.outer_viscosity_pa_s") && e.contains("-1"), "{e}");
    let e = err(&["shear.shear_rate_per_s=1e6"]);
    assert!(e.contains("shear.shear_rate_per_s") && e.contains("1000000"), "{e}");
    let e = err(&["shear.wind=3"]);
    assert!(e.contains("wind"), "{e}");
    let e = err(&["output.sample_every_strain=2"]);
    assert!(e.contains("output.sample_every_strain"), "{e}");
    // the shear stress sets the rate through the outer viscosity
    let sets: Vec<String> = ["shear.shear_rate_per_s=1.0", "shear.shear_stress_pa=0.5"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    assert!(load(&scenario_path(), &sets).is_err());
}

/// `--explain-units` prints the shear in SI and model units and the groups; the capillary
/// number agrees in both systems.
#[test]
fn shear_explain_units_prints_the_mapping() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_hemodpd"))
        .args(["run", scenario_path().to_str().unwrap(), "--explain-units"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    for key in [
        "shear rate",
        "shear stress",
        "time step",
        "Ca = η_out γ̇ R/μ0",
        "κ/kBT",
        "Mach",
        "Re",
    ] {
        assert!(text.contains(key), "no {key} in\n{text}");
    }
    let line = text.lines().find(|l| l.contains("Ca = η_out")).unwrap();
    let nums: Vec<&str> = line.split_whitespace().rev().take(2).collect();
    assert_eq!(nums[0], nums[1], "{line}");
}
