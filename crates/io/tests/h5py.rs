//! A written trajectory and checkpoint read with h5py (an independent HDF5 reader, often built
//! on a newer libhdf5). It fails, it does not skip, when h5py cannot be imported: `scripts/setup.sh`
//! installs Debian's `python3-h5py`, which `/usr/bin/python3` imports. The interpreter is
//! `$HEMODPD_PYTHON` when set, else `/usr/bin/python3` when it exists, else `python3` on the PATH
//! (which may be a pyenv or venv Python without Debian's packages).

mod common;

use common::*;
use glam::DVec3;
use hemodpd_io::checkpoint::{Checkpoint, ScalarValue};
use hemodpd_io::trajectory::{FrameScalar, GridSpec, TrajectoryWriter};
use hemodpd_io::Quantity;

const SCRIPT: &str = r#"
import sys, h5py, numpy as np
traj, ck = sys.argv[1], sys.argv[2]
L, T = 0.5e-6, 1e-4
with h5py.File(traj, "r") as f:
    a = f.attrs
    assert a["format"] == "hemodpd-trajectory", a["format"]
    assert int(a["format_version"]) == 1
    assert int(a["seed"]) == 42 and a["scenario_name"] == "test"
    assert "steps = 100" in a["scenario"]
    assert abs(a["unit_length_m"] - L) < 1e-20 and abs(a["unit_time_s"] - T) < 1e-20
    tri = f["membrane/triangles"]
    assert tri.dtype == np.uint32 and tri.ndim == 2 and tri.shape[1] == 3
    pos = f["membrane/positions"]
    assert pos.shape[0] == 4 and pos.shape[2] == 3 and pos.dtype == np.float64, pos.shape
    assert pos.maxshape[0] is None and pos.chunks[0] == 1
    assert pos.attrs["units"] == "m"
    assert f["membrane"].attrs["frames"] == 4
    assert list(f["membrane/step"][:]) == [0, 10, 20, 30]
    assert np.allclose(f["membrane/time"][:], np.arange(4) * 0.5 * T, rtol=0, atol=1e-18)
    assert f["membrane/time"].attrs["units"] == "s"
    # frame 3 is the unit sphere shifted by 3 model lengths along x
    p = pos[3]
    assert np.allclose(p.mean(axis=0), [3 * L, 0, 0], atol=1e-18), p.mean(axis=0)
    assert np.allclose(f["membrane/velocities"][2][0], [0, 0, 1e-3 * L / T])
    force = f["membrane/scalars/stretch_force"]
    assert force.attrs["units"] == "N" and np.isclose(force[3], 3e-12)
    v = f["fields/velocity/values"]
    assert v.shape == (2, 2, 3, 4, 3), v.shape   # (frames, nz, ny, nx, components)
    g = f["fields/velocity"].attrs
    assert list(g["shape"]) == [4, 3, 2] and int(g["components"]) == 3
    assert np.allclose(g["spacing"], [L, 2 * L, 3 * L])
    # value index ((k*ny + j)*nx + i)*3 + c, written as that index (x1 model velocity)
    assert np.isclose(v[1, 1, 2, 3, 2], (((1 * 3 + 2) * 4 + 3) * 3 + 2) * L / T)
    assert f["fluid/types"].dtype == np.uint8
with h5py.File(ck, "r") as f:
    assert f.attrs["format"] == "hemodpd-checkpoint"
    assert int(f.attrs["step"]) == 77
    x = f["arrays/positions"][:]
    assert x.shape == (5, 3) and x[4, 2] == 0.1 + 0.2
    assert f["arrays/ids"].dtype == np.uint64 and f["arrays/ids"][-1] == 2**64 - 1
    assert bool(f["scalars"].attrs["flag"]) is True
    assert f["scalars"].attrs["name"] == "µm"
print("H5PY-OK")
"#;

/// The Python that reads our files: `$HEMODPD_PYTHON`, else Debian's `/usr/bin/python3` (where
/// `python3-h5py` lives), else `python3` on the PATH.
fn python() -> String {
    if let Ok(p) = std::env::var("HEMODPD_PYTHON") {
        if !p.is_empty() {
            return p;
        }
    }
    if std::path::Path::new("/usr/bin/python3").exists() {
        return "/usr/bin/python3".to_string();
    }
    "python3".to_string()
}

#[test]
fn h5py_reads_what_we_write() {
    let py = python();
    let probe = std::process::Command::new(&py)
        .args(["-c", "import h5py, numpy; print(h5py.__version__)"])
        .output();
    match probe {
        Ok(o) if o.status.success() => {}
        Ok(o) => panic!(
            "`{py}` cannot import h5py and numpy, so the h5py cross-check cannot run. Run \
             ./scripts/setup.sh (installs Debian's python3-h5py for /usr/bin/python3) or set \
             HEMODPD_PYTHON to a Python with h5py.\n{}",
            String::from_utf8_lossy(&o.stderr)
        ),
        Err(e) => panic!(
            "cannot start `{py}` ({e}); run ./scripts/setup.sh or set HEMODPD_PYTHON to a Python \
             with h5py"
        ),
    }
    let dir = tempfile::tempdir().unwrap();
    let traj = dir.path().join("traj.h5");
    let (sphere, tri) = uv_sphere(6, 8);
    let mut w = TrajectoryWriter::create(&traj, &meta()).unwrap();
    w.write_mesh(&tri).unwrap();
    let grid = GridSpec {
        origin: DVec3::ZERO,
        spacing: DVec3::new(1.0, 2.0, 3.0),
        shape: [4, 3, 2],
    };
    for s in 0..4u64 {
        let p: Vec<DVec3> = sphere.iter().map(|v| *v + DVec3::X * s as f64).collect();
        let v = vec![DVec3::Z * 1e-3; p.len()];
        // 1 pN expressed in model force units (E/r = 1e-19/0.5e-6 N = 2e-13 N).
        let f = FrameScalar {
            name: "stretch_force",
            value: s as f64 * 1e-12 / 2e-13,
            quantity: Quantity::Force,
        };
        w.append_membrane_frame(s * 10, s as f64 * 0.5, &p, Some(&v), &[f])
            .unwrap();
        if s % 2 == 1 {
            let vals: Vec<f64> = (0..grid.len() * 3).map(|i| i as f64).collect();
            w.append_field("velocity", s * 10, s as f64 * 0.5, &grid, 3, &vals, Quantity::Velocity)
                .unwrap();
            w.append_fluid_frame(s * 10, s as f64 * 0.5, &p, None, Some(&vec![2u8; p.len()]))
                .unwrap();
        }
    }
    w.close().unwrap();
    let ck = dir.path().join("ck.h5");
    let mut c = Checkpoint::new(77, 1.0, 42, "x");
    c.insert_vec3(
        "positions",
        &[
            DVec3::ZERO,
            DVec3::ONE,
            DVec3::X,
            DVec3::Y,
            DVec3::new(0.0, 0.0, 0.1 + 0.2),
        ],
    );
    c.insert_u64("ids", vec![0, u64::MAX]);
    c.set_scalar("flag", ScalarValue::Bool(true));
    c.set_scalar("name", ScalarValue::Str("µm".into()));
    c.save_atomic(&ck).unwrap();

    let out = std::process::Command::new(&py)
        .args(["-c", SCRIPT])
        .arg(&traj)
        .arg(&ck)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && stdout.contains("H5PY-OK"),
        "h5py check failed:\n{stdout}\n{stderr}"
    );
}
