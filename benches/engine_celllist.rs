//! Cell-list build (counting sort + sorted copies) for the standard fluid.
//! `cargo bench --bench engine_celllist`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::DVec3;
use hemodpd_engine::cells::{CellGrid, CellList};
use hemodpd_engine::{init, ForceField, PairParams, PeriodicBox, SimConfig};

fn celllist(c: &mut Criterion) {
    let mut g = c.benchmark_group("engine_celllist");
    g.sample_size(10);
    for l in [12.0, 20.0] {
        let config = SimConfig::new(DVec3::splat(l), 0.01, 1);
        let field = ForceField::single(PairParams::groot_warren());
        let spec = init::FluidSpec {
            placement: init::Placement::Random,
            ..init::FluidSpec::standard()
        };
        let p = init::fluid(&config, &field, &spec, 2).expect("fluid");
        let domain = PeriodicBox::new(config.box_lengths).expect("box");
        let mut cl = CellList::new(CellGrid::new(&domain, 1.0).expect("grid"));
        let n = p.len() as u64;
        g.throughput(Throughput::Elements(n));
        g.bench_with_input(BenchmarkId::new("build", n), &n, |b, _| {
            b.iter(|| cl.build(&p.pos, &p.ptype, &p.id, |i| p.vel[i]))
        });
    }
    g.finish();
}

criterion_group!(benches, celllist);
criterion_main!(benches);
