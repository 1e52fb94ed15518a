//! The capillary scenario's file: its sections (`[tube]`, `[plasma]`, `[[stage]]`, `[output]`,
//! the capillary keys of `[model]`), their defaults, the stage's drive, the mapping the file asks
//! for, and the checks that name a bad key, its value and what is allowed.

use super::*;

fn d_ten() -> f64 {
    10.0
}
fn d_len() -> f64 {
    45.0
}
fn d_eta() -> f64 {
    1.2e-3
}
fn d_one() -> f64 {
    1.0
}
fn d_sample() -> u64 {
    20
}
fn d_control() -> u64 {
    50
}
fn d_tol() -> f64 {
    0.02
}
fn d_frame() -> f64 {
    1e-3
}

/// `[tube]`: the capillary.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CapillaryTube {
    /// Inner diameter, µm (default 10).
    #[serde(default = "d_ten")]
    pub diameter_um: f64,
    /// Length along the periodic axis, µm (default 45).
    #[serde(default = "d_len")]
    pub length_um: f64,
    /// How the resting cell faces the axis as it enters: "face-on" (default, the paper's),
    /// "edge-on" or "random" (a rotation drawn from the seed).
    #[serde(default, skip_serializing_if = "CellOrientation::is_face_on")]
    pub cell_orientation: CellOrientation,
}

impl CapillaryTube {
    /// Inner diameter, m.
    pub fn diameter_m(&self) -> f64 {
        um_to_m(self.diameter_um)
    }

    /// Length along the periodic axis, m.
    pub fn length_m(&self) -> f64 {
        um_to_m(self.length_um)
    }
}

/// `[plasma]`: the fluids.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PlasmaSection {
    /// Plasma viscosity, Pa·s (default 1.2e-3).
    #[serde(default = "d_eta")]
    pub viscosity_pa_s: f64,
    /// Inner (cytosol) over plasma viscosity (default 1, the paper; ≈ 5 is physiological).
    #[serde(default = "d_one")]
    pub viscosity_ratio: f64,
}

crate::cell::section::model_section! {
    /// `[model]`: how SI maps onto the DPD model (docs/units.md): the keys of every cell-in-flow
    /// kind, and the flow controller's.
    ModelSection {
        /// Steps between updates of the mean-velocity controller (default 50).
        #[serde(default = "d_control")]
        pub flow_control_every_steps: u64,
    }
}

/// One `[[stage]]` of the protocol. A stage drives the flow with at most one of the three
/// drive keys (none: drive off) and ends after `duration_s`, or earlier when `until_steady`
/// and the flow and the cell are steady (docs/capillary.md).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct StageSection {
    pub name: String,
    /// Longest duration, s.
    pub duration_s: f64,
    /// Mean fluid velocity held by a controller, m/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean_velocity_m_per_s: Option<f64>,
    /// Pressure gradient, Pa/m (a body force on the fluid).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pressure_gradient_pa_per_m: Option<f64>,
    /// Pressure gradient, mmHg/mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pressure_gradient_mmhg_per_mm: Option<f64>,
    /// Optical-tweezers stretch during the stage, N: this force pulls the 5 % of the vertices
    /// with the largest x (at rest) towards +x and the 5 % with the smallest x towards −x
    /// (across the tube, in the plane of the disc), shared equally; none when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stretch_force_n: Option<f64>,
    /// End as soon as steady (default false).
    #[serde(default)]
    pub until_steady: bool,
    /// Window over which steadiness is judged, s (default: a tenth of the duration).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steady_window_s: Option<f64>,
    /// Steady when consecutive window means change by less than this fraction of their scale
    /// (default 0.02).
    #[serde(default = "d_tol")]
    pub steady_tolerance: f64,
}

/// `[output]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CapillaryOutput {
    /// Steps between samples of the measures (default 20).
    #[serde(default = "d_sample")]
    pub sample_every_steps: u64,
    /// Seconds between trajectory frames (membrane + binned fluid); 0: none (default 1 ms).
    #[serde(default = "d_frame")]
    pub frame_every_s: f64,
    /// Steps between checkpoints; 0 (default): only at the end and on Ctrl-C.
    #[serde(default)]
    pub checkpoint_every_steps: u64,
}

impl Default for CapillaryOutput {
    fn default() -> Self {
        Self {
            sample_every_steps: d_sample(),
            frame_every_s: d_frame(),
            checkpoint_every_steps: 0,
        }
    }
}

/// `kind = "capillary"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CapillaryScenario {
    pub format_version: u32,
    pub kind: String,
    pub seed: u64,
    pub tube: CapillaryTube,
    #[serde(default = "default_plasma")]
    pub plasma: PlasmaSection,
    pub cell: CellSection,
    #[serde(default = "default_model")]
    pub model: ModelSection,
    pub stage: Vec<StageSection>,
    #[serde(default)]
    pub output: CapillaryOutput,
    /// Directory of the scenario file; not part of the file.
    #[serde(skip)]
    pub base_dir: PathBuf,
}

fn default_plasma() -> PlasmaSection {
    toml::from_str("").expect("defaults")
}
fn default_model() -> ModelSection {
    toml::from_str("").expect("defaults")
}

/// What drives a stage, in SI.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Drive {
    Off,
    MeanVelocity(f64),
    PressureGradient(f64),
}

impl StageSection {
    /// The drive (validated: at most one key).
    pub fn drive(&self) -> Drive {
        if let Some(u) = self.mean_velocity_m_per_s {
            Drive::MeanVelocity(u)
        } else if let Some(g) = self.pressure_gradient_pa_per_m {
            Drive::PressureGradient(g)
        } else if let Some(g) = self.pressure_gradient_mmhg_per_mm {
            Drive::PressureGradient(g * MMHG_PER_MM_IN_PA_PER_M)
        } else {
            Drive::Off
        }
    }
}

impl CapillaryScenario {
    /// The membrane parameters of level N.
    pub fn params(&self) -> Result<ModelParams, RunError> {
        cell_params(&self.cell)
    }

    /// The fastest stage's mean velocity (a target, or the Poiseuille estimate of a pressure
    /// gradient), m/s; the unit mapping is chosen for it.
    pub fn characteristic_velocity(&self) -> f64 {
        let d = self.tube.diameter_m();
        self.stage
            .iter()
            .map(|s| match s.drive() {
                Drive::Off => 0.0,
                Drive::MeanVelocity(u) => u.abs(),
                Drive::PressureGradient(g) => units::poiseuille_mean_velocity(g.abs(), d, self.plasma.viscosity_pa_s),
            })
            .fold(0.0, f64::max)
    }

    /// The physical system.
    pub fn physical(&self) -> Result<PhysicalSystem, RunError> {
        let p = self.params()?;
        let mut sys = PhysicalSystem::new(
            &p,
            self.tube.diameter_m(),
            self.tube.length_m(),
            self.plasma.viscosity_pa_s,
            self.characteristic_velocity().max(1e-9),
        );
        sys.viscosity_ratio = self.plasma.viscosity_ratio;
        sys.membrane_viscosity_n_s_per_m = self.cell.membrane_viscosity_pa_s_m;
        Ok(sys)
    }

    /// The fluid and the unit mapping (errors name the scenario key).
    pub fn mapping(&self) -> Result<(PhysicalSystem, FluidDecision), RunError> {
        let sys = self.physical()?;
        let d = cell_mapping(&sys, self.model.shared())?;
        Ok((sys, d))
    }

    /// The `--explain-units` text.
    pub fn explain_units(&self) -> Result<String, RunError> {
        let (sys, d) = self.mapping()?;
        Ok(format!(
            "{}{}{}",
            units::explain(&sys, &d.map, &d.fluid),
            units::explain_fluid(&d),
            self.cell.explain_parameters()
        ))
    }
}

/// Validates the capillary section of a file: every value, the cell fitting the tube, the
/// stages, and the unit mapping (Mach and Reynolds bounds, by building the [`Plan`]), before any work.
pub fn validate(s: &CapillaryScenario, file: &str) -> Result<(), ScenarioError> {
    let c = crate::file::Check { file };
    let fail = |key: &str, value: String, allowed: &str| c.fail(key, value, allowed);
    let range = |key: &str, v: f64, lo: f64, hi: f64, allowed: &str| c.range(key, v, lo, hi, allowed);
    range("tube.diameter_um", s.tube.diameter_um, 3.0, 100.0, "3–100 µm")?;
    range("tube.length_um", s.tube.length_um, 10.0, 1000.0, "10–1000 µm")?;
    range(
        "plasma.viscosity_pa_s",
        s.plasma.viscosity_pa_s,
        1e-4,
        1.0,
        "1e-4–1 Pa·s",
    )?;
    range("plasma.viscosity_ratio", s.plasma.viscosity_ratio, 0.1, 20.0, "0.1–20")?;
    validate_cell(&s.cell, file)?;
    validate_model(
        s.model.shared(),
        "1e-4–0.004 model units (default: the fluid's, 0.0025 for \"capillary\", 0.003 for \"dense\", divided by a viscosity ratio above 1; docs/units.md)",
        file,
    )?;
    if s.model.flow_control_every_steps == 0 {
        return Err(fail("model.flow_control_every_steps", "0".into(), "≥ 1"));
    }
    if s.output.sample_every_steps == 0 {
        return Err(fail("output.sample_every_steps", "0".into(), "≥ 1"));
    }
    range(
        "output.frame_every_s",
        s.output.frame_every_s,
        0.0,
        10.0,
        "0 (none) to 10 s",
    )?;
    if s.stage.is_empty() {
        return Err(ScenarioError::Missing {
            file: file.into(),
            key: "stage".into(),
            what: "at least one [[stage]] (name, duration_s, and a drive or none)".into(),
        });
    }
    for (k, st) in s.stage.iter().enumerate() {
        let key = |f: &str| format!("stage[{k}].{f}");
        range(&key("duration_s"), st.duration_s, 1e-6, 100.0, "1e-6–100 s")?;
        let drives = [
            st.mean_velocity_m_per_s.is_some(),
            st.pressure_gradient_pa_per_m.is_some(),
            st.pressure_gradient_mmhg_per_mm.is_some(),
        ];
        if drives.iter().filter(|&&b| b).count() > 1 {
            return Err(fail(
                &key("mean_velocity_m_per_s"),
                "several drives".into(),
                "at most one of mean_velocity_m_per_s, pressure_gradient_pa_per_m, pressure_gradient_mmhg_per_mm",
            ));
        }
        if let Some(u) = st.mean_velocity_m_per_s {
            range(&key("mean_velocity_m_per_s"), u, -0.1, 0.1, "−0.1–0.1 m/s")?;
        }
        if let Some(g) = st.pressure_gradient_pa_per_m {
            range(&key("pressure_gradient_pa_per_m"), g, -1e8, 1e8, "|g| ≤ 1e8 Pa/m")?;
        }
        if let Some(g) = st.pressure_gradient_mmhg_per_mm {
            range(
                &key("pressure_gradient_mmhg_per_mm"),
                g,
                -750.0,
                750.0,
                "|g| ≤ 750 mmHg/mm",
            )?;
        }
        if let Some(w) = st.steady_window_s {
            range(
                &key("steady_window_s"),
                w,
                1e-7,
                st.duration_s / 2.0,
                "positive, at most half the duration",
            )?;
        }
        range(&key("steady_tolerance"), st.steady_tolerance, 1e-4, 0.5, "1e-4–0.5")?;
        if let Some(f) = st.stretch_force_n {
            range(&key("stretch_force_n"), f, 0.0, 1e-9, "0–1e-9 N (0–1000 pN)")?;
        }
    }
    // the cell must fit: at rest, or pressed into the tube (narrower than the cell) with room
    // for the wall's slip, its repulsion range and a clearance; no closed surface of the cell's
    // area and volume is narrower than its capsule
    let d0 = 2.0 * EvansFung::healthy_um().r;
    let slip = FluidModel::by_name(&s.model.fluid).map_or_else(
        || FluidModel::table().iter().map(|f| f.wall_slip).fold(0.0, f64::max),
        |f| f.wall_slip,
    );
    let gap_um = (slip + s.model.wall_repulsion_range_rc + CLEARANCE_RC) * s.model.length_um_per_rc;
    let (area, volume) = EvansFung::healthy_um().area_and_volume();
    let narrowest = CAPSULE_MARGIN * capsule_radius(area, volume);
    if 0.5 * s.tube.diameter_um - gap_um < narrowest {
        return Err(fail(
            "tube.diameter_um",
            format!("{}", s.tube.diameter_um),
            &format!(
                "at least {:.2} µm at model.length_um_per_rc = {}: the cell ({area:.0} µm², {volume:.0} µm³) is pressed into a tube narrower than it is, but not below {narrowest:.2} µm of radius ({CAPSULE_MARGIN} × the {:.2} µm capsule of its area and volume), and the wall's slip, repulsion range and a clearance of {CLEARANCE_RC} rc take {gap_um:.2} µm more; a finer resolution (smaller model.length_um_per_rc) narrows that gap",
                2.0 * (narrowest + gap_um),
                s.model.length_um_per_rc,
                capsule_radius(area, volume)
            ),
        ));
    }
    if s.tube.length_um < 2.0 * d0 {
        return Err(fail(
            "tube.length_um",
            format!("{}", s.tube.length_um),
            &format!(
                "at least twice the cell's diameter ({:.1} µm) so that the cell does not meet its own periodic image",
                2.0 * d0
            ),
        ));
    }
    // the unit mapping's own bounds (Mach, Reynolds), with the key of the scenario
    if let Err(e) = Plan::new(s) {
        let (key, value) = if s.characteristic_velocity() > 0.0 {
            (
                "stage.mean_velocity_m_per_s",
                format!("{} m/s (fastest stage)", s.characteristic_velocity()),
            )
        } else {
            ("model", String::new())
        };
        return Err(fail(key, value, &e.to_string()));
    }
    Ok(())
}
