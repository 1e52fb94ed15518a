//! The optical-tweezers stretching scenario at N = 500 against Mills et al. (2004), plus
//! reproducibility and the area/volume constraints. Seconds at the test profile (opt-level 3).

use hemodpd_scenario::stretching::{self, mills_2004};
use hemodpd_scenario::Scenario;

fn scenario(sets: &[&str]) -> hemodpd_scenario::stretching::StretchingScenario {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/stretching.toml");
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    match hemodpd_scenario::load(&path, &sets).unwrap() {
        Scenario::Stretching(s) => s,
        _ => unreachable!(),
    }
}

/// The shipped stretching scenario with `sets`, solved at every force, against Mills 2004: the
/// RMS of D_A and of D_T over the forces Mills measured (and their number), after asserting that
/// D_A, and with `dt_inside` D_T too, lie inside Mills' error bars at each of them; and the
/// solved points.
fn rms_against_mills(sets: &[&str], dt_inside: bool) -> (f64, f64, f64, Vec<hemodpd_membrane::stretch::StretchPoint>) {
    let s = scenario(sets);
    let prepared = stretching::prepare(&s).unwrap();
    let points = stretching::solve(&s, &prepared, |_| {}).unwrap();
    let mills = mills_2004();
    let (mut sa, mut st, mut n) = (0.0, 0.0, 0.0);
    for p in &points {
        if let Some(m) = mills.iter().find(|m| (m.force_pn - p.force).abs() < 1e-9) {
            sa += (p.axial_diameter - m.da_um).powi(2);
            st += (p.transverse_diameter - m.dt_um).powi(2);
            n += 1.0;
            assert!(
                p.axial_diameter > m.da_lo && p.axial_diameter < m.da_hi,
                "D_A at {} pN",
                p.force
            );
            assert!(
                !dt_inside || (p.transverse_diameter > m.dt_lo && p.transverse_diameter < m.dt_hi),
                "D_T at {} pN",
                p.force
            );
        }
    }
    ((sa / n).sqrt(), (st / n).sqrt(), n, points)
}

/// D_A and D_T at 0, 68, 131 and 193 pN (N = 500, the paper's parameter set).
///
/// Tolerances: Mills' error bars (half-widths 0.6–2.4 µm) are the experimental cell-to-cell
/// scatter. The model must lie inside them for D_A at every force and for D_T at rest and at
/// the largest forces. At 193 pN D_A must also lie between the Mills (15.26 µm) and Suresh 2005
/// (16.24 µm) means — two independent experiments — widened by 0.2 µm, the spread of D_A between
/// mesh seeds that we measured (docs/validation.md). D_T at middle forces is known to lie above
/// Mills' bars for a faithful implementation (SPEC §7): it is reported, not asserted.
#[test]
fn n500_matches_mills_2004() {
    let s = scenario(&[
        "stretching.forces_pn=[0.0, 67.964, 130.513, 192.688]",
        "membrane.parameters=paper",
    ]);
    let prepared = stretching::prepare(&s).unwrap();
    let points = stretching::solve(&s, &prepared, |_| {}).unwrap();
    let mills = mills_2004();
    for p in &points {
        let m = mills.iter().find(|m| (m.force_pn - p.force).abs() < 1e-9).unwrap();
        eprintln!(
            "F = {:7.3} pN: D_A = {:.3} (Mills {:.2} [{:.2}, {:.2}])  D_T = {:.3} (Mills {:.2} [{:.2}, {:.2}])",
            p.force, p.axial_diameter, m.da_um, m.da_lo, m.da_hi, p.transverse_diameter, m.dt_um, m.dt_lo, m.dt_hi
        );
        assert!(
            p.axial_diameter > m.da_lo && p.axial_diameter < m.da_hi,
            "D_A at {} pN outside Mills' error bars",
            p.force
        );
        if p.force == 0.0 || p.force > 130.0 {
            assert!(
                p.transverse_diameter > m.dt_lo && p.transverse_diameter < m.dt_hi,
                "D_T at {} pN outside Mills' error bars",
                p.force
            );
        }
    }
    let top = points.last().unwrap();
    assert!(
        top.axial_diameter > 15.26 - 0.2 && top.axial_diameter < 16.24 + 0.2,
        "D_A(193 pN) = {}",
        top.axial_diameter
    );
    // the cell stretches monotonically
    for w in points.windows(2) {
        assert!(w[1].axial_diameter > w[0].axial_diameter && w[1].transverse_diameter < w[0].transverse_diameter);
    }
}

/// The two-parameter set (`membrane.parameters = "calibrated"`, docs/model.md §3b) at Mills'
/// 13 forces gives the RMS the calibration found (docs/fit.md: 0.91 / 0.68 µm for D_A / D_T,
/// within 0.03 µm, the spread between the fit's exact values and the set's rounded ones being
/// 0.01 µm), below the paper set's RMS of both diameters together (0.89 µm; the calibration
/// trades D_A for D_T): the set reaches the scenario, and what it was fitted to holds. D_A stays
/// inside Mills' error bars at every force.
#[test]
fn calibrated_set_matches_what_the_fit_found() {
    let s = scenario(&["membrane.parameters=\"calibrated\""]);
    assert_eq!(s.membrane.max_extension_ratio, 3.17);
    assert_eq!(
        s.membrane.reference,
        hemodpd_membrane::ReferenceState::Spheroid { reduced_volume: 0.972 }
    );
    assert_eq!(s.membrane.persistence_scale, 1.34);
    let (ra, rt, n, _) = rms_against_mills(&["membrane.parameters=\"calibrated\""], false);
    let rb = ((ra * ra + rt * rt) / 2.0).sqrt();
    eprintln!("calibrated: RMS D_A {ra:.3}, D_T {rt:.3}, both {rb:.3} µm over {n} forces");
    assert_eq!(n, 13.0);
    assert!((ra - 0.91).abs() < 0.03 && (rt - 0.68).abs() < 0.03, "RMS {ra} / {rt}");
    assert!(rb < 0.85, "RMS of both diameters {rb}");
}

/// The shipped stretching scenario runs the named set `"calibrated-x0"` (docs/fit.md: Mills 2004
/// fitted with the links' maximum extension free, Lmax/L0 = 2.0 instead of 3.17, persistence
/// scale 5, v = 0.98): the RMS of D_A and of D_T against Mills are both ≤ 0.5 µm, the issue's
/// target, which neither diameter of `"calibrated"` meets (measured 0.38 / 0.47 µm against
/// 0.91 / 0.69). The set's values reach the scenario; D_A and D_T lie inside Mills' error bars
/// at every force (the paper's and the two-parameter sets leave D_T outside them from 16 to
/// 109 pN), and the stiffening shows: D_A grows by less than 0.3 µm from 172 to 193 pN (Mills
/// 0.44 µm; the paper's set 0.66 µm).
#[test]
fn calibrated_x0_set_meets_mills_in_both_diameters() {
    let s = scenario(&[]);
    assert_eq!(s.membrane.parameters.as_deref(), Some("calibrated-x0"));
    assert_eq!(
        s.membrane.reference,
        hemodpd_membrane::ReferenceState::Spheroid { reduced_volume: 0.98 }
    );
    assert_eq!(
        (s.membrane.persistence_scale, s.membrane.max_extension_ratio),
        (5.0, 2.0)
    );
    let (ra, rt, n, points) = rms_against_mills(&[], true);
    eprintln!("calibrated-x0: RMS D_A {ra:.3}, D_T {rt:.3} µm over {n} forces");
    assert_eq!(n, 13.0);
    assert!(ra <= 0.5 && rt <= 0.5, "RMS {ra} / {rt}");
    let da = |f: f64| {
        points
            .iter()
            .find(|p| (p.force - f).abs() < 1e-6)
            .unwrap()
            .axial_diameter
    };
    assert!(
        da(192.688) - da(172.374) < 0.3,
        "D_A grows {} µm",
        da(192.688) - da(172.374)
    );
}

/// Area and volume: within 0.1 % when the cell is left alone, within 1 % at 200 pN (the
/// global constraints' job; k_a and k_v in docs/model.md).
#[test]
fn area_and_volume_are_held() {
    let s = scenario(&["stretching.forces_pn=[0.0, 200.0]"]);
    let prepared = stretching::prepare(&s).unwrap();
    let points = stretching::solve(&s, &prepared, |_| {}).unwrap();
    let rest = &points[0];
    assert!(
        rest.area_deviation.abs() < 1e-3 && rest.volume_deviation.abs() < 1e-3,
        "rest: {} {}",
        rest.area_deviation,
        rest.volume_deviation
    );
    let top = &points[1];
    assert!(
        top.area_deviation.abs() < 1e-2 && top.volume_deviation.abs() < 1e-2,
        "200 pN: {} {}",
        top.area_deviation,
        top.volume_deviation
    );
}

/// Same scenario and seed: the generated mesh and the stretched shapes are bit-identical
/// (mesh generated twice, without the cache); another seed gives another mesh.
#[test]
fn same_seed_same_result() {
    let a = hemodpd_scenario::mesh_cache::generate(500, 11).unwrap().0;
    let b = hemodpd_scenario::mesh_cache::generate(500, 11).unwrap().0;
    let c = hemodpd_scenario::mesh_cache::generate(500, 12).unwrap().0;
    assert_eq!(a, b);
    assert_ne!(a.vertices, c.vertices);
    let s = scenario(&["stretching.forces_pn=[0.0, 100.0]"]);
    let p1 = stretching::prepare(&s).unwrap();
    let r1 = stretching::solve(&s, &p1, |_| {}).unwrap();
    let p2 = stretching::prepare(&s).unwrap();
    let r2 = stretching::solve(&s, &p2, |_| {}).unwrap();
    for (x, y) in r1.iter().zip(&r2) {
        assert_eq!(x.positions, y.positions);
    }
}

/// A user's mesh file through the scenario (SI keys → µm/pN units): the shared 500-vertex golden
/// mesh with the paper's uniform reference, k_a = 1e-3 N/m and k_v = 1e3 N/m² reproduces every
/// energy term of `golden_energies_N500_uniform.json` at the mesh and on the perturbed copy.
/// The golden file was made with Eq. 8/12 parameters from the fine model; it agrees with two
/// independent codes to 1e-13, so 1e-9 relative leaves room only for round-off.
#[test]
fn user_mesh_reproduces_the_golden_energies() {
    // a copy of shared/reference/membrane_golden (data, with its README) kept with the tests
    let golden_dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/membrane_golden");
    let mesh_file = golden_dir.join("mesh_N500.vertices.csv");
    let s = scenario(&[
        &format!("membrane.mesh_file=\"{}\"", mesh_file.display()),
        // the golden energies are the paper's model's (persistence scale 1)
        "membrane.parameters=paper",
        "membrane.reference=uniform",
        "membrane.area_constraint_n_per_m=1e-3",
        "membrane.volume_constraint_n_per_m2=1e3",
    ]);
    let prepared = stretching::prepare(&s).unwrap();
    let golden: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(golden_dir.join("golden_energies_N500_uniform.json")).unwrap())
            .unwrap();
    let perturbed: Vec<glam::DVec3> = std::fs::read_to_string(golden_dir.join("mesh_N500.perturbed.vertices.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|t| t.trim().parse().unwrap()).collect();
            glam::DVec3::new(v[0], v[1], v[2])
        })
        .collect();
    for (key, x) in [("at_mesh", &prepared.mesh.vertices), ("perturbed", &perturbed)] {
        let e = prepared.model.energy(x).unwrap();
        let g = &golden[key];
        for (name, ours) in [
            ("wlc", e.wlc),
            ("C_over_A", e.c_over_a),
            ("bending", e.bending),
            ("area", e.area),
            ("volume", e.volume),
        ] {
            let want = g[name].as_f64().unwrap();
            let tol = 1e-9 * want.abs().max(1e-6);
            assert!((ours - want).abs() <= tol, "{key} {name}: {ours} vs golden {want}");
        }
    }
}

/// Stretching stopped after 3 of 6 forces (as Ctrl-C does: the force in progress is abandoned)
/// and resumed with `hemodpd_scenario::resume` ends with the uninterrupted run's results bit for
/// bit, and `shapes.h5` holds each force's shape exactly once.
#[test]
fn stretching_interrupted_and_resumed_is_bit_identical() {
    use hemodpd_scenario::{RunContext, RunError};
    let s = Scenario::Stretching(scenario(&[
        "membrane.vertices=300",
        "stretching.forces_pn=[0.0, 40.0, 80.0, 120.0, 160.0, 200.0]",
    ]));
    let a = tempfile::tempdir().unwrap();
    let full = hemodpd_scenario::run(&s, &RunContext::new(a.path(), 1, false)).unwrap();
    let b = tempfile::tempdir().unwrap();
    let mut ctx = RunContext::new(b.path(), 1, false);
    ctx.stop_at_step = Some(3);
    match hemodpd_scenario::run(&s, &ctx) {
        Err(RunError::Interrupted { step: 3, .. }) => {}
        other => panic!("expected an interrupt after 3 forces, got {other:?}"),
    }
    let reader = hemodpd_io::TrajectoryReader::open(b.path().join("shapes.h5")).unwrap();
    assert_eq!(reader.membrane_frames().unwrap(), 3);
    drop(reader);
    let (_, resumed) = hemodpd_scenario::resume(b.path(), &RunContext::new(b.path(), 2, false)).unwrap();
    assert_eq!(resumed["resumed_from_step"], 3);
    for key in [
        "force_pn",
        "axial_diameter_um",
        "transverse_diameter_um",
        "iterations",
        "residual_force_pn",
        "area_deviation",
        "volume_deviation",
        "mills2004",
    ] {
        assert_eq!(full[key], resumed[key], "{key}");
    }
    let (ra, rb) = (
        hemodpd_io::TrajectoryReader::open(a.path().join("shapes.h5")).unwrap(),
        hemodpd_io::TrajectoryReader::open(b.path().join("shapes.h5")).unwrap(),
    );
    assert_eq!(ra.membrane_frames().unwrap(), 6);
    assert_eq!(rb.membrane_frames().unwrap(), 6);
    for i in 0..6 {
        let (fa, fb) = (ra.membrane_frame(i).unwrap(), rb.membrane_frame(i).unwrap());
        assert_eq!(fa.step, i as u64);
        assert_eq!(fa, fb, "frame {i}");
    }
}

/// The shipped recovery scenario with `sets` (and no shapes file), run in `dir`: its
/// `results.recovery`.
fn recovery_results(dir: &std::path::Path, sets: &[&str]) -> serde_json::Value {
    use hemodpd_scenario::RunContext;
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/recovery.toml");
    let sets: Vec<String> = ["output.shapes=false"]
        .iter()
        .chain(sets)
        .map(|s| s.to_string())
        .collect();
    let s = hemodpd_scenario::load(&path, &sets).unwrap();
    let r = hemodpd_scenario::run(&s, &RunContext::new(dir, 0, false)).unwrap();
    r["recovery"].clone()
}

/// The number at JSON pointer `p` in `v`.
fn number(v: &serde_json::Value, p: &str) -> f64 {
    v.pointer(p)
        .and_then(|x| x.as_f64())
        .unwrap_or_else(|| panic!("{p} in {v}"))
}

/// The shipped recovery scenario (`scenarios/recovery.toml`: N = 500, released from 100 pN, the
/// `"calibrated-x0"` set: η_m = 3.9e-7 N·s/m in the central form) against Hochmuth et al. 1979:
/// the recovery time of its Kelvin–Voigt fit lies within 10 % of the mean of his four cells
/// fitted the same way (measured 0.147 s against 0.147 ± 0.033 s; the set's η_m was fitted to
/// it, with a σ of 17 %; docs/validation.md's target is 30 %). λ0 is 2.71: the calibrated cell
/// is stretched further at 100 pN than his cells started (1.9–2.2), which the test bounds
/// (2.3–2.8) rather than hides. The cell keeps its area and volume within 1 % (the
/// constraints' tolerance), and the time series has every sample. The two runs behind the
/// extrapolation agree with it to within 10 % (their t_c are 8 % and 4 % long).
#[test]
fn recovery_after_release_against_hochmuth_1979() {
    let dir = tempfile::tempdir().unwrap();
    let rec = &recovery_results(dir.path(), &[]);
    let f = |p: &str| number(rec, p);
    let (tc, mean) = (f("/t_c_s"), f("/hochmuth1979/mean_t_c_s"));
    eprintln!(
        "t_c {tc:.4} s (one run at ε: {:.4}, at ε/2: {:.4}); Hochmuth {mean:.4} ± {:.4} s; λ0 {:.3}, λ∞ {:.3}, rms {:.4}",
        f("/integration/t_c_s_coarse"),
        f("/integration/t_c_s_fine"),
        f("/hochmuth1979/sd_t_c_s"),
        f("/lambda_0"),
        f("/lambda_inf"),
        f("/fit_rms")
    );
    assert!((tc / mean - 1.0).abs() < 0.1, "t_c {tc} against Hochmuth's {mean}");
    assert!((mean - 0.147).abs() < 0.002, "Hochmuth's cells fit to {mean}");
    assert!(f("/lambda_0") > 2.3 && f("/lambda_0") < 2.8, "λ0 {}", f("/lambda_0"));
    for k in ["/integration/t_c_s_coarse", "/integration/t_c_s_fine"] {
        assert!(f(k) > tc && f(k) < 1.1 * tc, "{k}: {} against {tc}", f(k));
    }
    assert!(f("/max_abs_area_deviation") < 0.01 && f("/max_abs_volume_deviation") < 0.01);
    let csv = std::fs::read_to_string(dir.path().join("recovery.csv")).unwrap();
    assert_eq!(csv.lines().filter(|l| !l.starts_with('#')).count(), 1 + 101);
}

/// The recovery scenario with the two-parameter named set `"calibrated"` (η_m = 4.74e-7 N·s/m,
/// fitted to Hochmuth 1979 with the paper's Lmax/L0 = 3.17; docs/fit.md): t_c within 30 % of the
/// mean of Hochmuth's cells (measured 0.138 s against 0.147 s; the target of
/// docs/validation.md), λ0 2.53 (2.3–2.8), area and volume within 1 %.
#[test]
fn recovery_with_the_two_parameter_set_against_hochmuth_1979() {
    let dir = tempfile::tempdir().unwrap();
    let rec = &recovery_results(dir.path(), &["membrane.parameters=\"calibrated\""]);
    let f = |p: &str| number(rec, p);
    let (tc, mean) = (f("/t_c_s"), f("/hochmuth1979/mean_t_c_s"));
    eprintln!(
        "calibrated: t_c {tc:.4} s against Hochmuth {mean:.4} s, λ0 {:.3}",
        f("/lambda_0")
    );
    assert_eq!(f("/membrane_viscosity_pa_s_m"), 4.74e-7);
    assert!((tc / mean - 1.0).abs() < 0.3, "t_c {tc} against Hochmuth's {mean}");
    assert!(f("/lambda_0") > 2.3 && f("/lambda_0") < 2.8, "λ0 {}", f("/lambda_0"));
    assert!(f("/max_abs_area_deviation") < 0.01 && f("/max_abs_volume_deviation") < 0.01);
}

/// A run stopped during the recovery (after every force) resumes by redoing the release, and
/// ends with the uninterrupted run's results bit for bit; bad `[recovery]` values are refused
/// with the key and what is allowed.
#[test]
fn recovery_interrupted_and_resumed_and_bad_values() {
    use hemodpd_scenario::{RunContext, RunError};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/recovery.toml");
    let sets = |extra: &[&str]| -> Vec<String> {
        [
            "membrane.vertices=200",
            "recovery.duration_s=0.1",
            "recovery.samples=20",
        ]
        .iter()
        .chain(extra)
        .map(|s| s.to_string())
        .collect()
    };
    let s = hemodpd_scenario::load(&path, &sets(&[])).unwrap();
    let a = tempfile::tempdir().unwrap();
    let full = hemodpd_scenario::run(&s, &RunContext::new(a.path(), 1, false)).unwrap();
    let b = tempfile::tempdir().unwrap();
    let mut ctx = RunContext::new(b.path(), 1, false);
    ctx.stop_at_step = Some(4);
    match hemodpd_scenario::run(&s, &ctx) {
        Err(RunError::Interrupted { step: 4, .. }) => {}
        other => panic!("expected an interrupt in the release, got {other:?}"),
    }
    assert!(!b.path().join("recovery.csv").exists());
    let (_, resumed) = hemodpd_scenario::resume(b.path(), &RunContext::new(b.path(), 2, false)).unwrap();
    assert_eq!(full["recovery"], resumed["recovery"]);
    assert_eq!(
        std::fs::read(a.path().join("recovery.csv")).unwrap(),
        std::fs::read(b.path().join("recovery.csv")).unwrap()
    );
    // a finished run says so
    assert!(matches!(
        hemodpd_scenario::resume(b.path(), &RunContext::new(b.path(), 1, false)),
        Err(RunError::Finished { done: 4, total: 5, .. })
    ));
    for (set, wanted) in [
        ("recovery.samples=2", "recovery.samples"),
        ("recovery.duration_s=-1.0", "recovery.duration_s"),
        ("recovery.membrane_viscosity_pa_s_m=0.0", "never settles"),
        ("recovery.inertia_fraction=0.5", "recovery.inertia_fraction"),
        ("membrane.max_extension_ratio=7.0", "membrane.max_extension_ratio"),
    ] {
        let extra: &[&str] = if set.contains("membrane_viscosity") {
            &[set, "recovery.medium_viscosity_pa_s=0.0"]
        } else {
            &[set]
        };
        let err = hemodpd_scenario::load(&path, &sets(extra)).unwrap_err().to_string();
        assert!(err.contains(wanted), "{set}: {err}");
    }
}
