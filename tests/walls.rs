//! Walls: reflection keeps every fluid particle out, the adaptive control flattens the near-wall
//! density, Poiseuille flow in a tube and plane Couette flow against their analytic profiles.
//! Each test prints its numbers (`cargo test --release --test walls -- --nocapture`).

use glam::DVec3;
use hemodpd_engine::walls::{self, AdaptRecord, Reflection, WallConfig, WallSetup, WallShape, Walls};
use hemodpd_engine::{SimConfig, Simulation};

/// Reverse-Poiseuille viscosity of the standard fluid, docs/engine.md (0.846 ± 0.002).
const ETA_REVERSE_POISEUILLE: f64 = 0.846;

fn tube(radius: f64, length: f64, seed: u64, reflection: Reflection) -> Simulation<Walls> {
    let side = 2.0 * (radius + 1.0) + 0.5;
    let config = SimConfig::new(DVec3::new(side, side, length), 0.01, seed);
    let shape = WallShape::Cylinder { axis: 2, centre: [0.5 * side; 2], radius };
    let (field, p) = walls::build(&config, &WallSetup::standard(shape), seed).unwrap();
    let cfg = WallConfig { reflection, bins: 5, gain: 3.0, update_every: 500, ..WallConfig::default() };
    Simulation::with_extension(config, field, p, Walls::new(shape, cfg).unwrap()).unwrap()
}

fn plates(gap: f64, width: f64, u: f64, seed: u64) -> Simulation<Walls> {
    let config = SimConfig::new(DVec3::new(width, width, gap + 2.0), 0.01, seed);
    let shape = WallShape::Plates {
        axis: 2,
        lower: 1.0,
        upper: 1.0 + gap,
        period: gap + 2.0,
        lower_velocity: DVec3::new(-u, 0.0, 0.0),
        upper_velocity: DVec3::new(u, 0.0, 0.0),
    };
    let (field, p) = walls::build(&config, &WallSetup::standard(shape), seed).unwrap();
    let cfg = WallConfig { bins: 5, gain: 3.0, update_every: 500, ..WallConfig::default() };
    Simulation::with_extension(config, field, p, Walls::new(shape, cfg).unwrap()).unwrap()
}

fn print_history(h: &[AdaptRecord]) {
    for r in h {
        let rel: Vec<String> = r.relative_density.iter().map(|x| format!("{x:.3}")).collect();
        let f: Vec<String> = r.forces.iter().map(|x| format!("{x:.2}")).collect();
        println!("  iter {:2} step {:6} max|ρ/ρ0−1| {:.4}  ρ/ρ0 [{}]  F [{}]", r.iteration, r.step, r.max_deviation, rel.join(" "), f.join(" "));
    }
}

/// Max |ρ_k/ρ0 − 1| of the measured near-wall profile.
fn max_dev(w: &Walls) -> f64 {
    w.relative_density().iter().map(|r| (r - 1.0).abs()).fold(0.0, f64::max)
}

/// Radial profile of the axial velocity and density in a tube: (r centres, v_z, ρ).
struct Radial {
    width: f64,
    count: Vec<f64>,
    vz: Vec<f64>,
    samples: usize,
    length: f64,
}

impl Radial {
    fn new(radius: f64, nbins: usize, length: f64) -> Self {
        Self { width: radius / nbins as f64, count: vec![0.0; nbins], vz: vec![0.0; nbins], samples: 0, length }
    }
    fn sample(&mut self, sim: &Simulation<Walls>) {
        let shape = *sim.extension().shape();
        let p = sim.particles();
        for i in 0..p.len() {
            if p.ptype[i] != walls::FLUID_TYPE {
                continue;
            }
            let r = shape.signed_distance(p.pos[i]) + radius_of(&shape);
            let b = (r / self.width) as usize;
            if b < self.count.len() {
                self.count[b] += 1.0;
                self.vz[b] += p.vel[i].z;
            }
        }
        self.samples += 1;
    }
    fn centres(&self) -> Vec<f64> {
        (0..self.count.len()).map(|b| (b as f64 + 0.5) * self.width).collect()
    }
    fn velocity(&self) -> Vec<f64> {
        self.vz.iter().zip(&self.count).map(|(v, c)| v / c.max(1.0)).collect()
    }
    fn density(&self) -> Vec<f64> {
        (0..self.count.len())
            .map(|b| {
                let (r0, r1) = (b as f64 * self.width, (b + 1) as f64 * self.width);
                self.count[b] / (self.samples as f64 * std::f64::consts::PI * (r1 * r1 - r0 * r0) * self.length)
            })
            .collect()
    }
}

fn radius_of(s: &WallShape) -> f64 {
    match s {
        WallShape::Cylinder { radius, .. } => *radius,
        _ => 0.0,
    }
}

/// Weighted least squares y = c0 + c1·x (weights w): (c0, c1).
fn fit_line(x: &[f64], y: &[f64], w: &[f64]) -> (f64, f64) {
    let (mut s, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for i in 0..x.len() {
        s += w[i];
        sx += w[i] * x[i];
        sy += w[i] * y[i];
        sxx += w[i] * x[i] * x[i];
        sxy += w[i] * x[i] * y[i];
    }
    let c1 = (s * sxy - sx * sy) / (s * sxx - sx * sx);
    ((sy - c1 * sx) / s, c1)
}

/// Adapts the near-wall force for `updates` periods (with the flow on) and returns the history.
fn adapt(sim: &mut Simulation<Walls>, updates: u64) -> Vec<AdaptRecord> {
    let m = sim.extension().config().update_every;
    sim.extension_mut().set_adapt(true);
    sim.run(updates * m).unwrap();
    sim.extension_mut().set_adapt(false);
    sim.extension().history().to_vec()
}

/// Tube Poiseuille run: returns (η from the parabola, slip fraction, centre velocity,
/// max near-wall density deviation, reflections).
fn poiseuille(adaptive: bool, steps: u64, seed: u64) -> (f64, f64, f64, f64, u64) {
    let (radius, length, g) = (4.0, 6.0, 0.1);
    let mut sim = tube(radius, length, seed, Reflection::BounceBack);
    sim.set_body_force(0, DVec3::new(0.0, 0.0, g)).unwrap();
    if adaptive {
        let h = adapt(&mut sim, 12);
        println!("tube adaptation (R = {radius}, bins of 0.2 rc, M = 500, α = 3):");
        print_history(&h);
    } else {
        sim.extension_mut().set_adapt(false);
    }
    sim.run(1500).unwrap(); // flow development (viscous time R²ρ/η ≈ 57 ≈ 5700 steps; overlap with adaptation)
    sim.extension_mut().reset_measurements();
    let mut prof = Radial::new(radius, 16, length);
    for i in 0..steps {
        sim.step().unwrap();
        if i % 5 == 0 {
            prof.sample(&sim);
        }
    }
    let rho0 = sim.extension().target_density().unwrap();
    let (r, v, n) = (prof.centres(), prof.velocity(), prof.count.clone());
    let r2: Vec<f64> = r.iter().map(|x| x * x).collect();
    let (a, b) = fit_line(&r2, &v, &n);
    let b = -b;
    let eta = rho0 * g / (4.0 * b);
    let slip = (a - b * radius * radius) / a;
    println!("tube R = {radius}, g = {g}, {} samples, ρ0 = {rho0:.4}, adaptive = {adaptive}", prof.samples);
    let rho = prof.density();
    for k in 0..r.len() {
        println!("  r {:.3}  v_z {:.4}  fit {:.4}  ρ/ρ0 {:.4}", r[k], v[k], a - b * r2[k], rho[k] / rho0);
    }
    let dev = max_dev(sim.extension());
    println!(
        "  centre velocity {a:.4}, η = {eta:.4}, slip fraction {slip:.4}, near-wall max |ρ/ρ0−1| = {dev:.4} ({:?}), reflections {}",
        sim.extension().relative_density().iter().map(|x| (x * 1000.0).round() / 1000.0).collect::<Vec<_>>(),
        sim.extension().reflections()
    );
    (eta, slip, a, dev, sim.extension().reflections())
}

/// Couette run: returns (η from the wall stress / shear rate, slip at lower, slip at upper
/// (fractions of the wall speed difference), shear rate).
fn couette(steps: u64, seed: u64) -> (f64, f64, f64, f64) {
    let (gap, width, u) = (8.0, 6.0, 1.0);
    let mut sim = plates(gap, width, u, seed);
    let h = adapt(&mut sim, 8);
    println!("plates adaptation (gap {gap}, bins of 0.2 rc, M = 500, α = 3):");
    print_history(&h);
    sim.run(2000).unwrap();
    sim.extension_mut().reset_measurements();
    let shape = *sim.extension().shape();
    let nb = 16;
    let (mut cnt, mut vx) = (vec![0.0; nb], vec![0.0; nb]);
    let mut wall_force = [0.0f64; 2];
    for _ in 0..steps {
        sim.step().unwrap();
        let p = sim.particles();
        for i in 0..p.len() {
            if p.ptype[i] == walls::FLUID_TYPE {
                let b = (((p.pos[i].z - 1.0) / gap * nb as f64) as usize).min(nb - 1);
                cnt[b] += 1.0;
                vx[b] += p.vel[i].x;
            } else {
                wall_force[shape.side(p.pos[i])] += p.force[i].x;
            }
        }
    }
    let t = steps as f64 * 0.01;
    let imp = sim.extension().impulse();
    let area = width * width;
    let f_lower = (wall_force[0] + imp[0].x / t / 0.01 * 0.01) / steps as f64;
    let f_upper = (wall_force[1] + imp[1].x / 0.01) / steps as f64;
    let f_lower = f_lower + 0.0 * t;
    let _ = f_lower;
    let f_lower = (wall_force[0] + imp[0].x / 0.01) / steps as f64;
    let stress = (f_lower - f_upper) / (2.0 * area);
    let z: Vec<f64> = (0..nb).map(|b| 1.0 + (b as f64 + 0.5) * gap / nb as f64).collect();
    let v: Vec<f64> = vx.iter().zip(&cnt).map(|(a, c)| a / c).collect();
    let (c0, c1) = fit_line(&z, &v, &cnt);
    let eta = stress / c1;
    let slip_lo = ((c0 + c1 * 1.0) - (-u)) / (2.0 * u);
    let slip_hi = (u - (c0 + c1 * (1.0 + gap))) / (2.0 * u);
    println!("couette gap {gap}, ±{u}: shear rate {c1:.4} (no-slip {:.4}), wall forces {f_lower:.3} {f_upper:.3}, stress {stress:.4}, η = {eta:.4}", 2.0 * u / gap);
    for k in 0..nb {
        println!("  z {:.3}  v_x {:.4}  fit {:.4}  ρ {:.3}", z[k], v[k], c0 + c1 * z[k], cnt[k] / (steps as f64 * area * gap / nb as f64));
    }
    println!("  slip lower {slip_lo:.4}, upper {slip_hi:.4}, near-wall max dev {:.4}, reflections {}", max_dev(sim.extension()), sim.extension().reflections());
    (eta, slip_lo, slip_hi, c1)
}

#[test]
fn explore() {
    let t0 = std::time::Instant::now();
    poiseuille(false, 6000, 1);
    println!("{:?}", t0.elapsed());
    let t0 = std::time::Instant::now();
    poiseuille(true, 6000, 1);
    println!("{:?}", t0.elapsed());
    let t0 = std::time::Instant::now();
    couette(6000, 2);
    println!("{:?}", t0.elapsed());
}
