//! One interface for a scenario kind.
//!
//! A kind is the validated content of a scenario file with `kind = "NAME"`: a type that
//! implements [`Kind`] in its own module (its name, validation, files, schedule, run and resume,
//! the sweep table's columns, the unit explanation). `scenario_kinds!` turns the list of kinds
//! in [`crate::registry`] into the `Scenario` enum and every dispatch over it, so that adding a
//! kind is its module plus one line in that list.

use std::path::{Path, PathBuf};

use hemodpd_io::checkpoint::Checkpoint;
use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::context::{RunContext, RunError};
use crate::file::ScenarioError;

/// A column of the sweep table: its header, the JSON pointer of its figure in the run's
/// `results`, and whether it is a timing (which differs from run to run and is left out when
/// tables are compared).
pub type SweepColumn = (&'static str, &'static str, bool);

/// A scenario kind: the validated content of a scenario file with `kind = NAME`.
pub trait Kind: Sized + Clone + std::fmt::Debug + Serialize + DeserializeOwned {
    /// The `kind = "..."` of its files.
    const NAME: &'static str;
    /// What the sweep table shows of each point's results.
    const SWEEP_COLUMNS: &'static [SweepColumn];

    /// Checks every value before any work (the unit mapping included); the error names
    /// `file`, the key, the value and what is allowed.
    fn validate(&self, file: &str) -> Result<(), ScenarioError>;

    /// The master seed.
    fn seed(&self) -> u64;

    /// The directory files named in the scenario are relative to (made absolute by
    /// [`crate::load`](crate::registry::load) and kept in checkpoints). Default: the kind names no file.
    fn set_base_dir(&mut self, _dir: PathBuf) {}

    /// Checks that the files the scenario names exist and fit it (after [`Kind::set_base_dir`]).
    fn check_files(&self, _file: &str) -> Result<(), ScenarioError> {
        Ok(())
    }

    /// The end of the schedule in the unit its checkpoint's step counts: (total, unit).
    fn schedule_end(&self) -> (u64, &'static str);

    /// Runs the scenario into `ctx.out_dir`, from its start or from `checkpoint`; returns the
    /// `results` object of `summary.json`.
    fn run_from(&self, ctx: &RunContext, checkpoint: Option<&Checkpoint>) -> Result<serde_json::Value, RunError>;

    /// How the SI of the file maps onto model units (`hemodpd run --explain-units`); `None`
    /// for kinds written in model units.
    fn explain_units(&self) -> Option<Result<String, RunError>> {
        None
    }

    /// The same mapping as data: the scales (`length_m`, `energy_j`, `time_s`), the thermal
    /// factor, the chosen fluid and the dimensionless groups in SI and in the model (the Python
    /// package's `explain_units`); `None` for kinds written in model units.
    fn unit_mapping_json(&self) -> Option<Result<serde_json::Value, RunError>> {
        None
    }
}

/// Deserialises and validates one kind from a parsed file.
pub(crate) fn parse_kind<K: Kind>(value: toml::Value, file: &str) -> Result<K, ScenarioError> {
    let s: K = value.try_into().map_err(|e| crate::file::syntax(file, e))?;
    s.validate(file)?;
    Ok(s)
}

/// Declares `Scenario` over the kinds and its dispatch (`crate::registry`); each entry is
/// `Variant(Type)`.
macro_rules! scenario_kinds {
    ($($variant:ident($ty:ty)),+ $(,)?) => {
        /// A validated scenario of any kind.
        #[derive(Clone, Debug, serde::Serialize)]
        #[serde(untagged)]
        pub enum Scenario {
            $($variant($ty)),+
        }

        /// The `kind` names this build reads, in the order of the list.
        pub const KIND_NAMES: &[&str] = &[$(<$ty as $crate::kind::Kind>::NAME),+];

        /// The sweep columns of the kind named `kind` (empty for an unknown name).
        pub fn sweep_columns(kind: &str) -> &'static [$crate::kind::SweepColumn] {
            $(if kind == <$ty as $crate::kind::Kind>::NAME {
                return <$ty as $crate::kind::Kind>::SWEEP_COLUMNS;
            })+
            &[]
        }

        impl Scenario {
            /// Parses and validates the scenario of kind `kind`; `None` for an unknown kind.
            pub(crate) fn parse(kind: &str, value: toml::Value, file: &str) -> Option<Result<Scenario, $crate::file::ScenarioError>> {
                $(if kind == <$ty as $crate::kind::Kind>::NAME {
                    return Some($crate::kind::parse_kind::<$ty>(value, file).map(Scenario::$variant));
                })+
                None
            }
            /// The `kind = "..."` of the file.
            pub fn kind(&self) -> &'static str {
                match self { $(Scenario::$variant(_) => <$ty as $crate::kind::Kind>::NAME),+ }
            }
            /// The master seed.
            pub fn seed(&self) -> u64 {
                match self { $(Scenario::$variant(s) => <$ty as $crate::kind::Kind>::seed(s)),+ }
            }
            /// See [`Kind::set_base_dir`].
            pub fn set_base_dir(&mut self, dir: std::path::PathBuf) {
                match self { $(Scenario::$variant(s) => <$ty as $crate::kind::Kind>::set_base_dir(s, dir)),+ }
            }
            /// See [`Kind::check_files`].
            pub fn check_files(&self, file: &str) -> Result<(), $crate::file::ScenarioError> {
                match self { $(Scenario::$variant(s) => <$ty as $crate::kind::Kind>::check_files(s, file)),+ }
            }
            /// See [`Kind::schedule_end`].
            pub fn schedule_end(&self) -> (u64, &'static str) {
                match self { $(Scenario::$variant(s) => <$ty as $crate::kind::Kind>::schedule_end(s)),+ }
            }
            /// See [`Kind::run_from`].
            pub fn run_from(&self, ctx: &$crate::context::RunContext, checkpoint: Option<&hemodpd_io::checkpoint::Checkpoint>) -> Result<serde_json::Value, $crate::context::RunError> {
                match self { $(Scenario::$variant(s) => <$ty as $crate::kind::Kind>::run_from(s, ctx, checkpoint)),+ }
            }
            /// See [`Kind::explain_units`].
            pub fn explain_units(&self) -> Option<Result<String, $crate::context::RunError>> {
                match self { $(Scenario::$variant(s) => <$ty as $crate::kind::Kind>::explain_units(s)),+ }
            }
            /// See [`Kind::unit_mapping_json`].
            pub fn unit_mapping_json(&self) -> Option<Result<serde_json::Value, $crate::context::RunError>> {
                match self { $(Scenario::$variant(s) => <$ty as $crate::kind::Kind>::unit_mapping_json(s)),+ }
            }
            /// The sweep table's columns of this scenario's kind.
            pub fn sweep_columns(&self) -> &'static [$crate::kind::SweepColumn] {
                match self { $(Scenario::$variant(_) => <$ty as $crate::kind::Kind>::SWEEP_COLUMNS),+ }
            }
        }
    };
}
pub(crate) use scenario_kinds;

/// Checks a mesh file named under `key` (relative to `base`): it must exist, be readable and
/// have `vertices` vertices. For the kinds that take a `mesh_file`.
pub(crate) fn check_mesh_file(
    file: &str,
    key: &str,
    base: &Path,
    m: &Path,
    vertices: i64,
) -> Result<(), ScenarioError> {
    let full = base.join(m);
    let name = format!("{:?}", m.display().to_string());
    if !full.exists() {
        return Err(ScenarioError::Value {
            file: file.into(),
            key: key.into(),
            value: name,
            allowed: format!("an existing mesh file ({} does not exist)", full.display()),
        });
    }
    let mesh = hemodpd_membrane::meshio::read_mesh(&full).map_err(|e| ScenarioError::Value {
        file: file.into(),
        key: key.into(),
        value: name.clone(),
        allowed: format!(
            "a readable closed triangle mesh in µm (OFF, PLY or NAME.vertices.csv + NAME.triangles.csv): {e}"
        ),
    })?;
    let nv = mesh.vertices.len();
    if nv as i64 != vertices {
        return Err(ScenarioError::Value {
            file: file.into(),
            key: key.into(),
            value: format!("{name} (with {nv} vertices)"),
            allowed: format!(
                "a mesh with {vertices} vertices: the model parameters are coarse-grained from N (Eqs. 8, 9, 12), so the file and the vertex count must agree"
            ),
        });
    }
    Ok(())
}
