//! Pair-force loop of the engine on the standard DPD fluid (ρ = 3, a = 25, γ = 4.5, kBT = 1):
//! one full force evaluation (cell sort + pair loop + scatter), per loop scheme and kernel.
//! `cargo bench --bench engine_pairs`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::DVec3;
use hemodpd_engine::{init, ForceField, ForceScheme, PairParams, SimConfig, Simulation};

fn fluid(l: f64, scheme: ForceScheme, s: f64) -> Simulation {
    let mut config = SimConfig::new(DVec3::splat(l), 0.01, 1);
    config.scheme = scheme;
    let mut pp = PairParams::groot_warren();
    pp.s = s;
    let field = ForceField::single(pp);
    let p = init::fluid(&config, &field, &init::FluidSpec::standard(), 2).expect("fluid");
    let mut sim = Simulation::new(config, field, p).expect("simulation");
    sim.run(50).expect("equilibration");
    sim
}

fn pairs(c: &mut Criterion) {
    let mut g = c.benchmark_group("engine_pairs");
    g.sample_size(10);
    let l = 12.0;
    let n = (3.0 * l * l * l) as u64;
    g.throughput(Throughput::Elements(n));
    for (name, scheme, s) in [
        ("half_shell_s1", ForceScheme::HalfShell, 1.0),
        ("gather_s1", ForceScheme::Gather, 1.0),
        ("half_shell_s0.5", ForceScheme::HalfShell, 0.5),
    ] {
        let mut sim = fluid(l, scheme, s);
        g.bench_with_input(BenchmarkId::new(name, n), &n, |b, _| {
            b.iter(|| sim.recompute_forces().expect("forces"))
        });
    }
    g.finish();
}

criterion_group!(benches, pairs);
criterion_main!(benches);
