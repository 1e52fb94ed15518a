//! End-to-end tests of the shear scenario (docs/shear.md): one cell in simple shear by
//! Lees–Edwards boundaries or sliding plates, SI in and out, the motion classified.
//! Measured values are in the comments; tolerances say why.

use hemodpd_scenario::{load, run, RunContext, Scenario};
use serde_json::Value;
use std::path::{Path, PathBuf};

use crate::common::{self, f};

fn scenario_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/shear.toml")
}

/// The shipped scenario with a small cell (N = 100) in a small box (14 × 12 × 12 µm: ~6000
/// particles), then `sets`.
fn small(sets: &[&str]) -> Scenario {
    // the paper's membrane: these tests pin the engine and the regimes of the paper's model
    // (the calibrated cell's are in docs/validation.md, "The calibrated cell")
    let mut all: Vec<String> = vec![
        "cell.parameters=paper".into(),
        "cell.vertices=100".into(),
        "shear.box_um=[14.0, 12.0, 12.0]".into(),
        "output.frame_every_strain=0".into(),
    ];
    all.extend(sets.iter().map(|s| s.to_string()));
    load(&scenario_path(), &all).unwrap()
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

/// Fischer's highest shear rate (260 1/s at 28.9 mPa·s) runs with κ/kBT exact: `fluid = "auto"`
/// with `thermal_factor = "exact"` rules out the capillary fluid (Mach 66 at f = 1) and the dense
/// one (Mach 2.1) and takes the viscous fluid (Mach ≈ 0.25, Re ≈ 0.13). A short run of the N = 500
/// cell (0.3 strain, ≈ 1400 steps in a 14 × 12 × 12 µm box) keeps its area and volume within 2 %,
/// lets no fluid through, and the plasma carries the imposed shear rate within 5 %.
#[test]
fn fischer_top_rate_runs_with_exact_kappa() {
    let dir = tempfile::tempdir().unwrap();
    // the box and frames of `small`, with the N = 500 cell
    let s = small(&[
        "cell.vertices=500",
        "shear.shear_rate_per_s=260",
        "model.fluid=\"auto\"",
        "model.thermal_factor=\"exact\"",
        "shear.duration_strain=0.3",
        "shear.analysis_start_strain=0.1",
        "model.crossing_check_every_steps=100",
    ]);
    let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
    eprintln!("fluid {}; groups {}; cell {}", r["fluid"], r["groups_model"], r["cell"]);
    assert_eq!(r["fluid"]["name"], "viscous", "{}", r["fluid"]);
    let (k_si, k_m) = (
        f(&r["groups_si"]["kappa_over_kbt"]),
        f(&r["groups_model"]["kappa_over_kbt"]),
    );
    assert!((k_si / k_m - 1.0).abs() < 1e-9, "κ/kBT {k_si} vs {k_m}");
    assert!(f(&r["groups_model"]["mach"]) <= 0.25 + 1e-9);
    let measured = f(&r["shear"]["measured_fluid_shear_rate_per_s"]);
    assert!((measured / 260.0 - 1.0).abs() < 0.05, "fluid shear rate {measured}");
    assert!(f(&r["cell"]["max_abs_area_deviation"]) < 0.02);
    assert!(f(&r["cell"]["max_abs_volume_deviation"]) < 0.02);
    assert_eq!(r["crossings"]["misplaced_total"], 0, "{}", r["crossings"]);
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
    pool(2).install(|| common::run_in_three_parts(&s, &mut ctx, [333, 1001]));
    common::assert_same_end(whole.path(), parts.path(), "motion.csv", "motion series");
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
    let text = common::explain_units(&scenario_path());
    common::assert_explained(
        &text,
        &[
            "shear rate",
            "shear stress",
            "time step",
            "Ca = η_out γ̇ R/μ0",
            "κ/kBT",
            "Mach",
            "Re",
        ],
        "Ca = η_out",
    );
}

/// Real short runs land in the right class (N = 100, 14 × 12 × 12 µm): at Ca = 0.04 (3 1/s at
/// 28.9 mPa·s; 12 strain units, the motion classified from strain 3) the cell tumbles
/// (measured: 1 flip, 0.12 flips per unit strain, as over 16 strain units; a Jeffery period of
/// ~15 strain units for a disc of aspect ~0.4); at Ca = 0.68 (50 1/s; 16 strain units from
/// strain 4) its membrane tank-treads (measured: swinging, f/γ̇ = 0.061, inclination 18.7° ±
/// 5.3°; Fischer 2007–2015: f/γ̇ 0.02–0.06, 8–20°). The tank-treading run needs its length:
/// one membrane half-turn takes 8 strain units, and `hemodpd analyze`, whose window starts at
/// the first frame, finds none in a 12-unit run.
#[test]
fn low_stress_tumbles() {
    let dir = tempfile::tempdir().unwrap();
    let s = small(&[
        "shear.shear_rate_per_s=3",
        "shear.duration_strain=12",
        "shear.analysis_start_strain=3",
    ]);
    let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
    let m = &r["motion"];
    eprintln!("Ca {}: {m}", r["groups_si"]["capillary_number"]);
    assert_eq!(m["class"], "Tumbling", "{m}");
    assert!(m["flips"].as_u64().unwrap() >= 1);
    let per_strain = f(&m["tumbling_rate_flips_per_s"]) / 3.0;
    assert!(
        per_strain > 0.05 && per_strain < 0.5,
        "{per_strain} flips per unit strain"
    );
    assert_eq!(r["crossings"]["misplaced_total"], 0);
}

/// See [`low_stress_tumbles`].
#[test]
fn high_stress_tank_treads() {
    let dir = tempfile::tempdir().unwrap();
    let s = small(&[
        "shear.shear_rate_per_s=50",
        "shear.duration_strain=16",
        "shear.analysis_start_strain=4",
        "output.frame_every_strain=0.25",
    ]);
    let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
    let m = &r["motion"];
    eprintln!("Ca {}: {m}", r["groups_si"]["capillary_number"]);
    let class = m["class"].as_str().unwrap();
    assert!(class == "TankTreading" || class == "Swinging", "{m}");
    let ttf = f(&m["tank_treading_frequency_over_shear_rate"]);
    assert!(ttf > 0.02 && ttf < 0.1, "f/γ̇ = {ttf}");
    let incl = f(&m["mean_inclination_deg"]);
    assert!(incl > 5.0 && incl < 35.0, "inclination {incl}°");
    assert_eq!(r["crossings"]["misplaced_total"], 0);
    // `hemodpd analyze` classifies the trajectory's frames (every 0.25 strain) the same way,
    // with the same frequency within 5 % (its frames are 5× sparser than the run's samples and
    // its material reference is the first frame, not the resting mesh)
    let out = dir.path().join("analysis");
    let st = std::process::Command::new(env!("CARGO_BIN_EXE_hemodpd"))
        .args([
            "analyze",
            dir.path().join("trajectory.h5").to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .status()
        .unwrap();
    assert!(st.success());
    let a: Value = serde_json::from_str(&std::fs::read_to_string(out.join("shear.json")).unwrap()).unwrap();
    assert_eq!(a["class"], m["class"], "{a}");
    let ttf_a = f(&a["tank_treading_frequency_over_shear_rate"]);
    assert!((ttf_a / ttf - 1.0).abs() < 0.05, "analyze f/γ̇ {ttf_a} vs run {ttf}");
    assert!(std::fs::read_to_string(out.join("motion.csv")).unwrap().lines().count() > 50);
}

// ---------------------------------------------------------------------------------------------
// The Fig. 4 validation (scripts/validate_shear.sh): reduced grids through `hemodpd sweep`,
// compared with the experiments in tests/data. Long (an hour or more on 2 cores); the sweeps
// are resumable, so a second call only tabulates.

/// Rows of a reference CSV in tests/data (comments and the header skipped), split on commas.
fn reference_rows(name: &str) -> Vec<Vec<String>> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name);
    std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| l.split(',').map(|c| c.trim().to_string()).collect())
        .collect()
}

/// Runs (or continues) one grid with `hemodpd sweep` into `dir/name`; returns each point's
/// summary `results`.
fn sweep_grid(dir: &Path, name: &str, sets: &[&str], vary: &str) -> Vec<Value> {
    let out = dir.join(name);
    let scen = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/shear-sweep.toml");
    let mut args: Vec<String> = vec![
        "sweep".into(),
        scen.to_string_lossy().into_owned(),
        "--jobs".into(),
        "1".into(),
        "--quiet".into(),
        "--out".into(),
        out.to_string_lossy().into_owned(),
        "--vary".into(),
        vary.into(),
        // the tables of docs/validation.md §7 are the paper's set's (the elastic model)
        "--set".into(),
        "cell.parameters=paper".into(),
    ];
    for s in sets {
        args.push("--set".into());
        args.push(s.to_string());
    }
    let t = std::time::Instant::now();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_hemodpd"))
        .args(&args)
        .output()
        .unwrap();
    assert!(o.status.success(), "{name}: {}", String::from_utf8_lossy(&o.stderr));
    eprintln!(
        "{name}: {:.0} s\n{}",
        t.elapsed().as_secs_f64(),
        String::from_utf8_lossy(&o.stdout)
    );
    let table: Value = serde_json::from_str(&std::fs::read_to_string(out.join("sweep.json")).unwrap()).unwrap();
    table["runs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            let dir = out.join(r["point_dir"].as_str().unwrap());
            let s: Value = serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
            let mut res = s["results"].clone();
            // runs from before the field existed: the same fit from motion.csv
            if res["membrane_rotation"].is_null() {
                res["membrane_rotation"] = rotation_from_csv(&dir, &res);
            }
            res
        })
        .collect()
}

/// The membrane's mean rotation over the analysis window from a point's motion.csv (the
/// least-squares slope of Φ against time, as in the run's `membrane_rotation`).
fn rotation_from_csv(dir: &Path, res: &Value) -> Value {
    let start = f(&res["shear"]["analysis_start_strain"]);
    let rate = f(&res["shear"]["shear_rate_per_s"]);
    let rows: Vec<(f64, f64)> = std::fs::read_to_string(dir.join("motion.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|x| x.parse::<f64>().unwrap()).collect::<Vec<f64>>())
        .filter(|c| c[1] >= start)
        .map(|c| (c[0], c[8]))
        .collect();
    let n = rows.len() as f64;
    let (mt, mp) = rows.iter().fold((0.0, 0.0), |(a, b), r| (a + r.0 / n, b + r.1 / n));
    let num: f64 = rows.iter().map(|r| (r.0 - mt) * (r.1 - mp)).sum();
    let den: f64 = rows.iter().map(|r| (r.0 - mt).powi(2)).sum();
    let hz = -(num / den) / std::f64::consts::TAU;
    serde_json::json!({ "frequency_hz": hz, "over_shear_rate": hz / rate })
}

/// One row of the validation table.
fn point_row(n: u64, visc: bool, r: &Value) -> String {
    let m = &r["motion"];
    let num = |v: &Value, d: usize| v.as_f64().map_or("–".to_string(), |x| format!("{x:.d$}"));
    format!(
        "| {n} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
        if visc { "6.3e-7" } else { "0" },
        num(&r["shear"]["outer_viscosity_pa_s"].as_f64().map(|x| x * 1e3).into(), 1),
        num(&r["shear"]["shear_stress_pa"], 3),
        num(&r["shear"]["shear_rate_per_s"], 1),
        num(&r["groups_si"]["capillary_number"], 3),
        num(&r["unit_mapping"]["thermal_factor"], 1),
        m["class"].as_str().unwrap_or("?"),
        num(
            &m["tumbling_rate_flips_per_s"]
                .as_f64()
                .map(|x| x / f(&r["shear"]["shear_rate_per_s"]))
                .into(),
            3
        ),
        num(&m["tank_treading_frequency_over_shear_rate"], 4),
        num(&m["mean_inclination_deg"], 1),
        num(&m["inclination_amplitude_deg"], 1),
        num(&r["performance"]["seconds_per_unit_strain"], 1),
    )
}

fn is_tt(r: &Value) -> bool {
    matches!(r["motion"]["class"].as_str(), Some("TankTreading" | "Swinging"))
}

/// The reduced Fig. 4 grids, the transition stress per N and viscosity, f/γ̇ against Fischer's
/// cells at 28.9 mPa·s and the inclination against Fischer 2015 at 23.9 mPa·s. Prints the
/// tables of docs/validation.md §7 and writes the figures into `$HEMODPD_FIGURES_DIR`. Asserts
/// what the docs state: the lowest stress tumbles and the highest tank-treads at every N (the
/// transition is inside the grid), no fluid crossed a membrane, and the model's f/γ̇ at the
/// tank-treading points lies between Fischer's slowest cells (0.016) and the rotation of a rigid
/// sphere (1/4π = 0.080): the comparison itself is a table, not a pass/fail, because the elastic
/// model is known not to match it (docs/validation.md §7).
#[test]
#[ignore]
fn shear_validation_fig4() {
    use hemodpd_io::plot::{line_chart, Series};
    let dir = std::env::var_os("HEMODPD_SHEAR_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("hemodpd-shear-validation"));
    std::fs::create_dir_all(&dir).unwrap();
    let figs = std::env::var_os("HEMODPD_FIGURES_DIR").map(PathBuf::from);
    let stresses = "shear.shear_stress_pa=0.05,0.1,0.2,0.5,1,2";
    // (N, η_out in mPa·s, membrane viscosity on, the points)
    let grids: Vec<(u64, &str, bool, Vec<Value>)> = vec![
        (500, "28.9", false, sweep_grid(&dir, "shear-n500", &[], stresses)),
        (
            1000,
            "28.9",
            false,
            sweep_grid(
                &dir,
                "shear-n1000",
                &[
                    "cell.vertices=1000",
                    "shear.duration_strain=30",
                    "shear.analysis_start_strain=10",
                ],
                "shear.shear_stress_pa=0.2,0.5",
            ),
        ),
        (
            5000,
            "28.9",
            false,
            sweep_grid(
                &dir,
                "shear-n5000",
                &[
                    "cell.vertices=5000",
                    "shear.duration_strain=30",
                    "shear.analysis_start_strain=10",
                ],
                "shear.shear_stress_pa=0.2,0.5",
            ),
        ),
        (
            500,
            "23.9",
            false,
            sweep_grid(
                &dir,
                "shear-n500-eta23.9",
                &[
                    "fluid.outer_viscosity_pa_s=23.9e-3",
                    "shear.duration_strain=30",
                    "shear.analysis_start_strain=10",
                ],
                // 8, 17 and 38 1/s
                "shear.shear_stress_pa=0.1912,0.4063,0.9082",
            ),
        ),
        (
            500,
            "28.9",
            true,
            sweep_grid(
                &dir,
                "shear-n500-visc",
                &[
                    "cell.membrane_viscosity_pa_s_m=6.3e-7",
                    "model.membrane_substeps=auto",
                    "shear.duration_strain=30",
                    "shear.analysis_start_strain=10",
                ],
                "shear.shear_stress_pa=0.5,2",
            ),
        ),
    ];
    println!("| N | η_m (N·s/m) | η_out (mPa·s) | stress (Pa) | γ̇ (1/s) | Ca | f | class | flips per strain | f_TT/γ̇ | θ (°) | swing ± (°) | s per strain |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (n, _, visc, rs) in &grids {
        for r in rs {
            println!("{}", point_row(*n, *visc, r));
            assert_eq!(r["crossings"]["misplaced_total"], 0, "{}", r["crossings"]);
        }
    }
    // the transition: between the last tumbling and the first tank-treading stress
    let thresholds = reference_rows("shear_tt_tb_threshold_stress.csv");
    println!("\n| N | η_m | η_out (mPa·s) | transition stress (Pa) | experiments at similar η_out |");
    println!("|---|---|---|---|---|");
    for (n, eta, visc, rs) in &grids {
        let last_tb = rs
            .iter()
            .filter(|r| r["motion"]["class"] == "Tumbling")
            .map(|r| f(&r["shear"]["shear_stress_pa"]))
            .fold(f64::NAN, f64::max);
        let first_tt = rs
            .iter()
            .filter(|r| is_tt(r))
            .map(|r| f(&r["shear"]["shear_stress_pa"]))
            .fold(f64::NAN, f64::min);
        let eta_v: f64 = eta.parse().unwrap();
        let near: Vec<String> = thresholds
            .iter()
            .filter(|row| {
                let e: f64 = row[1].parse().unwrap();
                (e / eta_v - 1.0).abs() < 0.35
            })
            .map(|row| format!("{} {} mPa·s: {} Pa", row[0], row[1], row[2]))
            .collect();
        println!(
            "| {n} | {} | {eta} | {last_tb} – {first_tt} | {} |",
            if *visc { "6.3e-7" } else { "0" },
            near.join("; ")
        );
        if *eta == "28.9" && *n == 500 && !*visc {
            assert!(
                rs.first().unwrap()["motion"]["class"] == "Tumbling" && is_tt(rs.last().unwrap()),
                "the transition is not inside the N = 500 grid"
            );
        }
    }
    // f/γ̇ against Fischer's cells at 28.9 mPa·s
    let ttf = reference_rows("shear_ttf_fischer_28.9mPas.csv");
    let exp: Vec<(f64, f64)> = ttf
        .iter()
        .map(|r| (r[1].parse().unwrap(), r[2].parse().unwrap()))
        .collect();
    println!("\n| γ̇ (1/s) | η_m (N·s/m) | class | model f_TT/γ̇ (N = 500) | fitted membrane rotation / γ̇ | Fischer cells within ±20 % of γ̇: mean ± sd (n) |");
    println!("|---|---|---|---|---|---|");
    let mut model_pts = [Vec::new(), Vec::new()];
    let tt_points = grids[0]
        .3
        .iter()
        .map(|r| (false, r))
        .chain(grids[4].3.iter().map(|r| (true, r)));
    for (visc, r) in tt_points.filter(|(v, r)| is_tt(r) || (*v && r["motion"]["class"] == "Undetermined")) {
        let rate = f(&r["shear"]["shear_rate_per_s"]);
        // the classified frequency, or for a window too short to classify the fitted rotation
        let v = match r["motion"]["tank_treading_frequency_over_shear_rate"].as_f64() {
            Some(v) => v,
            None => f(&r["membrane_rotation"]["over_shear_rate"]),
        };
        let near: Vec<f64> = exp
            .iter()
            .filter(|(g, _)| (g / rate - 1.0).abs() < 0.2)
            .map(|p| p.1)
            .collect();
        let (mean, sd) = if near.is_empty() {
            (f64::NAN, f64::NAN)
        } else {
            let m = near.iter().sum::<f64>() / near.len() as f64;
            let sd = (near.iter().map(|x| (x - m).powi(2)).sum::<f64>() / near.len() as f64).sqrt();
            (m, sd)
        };
        println!(
            "| {rate:.1} | {} | {} | {v:.4} | {:.4} | {mean:.4} ± {sd:.4} ({}) |",
            if visc { "6.3e-7" } else { "0" },
            r["motion"]["class"].as_str().unwrap_or("?"),
            f(&r["membrane_rotation"]["over_shear_rate"]),
            near.len()
        );
        // elastic: between Fischer's slowest cells and a rigid sphere's rotation γ̇/2 (1/4π)
        if !visc {
            assert!(v > 0.016 && v < 0.25 / std::f64::consts::PI, "f/γ̇ = {v} at {rate} 1/s");
        }
        model_pts[visc as usize].push((rate, v));
    }
    // the inclination against Fischer 2015 at 23.9 mPa·s
    let incl = reference_rows("shear_inclination_angle_fischer2015.csv");
    let exp_incl: Vec<(f64, f64)> = incl
        .iter()
        .filter(|r| r[0] == "23.9")
        .map(|r| (r[2].parse().unwrap(), r[3].parse().unwrap()))
        .collect();
    println!("\n| γ̇ (1/s) | model θ (°), N = 500, 23.9 mPa·s | class | Fischer 2015 cells within ±30 % of γ̇: mean ± sd (n) |");
    println!("|---|---|---|---|");
    let mut incl_pts = Vec::new();
    for r in &grids[3].3 {
        let rate = f(&r["shear"]["shear_rate_per_s"]);
        let th = f(&r["motion"]["mean_inclination_deg"]);
        let near: Vec<f64> = exp_incl
            .iter()
            .filter(|(g, _)| (g / rate - 1.0).abs() < 0.3)
            .map(|p| p.1)
            .collect();
        let m = near.iter().sum::<f64>() / near.len().max(1) as f64;
        let sd = (near.iter().map(|x| (x - m).powi(2)).sum::<f64>() / near.len().max(1) as f64).sqrt();
        println!(
            "| {rate:.1} | {th:.1} | {} | {m:.1} ± {sd:.1} ({}) |",
            r["motion"]["class"].as_str().unwrap_or("?"),
            near.len()
        );
        if th.is_finite() {
            incl_pts.push((rate, th));
        }
    }
    if let Some(figs) = figs {
        std::fs::create_dir_all(&figs).unwrap();
        line_chart(
            figs.join("shear_ttf.png"),
            "Tank-treading frequency over shear rate, η_out = 28.9 mPa·s",
            "shear rate (1/s)",
            "f_TT / shear rate",
            &[
                Series::points("Fischer (cells)", exp.clone()),
                Series::line_with_points("model, N = 500, elastic", model_pts[0].clone()).with_color(200, 30, 30),
                Series::line_with_points("model, N = 500, η_m = 6.3e-7 N·s/m", model_pts[1].clone())
                    .with_color(30, 30, 200),
            ],
        )
        .unwrap();
        line_chart(
            figs.join("shear_inclination.png"),
            "Inclination of tank-treading cells, η_out = 23.9 mPa·s",
            "shear rate (1/s)",
            "inclination (deg)",
            &[
                Series::points("Fischer 2015 (cells)", exp_incl.clone()),
                Series::line_with_points("model, N = 500", incl_pts).with_color(200, 30, 30),
            ],
        )
        .unwrap();
        // Fig. 4 style: the rates against the stress, per N
        let mut series = Vec::new();
        for (n, eta, visc, rs) in &grids {
            if *eta != "28.9" || *visc {
                continue;
            }
            let tt: Vec<(f64, f64)> = rs
                .iter()
                .filter(|r| is_tt(r))
                .map(|r| {
                    (
                        f(&r["shear"]["shear_stress_pa"]),
                        f(&r["motion"]["tank_treading_frequency_hz"]),
                    )
                })
                .collect();
            let tb: Vec<(f64, f64)> = rs
                .iter()
                .filter(|r| r["motion"]["class"] == "Tumbling")
                .map(|r| {
                    (
                        f(&r["shear"]["shear_stress_pa"]),
                        f(&r["motion"]["tumbling_rate_flips_per_s"]) / 2.0,
                    )
                })
                .collect();
            series.push(Series::line_with_points(
                format!("tank-treading frequency, N = {n}"),
                tt,
            ));
            series.push(Series::line_with_points(
                format!("tumbling frequency (flips/2), N = {n}"),
                tb,
            ));
        }
        line_chart(
            figs.join("shear_fig4.png"),
            "Cell in shear (η_out = 28.9 mPa·s): tumbling at low stress, tank-treading at high",
            "shear stress (Pa)",
            "frequency (Hz)",
            &series,
        )
        .unwrap();
    }
}
