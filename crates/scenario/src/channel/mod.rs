//! Wall-bounded validation flows, in model units (docs/walls.md):
//! `kind = "poiseuille-tube"` (body-force-driven flow in a tube, against the parabola) and
//! `kind = "couette"` (plates moving at ±U, against the line; viscosity from the wall stress).
//!
//! Both cut the walls out of an equilibrated fluid, then run one stepped schedule:
//!
//! | steps | phase |
//! |---|---|
//! | `[0, A)` | adaptation of the near-wall force with the flow on (A = adapt_iterations × update_every, 0 when not adaptive) |
//! | `[A, A + F)` | flow development, not sampled (F = `run.flow_steps`) |
//! | `[A + F, A + F + S)` | sampling (S = `run.steps`), split into [`BLOCKS`] blocks for standard errors |
//!
//! then fit, and time the same number of fluid particles in a periodic box for the wall overhead.
//! The force profile is written to the run directory (and, after adaptation, to the cache) when
//! adaptation ends. Frames go to `trajectory.h5` every
//! `output.trajectory_every_steps` steps; `checkpoint.h5` (particles, the wall state and the
//! sums sampled so far) is written every `output.checkpoint_every_steps` steps, at the end and on
//! Ctrl-C, and `hemodpd run --resume DIR` continues bit-identically. The stepping loop is
//! [`crate::driver`]'s; the phase changes happen at the step boundaries
//! ([`crate::driver::Stepper::at_boundary`]), the sampling and flow control after each step.
//!
//! Layout: here, the sections both kinds share (`[walls]`, `[run]`, `[output]`; `[fluid]` is
//! [`FluidSection`]) with their validation, and the `Plan` a run is made from; in `run`, one
//! walled run for either kind (build, checkpoints, frames, its `Stepper`, the results every wall
//! kind reports); in [`measure`], the sums sampled and their analysis (fits, η(x) and its
//! plateau, jackknife errors); in [`tube`] and [`couette`], each kind's own section,
//! validation, plan and results.

mod run;

pub mod couette;
pub mod measure;
pub mod tube;

pub use couette::{run_couette, CouetteScenario, PlatesSection};
pub use measure::{fit_line, FlowControl, Measurement, ProfileSums, BLOCKS};
pub use tube::{run_tube, TubeScenario, TubeSection};

use crate::file::{
    f_dt, f_lambda, one_u64, validate_fluid_params, validate_output, validate_stepping, yes, Check, FluidSection,
    ScenarioError,
};
use glam::DVec3;
use hemodpd_engine::walls::{ControlLaw, Reflection, WallConfig, WallShape};
use hemodpd_engine::{PairParams, SimConfig};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

// ---- the scenario files' shared sections: `[walls]`, `[run]`, `[output]` ----

/// `impl Kind` of a wall kind: `wall_kind!(Type, "name", run_function, [sweep columns])`. The
/// two wall kinds differ only in these.
macro_rules! wall_kind {
    ($ty:ty, $name:literal, $run:ident, [$($col:expr),* $(,)?]) => {
        impl crate::kind::Kind for $ty {
            const NAME: &'static str = $name;
            const SWEEP_COLUMNS: &'static [crate::kind::SweepColumn] = &[$($col),*];
            fn validate(&self, file: &str) -> Result<(), crate::file::ScenarioError> {
                validate(self, file)
            }
            fn seed(&self) -> u64 {
                self.seed
            }
            fn set_base_dir(&mut self, dir: std::path::PathBuf) {
                self.base_dir = dir;
            }
            /// Steps: adaptation, flow development and sampling.
            fn schedule_end(&self) -> (u64, &'static str) {
                (super::scheduled_steps(&self.walls, &self.run), "steps")
            }
            fn run_from(
                &self,
                ctx: &crate::context::RunContext,
                checkpoint: Option<&hemodpd_io::checkpoint::Checkpoint>,
            ) -> Result<serde_json::Value, crate::context::RunError> {
                $run(self, ctx, checkpoint)
            }
        }
    };
}
pub(crate) use wall_kind;

/// The steps a wall scenario's schedule takes: adaptation (if adaptive), flow development and
/// sampling.
pub(crate) fn scheduled_steps(w: &WallsSection, r: &WallRunSection) -> u64 {
    let adapt = if w.adaptive {
        w.adapt_iterations.saturating_mul(w.update_every)
    } else {
        0
    };
    adapt.saturating_add(r.flow_steps).saturating_add(r.steps)
}

/// `[output]` of the wall scenarios (optional). Steps count from the start of the walled run
/// (adaptation included).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WallOutput {
    /// Write a frame (fluid and wall particles, with types) to `trajectory.h5` every this many
    /// steps; 0 (default) writes no trajectory.
    #[serde(default)]
    pub trajectory_every_steps: u64,
    /// Store every this-many-th particle in a frame (default 1: all).
    #[serde(default = "one_u64")]
    pub particle_stride: u64,
    /// Write `checkpoint.h5` every this many steps; 0 (default): only at the end and on Ctrl-C.
    #[serde(default)]
    pub checkpoint_every_steps: u64,
}

impl Default for WallOutput {
    fn default() -> Self {
        Self {
            trajectory_every_steps: 0,
            particle_stride: 1,
            checkpoint_every_steps: 0,
        }
    }
}

fn w_bins() -> usize {
    5
}

fn w_gain() -> f64 {
    3.0
}

fn w_every() -> u64 {
    500
}

fn w_iters() -> u64 {
    10
}

fn w_equil() -> u64 {
    300
}

fn w_profile_bins() -> usize {
    16
}

/// Initial near-wall force of the adaptive control, when no saved profile is loaded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum InitialWallForce {
    /// Start from zero (the frozen wall particles already supply the repulsion).
    #[default]
    Zero,
    /// The integrated conservative force of a half-space of fluid, πρa(rc − h)³(rc + 3h)/(12 rc).
    HalfSpace,
    /// The converged profile of an earlier adaptive run of the same fluid, geometry, bins,
    /// control law and reflection, from the cache directory (zero when there is none). The
    /// summary names the file it came from.
    Cached,
}

/// `[walls]`: reflection and the adaptive near-wall force (docs/walls.md).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WallsSection {
    /// `"bounce-back"` (default, no slip) or `"specular"`.
    #[serde(default)]
    pub reflection: Reflection,
    /// Adaptive control on (default true).
    #[serde(default = "yes")]
    pub adaptive: bool,
    /// `"gradient"` (default: F_k += α(e_k − e_{k+1})) or `"local"` (F_k += α e_k).
    #[serde(default)]
    pub law: ControlLaw,
    /// Bins of the near-wall layer 0 ≤ h < rc (default 5).
    #[serde(default = "w_bins")]
    pub bins: usize,
    /// Gain α, force units (default 3).
    #[serde(default = "w_gain")]
    pub gain: f64,
    /// Steps averaged per update M (default 500).
    #[serde(default = "w_every")]
    pub update_every: u64,
    /// Number of updates (default 10); the flow is on during adaptation.
    #[serde(default = "w_iters")]
    pub adapt_iterations: u64,
    /// Initial force profile: `"zero"` (default; the frozen wall particles supply the
    /// repulsion), `"half-space"` (πρa(rc − h)³(rc + 3h)/(12rc)) or `"cached"` (the converged
    /// profile of an earlier adaptive run with the same fluid, geometry, bins, law and
    /// reflection, from the cache directory; zero when there is none).
    #[serde(default)]
    pub initial: InitialWallForce,
    /// A force-profile CSV to start from (e.g. a previous run's `wall_force.csv`), relative to
    /// the scenario file: used instead of `initial` when it matches the fluid and bins. Only
    /// read, never written.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force_file: Option<PathBuf>,
}

/// `[run]` of the wall scenarios (model units).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WallRunSection {
    /// Time step (default 0.01).
    #[serde(default = "f_dt")]
    pub timestep: f64,
    /// Groot–Warren λ (default 0.5).
    #[serde(default = "f_lambda")]
    pub lambda: f64,
    /// Steps of the periodic fluid before the walls are cut out of it (default 300).
    #[serde(default = "w_equil")]
    pub equilibration_steps: u64,
    /// Steps of flow development after adaptation, not sampled.
    pub flow_steps: u64,
    /// Sampled steps.
    pub steps: u64,
    /// Sample the profiles every this many steps.
    pub sample_every: u64,
    /// Bins of the velocity/density profile across the channel (default 16).
    #[serde(default = "w_profile_bins")]
    pub profile_bins: usize,
    /// After the run, time 500 more steps of it and of a periodic box with the same number of
    /// fluid particles, for the wall overhead (default false: a benchmark, outside the schedule
    /// and its checkpoints; docs/walls.md, "Cost").
    #[serde(default)]
    pub measure_overhead: bool,
}

fn validate_wall_common(
    kind: &str,
    want: &str,
    f: &FluidSection,
    w: &WallsSection,
    r: &WallRunSection,
    output: &WallOutput,
    c: &Check,
) -> Result<(), ScenarioError> {
    if kind != want {
        return Err(c.fail("kind", kind, &format!("{want:?}")));
    }
    validate_fluid_params(f, c)?;
    if f.gamma <= 0.0 {
        return Err(c.fail(
            "fluid.gamma",
            f.gamma,
            "a positive dissipative coefficient (walls need dissipation for no slip)",
        ));
    }
    if let Some(b) = f.box_size {
        return Err(c.fail(
            "fluid.box_size",
            format!("{b:?}"),
            "no box: the wall scenarios size it from [tube] or [plates]",
        ));
    }
    if w.bins == 0 || w.bins > 100 {
        return Err(c.fail("walls.bins", w.bins, "an integer from 1 to 100"));
    }
    c.range(
        "walls.gain",
        w.gain,
        0.0,
        100.0,
        "a gain between 0 and 100 (stable below ≈ kBT·bins/rc; default 3)",
    )?;
    if w.update_every == 0 {
        return Err(c.fail("walls.update_every", 0, "a positive number of steps"));
    }
    if w.adaptive && w.adapt_iterations == 0 {
        return Err(c.fail(
            "walls.adapt_iterations",
            0,
            "a positive number of updates when walls.adaptive = true (zero adapts nothing; set walls.adaptive = false for no adaptation)",
        ));
    }
    if w.adaptive && w.gain == 0.0 {
        return Err(c.fail(
            "walls.gain",
            0,
            "a positive gain up to 100 when walls.adaptive = true (zero changes nothing; set walls.adaptive = false for no adaptation)",
        ));
    }
    validate_stepping(*c, r.timestep, 0.05, r.lambda, r.steps, r.sample_every)?;
    let adapt = if w.adaptive {
        w.adapt_iterations.checked_mul(w.update_every)
    } else {
        Some(0)
    };
    let total = adapt
        .and_then(|a| a.checked_add(r.flow_steps))
        .and_then(|a| a.checked_add(r.steps));
    if total.is_none_or(|t| t > 1_000_000_000_000) {
        return Err(c.fail(
            "walls.adapt_iterations",
            w.adapt_iterations,
            "a schedule of at most 1e12 steps in all (adapt_iterations × update_every + run.flow_steps + run.steps)",
        ));
    }
    if r.profile_bins < 2 || r.profile_bins > 1000 {
        return Err(c.fail("run.profile_bins", r.profile_bins, "an integer from 2 to 1000"));
    }
    validate_output(c, output.particle_stride)
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

/// The geometry a walled run measures in.
#[derive(Clone, Copy, Debug)]
enum Channel {
    /// Tube of radius `radius` along z, length `length`, body force along z; the
    /// independently measured viscosity to compare with, if any.
    Tube {
        radius: f64,
        length: f64,
        /// `tube.body_force` as written (set unless `mean_velocity` is: validated).
        body_force: Option<f64>,
        reference_viscosity: Option<f64>,
        /// Target mean velocity and controller period, when controlled.
        mean_velocity: Option<(f64, u64)>,
    },
    /// Plates at z = `lower` and `lower + gap`, moving at ∓`speed` along x; `area` = Lx·Ly.
    Couette {
        lower: f64,
        gap: f64,
        speed: f64,
        area: f64,
    },
}

/// Everything one walled run needs, from either scenario kind.
struct Plan<'a> {
    kind: &'static str,
    toml: String,
    seed: u64,
    fluid: &'a FluidSection,
    walls: &'a WallsSection,
    run: &'a WallRunSection,
    output: &'a WallOutput,
    base_dir: &'a Path,
    shape: WallShape,
    box_lengths: DVec3,
    channel: Channel,
    /// µm per rc, for reporting lengths in µm too.
    length_scale_um_per_rc: Option<f64>,
}

impl Plan<'_> {
    /// Steps of adaptation A.
    fn adapt_steps(&self) -> u64 {
        if self.walls.adaptive {
            self.walls.adapt_iterations * self.walls.update_every
        } else {
            0
        }
    }
    /// First sampled step A + F.
    fn sampling_start(&self) -> u64 {
        self.adapt_steps() + self.run.flow_steps
    }
    /// All steps A + F + S.
    fn total(&self) -> u64 {
        self.sampling_start() + self.run.steps
    }
    fn body_force(&self) -> DVec3 {
        match self.channel {
            Channel::Tube {
                body_force,
                radius,
                reference_viscosity,
                mean_velocity,
                ..
            } => match mean_velocity {
                // the flow controller's first force (see FlowControl)
                Some((u, _)) => DVec3::new(
                    0.0,
                    0.0,
                    8.0 * reference_viscosity.unwrap_or(1.0) * u / (self.fluid.density * radius * radius),
                ),
                None => DVec3::new(0.0, 0.0, body_force.unwrap_or(0.0)),
            },
            Channel::Couette { .. } => DVec3::ZERO,
        }
    }
    fn config(&self) -> SimConfig {
        let mut config = SimConfig::new(self.box_lengths, self.run.timestep, self.seed);
        config.lambda = self.run.lambda;
        config
    }
    fn wall_config(&self) -> WallConfig {
        let w = self.walls;
        WallConfig {
            reflection: w.reflection,
            bins: w.bins,
            rc: self.fluid.cutoff,
            law: w.law,
            gain: w.gain,
            update_every: w.update_every,
            adapt: false,
            target_density: None,
        }
    }
    /// The axis the flow runs along (tube: z; Couette: x).
    fn flow_axis(&self) -> usize {
        match self.channel {
            Channel::Tube { .. } => 2,
            Channel::Couette { .. } => 0,
        }
    }
    fn flow_direction(&self) -> DVec3 {
        let mut e = DVec3::ZERO;
        e[self.flow_axis()] = 1.0;
        e
    }
    fn frame_due(&self, step: u64) -> bool {
        let every = self.output.trajectory_every_steps;
        every > 0 && step.is_multiple_of(every)
    }
    /// The profile bin of a fluid particle at `x`, if inside the profiled region.
    #[inline]
    fn bin(&self, x: DVec3) -> Option<usize> {
        let nb = self.run.profile_bins;
        let k = match self.channel {
            Channel::Tube { radius, .. } => (self.shape.signed_distance(x) + radius) / radius * nb as f64,
            Channel::Couette { lower, gap, .. } => (x.z - lower) / gap * nb as f64,
        };
        (k >= 0.0).then(|| (k as usize).min(nb - 1))
    }
}
