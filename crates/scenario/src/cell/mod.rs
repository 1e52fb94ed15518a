//! The cell-in-flow family: one red blood cell in a flowing fluid, the kinds `capillary` (a
//! tube, [`crate::capillary`]) and `shear` ([`crate::shear`]). Each kind is its own module
//! holding only what is its own (geometry, drive, measures, results); here is what they share.
//!
//! Particle types: 0 outer fluid (plasma), 1 frozen wall, 2 inner fluid (cytosol), 3 membrane
//! vertex. Pairs: fluid–fluid of each side with its own γ; inner–outer conservative only (the
//! membrane has no thickness, so the two fluids still push on each other, but exchange no
//! momentum dissipatively); membrane–fluid a = 0 and the no-slip friction of each side
//! ([`crate::units::fsi_friction`]); membrane–wall as membrane–plasma plus a short repulsion;
//! membrane–membrane nothing (the membrane model acts between vertices).
//!
//! Layout: in [`section`], the `[cell]` section, the shared `[model]` keys (each kind declares
//! its `[model]` with `model_section!`) and their validation; in [`build`], the force field,
//! the membrane model and its dry run, and the cell placed in an equilibrated fluid (the
//! kind's [`build::CellPlan`] says where); in `checkpoint`, saving and restoring a run and
//! creating its trajectory; in [`placement`], the orientation a cell enters a tube with and
//! the cell pressed into a tube narrower than it is; in `summary`, the blocks of `summary.json` both kinds write.

pub mod build;
pub(crate) mod checkpoint;
pub mod placement;
pub mod section;
pub(crate) mod summary;

pub use build::{describe_engine_error, CellSim};
pub use placement::CellOrientation;
pub use section::{CellSection, ModelKeys, SubstepSetting, ThermalSetting, ViscosityForm};

/// Type of the outer fluid (plasma).
pub const OUTER: u16 = 0;
/// Type of the frozen wall particles.
pub const WALL: u16 = 1;
/// Type of the inner fluid (cytosol).
pub const INNER: u16 = 2;
/// Type of the membrane vertices.
pub const MEMBRANE: u16 = 3;

/// Mass of a membrane vertex (model units; the fluid's).
pub(crate) const VERTEX_MASS: f64 = 1.0;
