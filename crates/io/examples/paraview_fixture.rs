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

// the io tests' UV sphere (the same mesh the former ParaView test wrote)
#[path = "../tests/common/mod.rs"]
mod common;
use common::uv_sphere;

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
