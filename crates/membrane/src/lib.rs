//! The coarse-grained red-blood-cell membrane of Pivkin & Karniadakis (PRL 101, 118105, 2008).
//!
//! * [`params`]: the fine model and its coarse-graining to any N (Eqs. 4, 8–12), in SI.
//! * [`shape`]: the Evans–Fung biconcave reference shape (Eq. 7, with the corrected c0).
//! * [`mesh`]: triangulated closed surfaces, their topology (links, dihedrals), quality and file formats.
//! * [`meshgen`]: the paper's procedure: uniform points, triangulation, relaxation with link flips.
//! * [`forces`]: the free energy (Eq. 1) — WLC + C/A, bending, global area and volume — and its exact gradient.
//! * [`stretch`]: the optical-tweezers stretching experiment at static equilibrium.
//! * [`motion`]: tumbling, tank-treading, swinging or intermittent motion of a cell in shear flow.
//! * [`viscosity`]: membrane viscosity (Fedosov's link friction and noise), a Shardlow sweep.
//! * [`respa`]: membrane sub-stepping (the inner steps of an r-RESPA scheme) for a stiff viscosity.
//!
//! Units: this crate is unit-agnostic; callers pass numbers in one consistent system.
//! The stretching driver uses µm, pN and pN·µm (so kBT = 4.142e-3 pN·µm at 300 K).

mod block_matrix;
pub mod cellshape;
pub mod confine;
pub mod coupling;
pub mod forces;
mod lbfgs;
pub mod mesh;
pub mod meshgen;
pub mod meshio;
pub mod motion;
pub mod params;
pub mod precondition;
pub mod recovery;
pub mod reference;
pub mod respa;
pub mod shape;
pub mod stretch;
pub mod viscosity;

pub use forces::{EnergyTerms, MembraneModel, ReferenceState};
pub use mesh::{Mesh, MeshError, Topology};
pub use params::ModelParams;

/// Floating-point type of the whole project.
pub type Real = f64;
