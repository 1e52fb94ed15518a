//! Analysis metrics against analytic values on synthetic meshes.

mod common;

use std::f64::consts::PI;

use common::*;
use glam::DVec3;
use hemodpd_io::analysis::{
    analyze_file, analyze_frames, area_volume, asphericity, symmetric_eigen3, write_csv, write_json, AnalysisOptions,
    FrameInput, RotationMode, CSV_HEADER,
};
use hemodpd_io::trajectory::{MetaValue, TrajectoryWriter};
use std::path::Path;

fn frames_of<'a>(times: &'a [f64], pos: &'a [Vec<DVec3>]) -> Vec<FrameInput<'a>> {
    times
        .iter()
        .zip(pos)
        .enumerate()
        .map(|(i, (&t, p))| FrameInput {
            step: i as u64,
            time: t,
            positions: p,
            velocities: None,
        })
        .collect()
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * b.abs().max(1e-300)
}

#[test]
fn jacobi_eigen_matches_known_decompositions() {
    let mut noise = Noise(5);
    for _ in 0..200 {
        // Random rotation from three random angles; A = R diag(l) Rᵀ.
        let (a, b, c) = (noise.next() * PI, noise.next() * PI, noise.next() * PI);
        let rx = glam::DMat3::from_rotation_x(a);
        let ry = glam::DMat3::from_rotation_y(b);
        let rz = glam::DMat3::from_rotation_z(c);
        let r = rz * ry * rx;
        let l = [5.0 + noise.next(), 2.0 + noise.next(), -3.0 + noise.next()];
        let m = r * glam::DMat3::from_diagonal(DVec3::from_array(l)) * r.transpose();
        let arr = [
            [m.x_axis.x, m.y_axis.x, m.z_axis.x],
            [m.x_axis.y, m.y_axis.y, m.z_axis.y],
            [m.x_axis.z, m.y_axis.z, m.z_axis.z],
        ];
        let (vals, vecs) = symmetric_eigen3(arr);
        for k in 0..3 {
            assert!((vals[k] - l[k]).abs() < 1e-12, "{vals:?} vs {l:?}");
            let col = [r.x_axis, r.y_axis, r.z_axis][k];
            let e = DVec3::from_array(vecs[k]);
            assert!((e.dot(col).abs() - 1.0).abs() < 1e-10);
            assert!((e.length() - 1.0).abs() < 1e-12);
            // A e = λ e
            assert!((m * e - vals[k] * e).length() < 1e-10);
        }
    }
    // Degenerate and diagonal cases.
    let (v, _) = symmetric_eigen3([[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]]);
    assert_eq!(v, [2.0, 2.0, 2.0]);
    let (v, e) = symmetric_eigen3([[1.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 2.0]]);
    assert_eq!(v, [3.0, 2.0, 1.0]);
    assert_eq!(e[0], [0.0, 1.0, 0.0]);
}

#[test]
fn asphericity_limits() {
    assert_eq!(asphericity([1.0, 1.0, 1.0]), 0.0);
    assert!((asphericity([1.0, 0.0, 0.0]) - 1.0).abs() < 1e-15);
    assert!((asphericity([1.0, 1.0, 0.0]) - 0.25).abs() < 1e-15);
}

#[test]
fn octahedron_exact_area_volume_diameters() {
    let (v, t) = octahedron();
    let (a, vol) = area_volume(&v, &t);
    assert!((a - 4.0 * 3f64.sqrt()).abs() < 1e-14);
    assert!((vol - 4.0 / 3.0).abs() < 1e-14);
    let r = analyze_frames(Path::new("x"), &t, &frames_of(&[0.0], &[v]), None, false, 4).unwrap();
    let m = &r.frames[0];
    assert_eq!(m.axial_diameter, 2.0);
    assert_eq!(m.transverse_diameter, 2.0);
    assert!(m.asphericity < 1e-15, "octahedron surface gyration is isotropic");
    assert_eq!(m.centroid, [0.0; 3]);
}

#[test]
fn ellipsoid_shape_metrics() {
    let (unit, t) = uv_sphere(40, 80);
    let (a, b, c) = (4.0, 2.0, 1.0);
    let theta = 0.3;
    let center = DVec3::new(10.0, -3.0, 2.0);
    let pos = ellipsoid(&unit, DVec3::new(a, b, c), theta, center);
    let r = analyze_frames(Path::new("x"), &t, &frames_of(&[0.0], &[pos]), None, false, 4).unwrap();
    let m = &r.frames[0];
    for k in 0..3 {
        assert!((m.centroid[k] - center[k]).abs() < 1e-12);
    }
    // In the shear plane: long axis at θ, L = 2a, B = 2b (tips are vertices).
    assert!((m.inclination_angle - theta).abs() < 1e-12, "{}", m.inclination_angle);
    assert!(close(m.length, 2.0 * a, 1e-12), "{}", m.length);
    assert!(close(m.width, 2.0 * b, 1e-12), "{}", m.width);
    assert!(close(m.deformation_index, (a - b) / (a + b), 1e-12));
    assert!(close(m.length_over_width, a / b, 1e-12));
    // Principal axes: long axis along (cos θ, sin θ, 0), short along z.
    let e1 = DVec3::from_array(m.principal_axes[0]);
    assert!((e1 - DVec3::new(theta.cos(), theta.sin(), 0.0)).length() < 1e-10);
    assert!((DVec3::from_array(m.principal_axes[2]) - DVec3::Z).length() < 1e-10);
    assert!(m.gyration_eigenvalues[0] > m.gyration_eigenvalues[1]);
    assert!(m.gyration_eigenvalues[1] > m.gyration_eigenvalues[2]);
    // Area and volume of the ellipsoid (Knud Thomsen's area formula is within ~1%; use the
    // volume, exact in the limit, and a fine mesh).
    let vol = 4.0 / 3.0 * PI * a * b * c;
    assert!(close(m.volume, vol, 5e-3), "{} vs {vol}", m.volume);
    let p = 1.6075;
    let area = 4.0 * PI * (((a * b).powf(p) + (a * c).powf(p) + (b * c).powf(p)) / 3.0).powf(1.0 / p);
    assert!(close(m.area, area, 1.5e-2), "{} vs {area}", m.area);
    // Rotated about z by θ the x extent is that of an ellipse: 2·sqrt(a²cos²θ + b²sin²θ) on the
    // mesh up to discretisation; transverse = 2·max(sqrt(y² + z²)) ≥ 2·b.
    let ax = 2.0 * ((a * theta.cos()).powi(2) + (b * theta.sin()).powi(2)).sqrt();
    assert!(close(m.axial_diameter, ax, 5e-3), "{} vs {ax}", m.axial_diameter);
    let ay = 2.0 * ((a * theta.sin()).powi(2) + (b * theta.cos()).powi(2)).sqrt();
    assert!(
        close(m.transverse_diameter, ay, 5e-3),
        "{} vs {ay}",
        m.transverse_diameter
    );

    // A sphere: asphericity ~ 0, DI ~ 0, diameters 2r.
    let r = analyze_frames(
        Path::new("x"),
        &t,
        &frames_of(&[0.0], std::slice::from_ref(&unit)),
        None,
        false,
        4,
    )
    .unwrap();
    let s = &r.frames[0];
    assert!(s.asphericity < 1e-5, "{}", s.asphericity);
    assert!(s.deformation_index.abs() < 1e-12);
    assert!(close(s.axial_diameter, 2.0, 1e-12) && close(s.transverse_diameter, 2.0, 1e-12));
    assert!(close(s.area, 4.0 * PI, 2e-3) && close(s.volume, 4.0 / 3.0 * PI, 5e-3));
}

#[test]
fn velocity_from_finite_differences_and_from_vertices() {
    let (unit, t) = uv_sphere(8, 16);
    let v = DVec3::new(1.5, -0.5, 0.25);
    let times: Vec<f64> = (0..6).map(|i| 0.1 * i as f64 * (1.0 + 0.1 * i as f64)).collect();
    let pos: Vec<Vec<DVec3>> = times
        .iter()
        .map(|&tt| unit.iter().map(|p| *p + v * tt).collect())
        .collect();
    let r = analyze_frames(Path::new("x"), &t, &frames_of(&times, &pos), None, false, 4).unwrap();
    for m in &r.frames {
        assert!((DVec3::from_array(m.velocity) - v).length() < 1e-12);
        assert!(m.area_deviation.abs() < 1e-12 && m.volume_deviation.abs() < 1e-12);
    }
    // With stored velocities the mean vertex velocity is used.
    let vel: Vec<DVec3> = unit.iter().map(|p| *p + DVec3::X).collect();
    let frames: Vec<FrameInput> = (0..2)
        .map(|i| FrameInput {
            step: i,
            time: i as f64,
            positions: &pos[0],
            velocities: Some(&vel),
        })
        .collect();
    let r = analyze_frames(Path::new("x"), &t, &frames, Some((8.0, 2.0)), false, 4).unwrap();
    assert!((DVec3::from_array(r.frames[0].velocity) - DVec3::X).length() < 1e-12);
    // Deviations relative to the given reference.
    let m = &r.frames[1];
    assert!(close(m.area_deviation, (m.area - 8.0) / 8.0, 1e-12));
    assert!(close(m.volume_deviation, (m.volume - 2.0) / 2.0, 1e-12));
}

/// A rigid ellipsoid turning at Ω about z: tumbling rate Ω, no tank-treading.
#[test]
fn tumbling_rate_of_a_rigidly_rotating_ellipsoid() {
    let (unit, t) = uv_sphere(16, 32);
    let omega: f64 = -2.0; // rad/s, clockwise as in shear flow v_x = γ̇ y
    let times: Vec<f64> = (0..121).map(|i| i as f64 * 0.05).collect(); // ~2 turns of the axis
    let pos: Vec<Vec<DVec3>> = times
        .iter()
        .map(|&tt| ellipsoid(&unit, DVec3::new(3.0, 1.5, 1.0), 0.2 + omega * tt, DVec3::ZERO))
        .collect();
    let r = analyze_frames(Path::new("x"), &t, &frames_of(&times, &pos), None, true, 12).unwrap();
    let rot = r.rotation.unwrap();
    assert!(close(rot.tumbling_rate, omega, 1e-9), "{}", rot.tumbling_rate);
    assert!(close(rot.tumbling_frequency, omega.abs() / (2.0 * PI), 1e-9));
    assert!(rot.tank_treading_rate.abs() < 1e-9, "{}", rot.tank_treading_rate);
    assert_eq!(rot.tracked_vertices.len(), 12);
}

/// A still ellipsoid whose material points run around it at Ω: tank-treading rate Ω, no
/// tumbling, constant inclination.
#[test]
fn tank_treading_frequency_of_a_steady_ellipsoid() {
    let (unit, t) = uv_sphere(16, 32);
    let omega: f64 = -3.0;
    let incl = 0.35;
    let turns = 3.0;
    let n = 301;
    let times: Vec<f64> = (0..n)
        .map(|i| i as f64 / (n - 1) as f64 * turns * 2.0 * PI / omega.abs())
        .collect();
    let pos: Vec<Vec<DVec3>> = times
        .iter()
        .map(|&tt| {
            let moved: Vec<DVec3> = unit.iter().map(|u| rot_z(*u, omega * tt)).collect();
            ellipsoid(&moved, DVec3::new(2.0, 1.2, 0.8), incl, DVec3::new(1.0, 2.0, 3.0))
        })
        .collect();
    let r = analyze_frames(Path::new("x"), &t, &frames_of(&times, &pos), None, true, 16).unwrap();
    let rot = r.rotation.unwrap();
    assert!(close(rot.tank_treading_rate, omega, 0.02), "{}", rot.tank_treading_rate);
    assert!(close(rot.tank_treading_frequency, omega.abs() / (2.0 * PI), 0.02));
    assert!(rot.tumbling_rate.abs() < 1e-3, "{}", rot.tumbling_rate);
    assert!((rot.mean_inclination - incl).abs() < 1e-3, "{}", rot.mean_inclination);
    assert!(rot.inclination_amplitude < 1e-3);
    for m in &r.frames {
        assert!((m.inclination_angle - incl).abs() < 1e-3);
    }
}

/// End to end through a file: model units in, SI metrics out; CSV and JSON outputs.
#[test]
fn analyze_file_in_si_with_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("shear.h5");
    let u = units();
    let (unit, t) = uv_sphere(12, 24);
    let meta = meta().with_extra("flow", MetaValue::Str("shear".into()));
    let mut w = TrajectoryWriter::create(&path, &meta).unwrap();
    w.write_mesh(&t).unwrap();
    let omega = -1.0; // per model time unit
    for s in 0..60u64 {
        let time = s as f64 * 0.1;
        let p = ellipsoid(
            &unit,
            DVec3::new(8.0, 4.0, 2.0),
            omega * time,
            DVec3::new(s as f64, 0.0, 0.0),
        );
        w.append_membrane_frame(s * 10, time, &p, None, &[]).unwrap();
    }
    w.close().unwrap();
    let r = analyze_file(&path, &AnalysisOptions::default()).unwrap();
    assert_eq!(r.frames.len(), 60);
    let rot = r.rotation.as_ref().expect("shear run detected from /extra@flow");
    assert!(
        close(rot.tumbling_rate, omega / u.time_s, 1e-9),
        "{}",
        rot.tumbling_rate
    );
    let m = &r.frames[0];
    assert!(close(m.length, 16.0 * u.length_m, 1e-12));
    assert!(close(m.width, 8.0 * u.length_m, 1e-12));
    assert!(
        close(m.velocity[0], 10.0 * u.length_m / u.time_s, 1e-9),
        "{}",
        m.velocity[0]
    );
    assert_eq!(r.frames[7].step, 70);
    let never = AnalysisOptions {
        rotation: RotationMode::Never,
        ..Default::default()
    };
    assert!(analyze_file(&path, &never).unwrap().rotation.is_none());

    let csv = dir.path().join("m.csv");
    write_csv(&csv, &r.frames).unwrap();
    let text = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 61);
    assert_eq!(lines[0], CSV_HEADER);
    let ncol = CSV_HEADER.split(',').count();
    assert!(lines[1..].iter().all(|l| l.split(',').count() == ncol));
    let json = dir.path().join("m.json");
    write_json(&json, &r).unwrap();
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["frames"].as_array().unwrap().len(), 60);
    assert!(v["rotation"]["tumbling_rate"].is_number());

    let pngs = hemodpd_io::analysis::plot_time_series(dir.path().join("plots"), &r).unwrap();
    assert_eq!(pngs.len(), 5);
    for p in pngs {
        assert_eq!(&std::fs::read(&p).unwrap()[..4], b"\x89PNG");
    }
}
