//! What a wall run accumulates while sampling (profile and wall-stress sums per time block, the
//! flow controller's state) and the analysis of it: fits, the viscosity profile η(x) and its
//! plateau, jackknife errors over the blocks.

use hemodpd_engine::walls::{self, Walls};
use hemodpd_engine::Simulation;
use serde::{Deserialize, Serialize};
use serde_json::json;

/// Blocks the sampled steps are split into; the standard errors of the fitted viscosity and of
/// the wall stress come from the scatter between blocks.
pub const BLOCKS: usize = 10;

/// Departure, in standard errors, of the next two edges' mean from the plateau so far that
/// ends the plateau: 3σ, a 0.27 % chance per step in the bulk.
const DEPARTURE_Z: f64 = 3.0;

/// Relative standard error of the plateau above which the summary warns that the wall layer
/// may be in it.
const WEAK_SIGNAL: f64 = 0.02;

/// Largest relative standard error of an edge's η for it to enter the plateau. η is a ratio
/// whose bias is about the squared relative error of its denominator, 1 % at this bound; near a
/// tube's axis edges of 15–20 % were seen to read 40–50 % low and seed a false plateau.
const MAX_RELATIVE_ERROR: f64 = 0.1;

/// Fewest bin edges the plateau of η(r) must hold; with fewer the viscosity is not reported.
const MIN_PLATEAU_EDGES: usize = 3;

/// Weighted least squares y = c0 + c1 x (weights w): returns (c0, c1). Points of weight 0
/// (empty bins, whose y is NaN) are left out.
pub fn fit_line(x: &[f64], y: &[f64], w: &[f64]) -> (f64, f64) {
    let (mut s, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for i in (0..x.len()).filter(|&i| w[i] > 0.0) {
        s += w[i];
        sx += w[i] * x[i];
        sy += w[i] * y[i];
        sxx += w[i] * x[i] * x[i];
        sxy += w[i] * x[i] * y[i];
    }
    let c1 = (s * sxy - sx * sy) / (s * sxx - sx * sx);
    ((sy - c1 * sx) / s, c1)
}

/// Per-block sums of a profile across the channel: particle counts, the flow-direction
/// velocity and the squared velocity components, per bin.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProfileSums {
    /// `count[block][bin]`.
    pub count: Vec<Vec<f64>>,
    /// `velocity[block][bin]`: Σ of the velocity component along the flow.
    pub velocity: Vec<Vec<f64>>,
    /// `square[block][bin]`: Σ of the squared velocity components (wall-normal, the other
    /// tangential direction, along the flow), for the temperature profile.
    #[serde(default)]
    pub square: Vec<Vec<[f64; 3]>>,
    /// Samples per block.
    pub samples: Vec<u64>,
}

/// Sums of a [`ProfileSums`] over a set of blocks.
pub(super) struct BinSums {
    pub(super) count: Vec<f64>,
    pub(super) velocity: Vec<f64>,
    pub(super) square: Vec<[f64; 3]>,
    pub(super) samples: u64,
}

impl BinSums {
    /// Mean flow velocity per bin; NaN for a bin no particle visited.
    pub(super) fn mean_velocity(&self) -> Vec<f64> {
        self.velocity
            .iter()
            .zip(&self.count)
            .map(|(v, &c)| if c > 0.0 { v / c } else { f64::NAN })
            .collect()
    }

    /// Peculiar kBT per bin and component (normal, other tangential, flow), mass `m`: the flow
    /// component about the bin's mean velocity. NaN for an empty bin.
    pub(super) fn temperature(&self, m: f64) -> Vec<[f64; 3]> {
        (0..self.count.len())
            .map(|k| {
                let c = self.count[k];
                if c <= 0.0 {
                    return [f64::NAN; 3];
                }
                let u = self.velocity[k] / c;
                let q = self.square[k];
                [m * q[0] / c, m * q[1] / c, m * (q[2] / c - u * u)]
            })
            .collect()
    }
}

impl ProfileSums {
    pub(super) fn new(bins: usize) -> Self {
        Self {
            count: vec![vec![0.0; bins]; BLOCKS],
            velocity: vec![vec![0.0; bins]; BLOCKS],
            square: vec![vec![[0.0; 3]; bins]; BLOCKS],
            samples: vec![0; BLOCKS],
        }
    }

    /// The sums over the blocks for which `take(block)` holds.
    pub(super) fn sum(&self, take: impl Fn(usize) -> bool) -> BinSums {
        let nb = self.count[0].len();
        let mut s = BinSums {
            count: vec![0.0; nb],
            velocity: vec![0.0; nb],
            square: vec![[0.0; 3]; nb],
            samples: 0,
        };
        for b in (0..BLOCKS).filter(|&b| take(b)) {
            for k in 0..nb {
                s.count[k] += self.count[b][k];
                s.velocity[k] += self.velocity[b][k];
                for c in 0..3 {
                    s.square[k][c] += self.square[b][k][c];
                }
            }
            s.samples += self.samples[b];
        }
        s
    }

    /// (counts, mean velocity) over all blocks; the velocity of an empty bin is NaN.
    pub(super) fn mean(&self) -> (Vec<f64>, Vec<f64>) {
        let s = self.sum(|_| true);
        let v = s.mean_velocity();
        (s.count, v)
    }

    pub(super) fn total_samples(&self) -> u64 {
        self.samples.iter().sum()
    }
}

/// What a walled run accumulates while sampling; saved in checkpoints.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Measurement {
    /// Velocity and density profile across the channel.
    pub profile: ProfileSums,
    /// The wall shear stress summed over the sampled steps of each time block, and the steps
    /// summed (`[sum, steps]` per block; bounded size, whatever the run length): Couette, the
    /// mean of the two plates' stresses on the fluid; tube, the axial force of the fluid on the
    /// wall per wall area.
    pub stress: Vec<[f64; 2]>,
    /// The reflection impulse along the flow of each surface at the last step.
    pub impulse_prev: [f64; 2],
    /// Wall-clock seconds of the stepping so far (over all sessions of a resumed run).
    pub stepping_seconds: f64,
    /// The tube's flow controller, when the scenario asks for a mean velocity.
    pub flow_control: Option<FlowControl>,
}

/// Bessel J0's first zero: the slowest viscous mode of a tube decays as exp(−η j0² t/(n R²)).
pub(super) const J0_FIRST_ZERO: f64 = 2.404_825_557_695_773;

/// The tube's flow controller: a proportional–integral law on the body force f that holds a
/// target mean axial velocity U of the fluid. With ū the fluid's mean axial velocity averaged
/// over the last M steps, every M steps:
///
/// e = U − ū,  I ← I + e·MΔt/τ_v,  f = 8η/(nR²) · (e + I),
///
/// where 8η/(nR²) is the force per unit mean velocity of Poiseuille flow and τ_v = nR²/(η j0²)
/// the tube's slowest viscous time. I starts at 0, so the first force is the Poiseuille estimate
/// 8ηU/(nR²). For a flow that responds like one lag of time τ_v the loop is critically damped
/// (a double pole at −1/τ_v): no overshoot, settled to 1% in about 7τ_v. The law acts on window
/// means, one window late, so the scenario keeps MΔt ≤ τ_v/2 (validated). η is the scenario's
/// reference viscosity, or 1 when none is given; a run whose mean velocity runs away stops with
/// an error.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlowControl {
    /// Target mean velocity U.
    pub target: f64,
    /// Current body force f.
    pub force: f64,
    /// Integral term I (velocity units).
    pub integral: f64,
    /// Σ ū and steps of the current window.
    pub window_sum: f64,
    pub window_steps: u64,
    /// (step, ū over the window, f after the update) per update.
    pub history: Vec<[f64; 3]>,
    /// Σ f and steps over the sampling phase (the mean force the profile saw).
    pub sampling_force_sum: f64,
    pub sampling_steps: u64,
}

/// A parabola v = a − c r² fitted to the radial bins with centre r < `r_max`, weighted by
/// their counts; returns (a, c).
pub(super) fn fit_parabola(r: &[f64], v: &[f64], count: &[f64], r_max: f64) -> (f64, f64) {
    let (mut x, mut y, mut w) = (Vec::new(), Vec::new(), Vec::new());
    for k in 0..r.len() {
        if r[k] < r_max {
            x.push(r[k] * r[k]);
            y.push(v[k]);
            w.push(count[k]);
        }
    }
    let (a, b) = fit_line(&x, &y, &w);
    (a, -b)
}

/// A local shear viscosity η at the bin edges across a channel, and its plateau.
///
/// η(x_e) = σ(x_e)/(dv/dx)(x_e) at the edge x_e between bins e − 1 and e, with the slope
/// (v_e − v_{e−1})/w from the measured bin means (exact for a parabola, because the bins hold
/// count-weighted means over their volume) and σ from an exact momentum balance (tube: the
/// body force inside the edge; Couette: the measured wall stress). The balance gives the
/// fluid's own shear stress only across edges at least rc from the wall: closer, fluid on the
/// inner side of the edge interacts with wall particles directly, so part of the force crosses
/// the edge through wall–fluid pairs. Those edges are reported but not part of the plateau. It
/// needs no model of the profile and no chosen window: η is flat in the bulk and departs from
/// it in the wall layers. The plateau grows from the centre of the channel towards each wall along `paths`
/// and stops on a path where the mean of its next two edges departs from the plateau's running
/// inverse-variance mean by more than [`DEPARTURE_Z`] jackknife standard errors. With too
/// little signal (a weak drive, a short run) no departure is significant and the plateau takes
/// in the wall layer: the summary reports its extent. Standard errors are jackknife estimates
/// over the time blocks.
pub(super) struct ViscosityProfile {
    /// Edge positions x_e (e = 1 … bins − 1).
    pub(super) r: Vec<f64>,
    /// η(x_e) from all blocks, and its jackknife standard error.
    pub(super) eta: Vec<f64>,
    pub(super) se: Vec<f64>,
    /// The edges (indices into `r`) of the plateau, in increasing order; empty when none.
    pub(super) plateau_edges: Vec<usize>,
    /// Inverse-variance mean over the plateau, its jackknife standard error, χ²/dof.
    pub(super) plateau: Option<(f64, f64, f64)>,
}

/// See [`ViscosityProfile`]. `eta_of(take)` computes η at every edge from the blocks for which
/// `take(block)` holds; each path lists edge indices from the centre towards a wall.
pub(super) fn viscosity_profile(
    m: &Measurement,
    r: Vec<f64>,
    eta_of: impl Fn(&dyn Fn(usize) -> bool) -> Vec<f64>,
    paths: Vec<Vec<usize>>,
    fluid_stress: impl Fn(usize) -> bool,
) -> ViscosityProfile {
    let eta = eta_of(&|_| true);
    let used: Vec<usize> = (0..BLOCKS).filter(|&b| m.profile.samples[b] > 0).collect();
    let jack: Vec<Vec<f64>> = used.iter().map(|&out| eta_of(&|b| b != out)).collect();
    let jack_se =
        |values: &dyn Fn(&Vec<f64>) -> f64| -> f64 { jackknife_spread(&jack.iter().map(values).collect::<Vec<_>>()) };
    let se: Vec<f64> = (0..eta.len()).map(|k| jack_se(&|j: &Vec<f64>| j[k])).collect();
    // η = σ/(dv/dx) is a ratio; where dv/dx is poorly known (near the axis of a tube, dv/dx →
    // 0) it is biased by about the squared relative error of dv/dx and its jackknife error is
    // unreliable, so an edge known to worse than ±MAX_RELATIVE_ERROR is left out of the
    // plateau (it still appears in the profile)
    let ok = |k: usize| {
        eta[k].is_finite() && eta[k] > 0.0 && se[k].is_finite() && se[k] > 0.0 && se[k] < MAX_RELATIVE_ERROR * eta[k]
    };
    // the valid edges of each path; the first of each seeds the plateau
    let paths: Vec<Vec<usize>> = paths
        .into_iter()
        .map(|p| p.into_iter().filter(|&k| ok(k)).collect())
        .collect();
    let mut edges: Vec<usize> = paths.iter().filter_map(|p| p.first().copied()).collect();
    let mut next = vec![1usize; paths.len()];
    let mut open = vec![true; paths.len()];
    while open.iter().any(|&o| o) {
        for (p, path) in paths.iter().enumerate() {
            if !open[p] {
                continue;
            }
            let Some(&k) = path.get(next[p]).filter(|&&k| fluid_stress(k)) else {
                // the end of the path, or the first edge within rc of the wall
                open[p] = false;
                continue;
            };
            // the next two edges of the path (one at its end) against the plateau so far: the
            // difference of their mean from the plateau's inverse-variance mean, over its
            // jackknife standard error (neighbouring edges share a bin, so their errors are
            // anticorrelated and the pair is better determined than either edge). The second
            // may lie within rc of the wall: it tests, it is never added.
            let group: Vec<usize> = path[next[p]..path.len().min(next[p] + 2)].to_vec();
            let wsum: f64 = edges.iter().map(|&j| se[j].powi(-2)).sum();
            let weights: Vec<(usize, f64)> = edges.iter().map(|&j| (j, se[j].powi(-2) / wsum)).collect();
            let difference = |x: &Vec<f64>| {
                group.iter().map(|&j| x[j]).sum::<f64>() / group.len() as f64
                    - weights.iter().map(|&(j, w)| w * x[j]).sum::<f64>()
            };
            let z = difference(&eta) / jack_se(&difference);
            if z.abs() > DEPARTURE_Z {
                open[p] = false;
            } else {
                edges.push(k);
                next[p] += 1;
            }
        }
    }
    edges.sort_unstable();
    edges.dedup();
    let plateau = (edges.len() >= MIN_PLATEAU_EDGES).then(|| {
        let wsum: f64 = edges.iter().map(|&k| se[k].powi(-2)).sum();
        let weights: Vec<f64> = edges.iter().map(|&k| se[k].powi(-2) / wsum).collect();
        let mean: f64 = edges.iter().zip(&weights).map(|(&k, w)| w * eta[k]).sum();
        let chi2: f64 = edges.iter().map(|&k| ((eta[k] - mean) / se[k]).powi(2)).sum();
        let pse = jack_se(&|j: &Vec<f64>| edges.iter().zip(&weights).map(|(&k, w)| w * j[k]).sum());
        (mean, pse, chi2 / (edges.len() - 1) as f64)
    });
    ViscosityProfile {
        r,
        eta,
        se,
        plateau_edges: if plateau.is_some() { edges } else { Vec::new() },
        plateau,
    }
}

impl ViscosityProfile {
    /// The `viscosity` entry of a summary, with the extent of the plateau.
    pub(super) fn summary(&self, value: &str) -> serde_json::Value {
        match self.plateau {
            Some((eta, se, chi2)) => {
                let (lo, hi) = (self.plateau_edges[0], self.plateau_edges[self.plateau_edges.len() - 1]);
                let mut out = json!({ "value": eta, "standard_error": se, "plateau_edges": self.plateau_edges.len(),
                        "plateau_from": self.r[lo], "plateau_to": self.r[hi], "chi2_per_dof": chi2,
                        "method": format!("η(x) = σ/(dv/dx) at each bin edge, dv/dx from adjacent bins, σ from {value}; the plateau runs over the edges at least rc from the walls and known to ±10 %, from the centre out to where the mean of the next two edges departs from the plateau so far by more than 3 standard errors; standard errors by jackknife over the time blocks") });
                if se > WEAK_SIGNAL * eta {
                    out["note"] = json!(format!("weak signal (±{:.1} %): the plateau test cannot tell the bulk from the wall layer, which reads 10–15 % low, so the value may be biased low; a stronger drive or more sampled steps resolve it (docs/walls.md)", 100.0 * se / eta));
                }
                out
            }
            None => {
                json!({ "value": null, "note": format!("η(x) has no plateau of {MIN_PLATEAU_EDGES} or more consistent bin edges (a longer run, a wider channel or more run.profile_bins)") })
            }
        }
    }

    /// Rows (x, η, standard error, in the plateau) for `viscosity_profile.csv`.
    pub(super) fn rows(&self) -> Vec<Vec<f64>> {
        (0..self.r.len())
            .map(|k| {
                let inside = if self.plateau_edges.contains(&k) { 1.0 } else { 0.0 };
                vec![self.r[k], self.eta[k], self.se[k], inside]
            })
            .collect()
    }

    pub(super) fn json(&self) -> serde_json::Value {
        json!({ "edge": self.r, "eta": self.eta, "standard_error": self.se })
    }
}

/// Jackknife standard error over the time blocks of a quantity computed from the blocks for
/// which `take(block)` holds.
pub(super) fn jackknife_se(m: &Measurement, f: impl Fn(&dyn Fn(usize) -> bool) -> f64) -> f64 {
    let used: Vec<usize> = (0..BLOCKS).filter(|&b| m.profile.samples[b] > 0).collect();
    jackknife_spread(&used.iter().map(|&out| f(&|b| b != out)).collect::<Vec<_>>())
}

/// The jackknife standard error from the leave-one-out values `x`: √((n − 1)/n · Σ(x − x̄)²);
/// NaN with fewer than two.
fn jackknife_spread(x: &[f64]) -> f64 {
    if x.len() < 2 {
        return f64::NAN;
    }
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    ((n - 1.0) / n * x.iter().map(|v| (v - mean).powi(2)).sum::<f64>()).sqrt()
}

/// Mean of the per-step wall stress and its standard error over the [`BLOCKS`] time blocks of
/// the sampling phase. Not `observe::block_error` on the step series: the random force on the
/// wall particles makes the per-step stress a large white noise that the fluid gives back
/// within a few steps (the series is anticorrelated), so short blocks overstate the error
/// several times over; blocks of a tenth of the run do not.
pub(super) fn stress_mean_se(blocks: &[[f64; 2]]) -> (f64, f64) {
    let means: Vec<f64> = blocks.iter().filter(|b| b[1] > 0.0).map(|b| b[0] / b[1]).collect();
    let mean = block_mean(blocks, &|_| true);
    if means.len() < 2 {
        return (mean, f64::NAN);
    }
    let n = means.len() as f64;
    let m = means.iter().sum::<f64>() / n;
    let var = means.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// Mean wall stress over the blocks for which `take(block)` holds.
pub(super) fn block_mean(blocks: &[[f64; 2]], take: &dyn Fn(usize) -> bool) -> f64 {
    let (sum, steps) = blocks
        .iter()
        .enumerate()
        .filter(|(b, _)| take(*b))
        .fold((0.0, 0.0), |(s, c), (_, x)| (s + x[0], c + x[1]));
    sum / steps.max(1.0)
}

/// Mass of a fluid particle.
pub(super) fn fluid_mass(sim: &Simulation<Walls>) -> f64 {
    sim.field().types()[walls::FLUID_TYPE as usize].mass
}

/// Count-weighted mean of a temperature profile per component (empty bins left out).
pub(super) fn mean_temperature(count: &[f64], temp: &[[f64; 3]]) -> [f64; 3] {
    let n: f64 = count.iter().sum();
    std::array::from_fn(|c| {
        (0..count.len())
            .filter(|&k| count[k] > 0.0)
            .map(|k| count[k] * temp[k][c])
            .sum::<f64>()
            / n
    })
}
