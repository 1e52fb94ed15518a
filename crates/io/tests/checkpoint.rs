//! Checkpoints: bit-exact round trip, atomic replacement, clear errors on bad files.

mod common;

use common::*;
use glam::DVec3;
use hemodpd_io::checkpoint::{ArrayData, Checkpoint, ScalarValue};
use hemodpd_io::IoError;

fn sample() -> Checkpoint {
    let mut noise = Noise(99);
    let mut ck = Checkpoint::new(123_456, 1234.5678e-3, u64::MAX - 7, "[run]\nseed = 1\n");
    let pos: Vec<DVec3> = (0..1000).map(|_| noise.vec3() * 1e3).collect();
    ck.insert_vec3("positions", &pos);
    // Values that a lossy path would change: subnormals, -0.0, NaN payloads, infinities, extremes.
    let tricky = vec![
        f64::MIN_POSITIVE / 3.0,
        -0.0,
        f64::from_bits(0x7ff8_0000_dead_beef),
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::MAX,
        f64::EPSILON,
        0.1 + 0.2,
    ];
    ck.insert_f64("tricky", tricky);
    ck.insert_f64_shaped("matrix", vec![2, 3, 4], (0..24).map(|i| i as f64 / 7.0).collect());
    ck.insert_u64("ids", (0..1000).map(|i| i * 3 + (1 << 40)).collect());
    ck.insert_u32("cells", vec![0, 1, u32::MAX]);
    ck.insert_u8("types", (0..1000).map(|i| (i % 4) as u8).collect());
    ck.insert_f64("empty", vec![]);
    ck.set_scalar("controller_integral", ScalarValue::F64(-1.0 / 3.0));
    ck.set_scalar("rng_counter", ScalarValue::U64(u64::MAX));
    ck.set_scalar("offset", ScalarValue::I64(-42));
    ck.set_scalar("body_force_on", ScalarValue::Bool(true));
    ck.set_scalar("phase", ScalarValue::Str("relaxation — µm".to_string()));
    ck
}

#[test]
fn round_trip_is_bit_exact() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ck.h5");
    let ck = sample();
    ck.save_atomic(&path).unwrap();
    assert!(!dir.path().join("ck.h5.tmp").exists(), "temporary file renamed away");
    let back = Checkpoint::load(&path).unwrap();
    assert_eq!(back.bitwise_difference(&ck), None);
    assert_eq!(back.source.as_deref(), Some(path.as_path()));
    let pos = back.vec3s("positions", Some(1000)).unwrap();
    assert_eq!(pos, ck.vec3s("positions", None).unwrap());
    assert_eq!(back.array("matrix").unwrap().shape, vec![2, 3, 4]);
    assert_eq!(back.scalar_str("phase").unwrap(), "relaxation — µm");
    assert!(back.scalar_bool("body_force_on").unwrap());
    assert_eq!(back.scalar_u64("rng_counter").unwrap(), u64::MAX);
    assert_eq!(back.scalar_i64("offset").unwrap(), -42);
    let nan = back.f64s("tricky").unwrap()[2];
    assert_eq!(nan.to_bits(), 0x7ff8_0000_dead_beef);
    assert!(matches!(back.array("empty").unwrap().data, ArrayData::F64(ref v) if v.is_empty()));

    // Typed accessors report what is wrong, with the file name.
    let e = back.vec3s("positions", Some(999)).unwrap_err();
    assert!(matches!(e, IoError::Shape { .. }), "{e}");
    assert!(e.to_string().contains("ck.h5"), "{e}");
    let e = back.u32s("positions").unwrap_err();
    assert!(e.to_string().contains("/arrays/positions"), "{e}");
    let e = back.f64s("velocities").unwrap_err();
    assert!(matches!(e, IoError::MissingDataset { .. }), "{e}");
    assert!(back.scalar_f64("rng_counter").is_err());
    assert!(back.scalar("nope").is_err());
}

#[test]
fn save_replaces_atomically() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ck.h5");
    let mut ck = sample();
    ck.save_atomic(&path).unwrap();
    // A stale temporary file from a killed save does not matter.
    std::fs::write(dir.path().join("ck.h5.tmp"), b"half written").unwrap();
    ck.step += 1;
    ck.insert_f64("extra", vec![1.0]);
    ck.save_atomic(&path).unwrap();
    let back = Checkpoint::load(&path).unwrap();
    assert_eq!(back.step, ck.step);
    assert_eq!(back.bitwise_difference(&ck), None);
    assert!(!dir.path().join("ck.h5.tmp").exists());
}

#[test]
fn bad_checkpoints_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.h5");
    sample().save_atomic(&good).unwrap();

    // Missing file.
    let e = Checkpoint::load(dir.path().join("none.h5")).unwrap_err();
    assert!(e.to_string().contains("none.h5"), "{e}");

    // Garbage bytes.
    let garbage = dir.path().join("garbage.h5");
    std::fs::write(&garbage, vec![0x5a; 4096]).unwrap();
    let e = Checkpoint::load(&garbage).unwrap_err();
    assert!(matches!(e, IoError::Open { .. }), "{e}");
    assert!(e.to_string().contains("garbage.h5"), "{e}");

    // Truncated file: every cut gives an error, never a panic.
    let bytes = std::fs::read(&good).unwrap();
    let cut = dir.path().join("cut.h5");
    for frac in [0.1, 0.5, 0.9, 0.99] {
        std::fs::write(&cut, &bytes[..(bytes.len() as f64 * frac) as usize]).unwrap();
        let e = Checkpoint::load(&cut).unwrap_err();
        assert!(e.to_string().contains("cut.h5"), "{e}");
    }

    // A foreign HDF5 file, and a trajectory passed as a checkpoint.
    let foreign = dir.path().join("foreign.h5");
    {
        let f = hdf5::File::create(&foreign).unwrap();
        f.new_dataset_builder()
            .with_data(&[1.0f64, 2.0])
            .create("data")
            .unwrap();
    }
    let e = Checkpoint::load(&foreign).unwrap_err();
    assert!(matches!(e, IoError::Foreign { .. }), "{e}");
    assert!(e.to_string().contains("not a hemodpd checkpoint file"), "{e}");
    let traj = dir.path().join("traj.h5");
    hemodpd_io::TrajectoryWriter::create(&traj, &meta())
        .unwrap()
        .close()
        .unwrap();
    let e = Checkpoint::load(&traj).unwrap_err();
    assert!(e.to_string().contains("hemodpd-trajectory"), "{e}");

    // A newer format version.
    let newer = dir.path().join("newer.h5");
    std::fs::copy(&good, &newer).unwrap();
    {
        let f = hdf5::File::open_rw(&newer).unwrap();
        f.delete_attr("format_version").unwrap();
        f.new_attr::<u32>()
            .shape(())
            .create("format_version")
            .unwrap()
            .write_scalar(&99u32)
            .unwrap();
    }
    let e = Checkpoint::load(&newer).unwrap_err();
    assert!(matches!(e, IoError::UnsupportedVersion { found: 99, .. }), "{e}");

    // A missing required attribute.
    let nostep = dir.path().join("nostep.h5");
    std::fs::copy(&good, &nostep).unwrap();
    hdf5::File::open_rw(&nostep).unwrap().delete_attr("step").unwrap();
    let e = Checkpoint::load(&nostep).unwrap_err();
    assert!(matches!(e, IoError::MissingAttribute { .. }), "{e}");
    assert!(e.to_string().contains("step"), "{e}");
}

#[test]
fn corrupted_array_bytes_fail_the_checksum() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ck.h5");
    let mut ck = Checkpoint::new(1, 0.0, 1, "");
    let marker = 12345.678_f64;
    ck.insert_f64("velocities", vec![marker; 4096]);
    ck.save_atomic(&path).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    let pat = marker.to_le_bytes();
    let at = bytes
        .windows(8)
        .position(|w| w == pat)
        .expect("array bytes in the file");
    bytes[at + 8 * 100 + 3] ^= 0x40;
    std::fs::write(&path, &bytes).unwrap();
    let e = Checkpoint::load(&path).unwrap_err();
    assert!(e.to_string().contains("/arrays/velocities"), "{e}");
}
