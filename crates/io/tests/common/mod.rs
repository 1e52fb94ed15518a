//! Shared helpers of the io tests: synthetic meshes and metadata.
#![allow(dead_code)]

use glam::DVec3;
use hemodpd_io::{RunMetadata, UnitSystem};

/// A UV sphere of radius 1: poles on ±z, `n_lat` (even) latitude bands so the equator is a ring,
/// `n_lon` (multiple of 4) longitudes so the ±x and ±y tips are vertices. Outward triangles.
pub fn uv_sphere(n_lat: usize, n_lon: usize) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    assert!(n_lat.is_multiple_of(2) && n_lon.is_multiple_of(4));
    let mut v = vec![DVec3::Z];
    for i in 1..n_lat {
        let th = std::f64::consts::PI * i as f64 / n_lat as f64;
        for j in 0..n_lon {
            let ph = 2.0 * std::f64::consts::PI * j as f64 / n_lon as f64;
            v.push(DVec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()));
        }
    }
    v.push(-DVec3::Z);
    let ring = |i: usize, j: usize| (1 + (i - 1) * n_lon + j % n_lon) as u32;
    let south = (v.len() - 1) as u32;
    let mut t = Vec::new();
    for j in 0..n_lon {
        t.push([0, ring(1, j), ring(1, j + 1)]);
        t.push([south, ring(n_lat - 1, j + 1), ring(n_lat - 1, j)]);
    }
    for i in 1..n_lat - 1 {
        for j in 0..n_lon {
            t.push([ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)]);
            t.push([ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]);
        }
    }
    // Make the orientation outward whatever the convention above.
    let vol: f64 = t
        .iter()
        .map(|f| v[f[0] as usize].dot(v[f[1] as usize].cross(v[f[2] as usize])))
        .sum();
    if vol < 0.0 {
        for f in &mut t {
            f.swap(1, 2);
        }
    }
    (v, t)
}

/// Rotation about z.
pub fn rot_z(p: DVec3, angle: f64) -> DVec3 {
    let (s, c) = angle.sin_cos();
    DVec3::new(c * p.x - s * p.y, s * p.x + c * p.y, p.z)
}

/// Ellipsoid with semi-axes (a, b, c), turned by `angle` about z, centred at `center`, from the
/// unit-sphere points `unit`.
pub fn ellipsoid(unit: &[DVec3], abc: DVec3, angle: f64, center: DVec3) -> Vec<DVec3> {
    unit.iter().map(|u| rot_z(*u * abc, angle) + center).collect()
}

/// The regular octahedron with vertices at ±x, ±y, ±z (outward triangles).
pub fn octahedron() -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let v = vec![DVec3::X, -DVec3::X, DVec3::Y, -DVec3::Y, DVec3::Z, -DVec3::Z];
    let mut t = vec![
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ];
    let vol: f64 = t
        .iter()
        .map(|f: &[u32; 3]| v[f[0] as usize].dot(v[f[1] as usize].cross(v[f[2] as usize])))
        .sum();
    if vol < 0.0 {
        for f in &mut t {
            f.swap(1, 2);
        }
    }
    (v, t)
}

/// DPD-like units: 1 model length = 0.5 µm, 1 model time = 1e-4 s, energy 1e-19 J.
pub fn units() -> UnitSystem {
    UnitSystem {
        length_m: 0.5e-6,
        time_s: 1e-4,
        energy_j: 1e-19,
        label: "test model units".to_string(),
    }
}

pub fn meta() -> RunMetadata {
    RunMetadata::new("test", "[scenario]\nname = \"test\"\nsteps = 100\n", 42, units())
}

/// Deterministic pseudo-random numbers in [-1, 1) (xorshift), for test data.
pub struct Noise(pub u64);
impl Noise {
    pub fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
    pub fn vec3(&mut self) -> DVec3 {
        DVec3::new(self.next(), self.next(), self.next())
    }
}
