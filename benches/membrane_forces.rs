//! Membrane forces (Eq. 1: WLC + C/A, bending, global area and volume) on the relaxed
//! Evans–Fung mesh, stress-free reference: one `add_forces` call (serial) and one
//! `add_forces_parallel` call, at N = 500 and 5000. The meshes come from the mesh cache.
//! `cargo bench --bench membrane_forces`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::DVec3;
use hemodpd_membrane::forces::{DEFAULT_K_AREA_N_PER_M, DEFAULT_K_VOLUME_N_PER_M2};
use hemodpd_membrane::{MembraneModel, ModelParams};
use hemodpd_scenario::mesh_cache;

fn membrane(c: &mut Criterion) {
    let mut g = c.benchmark_group("membrane_forces");
    g.sample_size(20);
    for n in [500usize, 5000] {
        let (mesh, _) = mesh_cache::relaxed_mesh(n, 1).expect("mesh");
        let params = ModelParams::coarse_grained(n, 300.0).expect("parameters");
        let constants = mesh_cache::constants_um_pn(&params, DEFAULT_K_AREA_N_PER_M, DEFAULT_K_VOLUME_N_PER_M2);
        let topo = mesh.topology().expect("topology");
        let model = MembraneModel::stress_free(&topo, &mesh.vertices, &constants).expect("model");
        // a slightly deformed state, so that no term is at its zero
        let x: Vec<DVec3> = mesh
            .vertices
            .iter()
            .enumerate()
            .map(|(i, p)| *p * (1.0 + 0.01 * ((i % 7) as f64 - 3.0) / 3.0))
            .collect();
        let mut f = vec![DVec3::ZERO; x.len()];
        g.throughput(Throughput::Elements(n as u64));
        g.bench_with_input(BenchmarkId::new("serial", n), &n, |b, _| {
            b.iter(|| model.add_forces(&x, &mut f).expect("forces"))
        });
        let mut ws = model.workspace();
        g.bench_with_input(BenchmarkId::new("parallel", n), &n, |b, _| {
            b.iter(|| model.add_forces_parallel(&x, &mut f, &mut ws).expect("forces"))
        });
    }
    g.finish();
}

criterion_group!(benches, membrane);
criterion_main!(benches);
