//! Writes a small demo trajectory (a tumbling ellipsoidal "cell" translating along x, fluid
//! particles and binned velocity/density fields) plus its XDMF file, for trying ParaView or h5py:
//!
//! ```text
//! cargo run -p hemodpd-io --example demo_trajectory -- /tmp/demo.h5
//! paraview /tmp/demo.xmf
//! ```

use glam::DVec3;
use hemodpd_io::trajectory::{FrameScalar, GridSpec, MetaValue, RunMetadata, TrajectoryWriter};
use hemodpd_io::{Quantity, UnitSystem};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).unwrap_or_else(|| "demo.h5".to_string());
    let units = UnitSystem {
        length_m: 1e-6,
        time_s: 1e-3,
        energy_j: 4.1e-21,
        label: "µm, ms, kBT".into(),
    };
    let meta = RunMetadata::new("demo-shear", "[demo]\n", 1, units).with_extra("flow", MetaValue::Str("shear".into()));
    let mut w = TrajectoryWriter::create(&path, &meta)?;
    // UV sphere → ellipsoid with semi-axes 4, 2, 1 µm.
    let (n_lat, n_lon) = (16usize, 32usize);
    let mut unit = vec![DVec3::Z];
    for i in 1..n_lat {
        let th = std::f64::consts::PI * i as f64 / n_lat as f64;
        for j in 0..n_lon {
            let ph = 2.0 * std::f64::consts::PI * j as f64 / n_lon as f64;
            unit.push(DVec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()));
        }
    }
    unit.push(-DVec3::Z);
    let ring = |i: usize, j: usize| (1 + (i - 1) * n_lon + j % n_lon) as u32;
    let south = (unit.len() - 1) as u32;
    let mut tri = Vec::new();
    for j in 0..n_lon {
        tri.push([0, ring(1, j), ring(1, j + 1)]);
        tri.push([south, ring(n_lat - 1, j + 1), ring(n_lat - 1, j)]);
    }
    for i in 1..n_lat - 1 {
        for j in 0..n_lon {
            tri.push([ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)]);
            tri.push([ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]);
        }
    }
    w.write_mesh(&tri)?;
    let grid = GridSpec {
        origin: DVec3::new(-10.0, -5.0, -5.0),
        spacing: DVec3::splat(1.0),
        shape: [20, 10, 10],
    };
    let fluid: Vec<DVec3> = (0..2000)
        .map(|i| {
            let f = i as f64;
            DVec3::new(
                (f * 0.618).fract() * 20.0 - 10.0,
                (f * 0.414).fract() * 10.0 - 5.0,
                (f * 0.732).fract() * 10.0 - 5.0,
            )
        })
        .collect();
    for s in 0..40u64 {
        let t = s as f64 * 0.1;
        let angle = -0.5 * t;
        let pos: Vec<DVec3> = unit
            .iter()
            .map(|u| {
                let p = *u * DVec3::new(4.0, 2.0, 1.0);
                let (sn, c) = angle.sin_cos();
                DVec3::new(c * p.x - sn * p.y + 0.2 * t, sn * p.x + c * p.y, p.z)
            })
            .collect();
        let vel: Vec<DVec3> = pos.iter().map(|p| DVec3::new(0.5 * p.y, 0.0, 0.0)).collect();
        let f = FrameScalar {
            name: "tension",
            value: t,
            quantity: Quantity::Force,
        };
        w.append_membrane_frame(s * 100, t, &pos, Some(&vel), &[f])?;
        if s % 4 == 0 {
            let fv: Vec<DVec3> = fluid.iter().map(|p| DVec3::new(0.5 * p.y, 0.0, 0.0)).collect();
            let types: Vec<u8> = fluid.iter().map(|p| u8::from(p.length() < 3.0)).collect();
            w.append_fluid_frame(s * 100, t, &fluid, Some(&fv), Some(&types))?;
            let mut v = Vec::with_capacity(grid.len() * 3);
            let mut rho = Vec::with_capacity(grid.len());
            for k in 0..10 {
                for j in 0..10 {
                    for i in 0..20 {
                        let c = grid.origin + (DVec3::new(i as f64, j as f64, k as f64) + 0.5) * grid.spacing;
                        v.extend_from_slice(&[0.5 * c.y, 0.0, 0.0]);
                        rho.push(3.0 + 0.1 * c.x + 0.0 * k as f64);
                    }
                }
            }
            w.append_field("velocity", s * 100, t, &grid, 3, &v, Quantity::Velocity)?;
            w.append_field("density", s * 100, t, &grid, 1, &rho, Quantity::NumberDensity)?;
        }
    }
    w.close()?;
    println!(
        "wrote {path} and {}",
        std::path::Path::new(&path).with_extension("xmf").display()
    );
    Ok(())
}
