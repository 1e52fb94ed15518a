//! Throughput of the standard DPD fluid (ρ = 3, a = 25, γ = 4.5, kBT = 1, rc = 1, Δt = 0.01),
//! the same system as `shared/bench/lammps/in.dpd_fluid`.
//!
//! `cargo run --release -p hemodpd-engine --example fluid_bench -- L THREADS [STEPS] [NEQ] [SCHEME]`
//! (defaults STEPS 1000, NEQ 200, SCHEME half; `gather` for the other pair loop). Prints one
//! line: particle-steps/s of the timed steps, ⟨T⟩ and ⟨p⟩ sampled every 100 steps.
//! `SORT_EVERY=k` re-sorts the storage every k steps (`SimConfig::sort_every`; default 10 here,
//! as the fluid scenario does; 0 turns it off).
//!
//! `FLUID=dense` runs the dense fluid instead ([`PairParams::dense`]: ρ = 10, a = 100, γ = 41,
//! s = 1/8, Δt = 0.003), the system of `scripts/lammps/in.dpd_dense` (`pair_style dpd/ext`).

use std::time::Instant;

use glam::DVec3;
use hemodpd_engine::params::{DENSE_FLUID_DENSITY, DENSE_FLUID_TIMESTEP};
use hemodpd_engine::{init, observe, EngineError, ForceField, ForceScheme, PairParams, SimConfig, Simulation};

/// The allocator of the `hemodpd` binary (mimalloc, with transparent huge pages for large
/// arrays), so that this benchmark measures what a scenario run gets.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> Result<(), EngineError> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let l: f64 = a.first().and_then(|s| s.parse().ok()).unwrap_or(20.0);
    let threads: usize = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(1);
    let steps: u64 = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(1000);
    let neq: u64 = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(200);
    let scheme = match a.get(4).map(String::as_str) {
        Some("gather") => ForceScheme::Gather,
        _ => ForceScheme::HalfShell,
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| EngineError::ThreadPool(e.to_string()))?;
    let dense = std::env::var("FLUID").is_ok_and(|f| f == "dense");
    let (pair, density, dt) = if dense {
        (PairParams::dense(), DENSE_FLUID_DENSITY, DENSE_FLUID_TIMESTEP)
    } else {
        (PairParams::groot_warren(), 3.0, 0.01)
    };
    pool.install(|| {
        let mut config = SimConfig::new(DVec3::splat(l), dt, 34387);
        config.scheme = scheme;
        config.sort_every = std::env::var("SORT_EVERY").ok().and_then(|s| s.parse().ok()).unwrap_or(10);
        let field = ForceField::single(pair);
        let spec = init::FluidSpec {
            density,
            placement: if dense {
                // a = 100 at ρ = 10 from random positions takes long to relax; the timed steps
                // start from an equilibrated liquid either way
                init::Placement::JitteredLattice { jitter: 0.1 }
            } else {
                init::Placement::Random
            },
            ..init::FluidSpec::standard()
        };
        let p = init::fluid(&config, &field, &spec, 4928459)?;
        let n = p.len();
        let mut sim = Simulation::new(config, field, p)?;
        sim.run(neq)?;
        let (mut ts, mut ps) = (Vec::new(), Vec::new());
        let t0 = Instant::now();
        for k in 0..steps {
            if k % 100 == 99 {
                let w = sim.step_with_virial()?;
                ts.push(observe::temperature(sim.particles(), sim.field()));
                ps.push(observe::pressure(sim.particles(), sim.field(), sim.domain(), &w));
            } else {
                sim.step()?;
            }
        }
        let secs = t0.elapsed().as_secs_f64();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        println!(
            "hemodpd L={l} N={n} threads={threads} scheme={scheme:?} dt={dt}: {:.4e} particle-steps/s, T={:.5}, p={:.4} [loop {secs:.2} s / {steps} steps]",
            n as f64 * steps as f64 / secs,
            mean(&ts),
            mean(&ps)
        );
        Ok(())
    })
}
