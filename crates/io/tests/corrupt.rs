//! Corrupt, truncated or foreign HDF5 input to the trajectory reader and to `analyze` gives a
//! clear error naming the file, never a panic.

mod common;

use common::*;
use glam::DVec3;
use hemodpd_io::analysis::{analyze_file, AnalysisOptions};
use hemodpd_io::trajectory::{TrajectoryReader, TrajectoryWriter};
use hemodpd_io::IoError;

fn good_file(dir: &std::path::Path) -> std::path::PathBuf {
    let path = dir.join("good.h5");
    let (s, t) = uv_sphere(6, 8);
    let mut w = TrajectoryWriter::create(&path, &meta()).unwrap();
    w.write_mesh(&t).unwrap();
    for i in 0..20u64 {
        let p: Vec<DVec3> = s.iter().map(|p| *p + DVec3::X * i as f64).collect();
        w.append_membrane_frame(i, i as f64, &p, Some(&p), &[]).unwrap();
        w.append_fluid_frame(i, i as f64, &p, None, None).unwrap();
    }
    w.close().unwrap();
    path
}

fn assert_clear(e: &IoError, file: &str) {
    let msg = e.to_string();
    assert!(msg.contains(file), "message should name {file}: {msg}");
}

#[test]
fn missing_garbage_and_empty_files() {
    let dir = tempfile::tempdir().unwrap();
    let opts = AnalysisOptions::default();
    let e = analyze_file(dir.path().join("nope.h5"), &opts).unwrap_err();
    assert_clear(&e, "nope.h5");
    let g = dir.path().join("garbage.h5");
    std::fs::write(&g, b"this is not HDF5 at all\n".repeat(100)).unwrap();
    let e = analyze_file(&g, &opts).unwrap_err();
    assert!(matches!(e, IoError::Open { .. }), "{e}");
    assert_clear(&e, "garbage.h5");
    let z = dir.path().join("empty.h5");
    std::fs::write(&z, b"").unwrap();
    assert_clear(&analyze_file(&z, &opts).unwrap_err(), "empty.h5");
    assert!(TrajectoryWriter::open_append(&g, 0).is_err());
}

#[test]
fn truncated_trajectories() {
    let dir = tempfile::tempdir().unwrap();
    let good = good_file(dir.path());
    let bytes = std::fs::read(&good).unwrap();
    let cut = dir.path().join("cut.h5");
    let mut errors = 0;
    for k in 1..20 {
        let len = bytes.len() * k / 20;
        std::fs::write(&cut, &bytes[..len]).unwrap();
        // Either an error naming the file, or (if the cut spared everything needed) a result.
        if let Err(e) = analyze_file(&cut, &AnalysisOptions::default()) {
            assert_clear(&e, "cut.h5");
            errors += 1;
        }
        if let Err(e) = TrajectoryWriter::open_append(&cut, 5) {
            assert_clear(&e, "cut.h5");
        }
    }
    // HDF5 keeps its superblock end-of-file address: any cut is detected.
    assert_eq!(errors, 19);
}

#[test]
fn foreign_hdf5_files() {
    let dir = tempfile::tempdir().unwrap();
    let foreign = dir.path().join("foreign.h5");
    {
        let f = hdf5::File::create(&foreign).unwrap();
        f.create_group("membrane").unwrap();
        f.new_dataset_builder()
            .with_data(&[1u8, 2, 3])
            .create("membrane/positions")
            .unwrap();
    }
    let e = analyze_file(&foreign, &AnalysisOptions::default()).unwrap_err();
    assert!(matches!(e, IoError::Foreign { .. }), "{e}");
    assert!(e.to_string().contains("not a hemodpd trajectory file"), "{e}");
    let e = TrajectoryWriter::open_append(&foreign, 0).err().unwrap();
    assert!(matches!(e, IoError::Foreign { .. }), "{e}");

    // A checkpoint is not a trajectory.
    let ck = dir.path().join("ck.h5");
    hemodpd_io::checkpoint::Checkpoint::new(0, 0.0, 0, "")
        .save_atomic(&ck)
        .unwrap();
    let e = TrajectoryReader::open(&ck).err().unwrap();
    assert!(e.to_string().contains("hemodpd-checkpoint"), "{e}");
}

/// Our format tag, but damaged contents: wrong shapes, bad indices, missing datasets.
#[test]
fn tampered_trajectories() {
    let dir = tempfile::tempdir().unwrap();
    let good = good_file(dir.path());
    let opts = AnalysisOptions::default();
    let tamper = |name: &str, f: &dyn Fn(&hdf5::File)| {
        let p = dir.path().join(name);
        std::fs::copy(&good, &p).unwrap();
        f(&hdf5::File::open_rw(&p).unwrap());
        p
    };
    // Triangles with an index past the vertices.
    let p = tamper("badindex.h5", &|f| {
        f.unlink("membrane/triangles").unwrap();
        f.new_dataset_builder()
            .with_data(&ndarray::arr2(&[[0u32, 1, 9999]]))
            .create("membrane/triangles")
            .unwrap();
    });
    let e = analyze_file(&p, &opts).unwrap_err();
    assert!(e.to_string().contains("9999"), "{e}");
    // Triangles of the wrong shape.
    let p = tamper("badshape.h5", &|f| {
        f.unlink("membrane/triangles").unwrap();
        f.new_dataset_builder()
            .with_data(&[0u32, 1, 2, 3])
            .create("membrane/triangles")
            .unwrap();
    });
    let e = analyze_file(&p, &opts).unwrap_err();
    assert!(matches!(e, IoError::Shape { .. }), "{e}");
    assert!(e.to_string().contains("/membrane/triangles"), "{e}");
    // Positions missing.
    let p = tamper("nopos.h5", &|f| f.unlink("membrane/positions").unwrap());
    let e = analyze_file(&p, &opts).unwrap_err();
    assert!(e.to_string().contains("positions"), "{e}");
    // Step dataset shorter than the frame count: the reader caps the frames.
    let p = tamper("short.h5", &|f| {
        f.dataset("membrane/step").unwrap().resize(5).unwrap();
    });
    let r = TrajectoryReader::open(&p).unwrap();
    assert_eq!(r.membrane_frames().unwrap(), 5);
    assert_eq!(analyze_file(&p, &opts).unwrap().frames.len(), 5);
    // Positions stored as strings.
    let p = tamper("strings.h5", &|f| {
        f.unlink("membrane/positions").unwrap();
        f.new_dataset::<hdf5::types::VarLenUnicode>()
            .shape((20, 42, 3))
            .create("membrane/positions")
            .unwrap();
    });
    let e = analyze_file(&p, &opts).unwrap_err();
    assert_clear(&e, "strings.h5");
    // Missing metadata attribute.
    let p = tamper("noseed.h5", &|f| f.delete_attr("seed").unwrap());
    let e = TrajectoryReader::open(&p).err().unwrap();
    assert!(matches!(e, IoError::MissingAttribute { .. }), "{e}");
}
