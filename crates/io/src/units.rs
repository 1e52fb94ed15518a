//! Unit system of a run: how model units map to SI. Files store SI values; the writer converts.

use serde::{Deserialize, Serialize};

/// Model units of a run, each given in SI. The DPD model picks a length scale `r`, an energy scale
/// `E` and a time scale `τ` (SPEC §5); mass, force and velocity units follow from them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct UnitSystem {
    /// One model length unit, in metres.
    pub length_m: f64,
    /// One model time unit, in seconds.
    pub time_s: f64,
    /// One model energy unit, in joules.
    pub energy_j: f64,
    /// A human-readable name of the model units, e.g. `"DPD (r = D0/7.82 µm, E, tau)"`.
    pub label: String,
}

impl UnitSystem {
    /// Identity mapping: the values handed to the writer are already SI.
    pub fn si() -> Self {
        UnitSystem {
            length_m: 1.0,
            time_s: 1.0,
            energy_j: 1.0,
            label: "SI".to_string(),
        }
    }

    /// One model force unit, in newtons (E/r).
    pub fn force_n(&self) -> f64 {
        self.energy_j / self.length_m
    }

    /// One model mass unit, in kilograms (E τ²/r²).
    pub fn mass_kg(&self) -> f64 {
        self.energy_j * self.time_s * self.time_s / (self.length_m * self.length_m)
    }

    /// One model velocity unit, in m/s (r/τ).
    pub fn velocity_m_per_s(&self) -> f64 {
        self.length_m / self.time_s
    }

    /// Factor that turns a model value of `q` into SI.
    pub fn to_si(&self, q: Quantity) -> f64 {
        match q {
            Quantity::Dimensionless => 1.0,
            Quantity::Length => self.length_m,
            Quantity::Area => self.length_m * self.length_m,
            Quantity::Volume => self.length_m.powi(3),
            Quantity::Time => self.time_s,
            Quantity::Velocity => self.velocity_m_per_s(),
            Quantity::Force => self.force_n(),
            Quantity::Energy => self.energy_j,
            Quantity::Mass => self.mass_kg(),
            Quantity::NumberDensity => self.length_m.powi(-3),
            Quantity::Rate => 1.0 / self.time_s,
            Quantity::Other { model_to_si, .. } => model_to_si,
        }
    }
}

/// Physical kind of a stored value: decides the SI conversion factor and the `units` attribute.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Quantity {
    Dimensionless,
    Length,
    Area,
    Volume,
    Time,
    Velocity,
    Force,
    Energy,
    Mass,
    /// Particles per volume.
    NumberDensity,
    /// Frequency or shear rate.
    Rate,
    /// Anything else: the SI unit string and the model → SI factor (1 if already SI).
    Other {
        si_units: &'static str,
        model_to_si: f64,
    },
}

impl Quantity {
    /// The SI unit written in the `units` attribute.
    pub fn si_units(self) -> &'static str {
        match self {
            Quantity::Dimensionless => "1",
            Quantity::Length => "m",
            Quantity::Area => "m^2",
            Quantity::Volume => "m^3",
            Quantity::Time => "s",
            Quantity::Velocity => "m/s",
            Quantity::Force => "N",
            Quantity::Energy => "J",
            Quantity::Mass => "kg",
            Quantity::NumberDensity => "m^-3",
            Quantity::Rate => "1/s",
            Quantity::Other { si_units, .. } => si_units,
        }
    }
}
