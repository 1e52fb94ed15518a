//! Typed errors: invalid input and numerical instability. The engine never panics on bad input.

use crate::Real;

/// Everything that can go wrong in the engine.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EngineError {
    /// A constructor or setter was given a value it cannot work with.
    #[error("invalid {what}: {why}")]
    InvalidInput {
        /// Which parameter or input.
        what: String,
        /// What is wrong with it.
        why: String,
    },
    /// A position, velocity or force became NaN or infinite.
    #[error(
        "numerical instability at step {step}: particle id {id} (index {index}, type {ptype}) has non-finite {quantity} {value}; likely cause: {cause}"
    )]
    NonFinite {
        /// The step being taken (the step counter after the failed step would be `step`).
        step: u64,
        /// Global id of the particle.
        id: u32,
        /// Storage index of the particle.
        index: usize,
        /// Type index of the particle.
        ptype: u16,
        /// `"position"`, `"velocity"` or `"force"`.
        quantity: &'static str,
        /// The offending value, formatted.
        value: String,
        /// The most likely cause, in words.
        cause: &'static str,
    },
    /// A particle moved further than one cell in one step: the cell list would miss pairs.
    #[error(
        "numerical instability at step {step}: particle id {id} (index {index}, type {ptype}) moved {displacement:.4} in one step, more than the cell size {cell:.4} (velocity {velocity}); likely cause: {cause}"
    )]
    TooFast {
        /// The step being taken.
        step: u64,
        /// Global id of the particle.
        id: u32,
        /// Storage index of the particle.
        index: usize,
        /// Type index of the particle.
        ptype: u16,
        /// Distance moved in this step.
        displacement: Real,
        /// Smallest cell edge.
        cell: Real,
        /// Velocity used for the move, formatted.
        velocity: String,
        /// The most likely cause, in words.
        cause: &'static str,
    },
    /// An [`crate::Extension`] reported a failure.
    #[error("extension failed at step {step}: {message}")]
    Extension {
        /// The step being taken.
        step: u64,
        /// The extension's message.
        message: String,
    },
    /// A rayon thread pool could not be built (tests, benchmarks).
    #[error("thread pool: {0}")]
    ThreadPool(String),
}

impl EngineError {
    /// Shorthand for [`EngineError::InvalidInput`].
    pub fn invalid(what: impl Into<String>, why: impl Into<String>) -> Self {
        EngineError::InvalidInput {
            what: what.into(),
            why: why.into(),
        }
    }
}

pub(crate) const CAUSE_DT: &str =
    "time step too large for the forces (reduce dt), or overlapping particles in the initial state";
pub(crate) const CAUSE_FAST: &str =
    "time step too large or a huge force (overlapping initial state, too large a repulsion a or body force)";
