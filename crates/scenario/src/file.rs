//! The ground floor of scenario files, which every kind may use: the error type, [`load`] with
//! `--set` overrides, the format version, the `[fluid]` section of the DPD kinds and the checks
//! the time-stepping kinds share. Which kinds exist and how each is parsed, validated and run is
//! [`crate::kind`]'s; a kind's own sections live in its module.

use serde::{Deserialize, Serialize};

/// Version of the scenario file format this build reads.
pub const FORMAT_VERSION: u32 = 1;

/// A bad scenario: always names the file and, where it applies, the key, the value and what is allowed.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    #[error("{file}: cannot read: {source}")]
    Read { file: String, source: std::io::Error },
    #[error("{file}: {message}")]
    Syntax { file: String, message: String },
    #[error("{file}: key `{key}` = {value} is not allowed: {allowed}")]
    Value {
        file: String,
        key: String,
        value: String,
        allowed: String,
    },
    #[error("{file}: missing key `{key}` ({what})")]
    Missing { file: String, key: String, what: String },
    #[error("--set {assignment}: {message}")]
    Override { assignment: String, message: String },
}

// serde defaults several kinds' sections share
pub(crate) fn one() -> f64 {
    1.0
}
pub(crate) fn yes() -> bool {
    true
}
pub(crate) fn one_u64() -> u64 {
    1
}
pub(crate) fn f_lambda() -> f64 {
    0.5
}
pub(crate) fn f_dt() -> f64 {
    0.01
}

fn f_rho() -> f64 {
    3.0
}
fn f_a() -> f64 {
    25.0
}
fn f_gamma() -> f64 {
    4.5
}
fn f_cut() -> f64 {
    1.0
}

/// `[fluid]`, model units: lengths in rc, energies in kBT, masses in m.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FluidSection {
    /// Number density, particles per rc³ (default 3).
    #[serde(default = "f_rho")]
    pub density: f64,
    /// Box edges, rc (each ≥ 3 rc). Required by `dpd-fluid`; the wall scenarios size their box
    /// from `[tube]` or `[plates]` and reject it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub box_size: Option<[f64; 3]>,
    /// Conservative amplitude a (default 25).
    #[serde(default = "f_a")]
    pub a: f64,
    /// Dissipative coefficient γ (default 4.5).
    #[serde(default = "f_gamma")]
    pub gamma: f64,
    /// Thermal energy kBT (default 1).
    #[serde(default = "one")]
    pub kbt: f64,
    /// Cut-off radius (default 1).
    #[serde(default = "f_cut")]
    pub cutoff: f64,
    /// Random-weight exponent s, w^R = (1 − r/rc)^s (default 1; 0.5 and 0.25 raise the Schmidt number).
    #[serde(default = "one")]
    pub weight_exponent: f64,
}

pub(crate) fn syntax(file: &str, e: impl std::fmt::Display) -> ScenarioError {
    ScenarioError::Syntax {
        file: file.to_string(),
        message: e.to_string().trim_end().to_string(),
    }
}

/// Builds the [`ScenarioError::Value`] of a key in `file`.
#[derive(Clone, Copy)]
pub(crate) struct Check<'a> {
    pub(crate) file: &'a str,
}

impl Check<'_> {
    pub(crate) fn range(&self, key: &str, v: f64, lo: f64, hi: f64, allowed: &str) -> Result<(), ScenarioError> {
        if v.is_finite() && v >= lo && v <= hi {
            Ok(())
        } else {
            Err(ScenarioError::Value {
                file: self.file.into(),
                key: key.into(),
                value: format!("{v}"),
                allowed: allowed.into(),
            })
        }
    }
    pub(crate) fn fail(&self, key: &str, value: impl std::fmt::Display, allowed: &str) -> ScenarioError {
        ScenarioError::Value {
            file: self.file.into(),
            key: key.into(),
            value: value.to_string(),
            allowed: allowed.into(),
        }
    }
}

/// `[output]` keys every time-stepping scenario shares.
pub(crate) fn validate_output(c: &Check, particle_stride: u64) -> Result<(), ScenarioError> {
    if particle_stride == 0 || particle_stride > 1_000_000_000 {
        return Err(c.fail(
            "output.particle_stride",
            particle_stride,
            "a positive stride (1: every particle, 10: every tenth)",
        ));
    }
    Ok(())
}

/// `[run]` keys every time-stepping scenario shares: Δt up to `max_dt`, λ, steps, sampling.
pub(crate) fn validate_stepping(
    c: Check,
    dt: f64,
    max_dt: f64,
    lambda: f64,
    steps: u64,
    sample_every: u64,
) -> Result<(), ScenarioError> {
    c.range(
        "run.timestep",
        dt,
        1e-6,
        max_dt,
        &format!("a time step between 1e-6 and {max_dt} (standard: 0.01)"),
    )?;
    c.range(
        "run.lambda",
        lambda,
        0.0,
        1.0,
        "a Groot–Warren λ between 0 and 1 (0.5 standard)",
    )?;
    if steps == 0 {
        return Err(c.fail("run.steps", 0, "a positive number of steps"));
    }
    if sample_every == 0 || sample_every > steps {
        return Err(c.fail(
            "run.sample_every",
            sample_every,
            "a positive interval no longer than run.steps",
        ));
    }
    Ok(())
}

/// The `[fluid]` parameters every scenario with a DPD fluid shares.
pub(crate) fn validate_fluid_params(f: &FluidSection, c: &Check) -> Result<(), ScenarioError> {
    c.range(
        "fluid.density",
        f.density,
        0.1,
        30.0,
        "a number density between 0.1 and 30 per rc³ (standard: 3)",
    )?;
    c.range("fluid.cutoff", f.cutoff, 0.1, 10.0, "a cut-off between 0.1 and 10")?;
    c.range("fluid.a", f.a, 0.0, 1e4, "a conservative amplitude between 0 and 1e4")?;
    c.range(
        "fluid.gamma",
        f.gamma,
        0.0,
        1e4,
        "a dissipative coefficient between 0 and 1e4",
    )?;
    c.range("fluid.kbt", f.kbt, 1e-6, 1e3, "a thermal energy between 1e-6 and 1e3")?;
    c.range(
        "fluid.weight_exponent",
        f.weight_exponent,
        0.05,
        4.0,
        "an exponent between 0.05 and 4 (1 standard; 0.5, 0.25 for higher Schmidt number)",
    )
}
