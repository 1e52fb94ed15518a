#![allow(dead_code)]
use glam::DVec3;
use hemodpd_engine::{init, ForceField, ForceScheme, PairParams, SimConfig, Simulation};

pub fn standard(l: f64, dt: f64, seed: u64, scheme: ForceScheme) -> Simulation {
    let mut config = SimConfig::new(DVec3::splat(l), dt, seed);
    config.scheme = scheme;
    let field = ForceField::single(PairParams::groot_warren());
    let p = init::fluid(&config, &field, &init::FluidSpec::standard(), seed ^ 0xABCD).unwrap();
    Simulation::new(config, field, p).unwrap()
}

pub fn bits(v: &[DVec3]) -> Vec<[u64; 3]> {
    v.iter()
        .map(|x| [x.x.to_bits(), x.y.to_bits(), x.z.to_bits()])
        .collect()
}
