use glam::DVec3;
use hemodpd_io::*;
fn main() {
    let path = "/tmp/iocheck/bench.h5";
    let meta = RunMetadata::new("b", "", 1, UnitSystem::si());
    let mut w = TrajectoryWriter::create(path, &meta).unwrap();
    w.write_mesh(&[[0, 1, 2]]).unwrap();
    let pos = vec![DVec3::ONE; 500];
    let t0 = std::time::Instant::now();
    for s in 0..3000u64 {
        let f = FrameScalar { name: "force", value: 1.0, quantity: Quantity::Force };
        w.append_membrane_frame(s, s as f64, &pos, Some(&pos), &[f]).unwrap();
    }
    let dt = t0.elapsed();
    w.close().unwrap();
    let size = std::fs::metadata(path).unwrap().len();
    println!("3000 frames in {:?} ({:.2} ms/frame), file {} bytes, raw {} bytes", dt, dt.as_secs_f64() / 3.0, size, 3000 * 500 * 48);
}
