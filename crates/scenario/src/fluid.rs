//! The periodic DPD fluid scenario (`kind = "dpd-fluid"`).

use crate::file::FluidScenario;
use crate::{RunContext, RunError};

/// Runs the standard fluid and reports temperature, pressure and throughput.
pub fn run(_s: &FluidScenario, _ctx: &RunContext) -> Result<serde_json::Value, RunError> {
    Err(RunError::Engine(
        "the dpd-fluid driver is not wired yet".into(),
    ))
}
