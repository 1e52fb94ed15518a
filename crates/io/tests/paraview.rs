//! ParaView opens the XDMF files: the XDMF 2 file with *XDMF Reader* and the Xdmf3 file with
//! *Xdmf3ReaderS*, with every block, point and cell where expected. Skipped, with a notice, when
//! `pvpython` is missing (Debian: `apt-get install paraview python3-paraview`).

mod common;

use common::*;
use glam::DVec3;
use hemodpd_io::trajectory::{GridSpec, TrajectoryWriter};
use hemodpd_io::Quantity;

const SCRIPT: &str = r#"
import sys
from paraview.simple import *
from paraview import servermanager as sm
base, nv, nt, nf = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
for reader, ext in [(lambda f: XDMFReader(FileNames=[f]), ".xmf"), (lambda f: Xdmf3ReaderS(FileName=[f]), ".xmf3")]:
    r = reader(base + ext)
    r.UpdatePipelineInformation()
    ts = list(r.TimestepValues)
    assert len(ts) == 5, (ext, ts)
    r.UpdatePipeline(ts[2])
    d = sm.Fetch(r)
    blocks = []
    it = d.NewIterator(); it.InitTraversal()
    while not it.IsDoneWithTraversal():
        blocks.append(it.GetCurrentDataObject()); it.GoToNextItem()
    assert len(blocks) == 3, (ext, len(blocks))
    mem, fluid, field = blocks
    assert mem.GetNumberOfPoints() == nv and mem.GetNumberOfCells() == nt, ext
    assert mem.GetPointData().GetArray("velocity") is not None, ext
    b = mem.GetBounds()
    assert abs(b[0] - (-1 + 2) * 0.5e-6) < 1e-9 and abs(b[1] - (1 + 2) * 0.5e-6) < 1e-9, (ext, b)
    assert fluid.GetNumberOfPoints() == nf, ext
    rho = field.GetCellData().GetArray("density")
    assert rho is not None and field.GetNumberOfCells() == 24, ext
    lo, hi = rho.GetRange()
    assert abs(lo - 3 / (0.5e-6) ** 3) / lo < 1e-12 and abs(hi - 26 / (0.5e-6) ** 3) / hi < 1e-12, (lo, hi)
    # x-fastest storage: cell (i=1, j=0, k=0) is value 1 -> density 4
    assert abs(rho.GetValue(1) - 4 / (0.5e-6) ** 3) / hi < 1e-12, rho.GetValue(1)
    Delete(r)
print("PV-OK")
"#;

#[test]
fn paraview_opens_both_xdmf_dialects() {
    let has = std::process::Command::new("pvpython")
        .arg("--version")
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !has {
        eprintln!(
            "NOTICE: pvpython not found; skipping the ParaView check (apt-get install paraview python3-paraview)"
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pv.h5");
    let (sphere, tri) = uv_sphere(6, 8);
    let grid = GridSpec {
        origin: DVec3::ZERO,
        spacing: DVec3::ONE,
        shape: [4, 3, 2],
    };
    let mut w = TrajectoryWriter::create(&path, &meta()).unwrap();
    w.write_mesh(&tri).unwrap();
    for s in 0..5u64 {
        let p: Vec<DVec3> = sphere.iter().map(|v| *v + DVec3::X * s as f64).collect();
        w.append_membrane_frame(s, s as f64, &p, Some(&p), &[]).unwrap();
        w.append_fluid_frame(s, s as f64, &p[..10], None, None).unwrap();
        let rho: Vec<f64> = (0..grid.len()).map(|i| 3.0 + i as f64).collect();
        w.append_field("density", s, s as f64, &grid, 1, &rho, Quantity::NumberDensity)
            .unwrap();
    }
    w.close().unwrap();
    let out = std::process::Command::new("pvpython")
        .args(["-c", SCRIPT])
        .arg(dir.path().join("pv"))
        .args([sphere.len().to_string(), tri.len().to_string(), "10".to_string()])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && stdout.contains("PV-OK"),
        "ParaView check failed:\n{stdout}\n{stderr}"
    );
}
