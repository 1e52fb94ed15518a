//! Trajectory round trips, appending after reopen with truncation, and a writer killed mid-run.

mod common;

use common::*;
use glam::DVec3;
use hemodpd_io::trajectory::{FrameScalar, GridSpec, MetaValue, TrajectoryReader, TrajectoryWriter};
use hemodpd_io::{IoError, Quantity, WriterOptions};

fn frame_positions(base: &[DVec3], step: u64) -> Vec<DVec3> {
    base.iter()
        .enumerate()
        .map(|(i, p)| *p + DVec3::new(0.01 * step as f64, 0.001 * i as f64, -0.5))
        .collect()
}

fn fast_xdmf() -> WriterOptions {
    WriterOptions {
        xdmf_interval: std::time::Duration::ZERO,
        ..WriterOptions::default()
    }
}

#[test]
fn round_trip_membrane_fluid_fields_in_si() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("traj.h5");
    let u = units();
    let meta = meta()
        .with_extra("flow", MetaValue::Str("shear".into()))
        .with_extra("shear_rate", MetaValue::F64(12.5))
        .with_extra("cells", MetaValue::I64(1));
    let (sphere, tri) = uv_sphere(8, 12);
    let mut noise = Noise(7);
    let fluid: Vec<DVec3> = (0..50).map(|_| noise.vec3() * 5.0).collect();
    let types: Vec<u8> = (0..50).map(|i| (i % 3) as u8).collect();
    let grid = GridSpec {
        origin: DVec3::new(-1.0, -2.0, -3.0),
        spacing: DVec3::new(0.5, 1.0, 1.5),
        shape: [4, 3, 2],
    };
    {
        let mut w = TrajectoryWriter::create_with(&path, &meta, fast_xdmf()).unwrap();
        w.write_mesh(&tri).unwrap();
        w.set_membrane_reference(12.0, 4.0).unwrap();
        for f in 0..5u64 {
            let step = 100 * f;
            let pos = frame_positions(&sphere, step);
            let vel: Vec<DVec3> = pos.iter().map(|p| *p * 0.1).collect();
            let force = FrameScalar {
                name: "force",
                value: f as f64,
                quantity: Quantity::Force,
            };
            let extra = FrameScalar {
                name: "energy",
                value: 2.0,
                quantity: Quantity::Energy,
            };
            let scalars: Vec<FrameScalar> = if f == 2 { vec![force] } else { vec![force, extra] };
            w.append_membrane_frame(step, step as f64 * 0.01, &pos, Some(&vel), &scalars)
                .unwrap();
            if f % 2 == 0 {
                let fp: Vec<DVec3> = fluid.iter().map(|p| *p + DVec3::splat(f as f64)).collect();
                w.append_fluid_frame(step, step as f64 * 0.01, &fp, Some(&fluid), Some(&types))
                    .unwrap();
                let values: Vec<f64> = (0..grid.len() * 3).map(|i| i as f64 + f as f64).collect();
                w.append_field(
                    "velocity",
                    step,
                    step as f64 * 0.01,
                    &grid,
                    3,
                    &values,
                    Quantity::Velocity,
                )
                .unwrap();
                let dens: Vec<f64> = (0..grid.len()).map(|i| 3.0 + i as f64).collect();
                w.append_field(
                    "density",
                    step,
                    step as f64 * 0.01,
                    &grid,
                    1,
                    &dens,
                    Quantity::NumberDensity,
                )
                .unwrap();
            }
        }
        assert_eq!(w.membrane_frames().unwrap(), 5);
        assert_eq!(w.last_membrane_step().unwrap(), Some(400));
        w.close().unwrap();
    }
    assert!(path.with_extension("xmf").exists());

    let r = TrajectoryReader::open(&path).unwrap();
    let m = r.metadata();
    assert_eq!(m.seed, 42);
    assert_eq!(m.scenario_name, "test");
    assert_eq!(m.scenario_toml, meta.scenario_toml);
    assert_eq!(m.units, u);
    assert_eq!(m.extra("flow"), Some(&MetaValue::Str("shear".into())));
    assert_eq!(m.extra("shear_rate"), Some(&MetaValue::F64(12.5)));
    assert_eq!(m.extra("cells"), Some(&MetaValue::I64(1)));
    assert_eq!(r.triangles().unwrap(), tri);
    assert_eq!(r.membrane_frames().unwrap(), 5);
    assert_eq!(r.membrane_steps().unwrap(), vec![0, 100, 200, 300, 400]);
    let times = r.membrane_times().unwrap();
    assert!((times[3] - 3.0 * u.time_s).abs() < 1e-18);
    let (ra, rv) = r.membrane_reference().unwrap().unwrap();
    assert!((ra - 12.0 * u.length_m.powi(2)).abs() < 1e-24);
    assert!((rv - 4.0 * u.length_m.powi(3)).abs() < 1e-30);
    for f in 0..5 {
        let fr = r.membrane_frame(f).unwrap();
        let expect = frame_positions(&sphere, 100 * f as u64);
        assert_eq!(fr.positions.len(), expect.len());
        for (a, b) in fr.positions.iter().zip(&expect) {
            assert!((*a - *b * u.length_m).length() < 1e-20);
        }
        let v = fr.velocities.unwrap();
        let vs = u.length_m / u.time_s;
        assert!((v[1] - expect[1] * 0.1 * vs).length() < 1e-15);
    }
    let force = r.membrane_scalar("force").unwrap();
    assert_eq!(force.len(), 5);
    assert!((force[4] - 4.0 * u.force_n()).abs() < 1e-25);
    let energy = r.membrane_scalar("energy").unwrap();
    assert!(energy[2].is_nan(), "a scalar not given in a frame reads NaN");
    assert!((energy[3] - 2.0 * u.energy_j).abs() < 1e-30);

    assert_eq!(r.fluid_frames().unwrap(), 3);
    let ff = r.fluid_frame(2).unwrap();
    assert_eq!(ff.step, 400);
    assert_eq!(ff.types.as_deref(), Some(&types[..]));
    assert!((ff.positions[0] - (fluid[0] + DVec3::splat(4.0)) * u.length_m).length() < 1e-20);

    assert_eq!(r.field_names().unwrap(), vec!["density", "velocity"]);
    let info = r.field_info("velocity").unwrap();
    assert_eq!(info.components, 3);
    assert_eq!(info.frames, 3);
    assert_eq!(info.units, "m/s");
    assert_eq!(info.grid.shape, [4, 3, 2]);
    assert!((info.grid.spacing - grid.spacing * u.length_m).length() < 1e-20);
    let fv = r.field_frame("velocity", 1).unwrap();
    assert_eq!(fv.step, 200);
    assert_eq!(fv.values.len(), 72);
    assert!((fv.values[5] - (5.0 + 2.0) * u.velocity_m_per_s()).abs() < 1e-15);
    let fd = r.field_frame("density", 0).unwrap();
    assert!((fd.values[0] - 3.0 / u.length_m.powi(3)).abs() / fd.values[0] < 1e-14);

    // Frames out of range are errors, not panics.
    assert!(matches!(r.membrane_frame(5), Err(IoError::Invalid { .. })));
    assert!(r.field_frame("pressure", 0).is_err());
}

#[test]
fn writer_rejects_inconsistent_frames() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.h5");
    let (sphere, tri) = uv_sphere(4, 8);
    let mut w = TrajectoryWriter::create(&path, &meta()).unwrap();
    w.write_mesh(&tri).unwrap();
    w.append_membrane_frame(10, 0.1, &sphere, None, &[]).unwrap();
    // Same step again, an earlier step, another vertex count, velocities appearing.
    let e = w.append_membrane_frame(10, 0.1, &sphere, None, &[]).unwrap_err();
    assert!(e.to_string().contains("steps must increase"), "{e}");
    assert!(w.append_membrane_frame(5, 0.1, &sphere, None, &[]).is_err());
    let e = w.append_membrane_frame(20, 0.2, &sphere[1..], None, &[]).unwrap_err();
    assert!(e.to_string().contains("vertices"), "{e}");
    assert!(e.to_string().contains("bad.h5"), "{e}");
    assert!(w.append_membrane_frame(20, 0.2, &sphere, Some(&sphere), &[]).is_err());
    // Rewriting the same mesh is fine (resume), another mesh is not.
    w.write_mesh(&tri).unwrap();
    assert!(w.write_mesh(&tri[1..]).is_err());
    // A field with a wrong value count.
    let grid = GridSpec {
        origin: DVec3::ZERO,
        spacing: DVec3::ONE,
        shape: [2, 2, 2],
    };
    assert!(w
        .append_field("rho", 10, 0.1, &grid, 1, &[1.0; 7], Quantity::NumberDensity)
        .is_err());
    assert!(w
        .append_field("a/b", 10, 0.1, &grid, 1, &[1.0; 8], Quantity::NumberDensity)
        .is_err());
    w.append_membrane_frame(20, 0.2, &sphere, None, &[]).unwrap();
    w.close().unwrap();
    let r = TrajectoryReader::open(&path).unwrap();
    assert_eq!(r.membrane_steps().unwrap(), vec![10, 20]);
}

/// Particle types beyond the file's u8 are an error naming the particle and its type, not a
/// silent truncation (300 would be stored as 44): the frame is refused and the file keeps only
/// the valid frames; types up to 255 round-trip exactly.
#[test]
fn particle_types_beyond_u8_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("types.h5");
    let pos: Vec<DVec3> = (0..4).map(|i| DVec3::X * i as f64).collect();
    let mut w = TrajectoryWriter::create(&path, &meta()).unwrap();
    w.append_fluid_frame_u16(0, 0.0, &pos, None, Some(&[0, 1, 254, 255]))
        .unwrap();
    let e = w
        .append_fluid_frame_u16(1, 0.1, &pos, None, Some(&[0, 1, 300, 2]))
        .unwrap_err();
    match &e {
        IoError::TypeOutOfRange { index, value, max, .. } => {
            assert_eq!((*index, *value, *max), (2, 300, 255));
        }
        other => panic!("expected TypeOutOfRange, got {other:?}"),
    }
    let msg = e.to_string();
    assert!(
        msg.contains("types.h5") && msg.contains("type 300") && msg.contains("u8"),
        "{msg}"
    );
    assert_eq!(
        hemodpd_io::trajectory::types_to_u8(&path, &[7, 255]).unwrap(),
        vec![7u8, 255]
    );
    w.close().unwrap();
    let r = TrajectoryReader::open(&path).unwrap();
    assert_eq!(
        r.fluid_frames().unwrap(),
        1,
        "the refused frame must not be in the file"
    );
    assert_eq!(r.fluid_frame(0).unwrap().types, Some(vec![0u8, 1, 254, 255]));
}

/// Resume: frames after the checkpoint step are dropped, then the run continues; the result
/// equals the uninterrupted trajectory frame for frame.
#[test]
fn open_append_truncates_after_checkpoint_step() {
    let dir = tempfile::tempdir().unwrap();
    let (sphere, tri) = uv_sphere(4, 8);
    let grid = GridSpec {
        origin: DVec3::ZERO,
        spacing: DVec3::ONE,
        shape: [2, 1, 1],
    };
    let write = |w: &mut TrajectoryWriter, steps: std::ops::Range<u64>| {
        for s in steps {
            let step = s * 10;
            let pos = frame_positions(&sphere, step);
            let f = FrameScalar {
                name: "force",
                value: s as f64,
                quantity: Quantity::Force,
            };
            w.append_membrane_frame(step, step as f64, &pos, Some(&pos), &[f])
                .unwrap();
            if s % 3 == 0 {
                w.append_fluid_frame(step, step as f64, &pos, None, None).unwrap();
                w.append_field(
                    "rho",
                    step,
                    step as f64,
                    &grid,
                    1,
                    &[s as f64, 1.0],
                    Quantity::NumberDensity,
                )
                .unwrap();
            }
        }
    };
    // Uninterrupted run: steps 0..=190.
    let full = dir.path().join("full.h5");
    let mut w = TrajectoryWriter::create(&full, &meta()).unwrap();
    w.write_mesh(&tri).unwrap();
    write(&mut w, 0..20);
    w.close().unwrap();

    // Interrupted run: written up to step 130, checkpoint at step 95 (between frames 90 and 100).
    let part = dir.path().join("part.h5");
    let mut w = TrajectoryWriter::create(&part, &meta()).unwrap();
    w.write_mesh(&tri).unwrap();
    write(&mut w, 0..14);
    std::mem::drop(w);
    let mut w = TrajectoryWriter::open_append(&part, 95).unwrap();
    assert_eq!(w.last_membrane_step().unwrap(), Some(90));
    assert_eq!(w.membrane_frames().unwrap(), 10);
    w.write_mesh(&tri).unwrap();
    write(&mut w, 10..20);
    w.close().unwrap();

    let a = TrajectoryReader::open(&full).unwrap();
    let b = TrajectoryReader::open(&part).unwrap();
    assert_eq!(a.membrane_steps().unwrap(), b.membrane_steps().unwrap());
    assert_eq!(b.membrane_frames().unwrap(), 20);
    for i in 0..20 {
        assert_eq!(a.membrane_frame(i).unwrap(), b.membrane_frame(i).unwrap());
    }
    assert_eq!(a.membrane_scalar("force").unwrap(), b.membrane_scalar("force").unwrap());
    assert_eq!(a.fluid_frames().unwrap(), b.fluid_frames().unwrap());
    for i in 0..a.fluid_frames().unwrap() {
        assert_eq!(a.fluid_frame(i).unwrap(), b.fluid_frame(i).unwrap());
    }
    for i in 0..7 {
        assert_eq!(a.field_frame("rho", i).unwrap(), b.field_frame("rho", i).unwrap());
    }
    // The datasets themselves hold no stale rows.
    let ds = b.hdf5_file().dataset("/membrane/positions").unwrap();
    assert_eq!(ds.shape()[0], 20);
    let ds = b.hdf5_file().dataset("/fluid/step").unwrap();
    assert_eq!(ds.shape()[0], 7);
}

const CHILD_ENV: &str = "HEMODPD_IO_KILLED_WRITER_PATH";

/// The child process of `killed_writer_leaves_every_flushed_frame`: writes 7 frames to `path`
/// and aborts without closing anything (like a SIGKILL after the last flush).
fn killed_writer_child(path: &str) -> ! {
    let (sphere, tri) = uv_sphere(4, 8);
    let options = WriterOptions {
        xdmf: false,
        ..WriterOptions::default()
    };
    let mut w = TrajectoryWriter::create_with(path, &meta(), options).unwrap();
    w.write_mesh(&tri).unwrap();
    for s in 0..7u64 {
        let pos = frame_positions(&sphere, s);
        w.append_membrane_frame(s, s as f64, &pos, None, &[]).unwrap();
        w.append_fluid_frame(s, s as f64, &pos, None, None).unwrap();
    }
    std::process::abort();
}

/// A writer killed after its 7th frame (this test re-runs itself as a child process with
/// `HEMODPD_IO_KILLED_WRITER_PATH` set; the child writes and aborts) leaves a file with all 7
/// frames, which can be resumed and analysed.
#[test]
fn killed_writer_leaves_every_flushed_frame() {
    if let Ok(path) = std::env::var(CHILD_ENV) {
        killed_writer_child(&path);
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("killed.h5");
    let status = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "killed_writer_leaves_every_flushed_frame",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_ENV, &path)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .unwrap();
    assert!(!status.success(), "the child should have aborted");
    let (sphere, _) = uv_sphere(4, 8);
    let r = TrajectoryReader::open(&path).unwrap();
    assert_eq!(r.membrane_frames().unwrap(), 7);
    assert_eq!(r.fluid_frames().unwrap(), 7);
    for s in 0..7 {
        let f = r.membrane_frame(s).unwrap();
        let expect = frame_positions(&sphere, s as u64);
        assert!((f.positions[3] - expect[3] * units().length_m).length() < 1e-20);
    }
    drop(r);
    // The killed file can be resumed and analysed.
    let mut w = TrajectoryWriter::open_append(&path, 4).unwrap();
    w.append_membrane_frame(5, 5.0, &frame_positions(&sphere, 5), None, &[])
        .unwrap();
    w.close().unwrap();
    let r = TrajectoryReader::open(&path).unwrap();
    assert_eq!(r.membrane_steps().unwrap(), vec![0, 1, 2, 3, 4, 5]);
    hemodpd_io::analysis::analyze_file(&path, &Default::default()).unwrap();
}

/// In-process variant: the writer is leaked (never closed); a byte copy of the file on disk
/// (what a kill would leave) holds every appended frame.
#[test]
fn leaked_writer_file_on_disk_is_readable() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("leaked.h5");
    let copy = dir.path().join("copy.h5");
    let (sphere, tri) = uv_sphere(4, 8);
    let mut w = TrajectoryWriter::create(&path, &meta()).unwrap();
    w.write_mesh(&tri).unwrap();
    for s in 0..4u64 {
        w.append_membrane_frame(s, s as f64, &frame_positions(&sphere, s), None, &[])
            .unwrap();
    }
    std::fs::copy(&path, &copy).unwrap();
    std::mem::forget(w);
    let r = TrajectoryReader::open(&copy).unwrap();
    assert_eq!(r.membrane_frames().unwrap(), 4);
    assert_eq!(r.membrane_frame(3).unwrap().step, 3);
    let r = TrajectoryReader::open(&path).unwrap();
    assert_eq!(r.membrane_frames().unwrap(), 4);
}
