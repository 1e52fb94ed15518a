//! hemodpd-io: everything hemodpd writes and reads back, and the only crate linking HDF5.
//!
//! - [`trajectory`]: HDF5 trajectories (membrane mesh and frames, fluid particles, binned fields),
//!   appended and flushed frame by frame; [`xdmf`] writes the ParaView companion file.
//! - [`checkpoint`]: atomic HDF5 checkpoints with bit-exact round trips, for `--resume`.
//! - [`analysis`]: cell shape and motion metrics computed from a trajectory after the fact.
//! - [`plot`]: PNG line charts (with error bars) on top of `plotters`.
//! - [`summary`] and [`progress`]: run summaries and progress reporting.
//!
//! The crate works on plain arrays (`&[DVec3]`, `&[[u32; 3]]`, `&[f64]`) and metadata; it does
//! not depend on the engine or membrane crates. The layout is documented in `docs/output.md`.

pub mod analysis;
pub mod checkpoint;
pub mod error;
mod h5util;
mod layout;
pub mod plot;
pub mod progress;
pub mod summary;
pub mod trajectory;
pub mod units;
pub mod xdmf;

pub use error::{IoError, Result};
pub use trajectory::{
    FieldFrame, FieldInfo, FluidFrame, FrameScalar, GridSpec, MembraneFrame, MetaValue, RunMetadata, TrajectoryReader,
    TrajectoryWriter, WriterOptions,
};
pub use units::{Quantity, UnitSystem};
