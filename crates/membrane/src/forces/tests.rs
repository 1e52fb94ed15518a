//! Tests of the membrane energy and forces: finite-difference gradients of every term, the
//! golden N = 500 energies, the stress-free reference at rest, and the moduli of Eqs. 10–11.

use super::kernels;
use super::*;
use crate::mesh::{Mesh, Topology};
use crate::params::ModelParams;
use glam::DVec3;
use std::collections::HashMap;

// ---------------------------------------------------------------------------------------------
// Helpers

/// Deterministic uniform deviates in [-1, 1) (splitmix64).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
    fn vec(&mut self) -> DVec3 {
        DVec3::new(self.next(), self.next(), self.next())
    }
}

/// Icosahedron subdivided `levels` times, projected on a sphere of radius `radius`.
pub(crate) fn icosphere(levels: usize, radius: f64) -> Mesh {
    let phi = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v: Vec<DVec3> = Vec::new();
    for &(s1, s2) in &[(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
        v.push(DVec3::new(0.0, s1, s2 * phi));
        v.push(DVec3::new(s1, s2 * phi, 0.0));
        v.push(DVec3::new(s2 * phi, 0.0, s1));
    }
    // faces: every triple at mutual distance 2, oriented outward
    let mut t: Vec<[u32; 3]> = Vec::new();
    for i in 0..12 {
        for j in i + 1..12 {
            for k in j + 1..12 {
                let close = |a: usize, b: usize| ((v[a] - v[b]).length() - 2.0).abs() < 1e-9;
                if close(i, j) && close(j, k) && close(i, k) {
                    let n = (v[j] - v[i]).cross(v[k] - v[i]);
                    if n.dot(v[i] + v[j] + v[k]) > 0.0 {
                        t.push([i as u32, j as u32, k as u32]);
                    } else {
                        t.push([i as u32, k as u32, j as u32]);
                    }
                }
            }
        }
    }
    assert_eq!(t.len(), 20);
    for _ in 0..levels {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut nt = Vec::with_capacity(t.len() * 4);
        for tri in &t {
            let mut m = [0u32; 3];
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let key = (a.min(b), a.max(b));
                m[k] = *mid.entry(key).or_insert_with(|| {
                    v.push(0.5 * (v[a as usize] + v[b as usize]));
                    (v.len() - 1) as u32
                });
            }
            nt.push([tri[0], m[0], m[2]]);
            nt.push([tri[1], m[1], m[0]]);
            nt.push([tri[2], m[2], m[1]]);
            nt.push([m[0], m[1], m[2]]);
        }
        t = nt;
    }
    let v = v.into_iter().map(|p| p.normalize() * radius).collect();
    Mesh::new(v, t).unwrap()
}

fn golden_dir() -> String {
    concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/membrane_golden/").to_string()
}

fn read_csv_rows(path: &str) -> Vec<Vec<f64>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    text.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split(',').map(|s| s.trim().parse::<f64>().unwrap()).collect())
        .collect()
}

/// The golden N = 500 mesh: (topology, rest positions, perturbed positions, JSON). It ships
/// with the repository: a missing file fails the test (no skip path).
pub(crate) fn golden() -> (Topology, Vec<DVec3>, Vec<DVec3>, serde_json::Value) {
    let dir = golden_dir();
    // the data ships with the repository (tests/data/membrane_golden): its absence is a failure
    assert!(std::path::Path::new(&dir).exists(), "golden data not found at {dir}");
    let to_v = |rows: Vec<Vec<f64>>| {
        rows.into_iter()
            .map(|r| DVec3::new(r[0], r[1], r[2]))
            .collect::<Vec<_>>()
    };
    let x = to_v(read_csv_rows(&format!("{dir}mesh_N500.vertices.csv")));
    let xp = to_v(read_csv_rows(&format!("{dir}mesh_N500.perturbed.vertices.csv")));
    let tris: Vec<[u32; 3]> = read_csv_rows(&format!("{dir}mesh_N500.triangles.csv"))
        .into_iter()
        .map(|r| [r[0] as u32, r[1] as u32, r[2] as u32])
        .collect();
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(format!("{dir}golden_energies_N500_uniform.json")).unwrap())
            .unwrap();
    let topo = Topology::new(x.len(), &tris).unwrap();
    (topo, x, xp, json)
}

/// The golden file's constants (µm, pN, pN·µm). The JSON prints L0 = 0.51817 µm, p = 1.08554 nm,
/// θ0 = 6.909° and C = 0.103263 pN·µm³, rounded: the unrounded Eq. 8/9/12 values
/// (L0 = 0.5181735 µm, p = 1.0855438 nm, θ0 = 6.90898°) give C = 0.1032630 (Eq. 4) and
/// reproduce the energies to 1e-13, the rounded ones give C = 0.1032613 and 2e-5 errors.
fn golden_constants() -> MembraneConstants {
    constants_um(500, 1e-3, 1e3)
}

/// Constants of level `n` in µm / pN·µm with the given k_a, k_v (SI).
fn constants_um(n: usize, ka: f64, kv: f64) -> MembraneConstants {
    MembraneConstants::from_params(&ModelParams::coarse_grained(n, 300.0).unwrap(), 1e-6, 1e-18, ka, kv)
}

fn forces(model: &MembraneModel, x: &[DVec3], terms: TermSet) -> (Vec<DVec3>, EnergyTerms) {
    let mut f = vec![DVec3::ZERO; x.len()];
    let e = model.add_forces_terms(x, &mut f, terms).unwrap();
    (f, e)
}

/// Result of a finite-difference comparison.
#[derive(Debug)]
struct FdReport {
    /// |f_fd − f| / |f| over the whole force vector.
    norm_rel: f64,
    /// Largest per-component relative error among components with |f| > 1e-2 max|f|.
    comp_rel: f64,
    /// Largest per-component absolute error over max|f| (all components).
    comp_abs: f64,
    /// max |f| component.
    fmax: f64,
}

/// Central 4-point finite differences of the energy, step `h`, versus the analytic force.
/// The 4-point stencil −[8(E(h) − E(−h)) − (E(2h) − E(−2h))]/(12h) has truncation error
/// h⁴/30·E⁽⁵⁾ ~ (h/L)⁴ relative: with h = 1e-3 L that is ~1e-12, while the round-off
/// ε·E/h stays ~1e-10 of the force (a 2-point stencil would need h ~ 1e-6 L and lose 1e-7 to
/// round-off on energies of 10³).
fn fd_check(model: &MembraneModel, x: &[DVec3], terms: TermSet, h: f64) -> FdReport {
    let (f, e) = forces(model, x, terms);
    // energies from add_forces and energy_terms agree
    let e2 = model.energy_terms(x, terms).unwrap();
    assert!(
        (e.total() - e2.total()).abs() <= 1e-12 * e.total().abs().max(1e-300),
        "{e:?} vs {e2:?}"
    );
    let mut y = x.to_vec();
    let mut energy_at = |v: usize, k: usize, d: f64| {
        let old = y[v][k];
        y[v][k] = old + d;
        let en = model.energy_terms(&y, terms).unwrap().total();
        y[v][k] = old;
        en
    };
    let mut fd = vec![DVec3::ZERO; x.len()];
    for v in 0..x.len() {
        for k in 0..3 {
            let d1 = energy_at(v, k, h) - energy_at(v, k, -h);
            let d2 = energy_at(v, k, 2.0 * h) - energy_at(v, k, -2.0 * h);
            fd[v][k] = -(8.0 * d1 - d2) / (12.0 * h);
        }
    }
    let num: f64 = f
        .iter()
        .zip(&fd)
        .map(|(a, b)| (*a - *b).length_squared())
        .sum::<f64>()
        .sqrt();
    let den: f64 = f.iter().map(|a| a.length_squared()).sum::<f64>().sqrt();
    let fmax = f.iter().map(|a| a.abs().max_element()).fold(0.0, f64::max);
    let (mut comp_rel, mut comp_abs): (f64, f64) = (0.0, 0.0);
    for (a, b) in f.iter().zip(&fd) {
        for k in 0..3 {
            comp_abs = comp_abs.max((a[k] - b[k]).abs() / fmax);
            if a[k].abs() > 1e-2 * fmax {
                comp_rel = comp_rel.max((a[k] - b[k]).abs() / a[k].abs());
            }
        }
    }
    FdReport {
        norm_rel: num / den,
        comp_rel,
        comp_abs,
        fmax,
    }
}

const SINGLE_TERMS: [(&str, TermSet); 6] = [
    (
        "wlc",
        TermSet {
            wlc: true,
            ..TermSet::NONE
        },
    ),
    (
        "c_over_a",
        TermSet {
            c_over_a: true,
            ..TermSet::NONE
        },
    ),
    (
        "bending",
        TermSet {
            bending: true,
            ..TermSet::NONE
        },
    ),
    (
        "area",
        TermSet {
            area: true,
            ..TermSet::NONE
        },
    ),
    (
        "volume",
        TermSet {
            volume: true,
            ..TermSet::NONE
        },
    ),
    ("total", TermSet::ALL),
];

/// Runs the FD check of every term on `x` and asserts the 1e-6 bounds.
fn fd_all_terms(label: &str, model: &MembraneModel, x: &[DVec3], h: f64) {
    for (name, terms) in SINGLE_TERMS {
        let r = fd_check(model, x, terms, h);
        println!(
            "FD {label:<30} {name:<9} |df|/|f| = {:.1e}  component rel = {:.1e}  component abs/max = {:.1e}  (max |f_k| = {:.3e})",
            r.norm_rel, r.comp_rel, r.comp_abs, r.fmax
        );
        assert!(r.fmax > 0.0, "{label} {name}: zero force, the test would prove nothing");
        assert!(r.norm_rel < 1e-6, "{label} {name}: {r:?}");
        assert!(r.comp_rel < 1e-6, "{label} {name}: {r:?}");
        assert!(r.comp_abs < 1e-8, "{label} {name}: {r:?}");
    }
}

// ---------------------------------------------------------------------------------------------
// Finite-difference gradient tests

/// A 42-vertex icosphere with links ≈ L0(N = 500), perturbed; both reference states
/// (stress-free built from a differently perturbed rest mesh, so p_i ≠ p).
#[test]
fn fd_gradients_icosphere() {
    let c = constants_um(500, 1e-3, 1e3);
    let l0 = c.l0;
    // level-1 icosphere: mean link ≈ 0.55 R
    let mesh = icosphere(1, l0 / 0.55);
    let topo = mesh.topology().unwrap();
    let mut rng = Rng(7);
    let rest: Vec<DVec3> = mesh.vertices.iter().map(|p| *p + 0.03 * l0 * rng.vec()).collect();
    let x: Vec<DVec3> = rest.iter().map(|p| *p + 0.05 * l0 * rng.vec()).collect();
    let h = 1e-3 * l0;
    let uni = MembraneModel::new(&topo, &rest, &c, ReferenceState::Uniform).unwrap();
    fd_all_terms("icosphere42 uniform", &uni, &x, h);
    let sf = MembraneModel::new(&topo, &rest, &c, ReferenceState::StressFree).unwrap();
    let d = sf.tension_ratio_distribution();
    println!("icosphere42 stress-free T_i/f_i: {d:?}");
    assert!(d.max - d.min > 1e-3, "rest mesh should not be equilateral");
    fd_all_terms("icosphere42 stress-free", &sf, &x, h);
    // also a strongly folded configuration (bending far from θ0, some concave pairs)
    let y: Vec<DVec3> = rest.iter().map(|p| *p + 0.15 * l0 * rng.vec()).collect();
    fd_all_terms("icosphere42 stress-free rough", &sf, &y, h);
}

/// The golden 500-vertex cell, perturbed, with both reference states.
#[test]
fn fd_gradients_golden_mesh() {
    let (topo, x, xp, _) = golden();
    let c = golden_constants();
    let h = 1e-3 * c.l0;
    let uni = MembraneModel::new(&topo, &x, &c, ReferenceState::Uniform).unwrap();
    fd_all_terms("golden500 uniform", &uni, &xp, h);
    let sf = MembraneModel::new(&topo, &x, &c, ReferenceState::StressFree).unwrap();
    fd_all_terms("golden500 stress-free", &sf, &xp, h);
}

// ---------------------------------------------------------------------------------------------
// Golden energies

#[test]
fn golden_energies_n500_uniform() {
    let (topo, x, xp, json) = golden();
    let c = golden_constants();
    let num = |v: &serde_json::Value| v.as_f64().unwrap();
    let area0 = num(&json["A0_um2"]);
    let volume0 = num(&json["V0_um3"]);
    // A0, V0 of the mesh as we compute them
    assert!((crate::mesh::area_of(&x, &topo.triangles) / area0 - 1.0).abs() < 1e-14);
    assert!((crate::mesh::volume_of(&x, &topo.triangles) / volume0 - 1.0).abs() < 1e-14);
    // the JSON's (rounded) parameters
    assert!((c.kbt - 4.141947e-3).abs() < 1e-15);
    assert!((c.l0 - 0.51817).abs() < 0.5e-5 && (c.persistence_length - 1.08554e-3).abs() < 0.5e-8);
    assert!((c.theta0_rad.to_degrees() - 6.909).abs() < 0.5e-3);
    // C of Eq. 4: the JSON prints 0.103263 (6 digits)
    let cc = c.c_eq4_for(c.l0);
    println!("C (Eq. 4, unrounded L0 and p) = {cc:.10} pN um^3");
    assert!((cc - 0.103263).abs() < 0.5e-6, "C = {cc}");

    let model = MembraneModel::uniform(&topo, &c, area0, volume0).unwrap();
    let scale = 1000.0; // energies are O(10^3) pN·µm: absolute floor for the terms that vanish
    let check = |label: &str, got: EnergyTerms, want: &serde_json::Value| {
        let pairs = [
            ("wlc", got.wlc, num(&want["wlc"])),
            ("C_over_A", got.c_over_a, num(&want["C_over_A"])),
            ("bending", got.bending, num(&want["bending"])),
            ("area", got.area, num(&want["area"])),
            ("volume", got.volume, num(&want["volume"])),
        ];
        for (name, g, w) in pairs {
            let err = (g - w).abs();
            let rel = err / w.abs().max(1e-300);
            println!("golden {label:<10} {name:<9} ours {g:.15e} golden {w:.15e} rel {rel:.1e}");
            assert!(
                err <= 1e-10 * w.abs() || err <= 1e-15 * scale,
                "{label} {name}: {g} vs {w}"
            );
        }
    };
    check("at_mesh", model.energy(&x).unwrap(), &json["at_mesh"]);
    let (f, e) = forces(&model, &xp, TermSet::ALL);
    check("perturbed", e, &json["perturbed"]);
    let f0 = &json["perturbed_force_on_vertex0_pN"];
    let want0 = DVec3::new(num(&f0[0]), num(&f0[1]), num(&f0[2]));
    let err0 = (f[0] - want0).length() / want0.length();
    // "perturbed_max_abs_vertex_force_pN" is the largest |component| (max |f_v,k|), not the
    // largest vector norm (6.4196 pN here): only the former matches, to 1e-15.
    let fmax = f.iter().map(|v| v.abs().max_element()).fold(0.0, f64::max);
    let want_max = num(&json["perturbed_max_abs_vertex_force_pN"]);
    println!("golden force on vertex 0 {:?} vs {want0:?}: rel {err0:.1e}", f[0]);
    println!(
        "golden max |f_k| {fmax:.15e} vs {want_max:.15e}: rel {:.1e}",
        (fmax / want_max - 1.0).abs()
    );
    println!(
        "(largest vertex-force norm: {:.6} pN)",
        f.iter().map(|v| v.length()).fold(0.0, f64::max)
    );
    assert!(err0 < 1e-10);
    assert!((fmax / want_max - 1.0).abs() < 1e-10);
}

// ---------------------------------------------------------------------------------------------
// Stress-free reference

/// The in-plane force of the stress-free model vanishes at rest to round-off; the uniform
/// model's does not.
#[test]
fn stress_free_has_no_in_plane_force_at_rest() {
    let (topo, x, _, _) = golden();
    let c = golden_constants();
    // single-link force scale: the nominal WLC tension at L0, kBT/p·[1/(4(1−x0)²) − 1/4 + x0]
    let x0 = c.x0();
    let f_link = c.kbt / c.persistence_length * (0.25 / (1.0 - x0).powi(2) - 0.25 + x0);
    println!("single-link tension scale f_link = {f_link:.4} pN");

    let sf = MembraneModel::stress_free(&topo, &x, &c).unwrap();
    let (f, _) = forces(&sf, &x, TermSet::IN_PLANE);
    let sf_max = f.iter().map(|v| v.length()).fold(0.0, f64::max);
    let uni = MembraneModel::new(&topo, &x, &c, ReferenceState::Uniform).unwrap();
    let (fu, _) = forces(&uni, &x, TermSet::IN_PLANE);
    let uni_max = fu.iter().map(|v| v.length()).fold(0.0, f64::max);
    let uni_rms = (fu.iter().map(|v| v.length_squared()).sum::<f64>() / fu.len() as f64).sqrt();
    let d = sf.tension_ratio_distribution();
    let l = sf.rest_length_distribution();
    println!(
        "stress-free: max |f_in-plane| at rest = {sf_max:.3e} pN = {:.2e} f_link",
        sf_max / f_link
    );
    println!("uniform:     max |f_in-plane| at rest = {uni_max:.4} pN, rms {uni_rms:.4} pN");
    println!(
        "stress-free T_i/f_i: mean {:.5} min {:.5} max {:.5} rel sd {:.4}",
        d.mean, d.min, d.max, d.rel_sd
    );
    println!(
        "rest link lengths: mean {:.5} um = {:.4} L0, min {:.4} L0, max {:.4} L0, rel sd {:.4}",
        l.mean,
        l.mean / c.l0,
        l.min / c.l0,
        l.max / c.l0,
        l.rel_sd
    );
    // Each vertex sums ~6 link tensions of size f_link that cancel: round-off is a few
    // 1e-16 f_link; 1e-12 leaves three orders of margin and is still 10^9 below the uniform case.
    assert!(sf_max < 1e-12 * f_link, "stress-free in-plane force at rest {sf_max}");
    assert!(uni_max > 1e-2 * f_link, "uniform in-plane force at rest {uni_max}");
    // the distribution measured on this mesh (T_i/f_i = 0.1895 – 1.614): a few links whose
    // opposite angles sum to nearly 180° carry little C/A tension and get a large offset τ_i
    assert!((d.min - 0.18948).abs() < 1e-3 && (d.max - 1.6139).abs() < 1e-3, "{d:?}");
    let mut r = sf.link_tension_ratios().to_vec();
    r.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let q = |p: f64| r[((r.len() - 1) as f64 * p).round() as usize];
    println!(
        "T_i/f_i quantiles: 1% {:.3} 5% {:.3} 50% {:.3} 95% {:.3} 99% {:.3}",
        q(0.01),
        q(0.05),
        q(0.5),
        q(0.95),
        q(0.99)
    );

    // With every term, the only force left at rest is bending (A = A0, V = V0).
    let (fall, e) = forces(&sf, &x, TermSet::ALL);
    let (fb, _) = forces(
        &sf,
        &x,
        TermSet {
            bending: true,
            ..TermSet::NONE
        },
    );
    let diff = fall
        .iter()
        .zip(&fb)
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0, f64::max);
    assert!(diff < 1e-12 * f_link, "{diff}");
    assert!(e.area < 1e-20 && e.volume < 1e-20, "{e:?}");
}

/// An equilateral mesh gives p_i = p exactly, and C_α = the uniform C.
#[test]
fn stress_free_of_an_equilateral_mesh_is_uniform() {
    // the regular icosahedron: every link and triangle equal
    let c = constants_um(500, 1e-3, 1e3);
    let mesh = icosphere(0, 1.0);
    let edge = (mesh.vertices[mesh.triangles[0][0] as usize] - mesh.vertices[mesh.triangles[0][1] as usize]).length();
    let scale = c.l0 / edge;
    let x: Vec<DVec3> = mesh.vertices.iter().map(|p| *p * scale).collect();
    let topo = mesh.topology().unwrap();
    let sf = MembraneModel::stress_free(&topo, &x, &c).unwrap();
    let uni = MembraneModel::new(&topo, &x, &c, ReferenceState::Uniform).unwrap();
    for r in sf.link_tension_ratios() {
        assert!((r - 1.0).abs() < 1e-13, "{r}");
    }
    for t in sf.link_tension_offsets() {
        assert!(t.abs() < 1e-12, "{t}");
    }
    for (a, b) in sf.triangle_c().iter().zip(uni.triangle_c()) {
        assert!((a / b - 1.0).abs() < 1e-13);
    }
    let ea = sf.energy(&x).unwrap();
    let eb = uni.energy(&x).unwrap();
    assert!((ea.total() / eb.total() - 1.0).abs() < 1e-13);
    // and the uniform model of an equilateral mesh of side L0 is itself force-free in-plane
    let (f, _) = forces(&uni, &x, TermSet::IN_PLANE);
    let fm = f.iter().map(|v| v.length()).fold(0.0, f64::max);
    assert!(fm < 1e-13, "{fm}");
}

#[test]
fn stress_free_rejects_badly_shaped_meshes() {
    let c = constants_um(500, 1e-3, 1e3);
    let mesh = icosphere(1, c.l0 / 0.55);
    let topo = mesh.topology().unwrap();
    let mut x = mesh.vertices.clone();
    // squash one vertex towards a neighbour: its triangles get very obtuse/skinny
    let l = topo.links[0];
    let (a, b) = (l[0] as usize, l[1] as usize);
    x[a] = x[b] + 0.05 * (x[a] - x[b]);
    let err = MembraneModel::stress_free(&topo, &x, &c).unwrap_err();
    println!("badly shaped mesh: {err}");
    assert!(matches!(err, ForceError::BadlyShapedMesh { .. }));
}

// ---------------------------------------------------------------------------------------------
// Failures are reported, never clamped

#[test]
fn failures_are_errors() {
    let c = constants_um(500, 1e-3, 1e3);
    let mesh = icosphere(1, c.l0 / 0.55);
    let topo = mesh.topology().unwrap();
    let model = MembraneModel::new(&topo, &mesh.vertices, &c, ReferenceState::StressFree).unwrap();
    let mut f = vec![DVec3::ZERO; mesh.vertices.len()];
    // overstretched link: pull vertex 0 far out
    let mut x = mesh.vertices.clone();
    x[0] *= 5.0;
    let e = model.add_forces(&x, &mut f).unwrap_err();
    assert!(matches!(e, ForceError::LinkOverstretched { .. }), "{e}");
    assert!(matches!(
        model.energy(&x).unwrap_err(),
        ForceError::LinkOverstretched { .. }
    ));
    if let ForceError::LinkOverstretched {
        vertices, length, lmax, ..
    } = e
    {
        assert!(vertices.contains(&0) && length >= lmax);
    }
    // non-finite position
    let mut x = mesh.vertices.clone();
    x[3].y = f64::NAN;
    assert!(matches!(
        model.energy(&x).unwrap_err(),
        ForceError::NonFinitePosition { vertex: 3, .. }
    ));
    // degenerate triangle: collapse one vertex onto another (the link then has length 0)
    let mut x = mesh.vertices.clone();
    let t = topo.triangles[5];
    x[t[0] as usize] = x[t[1] as usize];
    assert!(matches!(
        model.energy(&x).unwrap_err(),
        ForceError::DegenerateTriangle { .. }
    ));
    // wrong lengths
    assert!(matches!(
        model.energy(&x[..5]).unwrap_err(),
        ForceError::WrongLength { .. }
    ));
    let mut short = vec![DVec3::ZERO; 3];
    assert!(matches!(
        model.add_forces(&mesh.vertices, &mut short).unwrap_err(),
        ForceError::WrongLength { .. }
    ));
    // bad constants
    let bad = MembraneConstants {
        persistence_length: 0.0,
        ..c
    };
    assert!(MembraneModel::uniform(&topo, &bad, 1.0, 1.0).is_err());
    let bad = MembraneConstants { lmax_over_l0: 1.0, ..c };
    assert!(MembraneModel::uniform(&topo, &bad, 1.0, 1.0).is_err());
}

#[test]
fn add_forces_adds() {
    let c = constants_um(500, 1e-3, 1e3);
    let mesh = icosphere(1, c.l0 / 0.55);
    let topo = mesh.topology().unwrap();
    let model = MembraneModel::new(&topo, &mesh.vertices, &c, ReferenceState::Uniform).unwrap();
    let mut rng = Rng(3);
    let x: Vec<DVec3> = mesh.vertices.iter().map(|p| *p + 0.02 * rng.vec()).collect();
    let (f, _) = forces(&model, &x, TermSet::ALL);
    let mut g = vec![DVec3::ONE; x.len()];
    model.add_forces(&x, &mut g).unwrap();
    for (a, b) in f.iter().zip(&g) {
        assert!((*b - *a - DVec3::ONE).length() < 1e-12);
    }
    // total force and torque vanish (translation and rotation invariance)
    let ft: DVec3 = f.iter().copied().sum();
    let tt: DVec3 = x.iter().zip(&f).map(|(p, q)| p.cross(*q)).sum();
    let fs: f64 = f.iter().map(|v| v.length()).sum();
    assert!(ft.length() < 1e-12 * fs && tt.length() < 1e-12 * fs, "{ft} {tt}");
}

#[test]
fn reference_state_serde_names() {
    assert_eq!(serde_json::to_string(&ReferenceState::Uniform).unwrap(), "\"uniform\"");
    assert_eq!(
        serde_json::to_string(&ReferenceState::StressFree).unwrap(),
        "\"stress-free\""
    );
    let r: ReferenceState = serde_json::from_str("\"stress-free\"").unwrap();
    assert_eq!(r, ReferenceState::StressFree);
}

#[test]
fn constants_from_params_units() {
    let p = ModelParams::coarse_grained(500, 300.0).unwrap();
    let c = MembraneConstants::from_params(&p, 1e-6, 1e-18, 1e-3, 1e3);
    assert!((c.kbt - 4.141947e-3).abs() < 1e-12);
    assert!((c.l0 / 0.51817 - 1.0).abs() < 1e-4);
    assert!((c.persistence_length / 1.08554e-3 - 1.0).abs() < 1e-5);
    assert!((c.k_area - 1000.0).abs() < 1e-9 && (c.k_volume - 1000.0).abs() < 1e-9);
    assert!((c.theta0_rad.to_degrees() - p.theta0_deg).abs() < 1e-12);
    // C of Eq. 4 in pN·µm³ equals the SI value (J·m²) / 1e-30
    assert!((c.c_eq4_for(c.l0) / (p.c_j_m2 / 1e-30) - 1.0).abs() < 1e-12);
}

// ---------------------------------------------------------------------------------------------
// Moduli (Eqs. 10, 11) on a flat periodic equilateral patch

/// A periodic triangular lattice of `nx × ny` vertices (ny even) with side `l0`: the reference
/// link vectors and triangle edge vectors (b − a, c − a), with their vertex indices.
struct PeriodicPatch {
    n: usize,
    links: Vec<(usize, usize, DVec3)>,
    triangles: Vec<(usize, usize, usize, DVec3, DVec3)>,
    area: f64,
}

fn periodic_patch(nx: usize, ny: usize, l0: f64) -> PeriodicPatch {
    assert!(ny.is_multiple_of(2));
    let h = 3f64.sqrt() / 2.0 * l0;
    let id = |i: isize, j: isize| (i.rem_euclid(nx as isize) as usize) + nx * (j.rem_euclid(ny as isize) as usize);
    // position in the unwrapped plane
    let pos = |i: isize, j: isize| DVec3::new((i as f64 + 0.5 * (j.rem_euclid(2) as f64)) * l0, j as f64 * h, 0.0);
    let mut links = Vec::new();
    let mut triangles = Vec::new();
    for j in 0..ny as isize {
        for i in 0..nx as isize {
            // up-right and up-left neighbours
            let (ri, li) = if j % 2 == 0 { (i, i - 1) } else { (i + 1, i) };
            let p = pos(i, j);
            let pr = pos(i + 1, j);
            let pur = pos(ri, j + 1);
            let pul = pos(li, j + 1);
            links.push((id(i, j), id(i + 1, j), pr - p));
            links.push((id(i, j), id(ri, j + 1), pur - p));
            links.push((id(i, j), id(li, j + 1), pul - p));
            triangles.push((id(i, j), id(i + 1, j), id(ri, j + 1), pr - p, pur - p));
            triangles.push((id(i, j), id(ri, j + 1), id(li, j + 1), pur - p, pul - p));
        }
    }
    PeriodicPatch {
        n: nx * ny,
        links,
        triangles,
        area: nx as f64 * l0 * ny as f64 * h,
    }
}

/// In-plane energy (WLC + C/A) of the patch under the homogeneous deformation `f` (2×2 in
/// the xy plane), with the model kernels; also returns the largest net force on a vertex.
fn patch_energy(p: &PeriodicPatch, f: glam::DMat3, lmax: f64, w: f64, c: f64) -> (f64, f64) {
    let mut e = 0.0;
    let mut force = vec![DVec3::ZERO; p.n];
    for &(a, b, d) in &p.links {
        let dd = f * d;
        let l = dd.length();
        let (v, t) = kernels::wlc(l, lmax, w).unwrap();
        e += v;
        force[a] += dd * (t / l);
        force[b] -= dd * (t / l);
    }
    for &(a, b, cc, u, v) in &p.triangles {
        let (pa, pb, pc) = (DVec3::ZERO, f * u, f * v);
        let n = (pb - pa).cross(pc - pa);
        let area = 0.5 * n.length();
        e += c / area;
        let g = kernels::area_gradient(n / n.length(), pa, pb, pc);
        let coef = c / (area * area);
        force[a] += g[0] * coef;
        force[b] += g[1] * coef;
        force[cc] += g[2] * coef;
    }
    (e, force.iter().map(|v| v.length()).fold(0.0, f64::max))
}

/// Measured moduli of the patch: (μ0, K, isotropic tension at rest), energy per reference area.
fn measure_moduli(l0: f64, lmax: f64, w: f64, c: f64, eps: f64) -> (f64, f64, f64, f64) {
    let p = periodic_patch(8, 8, l0);
    let e = |f: glam::DMat3| patch_energy(&p, f, lmax, w, c);
    let (e0, f0) = e(glam::DMat3::IDENTITY);
    // pure shear, area-preserving: diag(e^ε, e^−ε): W = 2 μ ε² + O(ε⁴) after symmetrising
    let shear = |s: f64| glam::DMat3::from_diagonal(DVec3::new(s.exp(), (-s).exp(), 1.0));
    let (ep, fp) = e(shear(eps));
    let (em, _) = e(shear(-eps));
    let mu = (ep + em - 2.0 * e0) / 2.0 / p.area / (2.0 * eps * eps);
    // isotropic dilation (1+ε)I: W = (K/2)(ΔA/A)² + τ ΔA/A, ΔA/A = 2ε + ε²
    let dil = |s: f64| glam::DMat3::from_diagonal(DVec3::new(1.0 + s, 1.0 + s, 1.0));
    let (dp, fd) = e(dil(eps));
    let (dm, _) = e(dil(-eps));
    let k = (dp + dm - 2.0 * e0) / 2.0 / p.area / (2.0 * eps * eps);
    let tension = (dp - dm) / (2.0 * eps) / p.area / 2.0; // dW/d(ΔA/A) at rest
    (mu, k, tension, f0.max(fp).max(fd))
}

/// μ0 and K of Eqs. 10–11 against the response of a flat periodic equilateral patch (side L0,
/// the paper's uniform reference, C from Eq. 4), at N = 500 and N = 5000 in µm / pN, with the
/// paper's Lmax/L0 = 3.17 and with the stiffer 2.2 (`cell.max_extension_ratio`).
#[test]
fn moduli_of_a_flat_patch_match_eqs_10_11() {
    for (n, ratio) in [(500, 3.17), (5000, 3.17), (23867, 3.17), (500, 2.2), (5000, 1.8)] {
        let params = ModelParams::coarse_grained(n, 300.0)
            .unwrap()
            .with_max_extension(ratio)
            .unwrap();
        assert!((params.lmax_m / params.l0_m - ratio).abs() < 1e-12);
        let c = MembraneConstants::from_params(&params, 1e-6, 1e-18, 0.0, 0.0);
        let lmax = c.lmax_over_l0 * c.l0;
        let w = c.kbt / (4.0 * c.persistence_length);
        let cc = c.c_eq4_for(c.l0);
        let (mu, k, tension, fres) = measure_moduli(c.l0, lmax, w, cc, 1e-4);
        let mu_eq = params.shear_modulus_n_per_m * 1e6; // N/m → pN/µm
        let k_eq = params.area_modulus_n_per_m * 1e6;
        let y = 4.0 * k * mu / (k + mu);
        println!(
            "N = {n:5}, Lmax/L0 = {ratio}: measured mu0 = {mu:.4} pN/um (Eq. 10: {mu_eq:.4}, ratio - 1 = {:.1e}), K = {k:.4} pN/um (Eq. 11: {k_eq:.4}, ratio - 1 = {:.1e}), Y = {y:.4}, tension at rest {tension:.1e} pN/um, max vertex force {fres:.1e} pN",
            mu / mu_eq - 1.0,
            k / k_eq - 1.0
        );
        // Eq. 4 makes the patch tension-free, and a Bravais lattice has no non-affine relaxation.
        // The central difference (W(ε) − W(−ε))/(2ε) carries an O(K ε²) = 2e-7 pN/µm
        // truncation error from the cubic term of W: bound it by 10 K ε².
        assert!(tension.abs() < 10.0 * k * 1e-8, "tension {tension}");
        assert!(fres < 1e-10, "net vertex force {fres}");
        // the symmetrised second difference is exact to O(ε²) = 1e-8; round-off of the
        // energy (~1e-14 relative, E/(A μ ε²) ~ 1e8 amplification) adds ~1e-6: assert 1e-4
        // (Eqs. 10–11 hold exactly for this lattice, the brief asked for 5 %)
        assert!((mu / mu_eq - 1.0).abs() < 1e-4, "mu {mu} vs {mu_eq}");
        assert!((k / k_eq - 1.0).abs() < 1e-4, "K {k} vs {k_eq}");
    }
}

/// The same patch with the uniform L0 but links 7.9 % longer (the golden relaxed mesh's mean),
/// i.e. the pre-stressed uniform model, and with Table I's C (≈ 4 × Eq. 4): figures for docs.
#[test]
fn moduli_of_prestressed_patches() {
    let params = ModelParams::coarse_grained(500, 300.0).unwrap();
    let c = MembraneConstants::from_params(&params, 1e-6, 1e-18, 0.0, 0.0);
    let lmax = c.lmax_over_l0 * c.l0;
    let w = c.kbt / (4.0 * c.persistence_length);
    let cc = c.c_eq4_for(c.l0);
    let (mu, k, tension, _) = measure_moduli(1.0794 * c.l0, lmax, w, cc, 1e-4);
    // with an isotropic pre-tension τ the symmetrised dilation difference measures K + τ/2
    println!(
        "uniform L0, links at 1.0794 L0: mu = {mu:.3} pN/um, K = {:.3} pN/um, isotropic tension {tension:.3} pN/um",
        k - tension / 2.0
    );
    assert!(tension > 0.0);
    // stress-free side length with Table I's C (1.81e-34 J m² at N = 23867 is 3.99 × Eq. 4):
    // (3/2) f_WLC(L) = 8 C / (√3 L³), solved by bisection in x = L/Lmax
    let fine = ModelParams::coarse_grained(23867, 300.0).unwrap();
    let ratio = 1.81e-34 / fine.c_j_m2;
    let balance = |x: f64| 1.5 * w * kernels::wlc_dg(x) - 8.0 * ratio * cc / (3f64.sqrt() * (x * lmax).powi(3));
    let (mut lo, mut hi) = (0.05, 0.99);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if balance(mid) < 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let l_table = lo * lmax / c.l0;
    println!("Table I C = {ratio:.3} x Eq. 4: stress-free equilateral side = {l_table:.4} L0");
    assert!((l_table - 1.36).abs() < 0.01);
}

/// Area and volume deviations at 0–200 pN stretching for a few (k_a, k_v), with the
/// stretching solver (`cargo test -p hemodpd-membrane ka_kv -- --ignored --nocapture`).
/// The figures behind the defaults in docs/model.md, asserted:
/// - the requirements the defaults were chosen for (docs/model.md §5): |ΔA/A0|, |ΔV/V0| within
///   0.1 % at rest (stress-free reference; 1 % for the uniform one) and 1 % at 200 pN, for every
///   pair in the table (the weakest, the golden file's 1000/1000, measured 4.5e-3 at 200 pN);
/// - a stiffer constraint never gives a larger deviation of its own quantity (a penalty
///   k(ΔA)²/A0 with a larger k holds A closer to A0 for the same load; 1e-6 absolute slack for
///   the solver's tolerance);
/// - the diameters depend on (k_a, k_v) by less than 0.05 µm at 200 pN (docs/model.md; the
///   constraints act on the global area and volume, not on the in-plane shear that sets D_A);
/// - D_A grows and D_T shrinks with the force (the cell stretches).
#[test]
#[ignore]
fn ka_kv_choice_under_stretching() {
    let (topo, x, _, _) = golden();
    let params = ModelParams::coarse_grained(500, 300.0).unwrap();
    let (d_a, d_t) = crate::stretch::diameters(&x);
    println!("rest mesh: D_A {d_a:.3} D_T {d_t:.3} um");
    // per reference state: rows of (k_a, k_v, |dA/A0| at 0, |dV/V0| at 0, at 200, at 200, D_A, D_T at 200)
    let mut rows: Vec<(ReferenceState, [f64; 8])> = Vec::new();
    for (ka, kv) in [
        (1e-3, 1e3),
        (DEFAULT_K_AREA_N_PER_M, DEFAULT_K_VOLUME_N_PER_M2),
        (5e-3, 5e3),
    ] {
        let c = MembraneConstants::from_params(&params, 1e-6, 1e-18, ka, kv);
        for reference in [ReferenceState::StressFree, ReferenceState::Uniform] {
            let model = MembraneModel::new(&topo, &x, &c, reference).unwrap();
            let opts = crate::stretch::StretchOptions {
                forces: vec![0.0, 50.0, 100.0, 150.0, 200.0],
                end_fraction: 0.05,
                tolerance: 1e-4,
                max_iterations: 200_000,
                preconditioning: Default::default(),
            };
            let t = std::time::Instant::now();
            let pts = crate::stretch::stretch(&model, &x, &opts, |_| {}).unwrap();
            for p in &pts {
                println!(
                    "k_a {:6.0} pN/um k_v {:6.0} pN/um^2 {reference:?}: F {:5.0} pN  D_A {:.3} D_T {:.3} um  dA/A0 {:+.3e}  dV/V0 {:+.3e}  ({} it)",
                    c.k_area, c.k_volume, p.force, p.axial_diameter, p.transverse_diameter, p.area_deviation, p.volume_deviation, p.iterations
                );
            }
            println!("  ({:.1} s)", t.elapsed().as_secs_f64());
            for w in pts.windows(2) {
                assert!(
                    w[1].axial_diameter > w[0].axial_diameter && w[1].transverse_diameter < w[0].transverse_diameter,
                    "{reference:?} k_a {ka}: the cell does not stretch monotonically: {:?} -> {:?}",
                    (w[0].force, w[0].axial_diameter, w[0].transverse_diameter),
                    (w[1].force, w[1].axial_diameter, w[1].transverse_diameter)
                );
            }
            let (rest, end) = (&pts[0], &pts[4]);
            rows.push((
                reference,
                [
                    ka,
                    kv,
                    rest.area_deviation.abs(),
                    rest.volume_deviation.abs(),
                    end.area_deviation.abs(),
                    end.volume_deviation.abs(),
                    end.axial_diameter,
                    end.transverse_diameter,
                ],
            ));
        }
    }
    for reference in [ReferenceState::StressFree, ReferenceState::Uniform] {
        let r: Vec<[f64; 8]> = rows.iter().filter(|(s, _)| *s == reference).map(|(_, v)| *v).collect();
        // the 0.1 % at rest holds for the stress-free reference the defaults were chosen for;
        // the uniform reference's own in-plane tension at rest compresses the area (measured
        // 2.6e-3 at k_a = 1000 pN/µm), so it gets the 1 % bound there too
        let rest_bound = if reference == ReferenceState::StressFree {
            1e-3
        } else {
            1e-2
        };
        for v in &r {
            assert!(
                v[2] < rest_bound && v[3] < rest_bound,
                "{reference:?} k_a {} k_v {}: at rest {v:?}",
                v[0],
                v[1]
            );
            assert!(
                v[4] < 1e-2 && v[5] < 1e-2,
                "{reference:?} k_a {} k_v {}: at 200 pN {v:?}",
                v[0],
                v[1]
            );
        }
        // rows are in increasing k_a (and non-decreasing k_v). A stiffer penalty holds its own
        // quantity closer: the area deviation falls with k_a, the volume deviation with k_v. (Not
        // across quantities: a tighter area lets the volume give a little more, measured
        // 7.8e-4 -> 8.2e-4 at 200 pN from k_a 1000 to 2000 at k_v 1000.)
        for w in r.windows(2) {
            let cols: &[usize] = if w[1][1] > w[0][1] { &[2, 3, 4, 5] } else { &[2, 4] };
            for &k in cols {
                assert!(
                    w[1][k] <= w[0][k] + 1e-6,
                    "{reference:?}: a stiffer constraint gave a larger deviation (column {k}): {:?} vs {:?}",
                    w[0],
                    w[1]
                );
            }
        }
        let spread = |k: usize| {
            let (lo, hi) = r
                .iter()
                .fold((f64::MAX, f64::MIN), |(lo, hi), v| (lo.min(v[k]), hi.max(v[k])));
            hi - lo
        };
        assert!(
            spread(6) < 0.05 && spread(7) < 0.05,
            "{reference:?}: D_A, D_T at 200 pN vary by {} and {} um across k_a, k_v",
            spread(6),
            spread(7)
        );
    }
}

/// Largest eigenvalue of the Hessian of F at rest (power iteration on finite differences of
/// the forces), with and without the global area/volume terms, and |∇A|², |∇V|²: how much the
/// global constraints stiffen the system (explicit time steps scale as 1/√λ_max).
#[test]
#[ignore]
fn hessian_stiffness_of_constraints() {
    let (topo, x, _, _) = golden();
    let params = ModelParams::coarse_grained(500, 300.0).unwrap();
    let lam_max = |model: &MembraneModel| {
        let n = x.len();
        let mut v: Vec<DVec3> = (0..n)
            .map(|i| DVec3::new((i as f64).sin(), (i as f64 * 1.3).cos(), 0.3))
            .collect();
        let mut lam = 0.0;
        let h = 1e-6;
        for _ in 0..3000 {
            let norm = v.iter().map(|a| a.length_squared()).sum::<f64>().sqrt();
            v.iter_mut().for_each(|a| *a /= norm);
            let xp: Vec<DVec3> = x.iter().zip(&v).map(|(a, b)| *a + *b * h).collect();
            let xm: Vec<DVec3> = x.iter().zip(&v).map(|(a, b)| *a - *b * h).collect();
            let (fp, _) = forces(model, &xp, TermSet::ALL);
            let (fm, _) = forces(model, &xm, TermSet::ALL);
            let hv: Vec<DVec3> = fp.iter().zip(&fm).map(|(a, b)| -(*a - *b) / (2.0 * h)).collect();
            lam = hv.iter().zip(&v).map(|(a, b)| a.dot(*b)).sum::<f64>();
            v = hv;
        }
        lam
    };
    let mut lambdas = Vec::new();
    for (ka, kv) in [
        (0.0, 0.0),
        (1e-3, 1e3),
        (DEFAULT_K_AREA_N_PER_M, DEFAULT_K_VOLUME_N_PER_M2),
        (5e-3, 5e3),
    ] {
        let c = MembraneConstants::from_params(&params, 1e-6, 1e-18, ka, kv);
        let model = MembraneModel::stress_free(&topo, &x, &c).unwrap();
        let lam = lam_max(&model);
        println!(
            "k_a {:.0} pN/um, k_v {:.0} pN/um^2: lambda_max = {:.2} pN/um",
            c.k_area, c.k_volume, lam
        );
        lambdas.push((c.k_area, c.k_volume, lam));
    }
    let c = MembraneConstants::from_params(&params, 1e-6, 1e-18, 1e-3, 1e3);
    let model = MembraneModel::stress_free(&topo, &x, &c).unwrap();
    // |∇A|² and |∇V|² from the kernels
    let (mut ga, mut gv) = (vec![DVec3::ZERO; x.len()], vec![DVec3::ZERO; x.len()]);
    for t in &topo.triangles {
        let [a, b, cc] = t.map(|v| x[v as usize]);
        let n = (b - a).cross(cc - a);
        let g = kernels::area_gradient(n.normalize(), a, b, cc);
        for k in 0..3 {
            ga[t[k] as usize] += g[k];
        }
        gv[t[0] as usize] += b.cross(cc) / 6.0;
        gv[t[1] as usize] += cc.cross(a) / 6.0;
        gv[t[2] as usize] += a.cross(b) / 6.0;
    }
    let na: f64 = ga.iter().map(|v| v.length_squared()).sum();
    let nv: f64 = gv.iter().map(|v| v.length_squared()).sum();
    println!(
        "|grad A|^2 = {na:.3} um^2, |grad V|^2 = {nv:.3} um^4: rank-one stiffness k_a|grad A|^2/A0 = {:.3e} k_a, k_v|grad V|^2/V0 = {:.3e} k_v",
        na / model.area0(),
        nv / model.volume0()
    );
    // At the stress-free rest state (a minimum: A = A0, V = V0) the global terms add the
    // rank-one, positive semi-definite k_a ∇A∇Aᵀ/A0 + k_v ∇V∇Vᵀ/V0 to the membrane's own
    // Hessian H0 (also PSD there). Weyl's inequalities then bound the largest eigenvalue:
    // max(λ0, k_a|∇A|²/A0, k_v|∇V|²/V0) − slack ≤ λ ≤ λ0 + k_a|∇A|²/A0 + k_v|∇V|²/V0 + slack.
    // Power iteration approaches λ from below (a Rayleigh quotient), and the finite-difference
    // Hessian is accurate to ~h²: 2 % slack covers both.
    let (ra, rv) = (na / model.area0(), nv / model.volume0());
    let lam0 = lambdas[0].2;
    // docs/model.md §5: the membrane's own λ_max ≈ 130 pN/µm on this mesh
    assert!(lam0 > 100.0 && lam0 < 160.0, "lambda_max without constraints {lam0}");
    for &(ka, kv, lam) in &lambdas[1..] {
        let lower = lam0.max(ka * ra).max(kv * rv);
        let upper = lam0 + ka * ra + kv * rv;
        assert!(
            lam >= 0.98 * lower && lam <= 1.02 * upper,
            "k_a {ka} k_v {kv}: lambda_max {lam} outside the Weyl bounds [{lower}, {upper}]"
        );
    }
    // stiffer constraints, stiffer system
    for w in lambdas.windows(2) {
        assert!(w[1].2 >= 0.98 * w[0].2, "{:?} -> {:?}", w[0], w[1]);
    }
}

/// The stress-free construction on meshes from `meshgen` (ignored: slow, and depends on the
/// mesh generator): the p_i/p distribution and the in-plane force at rest. A construction that
/// fails is a test failure. Asserted for each mesh: the generator converged; the in-plane force
/// at rest vanishes to round-off (< 1e-12 f_link, as for the golden mesh in
/// `stress_free_has_no_in_plane_force_at_rest`: ~6 link tensions of size f_link cancel at each
/// vertex); every link keeps a positive tension ratio T_i/f_i (a WLC link cannot push).
#[test]
#[ignore]
fn stress_free_on_generated_meshes() {
    let shape = crate::shape::EvansFung::healthy_um();
    for (n, seed) in [(500, 1), (500, 2), (1000, 1), (5000, 1)] {
        let c = constants_um(n, DEFAULT_K_AREA_N_PER_M, DEFAULT_K_VOLUME_N_PER_M2);
        let x0 = c.x0();
        let f_link = c.kbt / c.persistence_length * (0.25 / (1.0 - x0).powi(2) - 0.25 + x0);
        let t = std::time::Instant::now();
        let (mesh, report) =
            crate::meshgen::generate(&shape, &c, &crate::meshgen::MeshGenOptions::new(n, seed)).unwrap();
        let topo = mesh.topology().unwrap();
        let sf = MembraneModel::stress_free(&topo, &mesh.vertices, &c)
            .unwrap_or_else(|e| panic!("N {n} seed {seed}: stress-free construction failed: {e}"));
        let d = sf.tension_ratio_distribution();
        let mut r = sf.link_tension_ratios().to_vec();
        r.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let (f, _) = forces(&sf, &mesh.vertices, TermSet::IN_PLANE);
        let fm = f.iter().map(|v| v.length()).fold(0.0, f64::max);
        println!(
            "N {n} seed {seed} ({:.0} s, {} steps, converged {}): T_i/f_i mean {:.3} min {:.3} max {:.3}, 99% {:.3}, < 0.2: {}, > 2: {}; max |f_in-plane| at rest {fm:.1e} pN",
            t.elapsed().as_secs_f64(),
            report.steps,
            report.converged,
            d.mean,
            d.min,
            d.max,
            r[r.len() * 99 / 100],
            r.iter().filter(|&&v| v < 0.2).count(),
            r.iter().filter(|&&v| v > 2.0).count()
        );
        assert!(report.converged, "N {n} seed {seed}: mesh relaxation did not converge");
        assert!(fm < 1e-12 * f_link, "N {n} seed {seed}: in-plane force at rest {fm} pN");
        assert!(
            d.min > 0.0 && d.min.is_finite() && d.max.is_finite(),
            "N {n} seed {seed}: {d:?}"
        );
    }
}

/// A stretching run split in two (the second part continuing from the first part's last two
/// equilibria) gives the same equilibria bit for bit as one run, and a stop request abandons
/// the force in progress and returns the equilibria reached so far.
#[test]
fn stretching_split_in_two_is_bit_identical() {
    let (topo, x, _, _) = golden();
    let params = ModelParams::coarse_grained(500, 300.0).unwrap();
    let c = MembraneConstants::from_params(&params, 1e-6, 1e-18, DEFAULT_K_AREA_N_PER_M, DEFAULT_K_VOLUME_N_PER_M2);
    let model = MembraneModel::new(&topo, &x, &c, ReferenceState::StressFree).unwrap();
    let opts = |forces: &[f64]| crate::stretch::StretchOptions {
        forces: forces.to_vec(),
        end_fraction: 0.05,
        tolerance: 1e-4,
        max_iterations: 200_000,
        preconditioning: Default::default(),
    };
    let whole = crate::stretch::stretch(&model, &x, &opts(&[0.0, 60.0, 120.0, 180.0]), |_| {}).unwrap();
    let first = crate::stretch::stretch(&model, &x, &opts(&[0.0, 60.0]), |_| {}).unwrap();
    fn eq(p: &crate::stretch::StretchPoint) -> crate::stretch::Equilibrium<'_> {
        crate::stretch::Equilibrium {
            force: p.force,
            positions: &p.positions,
        }
    }
    let second = crate::stretch::stretch_from(
        &model,
        &x,
        &[eq(&first[0]), eq(&first[1])],
        &opts(&[120.0, 180.0]),
        || false,
        |_| {},
    )
    .unwrap();
    let split: Vec<_> = first.into_iter().chain(second).collect();
    assert_eq!(whole, split);
    // stop half-way through the second force: exactly one equilibrium comes back
    let polls = std::cell::Cell::new(0usize);
    let stopped = crate::stretch::stretch_from(
        &model,
        &x,
        &[],
        &opts(&[0.0, 60.0, 120.0]),
        || {
            polls.set(polls.get() + 1);
            polls.get() > whole[0].iterations + 1 + whole[1].iterations / 2
        },
        |_| {},
    )
    .unwrap();
    assert_eq!(stopped.len(), 1);
    assert_eq!(stopped[0], whole[0]);
    let short = crate::stretch::Equilibrium {
        force: 0.0,
        positions: &x[1..],
    };
    assert!(crate::stretch::stretch_from(&model, &x, &[short], &opts(&[0.0]), || false, |_| {}).is_err());
}

/// The stretching model of the golden N = 500 mesh (stress-free, default k_a and k_v).
fn stretching_model() -> (MembraneModel, Vec<DVec3>) {
    let (topo, x, _, _) = golden();
    let params = ModelParams::coarse_grained(500, 300.0).unwrap();
    let c = MembraneConstants::from_params(&params, 1e-6, 1e-18, DEFAULT_K_AREA_N_PER_M, DEFAULT_K_VOLUME_N_PER_M2);
    (
        MembraneModel::new(&topo, &x, &c, ReferenceState::StressFree).unwrap(),
        x,
    )
}

/// The solver at the shipped tolerance (1e-4 pN, with the force predictor), with either
/// preconditioner, gives the diameters of a run converged 1000 times tighter to 1e-3 µm (the
/// accuracy the speed work must keep); the Gauss–Newton preconditioner needs at most a fifth
/// of the plain L-BFGS iterations (N = 500: 139 against 1032 when this was written).
#[test]
fn stretching_diameters_are_converged_to_1e_3_um() {
    use crate::stretch::Preconditioning;
    let (model, x) = stretching_model();
    let opts = |tolerance: f64, preconditioning| crate::stretch::StretchOptions {
        forces: vec![0.0, 30.0, 60.0, 120.0, 200.0],
        end_fraction: 0.05,
        tolerance,
        max_iterations: 200_000,
        preconditioning,
    };
    let tight = crate::stretch::stretch(&model, &x, &opts(1e-7, Preconditioning::GaussNewton), |_| {}).unwrap();
    assert!(tight.iter().all(|p| p.preconditioned));
    let mut iterations = Vec::new();
    for pre in [Preconditioning::GaussNewton, Preconditioning::None] {
        let fast = crate::stretch::stretch(&model, &x, &opts(1e-4, pre), |_| {}).unwrap();
        for (f, t) in fast.iter().zip(&tight) {
            let (da, dt) = (
                f.axial_diameter - t.axial_diameter,
                f.transverse_diameter - t.transverse_diameter,
            );
            assert!(
                da.abs() < 1e-3 && dt.abs() < 1e-3,
                "{pre:?}, F = {}: D_A off by {da:.1e}, D_T by {dt:.1e} µm",
                f.force
            );
            assert_eq!(f.preconditioned, pre == Preconditioning::GaussNewton);
        }
        iterations.push(fast.iter().map(|p| p.iterations).sum::<usize>());
    }
    println!("iterations: Gauss-Newton {}, none {}", iterations[0], iterations[1]);
    assert!(5 * iterations[0] <= iterations[1], "iterations {iterations:?}");
}

/// Stretching with 1 and with 2 threads gives the same equilibria bit for bit (the parallel
/// force evaluation has a fixed partition and summation order).
#[test]
fn stretching_is_bit_identical_for_any_thread_count() {
    let (model, x) = stretching_model();
    let opts = crate::stretch::StretchOptions {
        forces: vec![0.0, 50.0, 100.0],
        end_fraction: 0.05,
        tolerance: 1e-4,
        max_iterations: 200_000,
        preconditioning: Default::default(),
    };
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| crate::stretch::stretch(&model, &x, &opts, |_| {}).unwrap())
    };
    let (one, two) = (run(1), run(2));
    assert_eq!(one, two);
    for (a, b) in one.iter().zip(&two) {
        assert_eq!(a.positions, b.positions);
    }
}
