//! Writes the trajectory `scripts/check_paraview.sh` opens in ParaView: a UV sphere (radius 1,
//! 6 latitude bands × 8 longitudes) translating by 1 along x per frame, 10 fluid particles and a
//! 4 × 3 × 2 density field whose cell k (x fastest) holds 3 + k, five frames, in the test units
//! of the io tests (1 model length = 0.5 µm, 1 model time = 1e-4 s). Prints the vertex,
//! triangle and fluid-particle counts the check expects.
//!
//! ```text
//! cargo run -p hemodpd-io --example paraview_fixture -- /tmp/pv.h5
//! ```

use glam::DVec3;
use hemodpd_io::trajectory::{GridSpec, RunMetadata, TrajectoryWriter};
use hemodpd_io::{Quantity, UnitSystem};

fn uv_sphere(n_lat: usize, n_lon: usize) -> (Vec<DVec3>, Vec<[u32; 3]>) {
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

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).ok_or("usage: paraview_fixture OUT.h5")?;
    let units = UnitSystem {
        length_m: 0.5e-6,
        time_s: 1e-4,
        energy_j: 1e-19,
        label: "test model units".to_string(),
    };
    let meta = RunMetadata::new("paraview-fixture", "[scenario]\nname = \"fixture\"\n", 42, units);
    let (sphere, tri) = uv_sphere(6, 8);
    let grid = GridSpec {
        origin: DVec3::ZERO,
        spacing: DVec3::ONE,
        shape: [4, 3, 2],
    };
    let mut w = TrajectoryWriter::create(&path, &meta)?;
    w.write_mesh(&tri)?;
    for s in 0..5u64 {
        let p: Vec<DVec3> = sphere.iter().map(|v| *v + DVec3::X * s as f64).collect();
        w.append_membrane_frame(s, s as f64, &p, Some(&p), &[])?;
        w.append_fluid_frame(s, s as f64, &p[..10], None, None)?;
        let rho: Vec<f64> = (0..grid.len()).map(|i| 3.0 + i as f64).collect();
        w.append_field("density", s, s as f64, &grid, 1, &rho, Quantity::NumberDensity)?;
    }
    w.close()?;
    println!("{} {} 10", sphere.len(), tri.len());
    Ok(())
}
