//! ⟨kBT⟩ and ⟨p⟩ of the standard fluid as a function of Δt (Groot–Warren modified velocity
//! Verlet). Usage:
//! `cargo run --release -p hemodpd-engine --example temperature_vs_dt -- [L] [time] [lambda] [dts...]`
//! (defaults: L = 10, 40 time units sampled after 5 time units of equilibration, λ = 0.5,
//! Δt = 0.005 0.01 0.02 0.03 0.04 0.05 0.06). Prints a markdown table.

use glam::DVec3;
use hemodpd_engine::{init, observe, EngineError, ForceField, PairParams, SimConfig, Simulation};

fn main() -> Result<(), EngineError> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let l: f64 = args.first().and_then(|s| s.parse().ok()).unwrap_or(10.0);
    let time: f64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(40.0);
    let lambda: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(0.5);
    let mut dts: Vec<f64> = args.iter().skip(3).filter_map(|s| s.parse().ok()).collect();
    if dts.is_empty() {
        dts = vec![0.005, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06];
    }
    println!(
        "standard fluid ρ=3 a=25 γ=4.5 kBT=1, L={l} (N={}), λ={lambda}, {time} time units sampled every step after 5 of equilibration",
        (3.0 * l * l * l) as u64
    );
    println!();
    println!("| Δt | ⟨kBT⟩ | SE | (⟨kBT⟩ − 1) % | ⟨p⟩ | SE |");
    println!("|---|---|---|---|---|---|");
    for dt in dts {
        let mut config = SimConfig::new(DVec3::splat(l), dt, 77);
        config.lambda = lambda;
        let field = ForceField::single(PairParams::groot_warren());
        let p = init::fluid(&config, &field, &init::FluidSpec::standard(), 5)?;
        let mut sim = Simulation::new(config, field, p)?;
        let neq = (5.0 / dt).round() as u64;
        let ns = (time / dt).round() as usize;
        let res = sim.run(neq).and_then(|_| {
            let (mut ts, mut ps) = (Vec::with_capacity(ns), Vec::with_capacity(ns));
            for _ in 0..ns {
                let w = sim.step_with_virial()?;
                ts.push(observe::temperature(sim.particles(), sim.field()));
                ps.push(observe::pressure(sim.particles(), sim.field(), sim.domain(), &w));
            }
            Ok((ts, ps))
        });
        match res {
            Ok((ts, ps)) => {
                let (t, set) = observe::block_error(&ts)?;
                let (p, sep) = observe::block_error(&ps)?;
                println!(
                    "| {dt} | {t:.4} | {set:.4} | {:+.2} | {p:.3} | {sep:.3} |",
                    100.0 * (t - 1.0)
                );
            }
            Err(e) => println!("| {dt} | unstable: {e} | | | | |"),
        }
    }
    Ok(())
}
