//! End-to-end tests of the capillary scenario (docs/capillary.md) and of the SI ↔ model mapping
//! it runs on (docs/units.md). Measured values are in the comments; tolerances say why.

use hemodpd_membrane::params::ModelParams;
use hemodpd_scenario::units::{poiseuille_mean_velocity, FluidModel, ThermalChoice, UnitMapping};
use hemodpd_scenario::{load, load_str, run, RunContext, RunError, Scenario};
use serde_json::Value;
use std::path::{Path, PathBuf};

use crate::common::{self, f};

fn scenario_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/capillary.toml")
}

/// The shipped capillary scenario with the paper's membrane parameters (the tests and
/// validations below pin the engine, the coupling and the paper's model, and are documented
/// with that set; `calibrated_default_*` runs the shipped calibrated cell, `"calibrated-x0"`),
/// then `sets`.
fn capillary(sets: &[&str]) -> Scenario {
    let sets: Vec<String> = std::iter::once("cell.parameters=paper")
        .chain(sets.iter().copied())
        .map(|s| s.to_string())
        .collect();
    load(&scenario_path(), &sets).unwrap()
}

fn stage<'a>(r: &'a Value, name: &str) -> &'a Value {
    r["stages"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == name)
        .unwrap_or_else(|| panic!("no stage {name}"))
}

/// A cell left in plasma at rest for 10 ms (4000 steps), at the mapping of the driven default:
/// - its shape stays within the thermal level of the resting shape. The scale is
///   √(kBT_fluid/μ0) = 0.074 µm (f = 10.84, so the fluid's kBT is 4.5e-20 J); measured
///   0.096 µm (1.3 × the scale; 0.116 µm over the last quarter of 15 ms). The bound,
///   2√(kBT/μ0), is less than a third of the parachute's 0.54 µm;
/// - area and volume stay within 1 % (measured 0.12 % and 0.21 %);
/// - the vertices' temperature equals the fluid's within 3 % (measured 1.003; its sampling
///   error over the last quarter of 10 ms is about 1.2 %);
/// - no fluid particle is found on the wrong side (checked every 100 steps).
#[test]
fn cell_at_rest_keeps_its_shape_area_volume_and_temperature() {
    let dir = tempfile::tempdir().unwrap();
    let s = capillary(&[
        "stage=[{name = \"rest\", duration_s = 0.010}]",
        // the mapping of the driven default (1 mm/s): with no drive, "auto" would pick f = 1,
        // whose membrane is 11× stiffer and needs a smaller time step
        "model.thermal_factor=10.841",
        "model.crossing_check_every_steps=100",
        "output.frame_every_s=0",
    ]);
    let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
    let rest = stage(&r, "rest");
    let q = &rest["final_quarter_means"];
    let m = &r["unit_mapping"];
    let mu0 = ModelParams::coarse_grained(500, 300.0).unwrap().shear_modulus_n_per_m;
    let level_um = (f(&m["energy_j"]) / mu0).sqrt() * 1e6;
    let d = f(&q["distance_from_rest_um"]);
    eprintln!(
        "distance from rest {d:.4} µm (scale {level_um:.4}); area {} volume {}; kBT ratio {}; crossings {}",
        rest["max_abs_area_deviation"],
        rest["max_abs_volume_deviation"],
        q["membrane_temperature_ratio"],
        r["crossings"]
    );
    assert!(
        d < 2.0 * level_um,
        "distance from rest {d} µm, thermal scale {level_um} µm"
    );
    assert!(f(&rest["max_abs_area_deviation"]) < 0.01);
    assert!(f(&rest["max_abs_volume_deviation"]) < 0.01);
    assert!((f(&q["membrane_temperature_ratio"]) - 1.0).abs() < 0.03);
    assert_eq!(r["crossings"]["misplaced_total"], 0);
    assert!(r["crossings"]["checks"].as_u64().unwrap() >= 35); // every 100 of ~4000 steps
                                                               // the fluid stays at rest
    assert!(f(&q["fluid_mean_velocity_m_per_s"]).abs() < 2e-5);
}

/// The paper's protocol, shortened: rest, flow on at 1 mm/s for 20 ms, flow off for 5 ms.
/// - The controller holds the mean velocity within 3 % (its window means scatter by ~1 %).
/// - The cell outruns the mean flow but not the centreline (2U): measured 1.38 U.
/// - It elongates and its rear cups (parachute): at rest, length 2.7 µm and concavity 0.69 µm;
///   at 20 ms, 4.7 µm and 1.8 µm.
/// - Its length lies within the scatter of Hochmuth et al. (1970) at D = 10.7 µm, the nearest
///   diameter measured (4.38–7.46 µm for cell velocities up to 0.7 cm/s), at the short end of
///   that band (docs/validation.md, §6 "The cell in the capillary").
/// - Without flow it heads back to its resting shape.
/// - No fluid crosses the membrane.
#[test]
fn parachute_forms_and_recovers() {
    let dir = tempfile::tempdir().unwrap();
    let s = capillary(&[
        "stage=[{name = \"rest\", duration_s = 0.001}, {name = \"parachute\", duration_s = 0.02, mean_velocity_m_per_s = 1e-3}, {name = \"recovery\", duration_s = 0.005}]",
        "output.frame_every_s=0",
    ]);
    let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
    let (rest, para, rec) = (stage(&r, "rest"), stage(&r, "parachute"), stage(&r, "recovery"));
    let q = |s: &Value, k: &str| f(&s["final_quarter_means"][k]);
    let u = q(para, "fluid_mean_velocity_m_per_s");
    let uc = q(para, "cell_velocity_m_per_s");
    eprintln!(
        "U {u:.4e} cell {uc:.4e}; length {} -> {} -> {}; concavity {} -> {}; distance {} -> {}",
        q(rest, "axial_length_um"),
        q(para, "axial_length_um"),
        q(rec, "axial_length_um"),
        q(rest, "concavity_depth_um"),
        q(para, "concavity_depth_um"),
        q(para, "distance_from_rest_um"),
        q(rec, "distance_from_rest_um")
    );
    assert!((u / 1e-3 - 1.0).abs() < 0.03, "mean velocity {u}");
    assert!(
        uc > 1.05 * u && uc < 2.0 * u,
        "cell velocity {uc} for a mean flow of {u}"
    );
    assert!(q(para, "axial_length_um") > 1.3 * q(rest, "axial_length_um"));
    assert!(q(para, "concavity_depth_um") > 2.0 * q(rest, "concavity_depth_um"));
    let len = q(para, "axial_length_um");
    assert!(
        (4.38..=7.46).contains(&len),
        "length {len} µm outside Hochmuth's band at 10.7 µm"
    );
    assert!(q(rec, "distance_from_rest_um") < q(para, "distance_from_rest_um"));
    assert!(q(rec, "fluid_mean_velocity_m_per_s").abs() < 0.1 * u);
    assert_eq!(r["crossings"]["misplaced_total"], 0);
    assert!(f(&para["max_abs_area_deviation"]) < 0.01 && f(&para["max_abs_volume_deviation"]) < 0.01);
}

/// The shipped default as it is (the `"calibrated-x0"` set, docs/model.md §3b; "outer"
/// sub-steps), shortened to 1 ms at rest and 8 ms at 1 mm/s:
/// - the set reaches the run: η_m = 3.9e-7 N·s/m in the central form, k = 100 sub-steps by
///   "auto", acting at ≥ 92 % of the friction (the analytic γ_eff of docs/model.md §7b);
/// - the controller holds the mean velocity within 3 %, and the cell moves between the mean and
///   the centreline velocity (1.05–2 U; measured 1.25 U at 8 ms);
/// - it elongates: its length grows by more than 20 % (measured 2.68 → 3.55 µm at 8 ms; the
///   two-parameter `"calibrated"` set 2.67 → 3.56 µm, the paper's cell 4.5 µm at 15 ms, faster
///   without membrane viscosity);
/// - area and volume within 1 %, no fluid on the wrong side.
#[test]
fn calibrated_default_runs_its_membrane_viscosity() {
    let dir = tempfile::tempdir().unwrap();
    let s = load(
        &scenario_path(),
        &[
            "stage=[{name = \"rest\", duration_s = 0.001}, {name = \"parachute\", duration_s = 0.008, mean_velocity_m_per_s = 1e-3}]".to_string(),
            "output.frame_every_s=0".to_string(),
        ],
    )
    .unwrap();
    let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
    let visc = &r["membrane_viscosity"];
    eprintln!("{visc}");
    assert!((f(&visc["pa_s_m"]) / 3.9e-7 - 1.0).abs() < 1e-12);
    assert_eq!(f(&visc["gamma_t"]), 0.0, "central form");
    assert_eq!(visc["form"], "central");
    assert_eq!(visc["substep_forces"], "outer");
    assert_eq!(visc["substeps"], 100);
    assert!(f(&visc["effective_friction_fraction"]) > 0.92);
    let (rest, para) = (stage(&r, "rest"), stage(&r, "parachute"));
    let q = |s: &Value, k: &str| f(&s["final_quarter_means"][k]);
    let (u, uc) = (q(para, "fluid_mean_velocity_m_per_s"), q(para, "cell_velocity_m_per_s"));
    let (l0, l) = (q(rest, "axial_length_um"), q(para, "axial_length_um"));
    eprintln!("U {u:.4e}, cell {uc:.4e}; length {l0:.3} -> {l:.3} µm");
    assert!((u / 1e-3 - 1.0).abs() < 0.03, "mean velocity {u}");
    assert!(uc > 1.05 * u && uc < 2.0 * u, "cell velocity {uc} for {u}");
    assert!(l > 1.2 * l0, "length {l0} -> {l}");
    assert!(f(&para["max_abs_area_deviation"]) < 0.01 && f(&para["max_abs_volume_deviation"]) < 0.01);
    assert_eq!(r["crossings"]["misplaced_total"], 0);
}

/// `model.fluid = "auto"` at the driven default (1 mm/s, 10 µm) chooses the dense fluid at
/// f = 1: κ/kBT is the physical 200 in the model, Mach and Re within the bounds; a short run
/// (0.3 ms at rest, 1 ms of flow) keeps the cell intact: area and volume within 1 %, no fluid on
/// the wrong side, the vertices at the fluid's temperature within 10 % (the mean of ≈ 80
/// samples of 500 vertices), the flow under way (mean velocity between 0.5 and 1.5 mm/s after
/// ≈ 4 viscous times of the tube). The summary names the fluid and its step (the membrane's
/// friction with this fluid shortens the step below the fluid's 0.003: docs/units.md).
#[test]
fn dense_fluid_runs_the_cell_at_exact_kappa() {
    let dir = tempfile::tempdir().unwrap();
    let s = capillary(&[
        "stage=[{name = \"rest\", duration_s = 0.0003}, {name = \"flow\", duration_s = 0.001, mean_velocity_m_per_s = 1e-3}]",
        "model.fluid=\"auto\"",
        "model.crossing_check_every_steps=50",
        "output.frame_every_s=0",
        "output.sample_every_steps=5",
    ]);
    let t = std::time::Instant::now();
    let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
    let flow = stage(&r, "flow");
    let q = &flow["final_quarter_means"];
    eprintln!(
        "dense fluid: {} ; f = {}, κ/kBT {}, Ma {}, Re {}; U {} m/s, kBT ratio {}, area {} volume {}, crossings {} ({:.1} s)",
        r["fluid"],
        r["unit_mapping"]["thermal_factor"],
        r["groups_model"]["kappa_over_kbt"],
        r["groups_model"]["mach"],
        r["groups_model"]["reynolds"],
        q["fluid_mean_velocity_m_per_s"],
        q["membrane_temperature_ratio"],
        flow["max_abs_area_deviation"],
        flow["max_abs_volume_deviation"],
        r["crossings"],
        t.elapsed().as_secs_f64()
    );
    assert_eq!(r["fluid"]["name"], "dense");
    assert_eq!(f(&r["unit_mapping"]["thermal_factor"]), 1.0);
    assert!((f(&r["groups_model"]["kappa_over_kbt"]) / f(&r["groups_si"]["kappa_over_kbt"]) - 1.0).abs() < 1e-12);
    assert!(f(&r["groups_model"]["mach"]) <= 0.25 && f(&r["groups_model"]["reynolds"]) <= 1.0);
    let dt = f(&r["fluid"]["timestep"]);
    assert!(dt < FluidModel::dense().timestep && dt > 0.001, "Δt {dt}");
    assert!(f(&flow["max_abs_area_deviation"]) < 0.01 && f(&flow["max_abs_volume_deviation"]) < 0.01);
    assert_eq!(r["crossings"]["misplaced_total"], 0);
    assert!((f(&q["membrane_temperature_ratio"]) - 1.0).abs() < 0.1);
    let u = f(&q["fluid_mean_velocity_m_per_s"]);
    assert!((0.5e-3..1.5e-3).contains(&u), "mean velocity {u}");
}

/// Tubes narrower than the cell (Tomaiuolo 2009's 4.7 and 6.6 µm): the resting cell is pressed
/// into the tube before the fluid is cut (edge-on and face-on), and the run starts with no
/// fluid particle on the wrong side (checked every 10 steps), area and volume within 1 %, the
/// membrane not through itself, and every vertex within the pressing radius, which leaves the
/// wall's repulsion range free.
#[test]
fn narrow_tubes_take_the_pressed_cell() {
    for (d, res, orientation) in [("4.7", "0.33", "edge-on"), ("6.6", "0.5", "face-on")] {
        let dir = tempfile::tempdir().unwrap();
        let s = capillary(&[
            &format!("tube.diameter_um={d}"),
            "tube.length_um=20",
            &format!("tube.cell_orientation=\"{orientation}\""),
            &format!("model.length_um_per_rc={res}"),
            "stage=[{name = \"rest\", duration_s = 0.0001}]",
            "model.crossing_check_every_steps=10",
            "output.frame_every_s=0",
        ]);
        let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
        let p = &r["mesh"]["placement"];
        let rest = stage(&r, "rest");
        eprintln!(
            "{d} µm at {res} µm/rc, {orientation}: placement {p}, crossings {}",
            r["crossings"]
        );
        assert_eq!(p["pressed"], true, "{p}");
        assert_eq!(p["orientation"], orientation);
        assert!(f(&p["widest_rc"]) <= f(&p["radius_rc"]) + 1e-12);
        assert!(f(&p["area_deviation"]).abs() < 0.01 && f(&p["volume_deviation"]).abs() < 0.01);
        // the folded membrane does not pass through itself (placement refuses a shape that
        // does) and its sheets keep apart
        assert!(f(&p["closest_self_contact"]) > 0.3, "{p}");
        assert!(f(&rest["max_abs_area_deviation"]) < 0.01 && f(&rest["max_abs_volume_deviation"]) < 0.01);
        assert!(r["crossings"]["checks"].as_u64().unwrap() >= 1, "{}", r["crossings"]);
        assert_eq!(r["crossings"]["misplaced_total"], 0);
        // the pressed cell is longer than the resting one is thick, and narrower than the tube
        let q = &rest["final_quarter_means"];
        assert!(f(&q["max_radial_extent_um"]) < 0.5 * d.parse::<f64>().unwrap());
        assert!(f(&q["axial_length_um"]) > 5.0, "{q}");
    }
}

/// A short run in Tomaiuolo 2009's 6.6 µm tube at a fixed pressure gradient (8.3 mmHg/mm, in
/// their range; 1 µm per rc, the coarsest resolution that admits the tube): the pressed cell
/// is carried at a steady velocity. Over the last half of the 4 ms stage the mean cell
/// velocities of its two quarters agree within 5 % (the noise of a 1 ms mean is ≈ 1 %), and
/// the cell, near the axis, is not slower than the mean flow.
#[test]
fn narrow_tube_reaches_a_steady_cell_velocity() {
    let dir = tempfile::tempdir().unwrap();
    let s = capillary(&[
        "tube.diameter_um=6.6",
        "tube.length_um=20",
        "model.length_um_per_rc=1.0",
        "stage=[{name = \"rest\", duration_s = 0.00005}, {name = \"flow\", duration_s = 0.004, pressure_gradient_mmhg_per_mm = 8.3}]",
        "output.frame_every_s=0",
        "output.sample_every_steps=10",
    ]);
    let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
    let csv = std::fs::read_to_string(dir.path().join("cell.csv")).unwrap();
    let mut lines = csv.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| head.iter().position(|h| *h == name).unwrap();
    let (stage_col, v_col, u_col) = (
        col("stage"),
        col("cell_velocity_m_per_s"),
        col("fluid_velocity_m_per_s"),
    );
    let rows: Vec<(f64, f64)> = lines
        .map(|l| l.split(',').map(|x| x.parse::<f64>().unwrap()).collect::<Vec<_>>())
        .filter(|x| x[stage_col] == 1.0)
        .map(|x| (x[v_col], x[u_col]))
        .collect();
    let n = rows.len();
    let mean =
        |a: &[(f64, f64)], k: usize| a.iter().map(|x| if k == 0 { x.0 } else { x.1 }).sum::<f64>() / a.len() as f64;
    let (early, late) = (&rows[n / 2..n * 3 / 4], &rows[n * 3 / 4..]);
    let (v1, v2, u2) = (mean(early, 0), mean(late, 0), mean(late, 1));
    eprintln!("6.6 µm, 8.3 mmHg/mm: cell velocity {v1:.4e} then {v2:.4e} m/s, mean flow {u2:.4e} m/s ({n} samples); placement {}", r["mesh"]["placement"]);
    assert!((v2 / v1 - 1.0).abs() < 0.05, "not steady: {v1} then {v2}");
    assert!(
        v2 > 0.0 && v2 / u2 > 0.95 && v2 / u2 < 2.0,
        "cell {v2} against mean flow {u2}"
    );
}

/// Interrupted twice (on 2 threads) and resumed, the run ends bit-identical to one
/// uninterrupted run on 1 thread: the same time series and the same final particles (the
/// checkpoint holds the membrane's unwrapped positions, its counters, its resting mesh and the
/// stage and controller state; pair noise and the Maxwell reflections are counter-based and
/// bounces are applied in particle order, so the thread count does not enter).
#[test]
fn capillary_resumes_bit_identically_on_any_thread_count() {
    let sets = [
        "stage=[{name = \"rest\", duration_s = 0.0005}, {name = \"flow\", duration_s = 0.002, mean_velocity_m_per_s = 1e-3}]",
        "output.frame_every_s=0.0004",
        "model.crossing_check_every_steps=50",
    ];
    let s = capillary(&sets);
    let pool = |n: usize| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
    let whole = tempfile::tempdir().unwrap();
    pool(1)
        .install(|| run(&s, &RunContext::new(whole.path(), 1, false)))
        .unwrap();
    let parts = tempfile::tempdir().unwrap();
    let mut ctx = RunContext::new(parts.path(), 2, false);
    // stopped inside the first stage, then inside the controlled stage
    pool(2).install(|| common::run_in_three_parts(&s, &mut ctx, [137, 301]));
    // the same series and particles, and the trajectory has each scheduled frame once
    common::assert_same_end(whole.path(), parts.path(), "cell.csv", "time series");
    // a finished run says so and is not touched
    assert!(matches!(
        hemodpd_scenario::resume(parts.path(), &ctx),
        Err(RunError::Finished { .. })
    ));
}

/// Bad input fails before any work, naming the key, the value and what is allowed.
#[test]
fn bad_capillary_input_names_the_key() {
    let err = |sets: &[&str]| {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        load(&scenario_path(), &sets).unwrap_err().to_string()
    };
    // a tube the cell cannot be pressed into at this resolution: the key, the value, the
    // least diameter and the fix; the same tube at a finer resolution is accepted
    let e = err(&["tube.diameter_um=4.5"]);
    assert!(
        e.contains("tube.diameter_um")
            && e.contains("4.5")
            && e.contains("at least")
            && e.contains("model.length_um_per_rc"),
        "{e}"
    );
    assert!(load(
        &scenario_path(),
        &["tube.diameter_um=4.5".into(), "model.length_um_per_rc=0.33".into()]
    )
    .is_ok());
    // narrower than any surface of the cell's area and volume, at any resolution
    let e = err(&["tube.diameter_um=3.2", "model.length_um_per_rc=0.25"]);
    assert!(e.contains("tube.diameter_um") && e.contains("capsule"), "{e}");
    // N out of range
    let e = err(&["cell.vertices=50"]);
    assert!(
        e.contains("cell.vertices") && e.contains("50") && e.contains("100"),
        "{e}"
    );
    // links that could not stretch to 1.5 L0
    let e = err(&["cell.max_extension_ratio=1.2"]);
    assert!(
        e.contains("cell.max_extension_ratio") && e.contains("1.2") && e.contains("1.5–6.5"),
        "{e}"
    );
    // an unknown named parameter set lists the known ones
    let e = err(&["cell.parameters=\"calibrated-x1\""]);
    assert!(
        e.contains("cell.parameters") && e.contains("calibrated-x0") && e.contains("paper"),
        "{e}"
    );
    // a drive whose Mach number breaks the bound when the mapping may not adapt
    let e = err(&["model.thermal_factor=\"exact\""]);
    assert!(e.contains("stage.mean_velocity_m_per_s") && e.contains("Mach"), "{e}");
    // two drives in one stage
    let e = err(&[
        "stage=[{name = \"x\", duration_s = 0.01, mean_velocity_m_per_s = 1e-3, pressure_gradient_pa_per_m = 1e5}]",
    ]);
    assert!(e.contains("stage[0]"), "{e}");
    // an unknown key
    let e = err(&["tube.radius_um=5"]);
    assert!(e.contains("radius_um"), "{e}");
    // a mesh file whose vertex count disagrees (the golden N = 500 mesh given as N = 4321)
    let mesh = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/membrane_golden/mesh_N500.vertices.csv");
    let e = err(&[&format!("cell.mesh_file=\"{}\"", mesh.display()), "cell.vertices=4321"]);
    assert!(
        e.contains("cell.mesh_file") && e.contains("4321") && e.contains("500"),
        "{e}"
    );
}

/// `--explain-units` prints the scales and the groups in both systems; the groups that the
/// mapping keeps exact agree to the digits printed.
#[test]
fn explain_units_prints_the_mapping() {
    let text = common::explain_units(&scenario_path());
    common::assert_explained(
        &text,
        &[
            "length r",
            "energy E",
            "time τ",
            "time step",
            "capillary η U/μ0",
            "Reynolds",
            "Mach",
            "κ/kBT",
        ],
        "capillary η U/μ0",
    );
    // a scenario in model units has nothing to explain
    let fluid = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/dpd-fluid.toml");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_hemodpd"))
        .args(["run", fluid.to_str().unwrap(), "--explain-units"])
        .output()
        .unwrap();
    assert!(!out.status.success());
}

/// Plasma alone in the 10 µm tube at a pressure gradient of 2 mmHg/mm: the mapping turns the
/// gradient into a body force per particle, the engine runs the capillary fluid in the walled
/// tube, and the measured mean velocity, back in m/s, is the Poiseuille value
/// ∇p R²/(8η_P) within 3 %. This holds only because the mapping uses the fluid's measured
/// viscosity (26.6; kinetic theory says 33.4, 26 % off) and puts the wall where its effective
/// no-slip radius is R (the fluid slips by b = 0.194 rc at the wall:
/// `CAPILLARY_FLUID_WALL_SLIP`; with the wall at R the flux is 15.5 % high).
#[test]
fn plasma_tube_gives_the_poiseuille_velocity_in_si() {
    let d = 10e-6;
    let eta_p = 1.2e-3;
    let g_si = 2.0 * hemodpd_scenario::units::MMHG_PER_MM_IN_PA_PER_M;
    let u_si = poiseuille_mean_velocity(g_si, d, eta_p);
    let params = ModelParams::coarse_grained(500, 300.0).unwrap();
    let mut sys = hemodpd_scenario::units::PhysicalSystem::new(&params, d, 45e-6, eta_p, u_si);
    sys.viscosity_ratio = 1.0;
    let fluid = FluidModel::capillary();
    let map = UnitMapping::choose(&sys, &fluid, 1e-6, ThermalChoice::default()).unwrap();
    let radius = map.length_to_model(0.5 * d);
    // the wall where the capillary scenario puts it: its effective no-slip radius is R
    let wall = hemodpd_scenario::capillary::wall_radius(radius, hemodpd_engine::params::CAPILLARY_FLUID_WALL_SLIP);
    let g = map.pressure_gradient_to_model(g_si) / fluid.density;
    // flux over the tube's cross-section πR²
    let (_, q) = capillary_fluid_tube(wall, g, 6000, 3);
    let u_model = q / (std::f64::consts::PI * radius * radius);
    let u = map.velocity_to_si(u_model);
    eprintln!(
        "mean velocity {u:.5e} m/s against Poiseuille {u_si:.5e} m/s ({:+.2} %)",
        100.0 * (u / u_si - 1.0)
    );
    assert!((u / u_si - 1.0).abs() < 0.03, "{u} vs {u_si}");
}

/// The capillary fluid alone in a poiseuille-tube run (model units, wall at `wall` rc, tube
/// 8 rc long, body force `g`, no adaptive wall force): returns (mean density n̄ in the tube, the
/// volume flux Q, from the radial profile: Σ ρ_k v_k A_k / n̄).
fn capillary_fluid_tube(wall: f64, g: f64, steps: u64, seed: u64) -> (f64, f64) {
    fluid_tube(&FluidModel::capillary(), wall, g, steps, seed)
}

/// [`capillary_fluid_tube`] for any fluid of the table.
fn fluid_tube(fluid: &FluidModel, wall: f64, g: f64, steps: u64, seed: u64) -> (f64, f64) {
    let p = fluid.pair;
    let text = format!(
        r#"format_version = 1
kind = "poiseuille-tube"
seed = {seed}
[fluid]
density = {}
a = {}
gamma = {}
kbt = {}
weight_exponent = {}
[tube]
radius = {wall}
length = 8.0
body_force = {g}
[walls]
adaptive = false
[run]
timestep = {}
equilibration_steps = 200
flow_steps = 2000
steps = {steps}
sample_every = 5
profile_bins = 10
measure_overhead = false
"#,
        fluid.density, p.a, p.gamma, p.kbt, p.s, fluid.timestep
    );
    let s = load_str(&text, "plasma.toml", &[]).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
    let prof = &r["profile"];
    let (rs, v, rho) = (
        prof["r"].as_array().unwrap(),
        prof["v_z"].as_array().unwrap(),
        prof["density"].as_array().unwrap(),
    );
    let dr = wall / rs.len() as f64;
    let (mut flux, mut mass) = (0.0, 0.0);
    for k in 0..rs.len() {
        let area = std::f64::consts::PI * dr * dr * (((k + 1) * (k + 1) - k * k) as f64);
        flux += f(&rho[k]) * f(&v[k]) * area;
        mass += f(&rho[k]) * area;
    }
    let n_mean = mass / (std::f64::consts::PI * wall * wall);
    (n_mean, flux / n_mean)
}

/// `hemodpd analyze` recomputes the run's measures from the trajectory: at the steps where a
/// frame and a sample coincide, every shape measure, the velocities, area, volume and the
/// membrane temperature agree with the run's `cell.csv` to round-off of the SI conversion.
#[test]
fn analyze_reproduces_the_run_measures() {
    let dir = tempfile::tempdir().unwrap();
    let s = capillary(&[
        "stage=[{name = \"rest\", duration_s = 0.0005}, {name = \"flow\", duration_s = 0.002, mean_velocity_m_per_s = 1e-3}]",
        // 160 steps of 2.51 µs: a multiple of the 20-step sampling, so frames and samples meet
        "output.frame_every_s=0.000402",
    ]);
    run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
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
    let read = |p: PathBuf| -> Vec<Vec<f64>> {
        std::fs::read_to_string(p)
            .unwrap()
            .lines()
            .skip(1)
            .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
            .collect()
    };
    let frames = read(out.join("capillary.csv"));
    let samples = read(dir.path().join("cell.csv"));
    let dt_s = samples[1][0] - samples[0][0]; // 20 steps
    let mut compared = 0;
    for fr in &frames {
        let Some(sm) = samples.iter().find(|s| (s[0] - fr[1]).abs() < 0.01 * dt_s) else {
            continue;
        };
        // cell.csv: time, stage, stage_time, cell v, fluid v, length, radius, DI, concavity,
        // distance, area, volume, temperature, body force, L/W, silhouette width, silhouette
        // DI, tilt, axis offset; capillary.csv: step, time, stage, then the same from cell v to
        // the temperature, then silhouette width, silhouette DI, tilt
        let pairs = [
            (15, 13),
            (16, 14),
            (17, 15),
            (3, 3),
            (4, 4),
            (5, 5),
            (6, 6),
            (7, 7),
            (8, 8),
            (9, 9),
            (10, 10),
            (11, 11),
            (12, 12),
        ];
        for (a, b) in pairs {
            let (x, y) = (sm[a], fr[b]);
            assert!(
                (x - y).abs() <= 1e-7 * x.abs().max(y.abs()).max(1e-12),
                "column {a}: run {x} analyze {y} at t = {}",
                fr[1]
            );
        }
        compared += 1;
    }
    assert!(compared >= 5, "only {compared} frames coincide with samples");
}

/// Rows (study, D µm, velocity cm/s, value) of a reference CSV in tests/data.
fn reference(name: &str) -> Vec<(String, f64, f64, f64)> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name);
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("study"))
        .filter_map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            Some((
                c[0].to_string(),
                c[1].parse().ok()?,
                c[2].parse().ok()?,
                c[3].parse().ok()?,
            ))
        })
        .collect()
}

/// Where the validation's figures go (`$HEMODPD_FIGURES_DIR`), a scratch directory, and a runner.
fn validation_setup() -> (Option<PathBuf>, tempfile::TempDir) {
    let figs = std::env::var_os("HEMODPD_FIGURES_DIR").map(PathBuf::from);
    if let Some(d) = &figs {
        std::fs::create_dir_all(d).unwrap();
    }
    (figs, tempfile::tempdir().unwrap())
}

fn go(work: &Path, name: &str, sets: &[&str]) -> (Value, PathBuf) {
    let dir = work.join(name);
    let t = std::time::Instant::now();
    let r = run(&capillary(sets), &RunContext::new(&dir, 0, false)).unwrap();
    eprintln!(
        "{name}: {:.0} s, {:.0} steps/s",
        t.elapsed().as_secs_f64(),
        f(&r["performance"]["steps_per_second"])
    );
    (r, dir)
}

fn q(r: &Value, st: &str, k: &str) -> f64 {
    f(&stage(r, st)["final_quarter_means"][k])
}

/// A tube just narrower than the cell (7.6 µm against its 7.8 µm, seed 2, at the mapping of a
/// 3 mm/s mean flow): the pressed cell ends inside the placement radius with area and volume
/// within 1 %. Before the overshoot correction moved the wall a hair past the overshoot, this
/// point stopped 1e-5 rc outside the radius and the run was refused (found by
/// `capillary_validation_hochmuth`).
#[test]
fn placement_into_a_tube_just_narrower_than_the_cell() {
    let dir = tempfile::tempdir().unwrap();
    let s = capillary(&[
        "stage=[{name = \"rest\", duration_s = 0.00001}, {name = \"flow\", duration_s = 0.00001, mean_velocity_m_per_s = 0.003}]",
        "tube.diameter_um=7.6",
        "tube.length_um=50",
        "plasma.viscosity_pa_s=1.0e-3",
        "seed=2",
        "output.frame_every_s=0",
    ]);
    let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
    let p = &r["mesh"]["placement"];
    assert_eq!(p["pressed"], true, "{p}");
    assert!(f(&p["widest_rc"]) <= f(&p["radius_rc"]), "{p}");
    assert!(f(&p["widest_at_rest_rc"]) > f(&p["radius_rc"]), "{p}");
    assert!(
        f(&p["area_deviation"]).abs() < 0.01 && f(&p["volume_deviation"]).abs() < 0.01,
        "{p}"
    );
}

/// Tomaiuolo et al. 2009's velocity against pressure gradient (4.7 and 6.6 µm glass tubes)
/// at their conditions as the tRBC-UQ authors ran them (suspending medium 1.0 mPa·s, one cell
/// per 50 µm of tube), with the cell length and deformation index at the same points; the
/// cell enters face-on and is pressed into the tube; two seeds per point. Prints the table of
/// docs/validation.md ("Narrow tubes": velocity, length, DI with the width 2 max ρ and seen
/// from the side, against Tomaiuolo's DI at 6.6 µm, the shape of each seed) and writes
/// `capillary_tomaiuolo_velocity.png`, `capillary_narrow_length.png` and
/// `capillary_tomaiuolo_di.png` into `$HEMODPD_FIGURES_DIR` when set. About 20 minutes on
/// 2 cores (`scripts/validate_capillary.sh`). Asserts what the docs state: the velocity rises
/// with the gradient, and fewer than 1 % of the particles a check tests were found on the wrong
/// side over the run.
#[test]
#[ignore]
fn capillary_validation_tomaiuolo() {
    use hemodpd_io::plot::{line_chart, Series};
    let (figs, work) = validation_setup();
    let work = work.path();
    let data: Vec<(f64, f64, f64)> = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/capillary_velocity_vs_pressure_gradient_tomaiuolo2009.csv"),
    )
    .unwrap()
    .lines()
    .filter(|l| !l.starts_with('#') && !l.starts_with("tube"))
    .map(|l| {
        let c: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
        (c[0], c[1], c[2])
    })
    .collect();
    // (diameter µm, resolution µm per rc, vertices, gradients mmHg/mm): in the 4.7 µm tube at
    // 0.5 µm per rc the N = 500 mesh (links ≈ 1.1 rc) let 130–350 fluid particles through its
    // folds in 6 ms; N = 2000 (links ≈ 0.55 rc) lets none
    let cases = [
        (6.6, "1.0", 500, [5.0, 10.0, 20.0]),
        (4.7, "0.5", 2000, [10.0, 20.0, 40.0]),
    ];
    // each point over two seeds
    let mut runs = Vec::new();
    for (d, res, n, gradients) in cases {
        for g in gradients {
            for seed in [1u64, 2] {
                let t = std::time::Instant::now();
                let drive = format!("pressure_gradient_mmhg_per_mm = {g}");
                let r = narrow_tube_run(work, &format!("d{d}_g{g}_s{seed}"), d, res, n, &drive, seed);
                // fluid through the folds of the pressed cell: reported, and held below 1 % of
                // the fluid particles each check tests near the cell, summed over the run
                // (docs/validation.md)
                let (misplaced, checks) = (f(&r["crossings"]["misplaced_total"]), f(&r["crossings"]["checks"]));
                let inside = f(&r["crossings"]["checked_last"]);
                eprintln!("  misplaced {misplaced} in {checks} checks ({inside} particles tested per check)");
                assert!(misplaced <= 0.01 * inside, "{}", r["crossings"]);
                runs.push(NarrowRun::new(d, g, &r, t.elapsed().as_secs_f64()));
            }
        }
    }
    // the two seeds of a point averaged, their shapes listed: (d, g, cell v, mean flow v,
    // length, DI (2 max ρ), DI (side view), f, run s, shapes, |length difference|)
    let rows: Vec<_> = runs.chunks(2).map(NarrowRun::mean_of_seeds).collect();
    // the experiment at the same gradient: linear interpolation between its nearest points
    let measured = |d: f64, g: f64| {
        let mut pts: Vec<(f64, f64)> = data
            .iter()
            .filter(|x| (x.0 - d).abs() < 0.01)
            .map(|x| (x.1, x.2))
            .collect();
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        pts.windows(2)
            .find(|w| w[0].0 <= g && g <= w[1].0)
            .map(|w| w[0].1 + (w[1].1 - w[0].1) * (g - w[0].0) / (w[1].0 - w[0].0))
            .unwrap_or(f64::NAN)
    };
    // Tomaiuolo's DI at 6.6 µm at the model's cell velocity (linear between their points)
    let di_ref: Vec<(f64, f64)> = reference("capillary_deformation_index_vs_velocity.csv")
        .into_iter()
        .filter(|r| r.0 == "Tomaiuolo2009")
        .map(|r| (r.2, r.3))
        .collect();
    eprintln!("\n| D (µm) | ∇p (mmHg/mm) | cell velocity (cm/s) | Tomaiuolo 2009 (cm/s) | model/experiment | cell/mean flow | length (µm) | length, seed 1 − seed 2 (µm) | DI (2 max ρ) | DI (side view) | Tomaiuolo DI at that velocity | shape (seeds 1, 2) | f | run (s, each seed) |");
    eprintln!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (d, g, v, u, len, di, di_side, fth, secs, shapes, dl) in &rows {
        let m = measured(*d, *g);
        let di_exp = if (*d - 6.6).abs() < 0.01 {
            interpolate(&di_ref, *v)
        } else {
            f64::NAN
        };
        eprintln!(
            "| {d} | {g} | {v:.4} | {m:.4} | {:.2} | {:.2} | {len:.2} | {dl:.2} | {di:.2} | {di_side:.2} | {di_exp:.2} | {shapes} | {fth:.2} | {secs:.0} |",
            v / m,
            v / u
        );
    }
    for d in [6.6, 4.7] {
        let v: Vec<f64> = rows.iter().filter(|r| r.0 == d).map(|r| r.2).collect();
        assert!(
            v.windows(2).all(|w| w[1] > w[0]),
            "{d} µm: velocity does not rise with the gradient: {v:?}"
        );
    }
    // the side view is never wider than 2 max ρ, so its DI is never below the other
    assert!(rows.iter().all(|r| r.6 >= r.5 * 0.999), "side-view DI below 2 max ρ DI");
    if let Some(dir) = &figs {
        let mut series = Vec::new();
        for d in [4.7, 6.6] {
            series.push(Series::line_with_points(
                format!("this model, D = {d} µm"),
                rows.iter().filter(|r| r.0 == d).map(|r| (r.1, r.2)).collect(),
            ));
            series.push(Series::points(
                format!("Tomaiuolo 2009, D = {d} µm"),
                data.iter()
                    .filter(|x| (x.0 - d).abs() < 0.01)
                    .map(|x| (x.1, x.2))
                    .collect(),
            ));
        }
        line_chart(
            dir.join("capillary_tomaiuolo_velocity.png"),
            "Cell velocity against pressure gradient",
            "pressure gradient (mmHg/mm)",
            "cell velocity (cm/s)",
            &series,
        )
        .unwrap();
        let length_ref = reference("capillary_cell_length_vs_velocity.csv");
        let mut series = Vec::new();
        for d in [4.7, 6.6] {
            series.push(Series::line_with_points(
                format!("this model, D = {d} µm"),
                rows.iter().filter(|r| r.0 == d).map(|r| (r.2, r.4)).collect(),
            ));
            series.push(Series::points(
                format!("Tomaiuolo 2009, D = {d} µm"),
                length_ref
                    .iter()
                    .filter(|r| r.0 == "Tomaiuolo2009" && (r.1 - d).abs() < 0.01)
                    .map(|r| (r.2, r.3))
                    .collect(),
            ));
        }
        series.push(Series::points(
            "Hochmuth 1970, D = 4.5 µm",
            length_ref
                .iter()
                .filter(|r| r.0 == "Hochmuth1970" && (r.1 - 4.5).abs() < 0.01)
                .map(|r| (r.2, r.3))
                .collect(),
        ));
        line_chart(
            dir.join("capillary_narrow_length.png"),
            "Cell length in narrow tubes",
            "cell velocity (cm/s)",
            "axial length (µm)",
            &series,
        )
        .unwrap();
        let at = |d: f64, k: fn(&NarrowRun) -> f64| -> Vec<(f64, f64)> {
            runs.iter().filter(|r| r.d == d).map(|r| (r.v, k(r))).collect()
        };
        line_chart(
            dir.join("capillary_tomaiuolo_di.png"),
            "Deformation index at 6.6 µm (each seed)",
            "cell velocity (cm/s)",
            "DI = length / width",
            &[
                Series::points("this model, side view (mean over views)", at(6.6, |r| r.di_side)),
                Series::points("this model, width 2 max ρ", at(6.6, |r| r.di)),
                Series::points("Tomaiuolo 2009, D = 6.6 µm", di_ref.clone()),
            ],
        )
        .unwrap();
    }
}

/// One narrow-tube run at `scenarios/capillary-tomaiuolo.toml`'s conditions (1.0 mPa·s, a
/// 50 µm tube): 0.1 ms at rest, then 6 ms with `drive` (a stage key = value), D µm, `res` µm
/// per rc, N vertices, the seed; no frames.
fn narrow_tube_run(work: &Path, name: &str, d: f64, res: &str, n: usize, drive: &str, seed: u64) -> Value {
    tube_run(work, name, d, res, n, drive, seed, 0.006, &[])
}

/// [`narrow_tube_run`] with `flow_s` seconds of flow and `extra` overrides (the fluid, the
/// starting orientation).
#[allow(clippy::too_many_arguments)]
fn tube_run(
    work: &Path,
    name: &str,
    d: f64,
    res: &str,
    n: usize,
    drive: &str,
    seed: u64,
    flow_s: f64,
    extra: &[&str],
) -> Value {
    let st = format!(
        "stage=[{{name = \"rest\", duration_s = 0.0001}}, {{name = \"flow\", duration_s = {flow_s}, {drive}}}]"
    );
    let (d, n, seed) = (
        format!("tube.diameter_um={d}"),
        format!("cell.vertices={n}"),
        format!("seed={seed}"),
    );
    let res = format!("model.length_um_per_rc={res}");
    let mut sets: Vec<&str> = vec![
        &st,
        &d,
        "tube.length_um=50",
        "plasma.viscosity_pa_s=1.0e-3",
        &res,
        &n,
        &seed,
        "output.frame_every_s=0",
    ];
    sets.extend_from_slice(extra);
    go(work, name, &sets).0
}

/// y at x on the polyline `pts` (sorted by x), linear between its points; NaN outside.
fn interpolate(pts: &[(f64, f64)], x: f64) -> f64 {
    pts.windows(2)
        .find(|w| w[0].0 <= x && x <= w[1].0)
        .map(|w| w[0].1 + (w[1].1 - w[0].1) * (x - w[0].0) / (w[1].0 - w[0].0))
        .unwrap_or(f64::NAN)
}

/// One run of the narrow-tube validations: the flow stage's final-quarter means.
struct NarrowRun {
    /// Tube diameter, µm.
    d: f64,
    /// The drive: pressure gradient (mmHg/mm) or mean velocity (mm/s), as the caller sets it.
    g: f64,
    /// Cell and mean-flow velocity, cm/s.
    v: f64,
    u: f64,
    /// Axial length, µm; DI with the width 2 max ρ and seen from the side.
    length: f64,
    di: f64,
    di_side: f64,
    shape: String,
    thermal: f64,
    secs: f64,
}

impl NarrowRun {
    fn new(d: f64, g: f64, r: &Value, secs: f64) -> Self {
        let fl = &stage(r, "flow")["final_quarter_means"];
        NarrowRun {
            d,
            g,
            v: f(&fl["cell_velocity_m_per_s"]) * 100.0,
            u: f(&fl["fluid_mean_velocity_m_per_s"]) * 100.0,
            length: f(&fl["axial_length_um"]),
            di: f(&fl["deformation_index"]),
            di_side: f(&fl["silhouette_deformation_index"]),
            shape: fl["shape"].as_str().unwrap_or("?").to_string(),
            thermal: f(&r["unit_mapping"]["thermal_factor"]),
            secs,
        }
    }

    /// The mean of two seeds of one point: (d, g, v, u, length, DI, side DI, f, s, shapes,
    /// |seed 1 − seed 2| of the length).
    #[allow(clippy::type_complexity)]
    fn mean_of_seeds(pair: &[NarrowRun]) -> (f64, f64, f64, f64, f64, f64, f64, f64, f64, String, f64) {
        let m = |k: fn(&NarrowRun) -> f64| pair.iter().map(k).sum::<f64>() / pair.len() as f64;
        (
            pair[0].d,
            pair[0].g,
            m(|r| r.v),
            m(|r| r.u),
            m(|r| r.length),
            m(|r| r.di),
            m(|r| r.di_side),
            pair[0].thermal,
            m(|r| r.secs),
            pair.iter().map(|r| r.shape.as_str()).collect::<Vec<_>>().join(", "),
            pair.iter().map(|r| r.length).fold(f64::NEG_INFINITY, f64::max)
                - pair.iter().map(|r| r.length).fold(f64::INFINITY, f64::min),
        )
    }
}

/// Hochmuth, Marple & Sutera 1970's eight tubes (4.5–10.7 µm): the cell's length, the quantity
/// they measured, at a mean flow of 3 mm/s (cells at 0.3–0.5 cm/s, inside the velocity range
/// of their cells in every tube), two seeds each, with `scenarios/capillary-tomaiuolo.toml`'s
/// conditions (1.0 mPa·s, a 50 µm tube, the cell entering face-on and pressed into tubes
/// narrower than it) and the capillary fluid. 4.5 µm at 0.5 µm per rc with N = 2000 (the least
/// tube at 1 µm per rc is 4.8 µm), the others at 1 µm per rc with N = 500. In the two tubes
/// wider than the cell (9.7 and 10.7 µm) it also enters edge-on, and the flow lasts 20 ms
/// there, 6 ms elsewhere: an unpressed cell turns and lengthens for 10–20 ms (face-on 5.1 µm
/// at 6 ms, 6.7 at 20 ms in the 9.7 µm tube), a pressed one settles within 6 ms. Prints the
/// table of docs/validation.md ("Hochmuth 1970's tubes"): the model's length beside the mean
/// and SD of their cells' lengths in the same tube within a factor of two of the model's
/// velocity; writes `capillary_hochmuth_length.png` into `$HEMODPD_FIGURES_DIR` when set.
/// ≈ 30 minutes on 2 cores (1744 s measured), 7 of them the 4.5 µm tube and 16 the 20 ms runs
/// in the two wide tubes. Asserts what the docs state: the cell
/// is longer in the narrowest tube than in the widest, and from 6.2 µm up fewer than 1 % of
/// the particles a check tests were on the wrong side; the leak at 4.5 µm is printed (a known
/// defect).
#[test]
#[ignore]
fn capillary_validation_hochmuth() {
    hochmuth_tubes(
        "capillary",
        &[4.5, 6.2, 6.7, 7.6, 8.0, 8.5, 9.7, 10.7],
        "capillary_hochmuth_length.png",
    );
}

/// [`capillary_validation_hochmuth`] with the dense fluid (κ/kBT exact) in the seven tubes
/// from 6.2 µm up (the 4.5 µm tube needs 0.5 µm per rc, 8 × the particles of the dense fluid's
/// 1 µm per rc: not run). Writes `capillary_hochmuth_length_dense.png`. About 1.5–2 hours on 2
/// cores, most of it the eight 20 ms runs in the wide tubes (7–13 min each: 669 and 757 s for
/// 9.7 µm face-on and edge-on, seed 1, on a slower machine, 432 and 422 s at 10.7 µm on a
/// faster one); the narrower tubes take 1–2 min a run.
#[test]
#[ignore]
fn capillary_validation_hochmuth_dense() {
    hochmuth_tubes(
        "dense",
        &[6.2, 6.7, 7.6, 8.0, 8.5, 9.7, 10.7],
        "capillary_hochmuth_length_dense.png",
    );
}

/// Hochmuth 1970's tubes `diameters` with `fluid`: see [`capillary_validation_hochmuth`].
fn hochmuth_tubes(fluid: &str, diameters: &[f64], figure: &str) {
    use hemodpd_io::plot::{line_chart, Series};
    let (figs, work) = validation_setup();
    let work = work.path();
    let length_ref: Vec<(f64, f64, f64)> = reference("capillary_cell_length_vs_velocity.csv")
        .into_iter()
        .filter(|r| r.0 == "Hochmuth1970")
        .map(|r| (r.1, r.2, r.3))
        .collect();
    let mean_velocity_mm_s = 3.0;
    let fluid_set = format!("model.fluid=\"{fluid}\"");
    let mut runs = Vec::new();
    // the starting orientation and the flow's duration (ms) of each pair of runs (two seeds)
    let mut starts = Vec::new();
    // (tube, seed, misplaced particles over all checks, checks, particles tested per check)
    let mut leaks = Vec::new();
    for &d in diameters {
        let (res, n) = if d < 4.8 { ("0.5", 2000) } else { ("1.0", 500) };
        // the tubes the resting cell (7.8 µm) enters without being pressed
        let wide = d > 9.0;
        let (flow_s, orientations): (f64, &[&str]) = if wide {
            (0.02, &["face-on", "edge-on"])
        } else {
            (0.006, &["face-on"])
        };
        for &orientation in orientations {
            let orientation_set = format!("tube.cell_orientation=\"{orientation}\"");
            for seed in [1u64, 2] {
                let t = std::time::Instant::now();
                let drive = format!("mean_velocity_m_per_s = {}", mean_velocity_mm_s * 1e-3);
                let name = format!("d{d}_{orientation}_s{seed}");
                let extra = [fluid_set.as_str(), orientation_set.as_str()];
                let r = tube_run(work, &name, d, res, n, &drive, seed, flow_s, &extra);
                let c = &r["crossings"];
                leaks.push((
                    d,
                    seed,
                    f(&c["misplaced_total"]),
                    f(&c["checks"]),
                    f(&c["checked_last"]),
                ));
                runs.push(NarrowRun::new(d, mean_velocity_mm_s, &r, t.elapsed().as_secs_f64()));
            }
            starts.push((orientation, flow_s * 1e3));
        }
    }
    eprintln!("\n{fluid} fluid; fluid on the wrong side of the membrane (all checks):");
    for (d, seed, m, checks, tested) in &leaks {
        eprintln!("  D = {d} µm, seed {seed}: {m} particles over {checks} checks of ≈ {tested} particles");
    }
    let rows: Vec<_> = runs.chunks(2).map(NarrowRun::mean_of_seeds).collect();
    eprintln!("\n| D (µm) | start | flow (ms) | cell velocity (cm/s) | length (µm) | length, seed 1 − seed 2 (µm) | DI (side view) | shape (seeds 1, 2) | Hochmuth 1970: cells within ×2 of the velocity | their length (µm), mean ± SD | model − experiment | f | run (s, each seed) |");
    eprintln!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for ((d, _, v, _, len, _, di_side, fth, secs, shapes, dl), (start, flow_ms)) in rows.iter().zip(&starts) {
        let near: Vec<f64> = length_ref
            .iter()
            .filter(|r| (r.0 - d).abs() < 0.01 && r.1 >= 0.5 * v && r.1 <= 2.0 * v)
            .map(|r| r.2)
            .collect();
        let (m, sd) = if near.len() > 1 {
            mean_sd(&near)
        } else {
            (f64::NAN, f64::NAN)
        };
        eprintln!(
            "| {d} | {start} | {flow_ms:.0} | {v:.3} | {len:.2} | {dl:.2} | {di_side:.2} | {shapes} | {} | {m:.2} ± {sd:.2} | {:+.0} % | {fth:.1} | {secs:.0} |",
            near.len(),
            100.0 * (len / m - 1.0)
        );
    }
    let (first, last) = (&rows[0], &rows[rows.len() - 1]);
    assert!(
        first.4 > last.4,
        "length at {} µm {} not above {} µm {}",
        first.0,
        first.4,
        last.0,
        last.4
    );
    // No fluid may cross: at most 1 % of a check's particles over all checks. The 4.5 µm tube
    // found 138 (seed 1, over 29 checks) while its pressed cell passed through itself, and
    // 0 and 6 since the pressing's self-contact term (docs/validation.md §6).
    for (d, seed, m, _, tested) in &leaks {
        assert!(*m <= 0.01 * tested, "D = {d} µm, seed {seed}: {m} particles crossed");
    }
    if let Some(dir) = &figs {
        let points = |start: &str| -> Vec<(f64, f64)> {
            runs.chunks(2)
                .zip(&starts)
                .filter(|(_, s)| s.0 == start)
                .flat_map(|(pair, _)| pair.iter().map(|r| (r.d, r.length)))
                .collect()
        };
        line_chart(
            dir.join(figure),
            &format!("Cell length against tube diameter (model: {fluid} fluid, mean flow 3 mm/s)"),
            "tube diameter (µm)",
            "axial length (µm)",
            // the experiment first, so that the model's points are drawn over it
            &[
                Series::points(
                    "Hochmuth 1970 (every cell, 0.03–1.9 cm/s)",
                    length_ref.iter().map(|r| (r.0, r.2)).collect(),
                ),
                Series::points("this model, face-on start (each seed)", points("face-on")),
                Series::points("this model, edge-on start (each seed)", points("edge-on")),
            ],
        )
        .unwrap();
    }
}

/// Mean and sample standard deviation.
fn mean_sd(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    (m, (x.iter().map(|e| (e - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt())
}

/// The validation behind docs/validation.md ("Capillary"), part 1 of 3 (all three:
/// `scripts/validate_capillary.sh [FIG_DIR]`, about 12 minutes on 2 cores): the shipped
/// protocol at 1 mm/s, the Fig. 3 shapes and the recovery against Hochmuth 1979. Prints the
/// stages; writes the figures into `$HEMODPD_FIGURES_DIR` when set. Asserts what the docs
/// state: the cell has recovered its resting shape (in its own frame) to within twice its
/// thermal roughness 50 ms after the flow stops, and no fluid crossed the membrane.
#[test]
#[ignore]
fn capillary_validation_protocol() {
    use hemodpd_io::plot::{line_chart, Series};
    let (figs, work) = validation_setup();
    let work = work.path();

    // the paper's protocol (the shipped file): Fig. 3 shapes and the recovery
    let (proto, pdir) = go(work, "protocol", &["output.frame_every_s=0.001"]);
    eprintln!("protocol: {}", serde_json::to_string_pretty(&proto["stages"]).unwrap());
    let reader = hemodpd_io::TrajectoryReader::open(pdir.join("trajectory.h5")).unwrap();
    let times = reader.membrane_times().unwrap();
    let tris = reader.triangles().unwrap();
    let drive_start = 0.002;
    let picks = [
        ("rest", 0.0019),
        ("8 ms after the drive starts", drive_start + 0.008),
        ("16 ms", drive_start + 0.016),
        ("steady (40 ms)", drive_start + 0.0399),
        ("10 ms after it stops", drive_start + 0.05),
        ("50 ms after it stops", drive_start + 0.0899),
    ];
    let mut shapes = Vec::new();
    for (label, t) in picks {
        let i = (0..times.len())
            .min_by(|&a, &b| (times[a] - t).abs().total_cmp(&(times[b] - t).abs()))
            .unwrap();
        let fr = reader.membrane_frame(i).unwrap();
        shapes.push((
            format!("{label} (t = {:.1} ms)", times[i] * 1e3),
            fr.positions.iter().map(|p| *p * 1e6).collect::<Vec<_>>(),
        ));
    }
    if let Some(d) = &figs {
        let list: Vec<hemodpd_scenario::figures::Shape> = shapes
            .iter()
            .map(|(t, p)| hemodpd_scenario::figures::Shape {
                title: t.clone(),
                positions: p,
                triangles: &tris,
            })
            .collect();
        hemodpd_scenario::figures::render_shapes_view(
            &d.join("capillary_fig3_shapes.png"),
            &list,
            3,
            true,
            hemodpd_scenario::figures::View::TubeSide,
        )
        .unwrap();
    }
    // recovery: DI and L/W over time against Hochmuth 1979 (normalised: (x − x_end)/(x_0 − x_end))
    let rows: Vec<Vec<f64>> = std::fs::read_to_string(pdir.join("cell.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
        .collect();
    let rec: Vec<&Vec<f64>> = rows.iter().filter(|r| r[1] == 2.0).collect();
    let norm = |y: Vec<f64>| {
        let n = y.len();
        let end = y[n - n / 5..].iter().sum::<f64>() / (n / 5) as f64;
        let y0 = y[0];
        y.iter().map(|v| (v - end) / (y0 - end)).collect::<Vec<f64>>()
    };
    let rec_t: Vec<f64> = rec.iter().map(|r| r[2]).collect();
    let rec_d = norm(rec.iter().map(|r| r[9]).collect());
    let hoch: Vec<(f64, f64, f64)> = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/relaxation_hochmuth1979_trbcuq.csv"),
    )
    .unwrap()
    .lines()
    .filter(|l| !l.starts_with('#') && !l.starts_with("cell"))
    .filter_map(|l| {
        let c: Vec<f64> = l.split(',').filter_map(|x| x.parse().ok()).collect();
        (c.len() == 3).then(|| (c[0], c[1], c[2]))
    })
    .collect();
    if let Some(d) = &figs {
        // the DI in the tube's frame is no measure of recovery here: the recovered disc turns
        // in the tube (docs/validation.md)
        let mut series = vec![Series::line(
            "this model: distance from the resting shape",
            rec_t.iter().cloned().zip(rec_d.iter().cloned()).collect(),
        )];
        for cell in 1..=4 {
            let pts: Vec<(f64, f64)> = hoch.iter().filter(|h| h.0 == cell as f64).map(|h| (h.1, h.2)).collect();
            if pts.is_empty() {
                continue;
            }
            let end = pts.last().unwrap().1;
            let y0 = pts[0].1;
            series.push(Series::points(
                format!("Hochmuth 1979 cell {cell}: L/W"),
                pts.iter().map(|(t, y)| (*t, (y - end) / (y0 - end))).collect(),
            ));
        }
        line_chart(
            d.join("capillary_recovery.png"),
            "Shape recovery after the flow stops",
            "time since release (s)",
            "(x − x_end)/(x_0 − x_end)",
            &series,
        )
        .unwrap();
    }
    let rest_d = q(&proto, "rest", "distance_from_rest_um");
    let end_d = q(&proto, "recovery", "distance_from_rest_um");
    eprintln!(
        "distance from rest: at rest {rest_d:.3} µm, end of recovery {end_d:.3} µm; recovery time {}",
        stage(&proto, "recovery")["recovery_time_s"]
    );
    assert!(
        end_d < 2.0 * rest_d.max(0.125),
        "not recovered: {end_d} µm against {rest_d} µm at rest"
    );
    assert_eq!(proto["crossings"]["misplaced_total"], 0);
}

/// Part 2 of the capillary validation: a sweep of mean velocities 0.2–1 mm/s at the mapping of
/// 1 mm/s (f fixed at 10.841, so every point has the same membrane), 40 ms each; cell length and
/// deformation index against Hochmuth 1970 (D = 9.7 and 10.7 µm) and Lanotte 2014 (10 µm).
/// Prints the table and draws the figures; asserts only that the length grows with velocity
/// (the comparison with the data is reported, not tuned).
#[test]
#[ignore]
fn capillary_validation_velocity_sweep() {
    use hemodpd_io::plot::{line_chart, Series};
    let (figs, work) = validation_setup();
    let work = work.path();
    let mut table = Vec::new();
    for u in [0.2e-3, 0.4e-3, 0.6e-3, 0.8e-3, 1.0e-3] {
        let st = format!("stage=[{{name = \"rest\", duration_s = 0.001}}, {{name = \"parachute\", duration_s = 0.04, mean_velocity_m_per_s = {u}}}]");
        let (r, _) = go(
            work,
            &format!("u{u}"),
            &[&st, "model.thermal_factor=10.841", "output.frame_every_s=0"],
        );
        table.push((
            u,
            q(&r, "parachute", "cell_velocity_m_per_s"),
            q(&r, "parachute", "axial_length_um"),
            q(&r, "parachute", "deformation_index"),
        ));
    }
    let length_ref = reference("capillary_cell_length_vs_velocity.csv");
    let di_ref = reference("capillary_deformation_index_vs_velocity.csv");
    eprintln!("\n| mean U (mm/s) | cell velocity (cm/s) | length (µm) | Hochmuth 10.7 µm nearest (cm/s, µm) | DI = L/W | Lanotte 10 µm nearest (cm/s, DI) |");
    eprintln!("|---|---|---|---|---|---|");
    for &(u, uc, len, di) in &table {
        let near = |rows: &[(String, f64, f64, f64)], study: &str, d: f64| {
            rows.iter()
                .filter(|r| r.0 == study && (r.1 - d).abs() < 0.01)
                .min_by(|a, b| (a.2 - uc * 100.0).abs().total_cmp(&(b.2 - uc * 100.0).abs()))
                .map(|r| (r.2, r.3))
                .unwrap_or((f64::NAN, f64::NAN))
        };
        let (hv, hl) = near(&length_ref, "Hochmuth1970", 10.7);
        let (lv, ld) = near(&di_ref, "Lanotte2014", 10.0);
        eprintln!(
            "| {:.1} | {:.4} | {len:.2} | {hv:.3}, {hl:.2} | {di:.3} | {lv:.3}, {ld:.3} |",
            u * 1e3,
            uc * 100.0
        );
    }
    if let Some(d) = &figs {
        let mut s1 = vec![Series::line_with_points(
            "this model (10 µm)",
            table.iter().map(|t| (t.1 * 100.0, t.2)).collect(),
        )];
        for dd in [9.7, 10.7] {
            s1.push(Series::points(
                format!("Hochmuth 1970, D = {dd} µm"),
                length_ref
                    .iter()
                    .filter(|r| r.0 == "Hochmuth1970" && (r.1 - dd).abs() < 0.01)
                    .map(|r| (r.2, r.3))
                    .collect(),
            ));
        }
        line_chart(
            d.join("capillary_length_vs_velocity.png"),
            "Cell length in a 10 µm tube",
            "cell velocity (cm/s)",
            "axial length (µm)",
            &s1,
        )
        .unwrap();
        let s2 = vec![
            Series::line_with_points(
                "this model: length/width",
                table.iter().map(|t| (t.1 * 100.0, t.3)).collect(),
            ),
            Series::points(
                "Lanotte 2014, D = 10 µm",
                di_ref
                    .iter()
                    .filter(|r| r.0 == "Lanotte2014")
                    .map(|r| (r.2, r.3))
                    .collect(),
            ),
        ];
        line_chart(
            d.join("capillary_di_vs_velocity.png"),
            "Deformation index in a 10 µm tube",
            "cell velocity (cm/s)",
            "DI",
            &s2,
        )
        .unwrap();
    }
    // Hochmuth's nearest tube, 10.7 µm, at the velocities where our ranges meet theirs
    for u in [0.6e-3, 1.0e-3] {
        let st = format!("stage=[{{name = \"rest\", duration_s = 0.001}}, {{name = \"parachute\", duration_s = 0.04, mean_velocity_m_per_s = {u}}}]");
        let (r, _) = go(
            work,
            &format!("d10.7_u{u}"),
            &[
                &st,
                "tube.diameter_um=10.7",
                "model.thermal_factor=10.841",
                "output.frame_every_s=0",
            ],
        );
        eprintln!(
            "D = 10.7 µm, mean U {:.1} mm/s: cell velocity {:.4} cm/s, length {:.2} µm, DI {:.3}",
            u * 1e3,
            q(&r, "parachute", "cell_velocity_m_per_s") * 100.0,
            q(&r, "parachute", "axial_length_um"),
            q(&r, "parachute", "deformation_index")
        );
    }
    assert!(
        table.windows(2).all(|w| w[1].2 > w[0].2 - 0.2),
        "length not growing with velocity: {table:?}"
    );
    assert!(table[table.len() - 1].2 > table[0].2);
}

/// Part 3 of the capillary validation: N = 500 and N = 5000 give steady cell velocity and length
/// within 5 % of each other (the issue's criterion), at 0.3 mm/s (f = 3.25: the cell's shape
/// scatters least between seeds there), each the mean of two seeds over the last 25 ms of
/// 100 ms of flow. Measured: velocity −3.8 %, length −3.0 %; seed-to-seed scatter ±3 % in
/// length (docs/validation.md).
#[test]
#[ignore]
fn capillary_validation_resolution() {
    let (_figs, work) = validation_setup();
    let work = work.path();
    let st = "stage=[{name = \"rest\", duration_s = 0.002}, {name = \"parachute\", duration_s = 0.1, mean_velocity_m_per_s = 3e-4}]";
    let mut means = Vec::new();
    for n in [500, 5000] {
        let (mut v, mut l) = (Vec::new(), Vec::new());
        for seed in [1, 2] {
            let nv = format!("cell.vertices={n}");
            let sd = format!("seed={seed}");
            let (r, _) = go(
                work,
                &format!("n{n}_s{seed}"),
                &[st, "output.frame_every_s=0", &nv, &sd],
            );
            v.push(q(&r, "parachute", "cell_velocity_m_per_s"));
            l.push(q(&r, "parachute", "axial_length_um"));
            eprintln!(
                "N = {n}, seed {seed}: cell velocity {:.4e} m/s, length {:.3} µm, performance {}",
                v[v.len() - 1],
                l[l.len() - 1],
                r["performance"]
            );
        }
        means.push((v.iter().sum::<f64>() / 2.0, l.iter().sum::<f64>() / 2.0));
    }
    let ((va, la), (vb, lb)) = (means[0], means[1]);
    eprintln!(
        "N = 500: {va:.4e} m/s, {la:.3} µm; N = 5000: {vb:.4e} m/s, {lb:.3} µm ({:+.1} %, {:+.1} %)",
        100.0 * (vb / va - 1.0),
        100.0 * (lb / la - 1.0)
    );
    assert!((vb / va - 1.0).abs() < 0.05, "velocity N=500 {va} N=5000 {vb}");
    assert!((lb / la - 1.0).abs() < 0.05, "length N=500 {la} N=5000 {lb}");
}

/// `--set` (and so `hemodpd sweep --vary`) reaches into the stages: `stage.1.mean_velocity_m_per_s`
/// is the second stage's drive; a missing stage is a clear error.
#[test]
fn set_reaches_into_stages() {
    let s = capillary(&["stage.1.mean_velocity_m_per_s=2e-3", "stage.2.duration_s=0.01"]);
    let Scenario::Capillary(c) = &s else {
        panic!("not a capillary scenario")
    };
    assert_eq!(c.stage[1].mean_velocity_m_per_s, Some(2e-3));
    assert_eq!(c.stage[2].duration_s, 0.01);
    let e = load(&scenario_path(), &["stage.7.duration_s=1".to_string()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("stage") && e.contains("no entry 7"), "{e}");
}

/// A time step the membrane cannot take is refused before the fluid is built: the dry run of
/// the membrane alone names `model.timestep`, the step it failed at, the likely cause and the
/// largest halving that passed. Here f = 1 (κ/kBT exact, the membrane 11× stiffer than at the
/// default mapping) and the stiffest area constraint allowed (1 N/m, 500× the default).
#[test]
fn membrane_timestep_is_checked_before_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let s = capillary(&[
        "stage=[{name = \"rest\", duration_s = 0.002}]",
        "model.thermal_factor=\"exact\"",
        "model.timestep=0.004",
        "cell.area_constraint_n_per_m=1.0",
        "output.frame_every_s=0",
    ]);
    let t = std::time::Instant::now();
    let e = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap_err().to_string();
    assert!(
        e.contains("model.timestep") && e.contains("membrane") && e.contains("step"),
        "{e}"
    );
    assert!(e.contains("likely cause") && e.contains("set model.timestep ≤"), "{e}");
    // the advice works: that time step passes the check and the run starts
    let dt: f64 = e
        .split("set model.timestep ≤ ")
        .nth(1)
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(dt < 0.004);
    let ok = capillary(&[
        "stage=[{name = \"rest\", duration_s = 0.00005}]",
        "model.thermal_factor=\"exact\"",
        &format!("model.timestep={dt}"),
        "cell.area_constraint_n_per_m=1.0",
        "output.frame_every_s=0",
    ]);
    run(&ok, &RunContext::new(dir.path().join("ok"), 0, false)).unwrap();
    eprintln!("{e} ({:.1} s)", t.elapsed().as_secs_f64());
}

/// An instability mid-run names the step, the part and the likely cause.
#[test]
fn instability_names_the_step_and_the_part() {
    let e = hemodpd_engine::EngineError::TooFast {
        step: 17,
        id: 3,
        index: 15_000,
        ptype: hemodpd_scenario::capillary::MEMBRANE,
        displacement: 1.2,
        cell: 1.0,
        velocity: "[0, 0, 480]".into(),
        cause: "time step too large",
    };
    let m = hemodpd_scenario::capillary::describe_engine_error(e).to_string();
    assert!(
        m.contains("step 17") && m.contains("membrane vertex") && m.contains("likely cause"),
        "{m}"
    );
    // a real one: the dense fluid at its own Δt = 0.003, where the vertices' friction with it
    // (γ_fsi ≈ 50) blows them up within ≈ 25 steps at rest; the time series up to the error
    // is kept in cell.csv
    let dir = tempfile::tempdir().unwrap();
    let s = capillary(&[
        "model.fluid=\"dense\"",
        "model.timestep=0.003",
        "stage=[{name = \"rest\", duration_s = 0.0003}]",
        "output.sample_every_steps=2",
        "output.frame_every_s=0",
    ]);
    let e = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap_err().to_string();
    assert!(e.contains("membrane") && e.contains("step"), "{e}");
    let csv = std::fs::read_to_string(dir.path().join("cell.csv")).unwrap();
    assert!(csv.lines().count() > 2, "{csv}");
}

/// The measurement behind `CAPILLARY_FLUID_WALL_SLIP`: the capillary fluid in a tube whose
/// bounce-back wall of frozen particles (no adaptive force) is at R = 5 exactly, L = 8, driven
/// by the body force whose no-slip Poiseuille mean velocity g n R²/(8η) is 0.5 (η =
/// `CAPILLARY_FLUID_VISCOSITY`, n the mean density in the tube). The measured mean velocity
/// (flux over πR²) is above it by 4b/R (Q ∝ R⁴(1 + 4b/R)), so b = R/4 · (U/U_P − 1). Flow
/// development 2000 steps (≈ 10 viscous times τ_v = nR²/(5.78 η) ≈ 0.49), 60 000 sampled steps
/// (150 time units) from each of four seeds (two seeds of 30 000 steps gave b = 0.204 and
/// 0.177: their spread alone is no error estimate); the error combines the seeds' standard
/// error with the viscosity's. Asserts the constant within 3 of those (≈ 4 min on 2 cores).
#[test]
#[ignore]
fn capillary_fluid_wall_slip() {
    let (mean, se) = measure_wall_slip(&FluidModel::capillary(), 60000, &[1, 2, 3, 4]);
    let b = hemodpd_engine::params::CAPILLARY_FLUID_WALL_SLIP;
    assert!(
        (mean - b).abs() < 3.0 * se,
        "b = {mean} ± {se}, CAPILLARY_FLUID_WALL_SLIP = {b}"
    );
}

/// The slip length b of `fluid` at its frozen bounce-back wall (R = 5, L = 8, the body force
/// whose no-slip mean velocity g n R²/(8η) is 0.5 with the fluid's table η), `steps` sampled
/// steps per seed: b = R/4 · (U/U_P − 1) per seed, and (mean, SE) with the seeds' SE and the
/// viscosity's SE combined (U_P ∝ 1/η moves every b alike).
fn measure_wall_slip(fluid: &FluidModel, steps: u64, seeds: &[u64]) -> (f64, f64) {
    let (eta, eta_rel_se) = (fluid.viscosity, fluid.viscosity_se / fluid.viscosity);
    let radius = 5.0;
    let g = 0.5 * 8.0 * eta / (fluid.density * radius * radius);
    let mut b = Vec::new();
    for &seed in seeds {
        let (n_mean, q) = fluid_tube(fluid, radius, g, steps, seed);
        let u = q / (std::f64::consts::PI * radius * radius);
        let u_p = g * n_mean * radius * radius / (8.0 * eta);
        let e = u / u_p - 1.0;
        eprintln!(
            "SUMMARY {} wall slip, seed {seed}: n = {n_mean:.4}, U = {u:.5}, g n R²/(8η) = {u_p:.5}, excess {:+.2} %, b = {:.4}",
            fluid.name,
            100.0 * e,
            radius * e / 4.0
        );
        b.push(radius * e / 4.0);
    }
    let nb = b.len() as f64;
    let mean = b.iter().sum::<f64>() / nb;
    let spread_se = (b.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (nb - 1.0) / nb).sqrt();
    let eta_se = radius / 4.0 * (1.0 + 4.0 * mean / radius) * eta_rel_se;
    let se = (spread_se * spread_se + eta_se * eta_se).sqrt();
    eprintln!(
        "SUMMARY {} wall slip b = {mean:.4} ± {se:.4} (seeds ± {spread_se:.4}, η ± {eta_se:.4}); table {}",
        fluid.name, fluid.wall_slip
    );
    (mean, se)
}

/// The measurement behind `DENSE_FLUID_WALL_SLIP`, as `capillary_fluid_wall_slip` for the
/// dense fluid (Mach 0.035 at the mean velocity 0.5): 2000 steps of flow development (6 time
/// units, ≈ 30 viscous times nR²/(5.78 η) ≈ 0.19), 20 000 sampled steps from each of three
/// seeds (≈ 6 min on 2 cores; measured b = 0.282, 0.273, 0.276, 0.277 ± 0.005). Asserts the
/// constant within 3 combined standard errors.
#[test]
#[ignore]
fn dense_fluid_wall_slip() {
    let (mean, se) = measure_wall_slip(&FluidModel::dense(), 20000, &[1, 2, 3]);
    assert_slip_is_the_table(&FluidModel::dense(), mean, se);
}

/// The measured slip (mean ± SE) within 3 SE of `fluid`'s table value.
fn assert_slip_is_the_table(fluid: &FluidModel, mean: f64, se: f64) {
    let b = fluid.wall_slip;
    assert!(
        (mean - b).abs() < 3.0 * se,
        "{}: b = {mean} ± {se}, table {b}",
        fluid.name
    );
}

/// The measurement behind `VISCOUS_FLUID_WALL_SLIP`, as `dense_fluid_wall_slip` (the same
/// mean velocity 0.5 at 10 × the drive; 2000 steps of development are ≈ 30 viscous times at
/// Δt = 0.0003, 20 000 sampled steps from each of three seeds). Asserts the constant within 3
/// combined standard errors.
#[test]
#[ignore]
fn viscous_fluid_wall_slip() {
    let (mean, se) = measure_wall_slip(&FluidModel::viscous(), 20000, &[1, 2, 3]);
    assert_slip_is_the_table(&FluidModel::viscous(), mean, se);
}

/// Optical-tweezers stretch and release in a wide tube without flow (docs/validation.md,
/// "Stretch and release"), shortened: 100 pN for 4 ms, released for 4 ms, with and without a
/// physiological membrane viscosity (6.3e-7 N·s/m). Stretched, the cell's in-plane L/W rises
/// well above its resting ≈ 1; released, it falls back, Hochmuth's Kelvin–Voigt form fits the
/// fall, and the membrane viscosity slows both the stretch and the recovery. No fluid crosses
/// the membrane; area and volume stay within 1 %. The membrane is not sub-stepped
/// (`model.membrane_substeps = 1`, not the default "auto"), so the viscosity acts at ≈ 4 % of its
/// value (the cap of docs/model.md §7b) and the test stays short; the sub-stepped run is
/// [`stretch_and_release_substepped`].
#[test]
fn stretch_and_release_with_and_without_membrane_viscosity() {
    let go = |eta: &str| {
        let dir = tempfile::tempdir().unwrap();
        let s = capillary(&[
            "tube.diameter_um=16.0",
            "tube.length_um=16.0",
            "stage=[{name = \"stretch\", duration_s = 0.004, stretch_force_n = 1e-10}, {name = \"release\", duration_s = 0.004}]",
            "model.thermal_factor=10.841",
            "output.frame_every_s=0",
            "model.membrane_substeps=1",
            &format!("cell.membrane_viscosity_pa_s_m={eta}"),
        ]);
        run(&s, &RunContext::new(dir.path(), 0, false)).unwrap()
    };
    let (plain, visc) = (go("0"), go("6.3e-7"));
    let lw = |r: &Value, st: &str, k: &str| f(&stage(r, st)["length_over_width"][k]);
    for (name, r) in [("elastic", &plain), ("viscous", &visc)] {
        let fit = &stage(r, "release")["length_over_width"]["hochmuth_fit"];
        eprintln!(
            "{name}: L/W stretched {:.3} (first {:.3}), released {:.3}; fit {fit}; η_m {}",
            lw(r, "stretch", "final_quarter_mean"),
            lw(r, "stretch", "first"),
            lw(r, "release", "final_quarter_mean"),
            r["membrane_viscosity"]
        );
        assert!(lw(r, "stretch", "first") < 1.15);
        assert!(lw(r, "release", "first") > 1.3, "{name}: not stretched");
        assert!(lw(r, "release", "final_quarter_mean") < lw(r, "release", "first"));
        assert!(f(&fit["recovery_time_s"]) > 0.0);
        assert_eq!(r["crossings"]["misplaced_total"], 0);
        for st in ["stretch", "release"] {
            assert!(f(&stage(r, st)["max_abs_area_deviation"]) < 0.01);
            assert!(f(&stage(r, st)["max_abs_volume_deviation"]) < 0.01);
        }
    }
    // the membrane viscosity resists the stretch (less stretched after 4 ms) and slows the
    // recovery
    assert!(lw(&visc, "release", "first") < lw(&plain, "release", "first"));
    let tc = |r: &Value| f(&stage(r, "release")["length_over_width"]["hochmuth_fit"]["recovery_time_s"]);
    assert!(tc(&visc) > 1.5 * tc(&plain), "t_c {} vs {}", tc(&visc), tc(&plain));
    assert!((f(&visc["membrane_viscosity"]["pa_s_m"]) - 6.3e-7).abs() < 1e-20);
}

/// Stretch and release with a physiological membrane viscosity (6.3e-7 N·s/m, η_m/μ0 = 76 ms),
/// sub-stepped (`model.membrane_substeps`, "auto" = 50 at this mapping: the link friction acts
/// at 93 % of its value instead of 4 %): 100 pN for `STRETCH` s in the 16 µm tube of
/// [`stretch_and_release_with_and_without_membrane_viscosity`], released for `RELEASE` s.
/// Prints t_c of the Hochmuth fit and the performance shares (docs/validation.md); asserts
/// that the recovery is slower than without sub-stepping's 2.3 ms by an order of magnitude,
/// that no fluid crosses and that area and volume hold. About 15 minutes on 2 busy cores:
/// `cargo test --test end_to_end stretch_and_release_substepped -- --ignored --nocapture` (the
/// test profile is optimised).
#[test]
#[ignore]
fn stretch_and_release_substepped() {
    const STRETCH: f64 = 0.02;
    const RELEASE: f64 = 0.04;
    let dir = tempfile::tempdir().unwrap();
    let s = capillary(&[
        "tube.diameter_um=16.0",
        "tube.length_um=16.0",
        &format!(
            "stage=[{{name = \"stretch\", duration_s = {STRETCH}, stretch_force_n = 1e-10}}, {{name = \"release\", duration_s = {RELEASE}}}]"
        ),
        "model.thermal_factor=10.841",
        "model.membrane_substeps=\"auto\"",
        "output.frame_every_s=0",
        "cell.membrane_viscosity_pa_s_m=6.3e-7",
    ]);
    let r = run(&s, &RunContext::new(dir.path(), 0, false)).unwrap();
    let lw = |st: &str, k: &str| f(&stage(&r, st)["length_over_width"][k]);
    let fit = &stage(&r, "release")["length_over_width"]["hochmuth_fit"];
    eprintln!(
        "SUMMARY substepped: L/W stretched {:.3} (first {:.3}), released first {:.3}, final quarter {:.3}; fit {fit}; η_m {}; performance {}",
        lw("stretch", "final_quarter_mean"),
        lw("stretch", "first"),
        lw("release", "first"),
        lw("release", "final_quarter_mean"),
        r["membrane_viscosity"],
        r["performance"]
    );
    assert_eq!(r["membrane_viscosity"]["substeps"], 50);
    assert_eq!(r["crossings"]["misplaced_total"], 0);
    for st in ["stretch", "release"] {
        assert!(f(&stage(&r, st)["max_abs_area_deviation"]) < 0.01);
        assert!(f(&stage(&r, st)["max_abs_volume_deviation"]) < 0.01);
    }
    assert!(lw("release", "first") > lw("stretch", "first"), "not stretched");
    assert!(f(&fit["recovery_time_s"]) > 0.01, "t_c {}", fit["recovery_time_s"]);
}

/// Hochmuth et al. 1979 (tests/data/relaxation_hochmuth1979_trbcuq.csv): (cell, t s, L/W).
fn hochmuth_1979() -> Vec<(u32, f64, f64)> {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/relaxation_hochmuth1979_trbcuq.csv"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("cell"))
        .filter_map(|l| {
            let c: Vec<f64> = l.split(',').filter_map(|x| x.parse().ok()).collect();
            (c.len() == 3).then(|| (c[0] as u32, c[1], c[2]))
        })
        .collect()
}

/// The stretch-and-release validation behind docs/validation.md ("Stretch and release against
/// Hochmuth 1979") and the capillary recovery with a membrane viscosity: prints the tables.
/// About 10 minutes on 2 cores:
/// `cargo test --release --test end_to_end membrane_viscosity_validation -- --ignored --nocapture`.
/// Asserts only that the fits exist and that the viscosity slows the recovery.
#[test]
#[ignore]
fn membrane_viscosity_validation() {
    use hemodpd_scenario::capillary::fit_hochmuth;
    let (_figs, work) = validation_setup();
    let work = work.path();
    println!("| | t_c (ms) | λ0 | λ∞ | rms |");
    println!("|---|---|---|---|---|");
    let data = hochmuth_1979();
    for cell in 1..=4 {
        let (t, l): (Vec<f64>, Vec<f64>) = data.iter().filter(|d| d.0 == cell).map(|d| (d.1, d.2)).unzip();
        let h = fit_hochmuth(&t, &l).unwrap();
        println!(
            "| Hochmuth 1979 cell {cell} | {:.1} | {:.3} | {:.3} | {:.3} |",
            h.t_c * 1e3,
            h.lambda_0,
            h.lambda_inf,
            h.rms
        );
    }
    let mut tcs = Vec::new();
    for eta in ["0", "6.3e-7"] {
        let (r, _) = go(
            work,
            &format!("stretch_{eta}"),
            &[
                "tube.diameter_um=20.0",
                "tube.length_um=16.0",
                "stage=[{name = \"stretch\", duration_s = 0.03, stretch_force_n = 1e-10}, {name = \"release\", duration_s = 0.1}]",
                "model.thermal_factor=10.841",
                "output.frame_every_s=0",
                &format!("cell.membrane_viscosity_pa_s_m={eta}"),
            ],
        );
        let rel = &stage(&r, "release")["length_over_width"];
        let h = &rel["hochmuth_fit"];
        println!(
            "| this model, η_m = {eta} N·s/m (100 pN, L/W stretched {:.3}) | {:.1} | {:.3} | {:.3} | {:.3} |",
            f(&stage(&r, "stretch")["length_over_width"]["final_quarter_mean"]),
            f(&h["recovery_time_s"]) * 1e3,
            f(&h["lambda_0"]),
            f(&h["lambda_inf"]),
            f(&h["rms"])
        );
        assert_eq!(r["crossings"]["misplaced_total"], 0);
        tcs.push(f(&h["recovery_time_s"]));
    }
    assert!(tcs[1] > tcs[0]);
    // the capillary recovery (the shipped protocol, shortened: 20 ms of flow at 1 mm/s, 50 ms
    // of recovery), with and without
    for eta in ["0", "6.3e-7"] {
        let (r, _) = go(
            work,
            &format!("capillary_{eta}"),
            &[
                "stage=[{name = \"rest\", duration_s = 0.001}, {name = \"parachute\", duration_s = 0.02, mean_velocity_m_per_s = 1e-3}, {name = \"recovery\", duration_s = 0.05}]",
                "output.frame_every_s=0",
                &format!("cell.membrane_viscosity_pa_s_m={eta}"),
            ],
        );
        let rec = stage(&r, "recovery");
        println!(
            "capillary recovery, η_m = {eta}: 1/e time of the distance from rest {:.2} ms; parachute length {:.3} µm; distance {:.3} -> {:.3} µm",
            f(&rec["recovery_time_s"]["distance_from_rest"]) * 1e3,
            q(&r, "parachute", "axial_length_um"),
            q(&r, "parachute", "distance_from_rest_um"),
            q(&r, "recovery", "distance_from_rest_um"),
        );
        assert_eq!(r["crossings"]["misplaced_total"], 0);
    }
}
