//! The scenario-file sections every cell-in-flow kind shares: `[cell]` ([`CellSection`]), the
//! shared keys of `[model]` (declared once by [`model_section!`]) and their validation, and
//! what they resolve to (membrane parameters, the thermal choice, membrane sub-steps).

use crate::context::RunError;
use crate::file::ScenarioError;
use crate::units::{self, ThermalChoice};
use hemodpd_membrane::coupling::MembraneReflection;
use hemodpd_membrane::params::ModelParams;
use hemodpd_membrane::viscosity::MembraneViscosity;
use hemodpd_membrane::ReferenceState;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

// serde defaults of the shared keys (paths named by `model_section!`, hence `pub(crate)`)
pub(crate) fn d_one() -> f64 {
    1.0
}
fn d_temp() -> f64 {
    300.0
}
fn d_vertices() -> i64 {
    500
}
fn d_max_extension() -> f64 {
    hemodpd_membrane::params::fine::LMAX_OVER_L0
}

/// The allowed Lmax/L0 (`cell.max_extension_ratio`, `membrane.max_extension_ratio`): links that
/// can stretch to at least 1.5 L0 (the stretched cell's links reach ≈ 1.4 L0 at 200 pN), up to
/// twice the paper's 3.17.
pub(crate) const MAX_EXTENSION_RANGE: (f64, f64) = (1.5, 6.5);
pub(crate) const MAX_EXTENSION_ALLOWED: &str =
    "1.5–6.5: Lmax/L0 of the WLC links (the paper's 3.17; x0 = 1/ratio; smaller stiffens the membrane at large strain)";

fn d_ka() -> f64 {
    hemodpd_membrane::forces::DEFAULT_K_AREA_N_PER_M
}
fn d_kv() -> f64 {
    hemodpd_membrane::forces::DEFAULT_K_VOLUME_N_PER_M2
}
pub(crate) fn d_thermal() -> ThermalSetting {
    ThermalSetting::Word("auto".into())
}
pub(crate) fn d_mach() -> f64 {
    units::MACH_LIMIT
}
pub(crate) fn d_fluid() -> String {
    "capillary".into()
}
pub(crate) fn d_reynolds() -> f64 {
    units::REYNOLDS_WARN
}
pub(crate) fn d_check() -> u64 {
    500
}
pub(crate) fn d_range() -> f64 {
    0.3
}
pub(crate) fn d_substeps() -> SubstepSetting {
    SubstepSetting::Word("auto".into())
}

/// `[cell]`: the membrane (parameters from N by the paper's Eqs. 8, 9, 12).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CellSection {
    /// Vertices N ≥ 100 (default 500).
    #[serde(default = "d_vertices")]
    pub vertices: i64,
    /// Temperature, K (default 300, the paper's).
    #[serde(default = "d_temp")]
    pub temperature_k: f64,
    /// A named membrane parameter set (`"paper"`, `"calibrated"`, `"calibrated-x0"`;
    /// crate::parameter_sets) whose values fill `reference`, `persistence_scale`,
    /// `max_extension_ratio` and the membrane viscosity where the file gives none. Absent: the keys' own defaults, the paper's set.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parameters: Option<String>,
    /// "stress-free" (default: the resting cell), "uniform" (the paper's single L0), or
    /// `{ spheroid = { reduced_volume = v } }` (the oblate spheroid of the cell's area and
    /// reduced volume v, 0.65–1).
    #[serde(default)]
    pub reference: ReferenceState,
    /// Multiplies the Eq. 12 persistence length (default 1).
    #[serde(default = "d_one")]
    pub persistence_scale: f64,
    /// Lmax/L0, the WLC links' maximum extension over their rest length (default 3.17, the
    /// paper's; x0 = 1/ratio); μ0 and K follow (Eqs. 10, 11) at the same persistence length.
    #[serde(default = "d_max_extension")]
    pub max_extension_ratio: f64,
    /// k_a, N/m (default 2e-3).
    #[serde(default = "d_ka")]
    pub area_constraint_n_per_m: f64,
    /// k_v, N/m² (default 1e3).
    #[serde(default = "d_kv")]
    pub volume_constraint_n_per_m2: f64,
    /// A mesh in µm instead of the generated one (its vertex count must equal `vertices`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh_file: Option<PathBuf>,
    /// 2D membrane viscosity η_m, Pa·s·m = N·s/m (default 0: off, the paper's model;
    /// physiological ≈ 5e-7–1e-6). Fedosov's link friction with γ_C = γ_T/3 (docs/model.md).
    #[serde(default)]
    pub membrane_viscosity_pa_s_m: f64,
    /// How η_m becomes link friction: "fedosov" (default: γ_C = γ_T/3) or "central" (γ_T = 0,
    /// γ_C = 4η_m/√3: resists only the links' stretching, not rigid rotation or bending).
    #[serde(default)]
    pub membrane_viscosity_form: ViscosityForm,
}

impl CellSection {
    /// The `--explain-units` lines on the membrane's free parameters: the named set, if any, and
    /// the values in effect.
    pub(crate) fn explain_parameters(&self) -> String {
        let set = match self.parameters.as_deref().and_then(crate::parameter_sets::find) {
            Some(p) => format!("set {:?}: {}", p.name, p.origin),
            None => "no named set (cell.parameters): each key's default, the paper's set".into(),
        };
        let reference = match self.reference {
            ReferenceState::Spheroid { reduced_volume } => {
                format!("the oblate spheroid of reduced volume {reduced_volume}")
            }
            ReferenceState::StressFree => "the resting biconcave cell".into(),
            ReferenceState::Uniform => "uniform (the paper's one L0)".into(),
        };
        format!(
            "Membrane parameters: {set}\n    stress-free on {reference}, persistence length × {}, Lmax/L0 = {}, η_m = {:.4e} N·s/m ({} form)\n",
            self.persistence_scale,
            self.max_extension_ratio,
            self.membrane_viscosity_pa_s_m,
            match self.membrane_viscosity_form {
                ViscosityForm::Central => "central",
                ViscosityForm::Fedosov => "fedosov",
            }
        )
    }

    /// Checks `cell.mesh_file`, if one is given (relative to `base`): it exists, reads, and has
    /// `cell.vertices` vertices.
    pub(crate) fn check_mesh_file(&self, file: &str, base: &std::path::Path) -> Result<(), crate::file::ScenarioError> {
        match &self.mesh_file {
            Some(m) => crate::kind::check_mesh_file(file, "cell.mesh_file", base, m, self.vertices),
            None => Ok(()),
        }
    }
}

/// How the membrane viscosity η_m is split into link friction (docs/model.md §7b).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ViscosityForm {
    /// Fedosov et al. 2010: γ_C = γ_T/3 (the relative velocity's whole vector is damped).
    #[default]
    Fedosov,
    /// γ_T = 0, γ_C = 4η_m/√3 (Mirheo's form: only the component along the link is damped).
    Central,
}

/// `model.thermal_factor`: "auto", "exact" or a number f ≥ 1.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(untagged)]
pub enum ThermalSetting {
    Factor(f64),
    Word(String),
}

impl std::fmt::Display for ThermalSetting {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ThermalSetting::Factor(x) => write!(f, "{x}"),
            ThermalSetting::Word(w) => write!(f, "{w:?}"),
        }
    }
}

/// `model.membrane_substeps`: an integer k (1–1000; 1: no sub-stepping) or "auto", the default
/// (the smallest k with (γ_T + γ_C)(Δt/k)/μ ≤ 1 when there is a membrane viscosity, so that it
/// acts at ≥ 93 % of its value; else 1).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(untagged)]
pub enum SubstepSetting {
    Count(i64),
    Word(String),
}

impl std::fmt::Display for SubstepSetting {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SubstepSetting::Count(k) => write!(f, "{k}"),
            SubstepSetting::Word(w) => write!(f, "{w:?}"),
        }
    }
}

/// The `[model]` keys every cell-in-flow kind shares, as read from its section
/// ([`model_section!`] declares the section and this view of it).
#[derive(Clone, Copy, Debug)]
pub struct ModelKeys<'a> {
    /// µm per rc.
    pub length_um_per_rc: f64,
    pub thermal_factor: &'a ThermalSetting,
    /// Mach bound of "auto" (and of the fluid chooser).
    pub max_mach: f64,
    /// The fluid: a name of [`units::FluidModel::table`] or "auto".
    pub fluid: &'a str,
    /// Reynolds bound of the fluid chooser.
    pub max_reynolds: f64,
    /// Model time step (None: the fluid's).
    pub timestep: Option<f64>,
    /// Steps between inside/outside checks of the fluid (0: never).
    pub crossing_check_every_steps: u64,
    /// Range of the membrane–wall repulsion, rc.
    pub wall_repulsion_range_rc: f64,
    pub membrane_reflection: MembraneReflection,
    pub membrane_substeps: &'a SubstepSetting,
    pub membrane_substep_forces: hemodpd_membrane::coupling::SubstepForces,
}

/// Declares a kind's `[model]` section: the keys every cell-in-flow kind shares, in the file's
/// order, with the kind's own keys (given as struct fields) after `wall_repulsion_range_rc`.
/// One derived struct a kind, so that an unknown key is refused by serde with the kind's own
/// list of keys, and the section is written back in the same order (serde's `flatten` can do
/// neither). Also declares `shared()`, the [`ModelKeys`] view of the section.
macro_rules! model_section {
    ($(#[$meta:meta])* $name:ident { $($(#[$fmeta:meta])* pub $field:ident: $ty:ty,)* }) => {
        $(#[$meta])*
        #[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
        #[serde(deny_unknown_fields)]
        pub struct $name {
            /// µm per rc (default 1).
            #[serde(default = "crate::cell::section::d_one")]
            pub length_um_per_rc: f64,
            /// "auto" (default: the smallest thermal factor f ≥ 1 that keeps the Mach number of
            /// the kind's characteristic velocity ≤ `max_mach`: the fastest stage's mean velocity
            /// in a capillary, γ̇ D0/2 in shear), "exact" (f = 1) or a number f ≥ 1.
            #[serde(default = "crate::cell::section::d_thermal")]
            pub thermal_factor: $crate::cell::ThermalSetting,
            /// Mach bound for "auto" (default 0.25, the largest allowed); with `fluid = "auto"`
            /// also the bound every candidate fluid must meet.
            #[serde(default = "crate::cell::section::d_mach")]
            pub max_mach: f64,
            /// The DPD fluid: "capillary" (default: n = 3, a = 25, γ = 120, s = 1/4), "dense"
            /// (n = 10, a = 100, γ = 41, s = 1/8), "viscous" (the dense fluid with γ = 410, for
            /// shear at Fischer's rates) or "auto": the fluid of the table that meets
            /// `thermal_factor`, `max_mach` and `max_reynolds` at the least cost (docs/units.md,
            /// "Choosing the fluid").
            #[serde(default = "crate::cell::section::d_fluid")]
            pub fluid: String,
            /// Reynolds bound of `fluid = "auto"` (default 1; at most 5).
            #[serde(default = "crate::cell::section::d_reynolds")]
            pub max_reynolds: f64,
            /// Model time step (default: the capillary fluid's, 0.0025).
            #[serde(default, skip_serializing_if = "Option::is_none")]
            pub timestep: Option<f64>,
            /// Steps between inside/outside checks of the fluid (default 500; 0: never).
            #[serde(default = "crate::cell::section::d_check")]
            pub crossing_check_every_steps: u64,
            /// Range of the membrane–wall repulsion, rc (default 0.3; with walls only).
            #[serde(default = "crate::cell::section::d_range")]
            pub wall_repulsion_range_rc: f64,
            $($(#[$fmeta])* pub $field: $ty,)*
            /// How fluid leaves the membrane after crossing a triangle: "maxwell" (default:
            /// diffuse, at the fluid's temperature) or "bounce-back" (v → 2u_w − v; unstable when
            /// thermal creases trap particles, docs/capillary.md).
            #[serde(default)]
            pub membrane_reflection: hemodpd_membrane::coupling::MembraneReflection,
            /// Membrane sub-steps k per fluid step: an integer 1–1000 (default 1: none, the
            /// membrane integrated with the fluid) or "auto": the smallest k with
            /// (γ_T + γ_C)(Δt/k)/μ ≤ 1 when `cell.membrane_viscosity_pa_s_m` > 0 (μ the reduced
            /// mass of a link, half a vertex mass), else 1. One Shardlow sweep per Δt caps the
            /// link friction near 2μ/Δt, 25 × below a physiological η_m at the default Δt; "auto"
            /// (50 there) lifts the cap (docs/model.md §7b).
            #[serde(default = "crate::cell::section::d_substeps")]
            pub membrane_substeps: $crate::cell::SubstepSetting,
            /// With k > 1 sub-steps: "inner" (default: r-RESPA, the membrane's elastic forces in
            /// each inner step, k evaluations per fluid step) or "outer" (the elastic forces
            /// once per fluid step with the fluid's; only the drift and the viscosity sweep are
            /// sub-stepped: the same friction, ≈ k × fewer force evaluations; docs/model.md §7b).
            #[serde(default)]
            pub membrane_substep_forces: hemodpd_membrane::coupling::SubstepForces,
        }

        impl $name {
            /// The keys every cell-in-flow kind shares.
            pub fn shared(&self) -> $crate::cell::ModelKeys<'_> {
                $crate::cell::ModelKeys {
                    length_um_per_rc: self.length_um_per_rc,
                    thermal_factor: &self.thermal_factor,
                    max_mach: self.max_mach,
                    fluid: &self.fluid,
                    max_reynolds: self.max_reynolds,
                    timestep: self.timestep,
                    crossing_check_every_steps: self.crossing_check_every_steps,
                    wall_repulsion_range_rc: self.wall_repulsion_range_rc,
                    membrane_reflection: self.membrane_reflection,
                    membrane_substeps: &self.membrane_substeps,
                    membrane_substep_forces: self.membrane_substep_forces,
                }
            }
        }
    };
}
pub(crate) use model_section;

/// The membrane parameters of level N of a `[cell]` section.
pub(crate) fn cell_params(cell: &CellSection) -> Result<ModelParams, RunError> {
    Ok(
        ModelParams::with_persistence_scale(cell.vertices as usize, cell.temperature_k, cell.persistence_scale)?
            .with_max_extension(cell.max_extension_ratio)?,
    )
}

/// The [`ThermalChoice`] of a `model.thermal_factor` setting.
pub(crate) fn thermal_choice(setting: &ThermalSetting, max_mach: f64) -> ThermalChoice {
    match setting {
        ThermalSetting::Factor(f) => ThermalChoice::Factor(*f),
        ThermalSetting::Word(w) => match w.trim() {
            "auto" => ThermalChoice::Auto { max_mach },
            "exact" => ThermalChoice::Exact,
            s => ThermalChoice::Factor(s.parse().unwrap_or(f64::NAN)),
        },
    }
}

/// Validates a `[cell]` section.
pub(crate) fn validate_cell(cell: &CellSection, file: &str) -> Result<(), ScenarioError> {
    let c = crate::file::Check { file };
    let fail = |key: &str, value: String, allowed: &str| c.fail(key, value, allowed);
    let range = |key: &str, v: f64, lo: f64, hi: f64, allowed: &str| c.range(key, v, lo, hi, allowed);
    if cell.vertices < 100 || cell.vertices > 50_000 {
        return Err(fail(
            "cell.vertices",
            cell.vertices.to_string(),
            "100–50000 (the coarse-grained model needs N ≥ 100)",
        ));
    }
    range("cell.temperature_k", cell.temperature_k, 250.0, 350.0, "250–350 K")?;
    range(
        "cell.persistence_scale",
        cell.persistence_scale,
        0.1,
        10.0,
        "a factor between 0.1 and 10 multiplying the Eq. 12 persistence length",
    )?;
    range(
        "cell.max_extension_ratio",
        cell.max_extension_ratio,
        MAX_EXTENSION_RANGE.0,
        MAX_EXTENSION_RANGE.1,
        MAX_EXTENSION_ALLOWED,
    )?;
    validate_reference(&cell.reference, "cell.reference", &c)?;
    range(
        "cell.membrane_viscosity_pa_s_m",
        cell.membrane_viscosity_pa_s_m,
        0.0,
        f64::MAX,
        "≥ 0 and finite, Pa·s·m = N·s/m (0: off; physiological ≈ 5e-7–1e-6)",
    )?;
    range(
        "cell.area_constraint_n_per_m",
        cell.area_constraint_n_per_m,
        0.0,
        1.0,
        "0–1 N/m",
    )?;
    range(
        "cell.volume_constraint_n_per_m2",
        cell.volume_constraint_n_per_m2,
        0.0,
        1e6,
        "0–1e6 N/m²",
    )
}

/// Lowest reduced volume of a spheroidal reference: the resting cell's is 0.644, and a
/// reference less spherical than the cell it rests as is not one the peer studies consider.
pub const MIN_REFERENCE_REDUCED_VOLUME: f64 = 0.65;

/// Checks the reduced volume of a spheroidal `reference` (under `key`, e.g. `cell.reference`).
pub(crate) fn validate_reference(
    reference: &ReferenceState,
    key: &str,
    c: &crate::file::Check,
) -> Result<(), ScenarioError> {
    if let ReferenceState::Spheroid { reduced_volume } = reference {
        c.range(
            &format!("{key}.spheroid.reduced_volume"),
            *reduced_volume,
            MIN_REFERENCE_REDUCED_VOLUME,
            1.0,
            "a reduced volume from 0.65 to 1 (a sphere); the resting cell's is 0.644, the peer studies' stress-free spheroids 0.93–0.97",
        )?;
    }
    Ok(())
}

/// Validates the shared `[model]` keys, in the order the kinds have always checked them:
/// `length_um_per_rc`, `thermal_factor` and `max_mach`, `timestep` (`timestep_allowed`: the
/// kind's wording of its bounds, 1e-4–0.004), `membrane_substeps`, `wall_repulsion_range_rc`.
pub(crate) fn validate_model(m: ModelKeys, timestep_allowed: &str, file: &str) -> Result<(), ScenarioError> {
    let c = crate::file::Check { file };
    let range = |key: &str, v: f64, lo: f64, hi: f64, allowed: &str| c.range(key, v, lo, hi, allowed);
    range(
        "model.length_um_per_rc",
        m.length_um_per_rc,
        0.25,
        2.0,
        "0.25–2 µm per rc",
    )?;
    validate_thermal(m.thermal_factor, m.max_mach, file)?;
    validate_fluid(m.fluid, m.max_reynolds, file)?;
    if let Some(dt) = m.timestep {
        range("model.timestep", dt, 1e-4, 0.004, timestep_allowed)?;
    }
    validate_substeps(m.membrane_substeps, file)?;
    range(
        "model.wall_repulsion_range_rc",
        m.wall_repulsion_range_rc,
        0.05,
        1.0,
        "0.05–1 rc",
    )
}

/// Validates `model.thermal_factor` and `model.max_mach`.
pub(crate) fn validate_thermal(setting: &ThermalSetting, max_mach: f64, file: &str) -> Result<(), ScenarioError> {
    let thermal_ok = match setting {
        ThermalSetting::Factor(f) => f.is_finite() && *f >= 1.0,
        ThermalSetting::Word(w) => matches!(w.trim(), "auto" | "exact"),
    };
    if !thermal_ok {
        return Err(ScenarioError::Value {
            file: file.into(),
            key: "model.thermal_factor".into(),
            value: setting.to_string(),
            allowed: "\"auto\", \"exact\" or a number ≥ 1".into(),
        });
    }
    if !(max_mach.is_finite() && (1e-3..=units::MACH_LIMIT).contains(&max_mach)) {
        return Err(ScenarioError::Value {
            file: file.into(),
            key: "model.max_mach".into(),
            value: format!("{max_mach}"),
            allowed: "(0, 0.25]".into(),
        });
    }
    Ok(())
}

/// Validates `model.fluid` (a name of the table or "auto") and `model.max_reynolds`.
pub(crate) fn validate_fluid(fluid: &str, max_reynolds: f64, file: &str) -> Result<(), ScenarioError> {
    if fluid != "auto" && units::FluidModel::by_name(fluid).is_none() {
        return Err(ScenarioError::Value {
            file: file.into(),
            key: "model.fluid".into(),
            value: format!("{fluid:?}"),
            allowed: format!(
                "\"auto\" or a fluid of the table: {}",
                units::FluidModel::names()
                    .iter()
                    .map(|n| format!("{n:?}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        });
    }
    if !(max_reynolds.is_finite() && max_reynolds > 0.0 && max_reynolds <= units::REYNOLDS_LIMIT) {
        return Err(ScenarioError::Value {
            file: file.into(),
            key: "model.max_reynolds".into(),
            value: format!("{max_reynolds}"),
            allowed: format!("(0, {}]", units::REYNOLDS_LIMIT),
        });
    }
    Ok(())
}

/// The fluid and the unit mapping of a cell-in-flow run ([`units::choose_fluid`] with the
/// shared `[model]` keys); errors read "unit mapping: …" with the key.
pub(crate) fn cell_mapping(sys: &units::PhysicalSystem, m: ModelKeys) -> Result<units::FluidDecision, RunError> {
    let choice = match m.fluid {
        "auto" => units::FluidChoice::Auto,
        name => units::FluidChoice::Named(name.to_string()),
    };
    units::choose_fluid(
        sys,
        crate::units::um_to_m(m.length_um_per_rc),
        thermal_choice(m.thermal_factor, m.max_mach),
        &choice,
        m.max_mach,
        m.max_reynolds,
    )
    .map_err(|e| RunError::Output(format!("unit mapping: {e}")))
}

/// Largest `model.membrane_substeps`.
pub(crate) const MAX_SUBSTEPS: i64 = 1000;

/// Checks `model.membrane_substeps`.
pub(crate) fn validate_substeps(k: &SubstepSetting, file: &str) -> Result<(), ScenarioError> {
    let ok = match k {
        SubstepSetting::Count(k) => (1..=MAX_SUBSTEPS).contains(k),
        SubstepSetting::Word(w) => w == "auto",
    };
    if ok {
        Ok(())
    } else {
        Err(ScenarioError::Value {
            file: file.into(),
            key: "model.membrane_substeps".into(),
            value: k.to_string(),
            allowed: format!(
                "an integer 1–{MAX_SUBSTEPS} (1: no sub-stepping) or \"auto\" (the default: from the membrane viscosity)"
            ),
        })
    }
}

/// The membrane sub-steps k of a run: the count when given, else ("auto") the smallest k with
/// (γ_T + γ_C)(Δt/k)/μ ≤ 1 for a link of two vertices of mass `vertex_mass` (μ = m/2; at most
/// [`MAX_SUBSTEPS`]), or 1 without a membrane viscosity. The setting is validated first.
pub(crate) fn resolve_substeps(
    setting: &SubstepSetting,
    visc: Option<&MembraneViscosity>,
    dt: f64,
    vertex_mass: f64,
) -> u32 {
    match (setting, visc) {
        (SubstepSetting::Count(k), _) => (*k).clamp(1, MAX_SUBSTEPS) as u32,
        (SubstepSetting::Word(_), Some(v)) => {
            let mu = 0.5 * vertex_mass;
            let k = ((v.gamma_t + v.gamma_c) * dt / mu).ceil();
            k.clamp(1.0, MAX_SUBSTEPS as f64) as u32
        }
        (SubstepSetting::Word(_), None) => 1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// "auto" membrane sub-steps (the default): the smallest k with (γ_T + γ_C)(Δt/k)/μ ≤ 1
    /// (μ = ½ for unit vertex masses), 1 without a viscosity; a count is taken as it is. The physiological
    /// 6.3e-7 N·s/m of the default capillary mapping (γ_T + γ_C ≈ 9923 at Δt = 0.0025) gives 50.
    #[test]
    fn automatic_membrane_substeps() {
        let v = MembraneViscosity {
            gamma_t: 7442.5,
            gamma_c: 7442.5 / 3.0,
        };
        let auto = SubstepSetting::Word("auto".into());
        assert_eq!(resolve_substeps(&auto, Some(&v), 0.0025, 1.0), 50);
        assert_eq!(resolve_substeps(&auto, None, 0.0025, 1.0), 1);
        assert_eq!(resolve_substeps(&SubstepSetting::Count(7), Some(&v), 0.0025, 1.0), 7);
        assert_eq!(resolve_substeps(&d_substeps(), Some(&v), 0.0025, 1.0), 50);
        assert_eq!(resolve_substeps(&d_substeps(), None, 0.0025, 1.0), 1);
        let weak = MembraneViscosity {
            gamma_t: 10.0,
            gamma_c: 10.0 / 3.0,
        };
        assert_eq!(resolve_substeps(&auto, Some(&weak), 0.0025, 1.0), 1);
        let k = resolve_substeps(&auto, Some(&v), 0.0025, 1.0) as f64;
        assert!((v.gamma_t + v.gamma_c) * 0.0025 / k / 0.5 <= 1.0);
        assert!((v.gamma_t + v.gamma_c) * 0.0025 / (k - 1.0) / 0.5 > 1.0);
    }
}
