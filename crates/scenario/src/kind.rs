//! One interface for a scenario kind, and the one list of the kinds this build knows.
//!
//! A kind is the validated content of a scenario file with `kind = "NAME"`: a type that
//! implements [`Kind`] in its own module (its name, validation, schedule, run and resume, the
//! sweep table's columns). [`scenario_kinds!`] turns the list of kinds into the [`Scenario`] enum
//! and every dispatch over it (parsing a file, the seed, running, resuming, the sweep columns),
//! so that adding a kind is its module plus one line in that list (at the end of this file).

use std::path::{Path, PathBuf};

use hemodpd_io::checkpoint::Checkpoint;
use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::file::ScenarioError;
use crate::{RunContext, RunError};

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
    /// [`crate::load`] and kept in checkpoints). Default: the kind names no file.
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
}

/// Deserialises and validates one kind from a parsed file.
fn parse_kind<K: Kind>(value: toml::Value, file: &str) -> Result<K, ScenarioError> {
    let s: K = value.try_into().map_err(|e| crate::file::syntax(file, e))?;
    s.validate(file)?;
    Ok(s)
}

/// Declares [`Scenario`] over the kinds and its dispatch; each entry is `Variant(Type)`.
macro_rules! scenario_kinds {
    ($($variant:ident($ty:ty)),+ $(,)?) => {
        /// A validated scenario of any kind.
        #[derive(Clone, Debug, Serialize)]
        #[serde(untagged)]
        pub enum Scenario {
            $($variant($ty)),+
        }

        /// The `kind` names this build reads, in the order of the list.
        pub const KIND_NAMES: &[&str] = &[$(<$ty as Kind>::NAME),+];

        /// The sweep columns of the kind named `kind` (empty for an unknown name).
        pub fn sweep_columns(kind: &str) -> &'static [SweepColumn] {
            $(if kind == <$ty as Kind>::NAME {
                return <$ty as Kind>::SWEEP_COLUMNS;
            })+
            &[]
        }

        impl Scenario {
            /// Parses and validates the scenario of kind `kind`; `None` for an unknown kind.
            pub(crate) fn parse(kind: &str, value: toml::Value, file: &str) -> Option<Result<Scenario, ScenarioError>> {
                $(if kind == <$ty as Kind>::NAME {
                    return Some(parse_kind::<$ty>(value, file).map(Scenario::$variant));
                })+
                None
            }
            /// The `kind = "..."` of the file.
            pub fn kind(&self) -> &'static str {
                match self { $(Scenario::$variant(_) => <$ty as Kind>::NAME),+ }
            }
            /// The master seed.
            pub fn seed(&self) -> u64 {
                match self { $(Scenario::$variant(s) => <$ty as Kind>::seed(s)),+ }
            }
            /// See [`Kind::set_base_dir`].
            pub fn set_base_dir(&mut self, dir: PathBuf) {
                match self { $(Scenario::$variant(s) => <$ty as Kind>::set_base_dir(s, dir)),+ }
            }
            /// See [`Kind::check_files`].
            pub fn check_files(&self, file: &str) -> Result<(), ScenarioError> {
                match self { $(Scenario::$variant(s) => <$ty as Kind>::check_files(s, file)),+ }
            }
            /// See [`Kind::schedule_end`].
            pub fn schedule_end(&self) -> (u64, &'static str) {
                match self { $(Scenario::$variant(s) => <$ty as Kind>::schedule_end(s)),+ }
            }
            /// See [`Kind::run_from`].
            pub fn run_from(&self, ctx: &RunContext, checkpoint: Option<&Checkpoint>) -> Result<serde_json::Value, RunError> {
                match self { $(Scenario::$variant(s) => <$ty as Kind>::run_from(s, ctx, checkpoint)),+ }
            }
            /// See [`Kind::explain_units`].
            pub fn explain_units(&self) -> Option<Result<String, RunError>> {
                match self { $(Scenario::$variant(s) => <$ty as Kind>::explain_units(s)),+ }
            }
            /// The sweep table's columns of this scenario's kind.
            pub fn sweep_columns(&self) -> &'static [SweepColumn] {
                match self { $(Scenario::$variant(_) => <$ty as Kind>::SWEEP_COLUMNS),+ }
            }
        }
    };
}

/// `"a", "b" or "c"`: the kind names for messages.
pub fn kind_list() -> String {
    let quoted: Vec<String> = KIND_NAMES.iter().map(|k| format!("{k:?}")).collect();
    match quoted.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("one of {} or {last}", rest.join(", ")),
        Some((last, _)) => last.clone(),
        None => String::new(),
    }
}

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

// The kinds of this build: one line each.
scenario_kinds! {
    Stretching(crate::stretching::StretchingScenario),
    DpdFluid(crate::fluid::FluidScenario),
    PoiseuilleTube(crate::channel::TubeScenario),
    Couette(crate::channel::CouetteScenario),
    Capillary(crate::capillary::CapillaryScenario),
    Shear(crate::shear::ShearScenario),
}

impl Kind for crate::capillary::CapillaryScenario {
    const NAME: &'static str = "capillary";
    const SWEEP_COLUMNS: &'static [SweepColumn] = &[
        ("cell velocity (m/s)", "/driven/cell_velocity_m_per_s", false),
        ("fluid velocity (m/s)", "/driven/fluid_mean_velocity_m_per_s", false),
        ("length (um)", "/driven/axial_length_um", false),
        ("DI", "/driven/deformation_index", false),
        ("misplaced", "/crossings/misplaced_total", false),
    ];
    fn validate(&self, file: &str) -> Result<(), ScenarioError> {
        crate::capillary::validate(self, file)
    }
    fn seed(&self) -> u64 {
        self.seed
    }
    fn set_base_dir(&mut self, dir: PathBuf) {
        self.base_dir = dir;
    }
    fn check_files(&self, file: &str) -> Result<(), ScenarioError> {
        match &self.cell.mesh_file {
            Some(m) => check_mesh_file(file, "cell.mesh_file", &self.base_dir, m, self.cell.vertices),
            None => Ok(()),
        }
    }
    /// Steps of the longest schedule (stages that end when steady end earlier).
    fn schedule_end(&self) -> (u64, &'static str) {
        (
            crate::capillary::Plan::new(self)
                .map(|p| p.max_steps())
                .unwrap_or(u64::MAX),
            "steps",
        )
    }
    fn run_from(&self, ctx: &RunContext, checkpoint: Option<&Checkpoint>) -> Result<serde_json::Value, RunError> {
        crate::capillary::run_from(self, ctx, checkpoint)
    }
    fn explain_units(&self) -> Option<Result<String, RunError>> {
        Some(crate::capillary::CapillaryScenario::explain_units(self))
    }
}

impl Kind for crate::shear::ShearScenario {
    const NAME: &'static str = "shear";
    const SWEEP_COLUMNS: &'static [SweepColumn] = &[
        ("stress (Pa)", "/shear/shear_stress_pa", false),
        ("Ca", "/groups_si/capillary_number", false),
        ("class", "/motion/class", false),
        ("TTF/rate", "/motion/tank_treading_frequency_over_shear_rate", false),
        ("flips/s", "/motion/tumbling_rate_flips_per_s", false),
        ("incl (deg)", "/motion/mean_inclination_deg", false),
        ("swing (deg)", "/motion/inclination_amplitude_deg", false),
    ];
    fn validate(&self, file: &str) -> Result<(), ScenarioError> {
        crate::shear::validate(self, file)
    }
    fn seed(&self) -> u64 {
        self.seed
    }
    fn set_base_dir(&mut self, dir: PathBuf) {
        self.base_dir = dir;
    }
    fn check_files(&self, file: &str) -> Result<(), ScenarioError> {
        match &self.cell.mesh_file {
            Some(m) => check_mesh_file(file, "cell.mesh_file", &self.base_dir, m, self.cell.vertices),
            None => Ok(()),
        }
    }
    fn schedule_end(&self) -> (u64, &'static str) {
        (
            crate::shear::Plan::new(self).map(|p| p.steps).unwrap_or(u64::MAX),
            "steps",
        )
    }
    fn run_from(&self, ctx: &RunContext, checkpoint: Option<&Checkpoint>) -> Result<serde_json::Value, RunError> {
        crate::shear::run_from(self, ctx, checkpoint)
    }
    fn explain_units(&self) -> Option<Result<String, RunError>> {
        Some(crate::shear::ShearScenario::explain_units(self))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_is_registered_once_with_columns_and_a_shipped_scenario() {
        let mut names = KIND_NAMES.to_vec();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), KIND_NAMES.len(), "a kind name is registered twice");
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios");
        let mut shipped = std::collections::BTreeSet::new();
        for e in std::fs::read_dir(&root).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "toml") {
                let s = crate::load(&p, &[]).unwrap();
                assert!(!s.sweep_columns().is_empty(), "{}", s.kind());
                assert_eq!(s.sweep_columns(), sweep_columns(s.kind()));
                shipped.insert(s.kind());
            }
        }
        for k in KIND_NAMES {
            assert!(shipped.contains(k), "no shipped scenario of kind {k}");
        }
        assert!(sweep_columns("wormhole").is_empty());
        assert_eq!(
            kind_list(),
            r#"one of "stretching", "dpd-fluid", "poiseuille-tube", "couette", "capillary" or "shear""#
        );
    }
}
