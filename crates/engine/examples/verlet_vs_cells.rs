//! A half Verlet list with a skin against the engine's per-step cell list: cost of one force
//! evaluation of the standard DPD fluid (ρ = 3, a = 25, γ = 4.5, kBT = 1, rc = 1, Δt = 0.01)
//! on 1 thread. See docs/performance.md, "Verlet list against cell lists (measured)".
//!
//! `cargo run --release -p hemodpd-engine --example verlet_vs_cells -- [L] [NEQ] [STEPS] [SKIN...]`
//! (defaults 20, 300, 400, skins 0.1 0.2 0.3 0.4).
//!
//! The fluid is equilibrated with the engine's `Simulation` for NEQ steps. Then, for each skin,
//! the engine simulation is restarted from that state and advanced STEPS steps with `step()`.
//! After every step, the forces at its positions (current velocities, noise key of the current
//! step) are evaluated twice, in alternating order, and timed:
//! * `cells`: the engine's own force path, called through its public API exactly as
//!   `Simulation` does it on a normal step (cell sort with the sorted copy, `pairs::compute` with
//!   the half shell and no virial, gather back to storage order);
//! * `verlet`: the list written here. It keeps the particles in the spatial order of its last
//!   build, and each evaluation gathers positions and velocities into that order, checks the
//!   largest displacement since the build, rebuilds the half list (cutoff rc + skin, from a cell
//!   list with cells ≥ rc + skin) when it exceeds skin/2, runs the pair loop with Newton's third
//!   law and scatters the forces back. Its timings include the rebuilds.
//!
//! Both use the engine's `DpdLinear` kernel and `pair_xi` noise, so their forces agree to
//! round-off; that is checked on the equilibrated state (conservative part alone and full force)
//! and along every timed trajectory.

use std::time::Instant;

use glam::DVec3;
use hemodpd_engine::cells::{CellGrid, CellList};
use hemodpd_engine::kernel::{DpdLinear, KernelTable, PairKernel};
use hemodpd_engine::rng::{pair_xi, step_key};
use hemodpd_engine::{
    init, pairs, EngineError, ForceField, ForceScheme, PairParams, Particles, PeriodicBox, SimConfig, Simulation,
};

/// The 13 forward neighbour offsets of the half shell (as in the engine's `pairs.rs`).
const HALF: [[i32; 3]; 13] = [
    [1, 0, 0],
    [-1, 1, 0],
    [0, 1, 0],
    [1, 1, 0],
    [-1, -1, 1],
    [0, -1, 1],
    [1, -1, 1],
    [-1, 0, 1],
    [0, 0, 1],
    [1, 0, 1],
    [-1, 1, 1],
    [0, 1, 1],
    [1, 1, 1],
];

/// A list entry is `j | shift_code << SHIFT_BITS`.
const SHIFT_BITS: u32 = 27;
const J_MASK: u32 = (1 << SHIFT_BITS) - 1;
const ZERO_SHIFT: u32 = 13;

/// The engine's force evaluation, as `Simulation::forces_at` does it in a normal step.
struct CellsEval {
    cl: CellList,
    table: KernelTable<DpdLinear>,
    sf: Vec<DVec3>,
}

impl CellsEval {
    fn new(domain: &PeriodicBox, kern: DpdLinear) -> Result<Self, EngineError> {
        Ok(Self {
            cl: CellList::new(CellGrid::new(domain, kern.cutoff2().sqrt())?),
            table: KernelTable::from_fn(1, |_, _| kern),
            sf: Vec::new(),
        })
    }

    fn eval(&mut self, p: &Particles, key: u64, out: &mut [DVec3]) {
        let vel = &p.vel;
        self.cl.build(&p.pos, &p.ptype, &p.id, |i| vel[i]);
        pairs::compute(
            ForceScheme::HalfShell,
            &self.cl,
            &self.table,
            key,
            &mut self.sf,
            false,
            None,
        );
        for (f, &k) in out.iter_mut().zip(self.cl.inverse()) {
            *f = self.sf[k as usize];
        }
    }
}

/// A serial half Verlet list.
struct Verlet {
    kern: DpdLinear,
    rc2: f64,
    rl2: f64,
    half_skin2: f64,
    lengths: DVec3,
    shifts: [DVec3; 27],
    cl: CellList,
    /// Spatial order of the last build: sorted index → storage index.
    perm: Vec<u32>,
    /// Sorted positions at the last build (inside the box).
    xref: Vec<DVec3>,
    id: Vec<u32>,
    /// CSR: the list of sorted particle i is `nbr[start[i]..start[i + 1]]` (all j > i in
    /// visiting order, with the periodic shift code).
    start: Vec<usize>,
    nbr: Vec<u32>,
    xs: Vec<DVec3>,
    vs: Vec<DVec3>,
    sf: Vec<DVec3>,
    hits: Vec<(DVec3, f64, u32)>,
    /// Branch-free compaction of the hits (as the engine does) or a plain `if` in the loop.
    compact: bool,
    builds: u64,
    listed: u64,
    inside: u64,
    /// Seconds spent in `build` (included in the evaluation timings).
    t_build: f64,
}

impl Verlet {
    fn new(domain: &PeriodicBox, kern: DpdLinear, skin: f64, compact: bool) -> Result<Self, EngineError> {
        let rc = kern.cutoff2().sqrt();
        let l = domain.lengths();
        let mut shifts = [DVec3::ZERO; 27];
        for (c, s) in shifts.iter_mut().enumerate() {
            let k = [(c % 3) as f64 - 1.0, ((c / 3) % 3) as f64 - 1.0, (c / 9) as f64 - 1.0];
            *s = DVec3::new(k[0] * l.x, k[1] * l.y, k[2] * l.z);
        }
        Ok(Self {
            kern,
            rc2: rc * rc,
            rl2: (rc + skin) * (rc + skin),
            half_skin2: 0.25 * skin * skin,
            lengths: l,
            shifts,
            cl: CellList::new(CellGrid::new(domain, rc + skin)?),
            perm: Vec::new(),
            xref: Vec::new(),
            id: Vec::new(),
            start: Vec::new(),
            nbr: Vec::new(),
            xs: Vec::new(),
            vs: Vec::new(),
            sf: Vec::new(),
            hits: Vec::new(),
            compact,
            builds: 0,
            listed: 0,
            inside: 0,
            t_build: 0.0,
        })
    }

    fn shift_code(&self, sh: DVec3) -> u32 {
        let s = |v: f64| {
            if v > 0.0 {
                2
            } else if v < 0.0 {
                0
            } else {
                1
            }
        };
        s(sh.x) + 3 * s(sh.y) + 9 * s(sh.z)
    }

    fn build(&mut self, p: &Particles) {
        let t0 = Instant::now();
        self.builds += 1;
        self.cl.build(&p.pos, &p.ptype, &p.id, |_| DVec3::ZERO);
        let n = p.len();
        assert!(n <= J_MASK as usize);
        self.perm.clone_from(&self.cl.perm);
        let cl = &self.cl;
        self.xref.clear();
        self.xref.extend((0..cl.len()).map(|k| cl.position(k)));
        self.id.clear();
        self.id.extend((0..cl.len()).map(|k| cl.id(k)));
        self.start.clear();
        self.start.push(0);
        let g = self.cl.grid;
        let [nx, ny, nz] = g.n;
        let mut len = 0usize;
        let mut nb = [(0usize, 0usize, DVec3::ZERO, 0u32); 13];
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let (s0, s1) = self.cl.range(g.index(x, y, z));
                    if s0 == s1 {
                        continue;
                    }
                    let mut m = s1 - s0;
                    for (k, d) in HALF.iter().enumerate() {
                        let (c, sh) = g.neighbour(x, y, z, *d);
                        let (a, e) = self.cl.range(c);
                        nb[k] = (a, e, sh, self.shift_code(sh) << SHIFT_BITS);
                        m += e - a;
                    }
                    for i in s0..s1 {
                        // Sorted order is cell order, so i runs 0, 1, 2, … here.
                        debug_assert_eq!(self.start.len(), i + 1);
                        if self.nbr.len() < len + m + 1 {
                            self.nbr.resize(len + m + 1, 0);
                        }
                        let pi = self.xref[i];
                        let (pos, out) = (&self.xref, &mut self.nbr);
                        for j in i + 1..s1 {
                            let r2 = (pi - pos[j]).length_squared();
                            out[len] = j as u32 | (ZERO_SHIFT << SHIFT_BITS);
                            len += (r2 < self.rl2) as usize;
                        }
                        for &(a, e, sh, code) in &nb {
                            let pis = pi - sh;
                            for j in a..e {
                                let r2 = (pis - pos[j]).length_squared();
                                out[len] = j as u32 | code;
                                len += (r2 < self.rl2) as usize;
                            }
                        }
                        self.start.push(len);
                    }
                }
            }
        }
        self.nbr.truncate(len);
        self.t_build += t0.elapsed().as_secs_f64();
    }

    /// Gathers positions (continuous since the last build) and velocities into the list order;
    /// returns the largest squared displacement since the last build.
    fn gather(&mut self, p: &Particles) -> f64 {
        let n = p.len();
        self.xs.resize(n, DVec3::ZERO);
        self.vs.resize(n, DVec3::ZERO);
        let (l, h) = (self.lengths, self.lengths * 0.5);
        let unwrap = |v: f64, l: f64, h: f64| {
            if v > h {
                v - l
            } else if v < -h {
                v + l
            } else {
                v
            }
        };
        let mut max_d2: f64 = 0.0;
        for k in 0..n {
            let i = self.perm[k] as usize;
            let x0 = self.xref[k];
            let d = p.pos[i] - x0;
            let d = DVec3::new(unwrap(d.x, l.x, h.x), unwrap(d.y, l.y, h.y), unwrap(d.z, l.z, h.z));
            self.xs[k] = x0 + d;
            self.vs[k] = p.vel[i];
            max_d2 = max_d2.max(d.length_squared());
        }
        max_d2
    }

    fn eval(&mut self, p: &Particles, key: u64, out: &mut [DVec3]) {
        if self.perm.len() != p.len() || self.gather(p) > self.half_skin2 {
            self.build(p);
            self.gather(p);
        }
        let n = p.len();
        self.sf.clear();
        self.sf.resize(n, DVec3::ZERO);
        self.listed += self.nbr.len() as u64;
        let (kern, rc2) = (self.kern, self.rc2);
        let (xs, vs, id, sf, shifts) = (&self.xs, &self.vs, &self.id, &mut self.sf, &self.shifts);
        let mut inside = 0usize;
        for i in 0..n {
            let list = &self.nbr[self.start[i]..self.start[i + 1]];
            let (xi, vi, idi) = (xs[i], vs[i], id[i]);
            let mut fi = DVec3::ZERO;
            if self.compact {
                if self.hits.len() < list.len() + 1 {
                    self.hits.resize(list.len() + 1, (DVec3::ZERO, 0.0, 0));
                }
                let h = &mut self.hits[..];
                let mut m = 0usize;
                for &w in list {
                    let j = (w & J_MASK) as usize;
                    let dr = (xi - shifts[(w >> SHIFT_BITS) as usize]) - xs[j];
                    let r2 = dr.length_squared();
                    h[m] = (dr, r2, j as u32);
                    m += ((r2 < rc2) & (r2 > 0.0)) as usize;
                }
                inside += m;
                for &(dr, r2, j) in &h[..m] {
                    let j = j as usize;
                    let f = kern.force(dr, r2, vi - vs[j], pair_xi(key, idi, id[j]));
                    fi += f;
                    sf[j] -= f;
                }
            } else {
                for &w in list {
                    let j = (w & J_MASK) as usize;
                    let dr = (xi - shifts[(w >> SHIFT_BITS) as usize]) - xs[j];
                    let r2 = dr.length_squared();
                    if r2 < rc2 && r2 > 0.0 {
                        inside += 1;
                        let f = kern.force(dr, r2, vi - vs[j], pair_xi(key, idi, id[j]));
                        fi += f;
                        sf[j] -= f;
                    }
                }
            }
            sf[i] += fi;
        }
        self.inside += inside as u64;
        for (k, &i) in self.perm.iter().enumerate() {
            out[i as usize] = self.sf[k];
        }
    }
}

/// max |a − b| / max |b|.
fn rel_dev(a: &[DVec3], b: &[DVec3]) -> f64 {
    let num = a.iter().zip(b).map(|(x, y)| (*x - *y).length()).fold(0.0, f64::max);
    let den = b.iter().map(|y| y.length()).fold(0.0, f64::max);
    num / den
}

fn main() -> Result<(), EngineError> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let l: f64 = a.first().and_then(|s| s.parse().ok()).unwrap_or(20.0);
    let neq: u64 = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(300);
    let steps: u64 = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(400);
    let mut skins: Vec<f64> = a.iter().skip(3).filter_map(|s| s.parse().ok()).collect();
    if skins.is_empty() {
        skins = vec![0.1, 0.2, 0.3, 0.4];
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .map_err(|e| EngineError::ThreadPool(e.to_string()))?;
    pool.install(|| {
        let seed = 34387;
        let config = SimConfig::new(DVec3::splat(l), 0.01, seed);
        let pp = PairParams::groot_warren();
        let field = ForceField::single(pp);
        let spec = init::FluidSpec {
            placement: init::Placement::Random,
            ..init::FluidSpec::standard()
        };
        let p = init::fluid(&config, &field, &spec, 4928459)?;
        let n = p.len();
        let mut sim = Simulation::new(config.clone(), field, p)?;
        sim.run(neq)?;
        let snap = sim.state();
        let domain = *sim.domain();
        let dt = config.dt;
        let kern = DpdLinear::new(&pp, dt, true);
        let kern_c = DpdLinear::new(
            &PairParams {
                gamma: 0.0,
                kbt: 0.0,
                ..pp
            },
            dt,
            true,
        );
        println!("N = {n}, L = {l}, equilibrated {neq} steps, {steps} timed steps per skin, 1 thread");

        // Like-for-like checks on the equilibrated state.
        let mut check = Simulation::from_state(snap.clone(), ())?;
        check.recompute_forces()?;
        let f_sim = check.particles().force.clone();
        let key = step_key(seed, snap.step);
        let (mut fa, mut fb) = (vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]);
        CellsEval::new(&domain, kern)?.eval(&snap.particles, key, &mut fa);
        println!("check: cells path vs Simulation::recompute_forces: max|df|/max|f| = {:.2e}", rel_dev(&fa, &f_sim));
        for &skin in &skins {
            for compact in [true, false] {
                Verlet::new(&domain, kern, skin, compact)?.eval(&snap.particles, key, &mut fb);
                let full = rel_dev(&fb, &fa);
                CellsEval::new(&domain, kern_c)?.eval(&snap.particles, key, &mut fa);
                Verlet::new(&domain, kern_c, skin, compact)?.eval(&snap.particles, key, &mut fb);
                let cons = rel_dev(&fb, &fa);
                CellsEval::new(&domain, kern)?.eval(&snap.particles, key, &mut fa);
                println!(
                    "check: verlet skin {skin} compact {compact}: full force {full:.2e}, conservative only {cons:.2e} (max|df|/max|f|)"
                );
            }
        }

        println!(
            "{:>5} {:>8} {:>11} {:>11} {:>11} {:>7} {:>9} {:>8} {:>9} {:>10} {:>7}",
            "skin", "variant", "cells ps/s", "verlet ps/s", "step() ps/s", "ratio", "rebuild/", "inside", "pairs/i", "max dev", "build %"
        );
        for &skin in &skins {
            for compact in [true, false] {
                let mut sim = Simulation::from_state(snap.clone(), ())?;
                let mut ce = CellsEval::new(&domain, kern)?;
                let mut ve = Verlet::new(&domain, kern, skin, compact)?;
                let (mut t_c, mut t_v, mut t_s, mut dev) = (0.0, 0.0, 0.0, 0.0f64);
                for k in 0..steps {
                    let t = Instant::now();
                    sim.step()?;
                    t_s += t.elapsed().as_secs_f64();
                    let pt = sim.particles();
                    let key = step_key(seed, sim.step_count());
                    let order = if k % 2 == 0 { [0, 1] } else { [1, 0] };
                    for w in order {
                        let t = Instant::now();
                        if w == 0 {
                            ce.eval(pt, key, &mut fa);
                            t_c += t.elapsed().as_secs_f64();
                        } else {
                            ve.eval(pt, key, &mut fb);
                            t_v += t.elapsed().as_secs_f64();
                        }
                    }
                    dev = dev.max(rel_dev(&fb, &fa));
                }
                let work = n as f64 * steps as f64;
                println!(
                    "{:>5} {:>8} {:>11.3e} {:>11.3e} {:>11.3e} {:>7.3} {:>9.2} {:>8.3} {:>9.2} {:>10.1e} {:>7.1}",
                    skin,
                    if compact { "compact" } else { "branch" },
                    work / t_c,
                    work / t_v,
                    work / t_s,
                    t_c / t_v,
                    steps as f64 / ve.builds as f64,
                    ve.inside as f64 / ve.listed as f64,
                    ve.listed as f64 / steps as f64 / n as f64,
                    dev,
                    100.0 * ve.t_build / t_v
                );
            }
        }
        Ok(())
    })
}
