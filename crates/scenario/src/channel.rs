//! Wall-bounded validation flows, in model units (docs/walls.md):
//! `kind = "poiseuille-tube"` (body-force-driven flow in a tube, against the parabola) and
//! `kind = "couette"` (plates moving at ±U, against the line; viscosity from the wall stress).
//!
//! Both: cut the walls out of an equilibrated fluid, adapt the near-wall force with the flow on
//! (or load a saved profile), let the flow develop, sample the profiles, fit, and time the same
//! number of fluid particles in a periodic box for the wall overhead.

use crate::file::{CouetteScenario, FluidSection, InitialWallForce, TubeScenario, WallRunSection, WallsSection};
use crate::{RunContext, RunError};
use glam::DVec3;
use hemodpd_engine::walls::{self, WallConfig, WallForceProfile, WallSetup, WallShape, Walls};
use hemodpd_engine::{init, observe, ForceField, PairParams, SimConfig, Simulation};
use serde_json::json;
use std::path::Path;
use std::time::Instant;

fn engine_err(e: hemodpd_engine::EngineError) -> RunError {
    RunError::Engine(e.to_string())
}

fn pair(f: &FluidSection) -> PairParams {
    PairParams {
        a: f.a,
        gamma: f.gamma,
        kbt: f.kbt,
        rc: f.cutoff,
        s: f.weight_exponent,
    }
}

/// Weighted least squares y = c0 + c1 x (weights w): returns (c0, c1).
pub fn fit_line(x: &[f64], y: &[f64], w: &[f64]) -> (f64, f64) {
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

/// Builds the walled simulation; loads the force file if it matches. Returns the simulation and
/// where the profile came from.
fn build(
    shape: WallShape,
    box_lengths: DVec3,
    f: &FluidSection,
    w: &WallsSection,
    r: &WallRunSection,
    seed: u64,
    base_dir: &Path,
) -> Result<(Simulation<Walls>, String), RunError> {
    let mut config = SimConfig::new(box_lengths, r.timestep, seed);
    config.lambda = r.lambda;
    let p = pair(f);
    let setup = WallSetup {
        shape,
        pair: p,
        density: f.density,
        thickness: f.cutoff,
        equilibration_steps: r.equilibration_steps,
    };
    let (field, particles) = walls::build(&config, &setup, seed).map_err(engine_err)?;
    let cfg = WallConfig {
        reflection: w.reflection,
        bins: w.bins,
        rc: f.cutoff,
        law: w.law,
        gain: w.gain,
        update_every: w.update_every,
        adapt: false,
        target_density: None,
    };
    let mut ext = Walls::new(shape, cfg).map_err(engine_err)?;
    let mut source = format!("{:?}", w.initial);
    let mut loaded = false;
    if let Some(file) = &w.force_file {
        let path = base_dir.join(file);
        if path.exists() {
            let text = std::fs::read_to_string(&path).map_err(|source| RunError::Io {
                path: path.clone(),
                source,
            })?;
            let prof =
                WallForceProfile::from_csv(&text).map_err(|e| RunError::Output(format!("{}: {e}", path.display())))?;
            if prof.matches(&p, f.density, w.bins) {
                ext = ext.with_profile(&prof).map_err(engine_err)?;
                source = format!("file {}", path.display());
                loaded = true;
            } else {
                source = format!(
                    "{:?} ({} is for another fluid or bin layout)",
                    w.initial,
                    path.display()
                );
            }
        }
    }
    if !loaded && w.initial == InitialWallForce::HalfSpace {
        ext = ext
            .with_profile(&WallForceProfile::half_space(p, f.density, w.bins))
            .map_err(engine_err)?;
    }
    let sim = Simulation::with_extension(config, field, particles, ext).map_err(engine_err)?;
    Ok((sim, source))
}

/// Adaptation (flow on), then the force file is written. Returns the convergence table.
fn adapt(
    sim: &mut Simulation<Walls>,
    s: &WallsSection,
    f: &FluidSection,
    base_dir: &Path,
    ctx: &RunContext,
) -> Result<serde_json::Value, RunError> {
    if s.adaptive && s.adapt_iterations > 0 {
        sim.extension_mut().set_adapt(true);
        sim.run(s.adapt_iterations * s.update_every).map_err(engine_err)?;
        sim.extension_mut().set_adapt(false);
    }
    let prof = sim.extension().profile(pair(f), f.density);
    let csv = prof.to_csv();
    let mut paths = vec![ctx.out_dir.join("wall_force.csv")];
    if let Some(file) = &s.force_file {
        if s.adaptive {
            paths.push(base_dir.join(file));
        }
    }
    for path in paths {
        std::fs::write(&path, &csv).map_err(|source| RunError::Io { path, source })?;
    }
    let table: Vec<_> = sim
        .extension()
        .history()
        .iter()
        .map(|h| json!({"iteration": h.iteration, "step": h.step, "max_density_deviation": h.max_deviation, "relative_density": h.relative_density, "forces": h.forces}))
        .collect();
    Ok(
        json!({ "iterations": table, "final_forces": sim.extension().forces(), "bin_centres": sim.extension().bin_centres() }),
    )
}

/// Seconds per (step × fluid particle) of the walled run and of a periodic box of the same
/// fluid with the same number of fluid particles.
fn overhead(
    sim: &mut Simulation<Walls>,
    f: &FluidSection,
    r: &WallRunSection,
    seed: u64,
) -> Result<serde_json::Value, RunError> {
    let steps = 500u64;
    let nf = sim
        .particles()
        .ptype
        .iter()
        .filter(|&&t| t == walls::FLUID_TYPE)
        .count();
    let sampling = true;
    sim.extension_mut().set_sampling(false);
    let t0 = Instant::now();
    sim.run(steps).map_err(engine_err)?;
    let tw = t0.elapsed().as_secs_f64() / (steps as f64 * nf as f64);
    sim.extension_mut().set_sampling(sampling);
    let l = (nf as f64 / f.density).cbrt().max(3.0 * f.cutoff);
    let mut config = SimConfig::new(DVec3::splat(l), r.timestep, seed);
    config.lambda = r.lambda;
    let field = ForceField::single(pair(f));
    let spec = init::FluidSpec {
        density: f.density,
        kbt: f.kbt,
        ..init::FluidSpec::standard()
    };
    let p = init::fluid(&config, &field, &spec, seed).map_err(engine_err)?;
    let n = p.len();
    let mut plain = Simulation::new(config, field, p).map_err(engine_err)?;
    plain.run(50).map_err(engine_err)?;
    let t0 = Instant::now();
    plain.run(steps).map_err(engine_err)?;
    let tp = t0.elapsed().as_secs_f64() / (steps as f64 * n as f64);
    Ok(json!({
        "seconds_per_fluid_particle_step_with_walls": tw,
        "seconds_per_particle_step_periodic": tp,
        "ratio": tw / tp,
        "fluid_particles": nf,
        "wall_particles": sim.particles().len() - nf,
        "periodic_particles": n,
        "steps_timed": steps,
        "threads": rayon::current_num_threads(),
    }))
}

fn write_csv(ctx: &RunContext, name: &str, header: &str, rows: &[Vec<f64>]) -> Result<(), RunError> {
    let mut s = String::from(header);
    s.push('\n');
    for r in rows {
        s += &r.iter().map(|x| format!("{x:e}")).collect::<Vec<_>>().join(",");
        s.push('\n');
    }
    let path = ctx.out_dir.join(name);
    std::fs::write(&path, s).map_err(|source| RunError::Io { path, source })
}

/// Runs `kind = "poiseuille-tube"`.
pub fn run_tube(s: &TubeScenario, ctx: &RunContext) -> Result<serde_json::Value, RunError> {
    let (f, t, r) = (&s.fluid, &s.tube, &s.run);
    let side = 2.0 * (t.radius + f.cutoff) + 0.5;
    let shape = WallShape::Cylinder {
        axis: 2,
        centre: [0.5 * side; 2],
        radius: t.radius,
    };
    let (mut sim, source) = build(
        shape,
        DVec3::new(side, side, t.length),
        f,
        &s.walls,
        r,
        s.seed,
        &s.base_dir,
    )?;
    sim.set_body_force(0, DVec3::new(0.0, 0.0, t.body_force))
        .map_err(engine_err)?;
    let adaptation = adapt(&mut sim, &s.walls, f, &s.base_dir, ctx)?;
    sim.run(r.flow_steps).map_err(engine_err)?;
    sim.extension_mut().reset_measurements();
    let nb = r.profile_bins;
    let w = t.radius / nb as f64;
    let (mut cnt, mut vz) = (vec![0.0f64; nb], vec![0.0f64; nb]);
    let mut samples = 0usize;
    for i in 0..r.steps {
        sim.step().map_err(engine_err)?;
        if i % r.sample_every == 0 {
            let p = sim.particles();
            for k in 0..p.len() {
                if p.ptype[k] == walls::FLUID_TYPE {
                    let b = ((shape.signed_distance(p.pos[k]) + t.radius) / w) as usize;
                    if b < nb {
                        cnt[b] += 1.0;
                        vz[b] += p.vel[k].z;
                    }
                }
            }
            samples += 1;
        }
    }
    let rho0 = sim.extension().target_density().unwrap_or(f.density);
    let rc: Vec<f64> = (0..nb).map(|b| (b as f64 + 0.5) * w).collect();
    let v: Vec<f64> = vz.iter().zip(&cnt).map(|(a, c)| a / c.max(1.0)).collect();
    let rho: Vec<f64> = (0..nb)
        .map(|b| {
            let (r0, r1) = (b as f64 * w, (b + 1) as f64 * w);
            cnt[b] / (samples.max(1) as f64 * std::f64::consts::PI * (r1 * r1 - r0 * r0) * t.length)
        })
        .collect();
    let r2: Vec<f64> = rc.iter().map(|x| x * x).collect();
    let (a, b) = fit_line(&r2, &v, &cnt);
    let curv = -b;
    let eta = rho0 * t.body_force / (4.0 * curv);
    let slip = (a - curv * t.radius * t.radius) / a;
    let fit: Vec<f64> = r2.iter().map(|x| a - curv * x).collect();
    let rows: Vec<Vec<f64>> = (0..nb).map(|k| vec![rc[k], v[k], fit[k], rho[k]]).collect();
    write_csv(ctx, "velocity_profile.csv", "r,v_z,parabola,density", &rows)?;
    let near = sim.extension().relative_density();
    let dev = near.iter().map(|x| (x - 1.0).abs()).fold(0.0, f64::max);
    let over = if r.measure_overhead {
        overhead(&mut sim, f, r, s.seed)?
    } else {
        serde_json::Value::Null
    };
    let um = t.length_scale_um_per_rc;
    Ok(json!({
        "units": "DPD model units: length rc, energy kBT, mass m",
        "geometry": { "radius": t.radius, "length": t.length, "diameter_um": um.map(|l| 2.0 * t.radius * l), "length_um": um.map(|l| t.length * l) },
        "wall_force_source": source,
        "adaptation": adaptation,
        "profile": { "r": rc, "v_z": v, "parabola": fit, "density": rho, "samples": samples },
        "parabola": { "centre_velocity": a, "curvature": curv, "viscosity": eta, "slip_velocity": a - curv * t.radius * t.radius, "slip_fraction": slip },
        "near_wall": { "bin_centres": sim.extension().bin_centres(), "relative_density": near, "max_density_deviation": dev, "target_density": rho0 },
        "wall_crossings_after_reflection": 0,
        "reflections": sim.extension().reflections(),
        "overhead": over,
        "temperature": observe::peculiar_temperature(sim.particles(), sim.field(), |x| {
            let rr = shape.signed_distance(x) + t.radius;
            DVec3::new(0.0, 0.0, (a - curv * rr * rr).max(0.0))
        }),
    }))
}

/// Runs `kind = "couette"`.
pub fn run_couette(s: &CouetteScenario, ctx: &RunContext) -> Result<serde_json::Value, RunError> {
    let (f, pl, r) = (&s.fluid, &s.plates, &s.run);
    let rc = f.cutoff;
    let (lower, upper, period) = (rc, rc + pl.gap, pl.gap + 2.0 * rc);
    let u = pl.wall_speed;
    let shape = WallShape::Plates {
        axis: 2,
        lower,
        upper,
        period,
        lower_velocity: DVec3::new(-u, 0.0, 0.0),
        upper_velocity: DVec3::new(u, 0.0, 0.0),
    };
    let (mut sim, source) = build(
        shape,
        DVec3::new(pl.width[0], pl.width[1], period),
        f,
        &s.walls,
        r,
        s.seed,
        &s.base_dir,
    )?;
    let adaptation = adapt(&mut sim, &s.walls, f, &s.base_dir, ctx)?;
    sim.run(r.flow_steps).map_err(engine_err)?;
    sim.extension_mut().reset_measurements();
    let nb = r.profile_bins;
    let dt = r.timestep;
    let area = pl.width[0] * pl.width[1];
    let (mut cnt, mut vx) = (vec![0.0f64; nb], vec![0.0f64; nb]);
    let mut stress = Vec::with_capacity(r.steps as usize);
    let mut imp_prev = [0.0f64; 2];
    let mut samples = 0usize;
    for i in 0..r.steps {
        sim.step().map_err(engine_err)?;
        let p = sim.particles();
        let mut fw = [0.0f64; 2];
        let sample = i % r.sample_every == 0;
        for k in 0..p.len() {
            if p.ptype[k] == walls::FLUID_TYPE {
                if sample {
                    let b = (((p.pos[k].z - lower) / pl.gap * nb as f64) as usize).min(nb - 1);
                    cnt[b] += 1.0;
                    vx[b] += p.vel[k].x;
                }
            } else {
                fw[shape.side(p.pos[k])] += p.force[k].x;
            }
        }
        samples += sample as usize;
        let imp = sim.extension().impulse();
        for k in 0..2 {
            fw[k] += (imp[k].x - imp_prev[k]) / dt;
            imp_prev[k] = imp[k].x;
        }
        stress.push((fw[0] - fw[1]) / (2.0 * area));
    }
    let (sigma, sigma_se) = observe::block_error(&stress)
        .or_else(|_| observe::block_average(&stress, 2))
        .unwrap_or((f64::NAN, f64::NAN));
    let z: Vec<f64> = (0..nb).map(|b| lower + (b as f64 + 0.5) * pl.gap / nb as f64).collect();
    let v: Vec<f64> = vx.iter().zip(&cnt).map(|(a, c)| a / c.max(1.0)).collect();
    let rho: Vec<f64> = cnt
        .iter()
        .map(|c| c / (samples.max(1) as f64 * area * pl.gap / nb as f64))
        .collect();
    let (c0, c1) = fit_line(&z, &v, &cnt);
    let fit: Vec<f64> = z.iter().map(|x| c0 + c1 * x).collect();
    let rows: Vec<Vec<f64>> = (0..nb).map(|k| vec![z[k], v[k], fit[k], rho[k]]).collect();
    write_csv(ctx, "velocity_profile.csv", "z,v_x,line,density", &rows)?;
    let slip_lo = ((c0 + c1 * lower) + u) / (2.0 * u);
    let slip_hi = (u - (c0 + c1 * upper)) / (2.0 * u);
    let near = sim.extension().relative_density();
    let dev = near.iter().map(|x| (x - 1.0).abs()).fold(0.0, f64::max);
    let over = if r.measure_overhead {
        overhead(&mut sim, f, r, s.seed)?
    } else {
        serde_json::Value::Null
    };
    Ok(json!({
        "units": "DPD model units: length rc, energy kBT, mass m",
        "geometry": { "gap": pl.gap, "width": pl.width, "wall_speed": u },
        "wall_force_source": source,
        "adaptation": adaptation,
        "profile": { "z": z, "v_x": v, "line": fit, "density": rho, "samples": samples },
        "line": { "intercept": c0, "shear_rate": c1, "no_slip_shear_rate": 2.0 * u / pl.gap, "slip_fraction_lower": slip_lo, "slip_fraction_upper": slip_hi },
        "shear_stress": { "mean": sigma, "standard_error": sigma_se, "samples": stress.len() },
        "viscosity": { "value": sigma / c1, "standard_error": sigma_se / c1.abs() },
        "near_wall": { "bin_centres": sim.extension().bin_centres(), "relative_density": near, "max_density_deviation": dev, "target_density": sim.extension().target_density() },
        "wall_crossings_after_reflection": 0,
        "reflections": sim.extension().reflections(),
        "overhead": over,
    }))
}
