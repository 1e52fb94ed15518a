//! # hemodpd-engine: the dissipative particle dynamics (DPD) core
//!
//! A periodic, orthorhombic box of point particles interacting through the Groot–Warren DPD pair
//! force (conservative + dissipative + random), integrated with the modified velocity-Verlet scheme
//! of Groot & Warren (1997). Everything other crates build on lives here:
//!
//! * [`Particles`]: structure-of-arrays particle storage (position, velocity, force, type, id).
//!   The storage order never changes: index `i` is the same particle for the whole run.
//! * [`ForceField`]: per-type properties ([`TypeSpec`]: mass, frozen, body force) and the per
//!   type-pair DPD parameters ([`PairParams`]).
//! * [`SimConfig`]: box, time step, λ, seed and the force-loop scheme.
//! * [`Simulation`]: the stepper, generic over an [`Extension`] (walls, membranes, custom forces)
//!   with `()` as the do-nothing default (static dispatch: a plain fluid pays nothing).
//! * [`observe`]: temperature, pressure tensor, momentum, binned profiles, block averages.
//! * [`init`]: initial fluid configurations (random or jittered lattice, Maxwell–Boltzmann).
//! * [`kernel`]: pair kernels (small `Copy` structs with one `force` method).
//! * [`walls`]: walls from a signed distance (tube, plates), frozen wall particles, bounce-back
//!   and the adaptive near-wall force, as the [`Walls`] extension (docs/walls.md).
//!
//! All quantities are in DPD model units (length rc, energy kBT, mass m of a solvent particle)
//! unless a doc comment says otherwise.
//!
//! ```
//! use hemodpd_engine::{init, ForceField, PairParams, SimConfig, Simulation};
//! use glam::DVec3;
//! # fn main() -> Result<(), hemodpd_engine::EngineError> {
//! let config = SimConfig::new(DVec3::splat(5.0), 0.01, 42);
//! let field = ForceField::single(PairParams::groot_warren());
//! let particles = init::fluid(&config, &field, &init::FluidSpec::standard(), 7)?;
//! let mut sim = Simulation::new(config, field, particles)?;
//! sim.run(10)?;
//! let t = hemodpd_engine::observe::temperature(sim.particles(), sim.field());
//! assert!(t > 0.5 && t < 1.5);
//! # Ok(()) }
//! ```

pub mod cells;
pub mod domain;
pub mod error;
pub mod init;
pub mod kernel;
pub mod mesh_bounce;
pub mod observe;
pub mod pairs;
pub mod params;
pub mod particles;
pub mod rng;
mod shared;
pub mod sim;
mod simd;
pub mod walls;

/// The floating-point type of the engine.
pub type Real = f64;

pub use domain::PeriodicBox;
pub use error::EngineError;
pub use params::{ForceField, ForceScheme, PairParams, SimConfig, TypeSpec};
pub use particles::{Particles, SimState, StateMut};
pub use sim::{Extension, Simulation, Timed};
pub use walls::{ControlLaw, Reflection, WallConfig, WallShape, Walls, WallsState};

/// Convenience alias.
pub type Result<T, E = EngineError> = std::result::Result<T, E>;
