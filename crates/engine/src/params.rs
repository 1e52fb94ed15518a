//! Plain parameter structs. Every value is in DPD model units (length rc of the solvent, energy
//! kBT of the solvent, mass m of a solvent particle); each field documents its default.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::{EngineError, Real};

/// DPD parameters of one type pair.
///
/// Forces on i from j (r = |x_i − x_j| < rc, e = (x_i − x_j)/r, w = 1 − r/rc):
/// F^C = a·w·e, F^D = −γ·w^D·(e·v_ij)·e, F^R = σ·w^R·ξ·e/√Δt with w^R = w^s, w^D = (w^R)²,
/// σ² = 2γ·kBT.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PairParams {
    /// Conservative repulsion a (energy/length). Standard fluid: 25.
    pub a: Real,
    /// Dissipative coefficient γ (mass/time). Standard fluid: 4.5.
    pub gamma: Real,
    /// Thermostat temperature kBT of the pair (energy); σ = √(2γ kBT). Standard: 1.
    pub kbt: Real,
    /// Cutoff radius rc (length). Standard: 1.
    pub rc: Real,
    /// Weight exponent s of w^R = (1 − r/rc)^s. Standard: 1; 1/2 and 1/4 raise the Schmidt number.
    pub s: Real,
}

/// Shear viscosity of the standard fluid ([`PairParams::groot_warren`], ρ = 3, m = 1) with
/// Δt = 0.01 and λ = 0.5, measured by this engine in reverse-Poiseuille flow (the fit over the
/// bins at least rc from the kinks, 8 halves of 6 × 6 × 16 at g = 0.1 and 0.05). The wall
/// tests compare their viscosities with it: engine against engine. Kinetic theory gives 0.957
/// (no pair correlations); LAMMPS `pair_style dpd` gives 0.87 ± 0.01 on the same fluid
/// (docs/walls.md). `scripts/validate_viscosity.sh` re-measures it and fails when it moves.
pub const STANDARD_FLUID_VISCOSITY: Real = 0.842;
/// Standard error of [`STANDARD_FLUID_VISCOSITY`].
pub const STANDARD_FLUID_VISCOSITY_SE: Real = 0.004;

/// Number density of the capillary fluid ([`PairParams::capillary`]); particle mass 1.
pub const CAPILLARY_FLUID_DENSITY: Real = 3.0;
/// Time step of the capillary fluid: the largest of 0.005, 0.004, 0.0025 and 0.002 at which a
/// periodic box at rest keeps its kinetic kBT within 1.5 % of the thermostat's 1 (within 0.5 %
/// where one does) and which the capillary scenario's membrane tolerates (Δt ≤ ~0.003 at this
/// fluid's mapping; the scenario's `model.timestep` defaults to this step)
/// (`capillary_fluid_timestep_scan` in crates/engine/tests/capillary_fluid.rs: 8 × 8 × 8,
/// ρ = 3, mean of steps 1000–6000): kBT = 1.0923 ± 0.0011 at 0.005 (γΔt = 0.6: the explicit
/// friction is near its limit), 1.0022 ± 0.0005 at 0.004, 1.0007 ± 0.0005 at 0.0025,
/// 0.9996 ± 0.0006 at 0.002; 0.01 blows up within 5 steps.
pub const CAPILLARY_FLUID_TIMESTEP: Real = 0.0025;
/// Shear viscosity of the capillary fluid ([`PairParams::capillary`], ρ = 3, m = 1, Δt =
/// [`CAPILLARY_FLUID_TIMESTEP`], λ = 0.5), measured by this engine in reverse-Poiseuille flow
/// like [`STANDARD_FLUID_VISCOSITY`] (6 × 6 × 16, fit over the bins at least rc from the kinks;
/// `viscosity_capillary_long` in crates/engine/tests/viscosity.rs: 6 seeds × 2 halves at
/// g = 0.5 (centre velocity ≈ 0.45), 60 000 steps each, 26.62 ± 0.11, SD 0.38 per half;
/// 3 seeds at g = 0.25 give 26.80 ± 0.39, so the response is linear). Kinetic theory
/// ([`kinetic_theory_viscosity`], g(r) = 1) gives 33.43, 26 % more; the standard fluid
/// measures 12 % below its theory.
pub const CAPILLARY_FLUID_VISCOSITY: Real = 26.6;
/// Standard error of [`CAPILLARY_FLUID_VISCOSITY`] (SD of the 12 halves / √12).
pub const CAPILLARY_FLUID_VISCOSITY_SE: Real = 0.11;

/// Slip length b of the capillary fluid ([`PairParams::capillary`]) at a wall of its own frozen
/// particles with bounce-back and no adaptive force, rc: tube Poiseuille flow carries
/// Q = πgnR⁴/(8η)·(1 + 4b/R), as if the wall were b further out. Measured in a tube with the
/// wall at R = 5, L = 8, at the body force g = 4η/(nR²) ≈ 1.42 whose no-slip mean velocity is
/// 0.5 (`capillary_fluid_wall_slip` in tests/capillary.rs: 4 seeds × 60 000 sampled steps of
/// Δt = [`CAPILLARY_FLUID_TIMESTEP`] after 2000 of flow development, ≈ 10 viscous times): the
/// mean velocity was 15.5 % above gnR²/(8η) with η = [`CAPILLARY_FLUID_VISCOSITY`] and n the
/// mean density in the tube, so b = R·0.155/4 = 0.194 ± 0.007 (seeds 0.206, 0.186, 0.190,
/// 0.194: ± 0.004; η's SE: ± 0.006). The capillary scenario puts its wall at the radius whose
/// effective no-slip radius is the physical one (`tests/capillary.rs` checks the flux in SI
/// to 3 %).
pub const CAPILLARY_FLUID_WALL_SLIP: Real = 0.194;

/// Number density of the dense fluid ([`PairParams::dense`]); particle mass 1.
pub const DENSE_FLUID_DENSITY: Real = 10.0;
/// Time step of the dense fluid: γΔt = 0.123, where a periodic box at rest keeps its kinetic
/// kBT within 0.2 % of 1 (`dense_fluid_timestep_scan` in crates/engine/tests/dense_fluid.rs,
/// 8³ box, mean of 4000 steps after 1000: 1.0001 ± 0.0003 at 0.002, 1.0004 ± 0.0002 at 0.0025,
/// 1.0011 ± 0.0002 at 0.003, 1.0339 ± 0.0003 at 0.0035; 0.004 blows up at step 119): the
/// explicit friction's cliff is close above it.
pub const DENSE_FLUID_TIMESTEP: Real = 0.003;
/// Kinetic kBT of the dense fluid at rest at [`DENSE_FLUID_TIMESTEP`], relative to the
/// thermostat's (`dense_fluid_timestep_scan`).
pub const DENSE_FLUID_KBT_AT_TIMESTEP: Real = 1.0011;
/// Shear viscosity of the dense fluid at [`DENSE_FLUID_TIMESTEP`], measured by reverse
/// Poiseuille flow like [`CAPILLARY_FLUID_VISCOSITY`] (`viscosity_dense_long` in
/// crates/engine/tests/viscosity.rs: 6 × 6 × 16, g = 1.3 (centre velocity ≈ 0.45), 4 seeds ×
/// 2 halves × 40 000 steps: 228.08 ± 0.71, SD 2.0 per half; 2 seeds at g = 0.65 give
/// 231.8 ± 2.0: linear response). Kinetic theory ([`kinetic_theory_viscosity`]) gives 202.1,
/// 11 % *below* the measurement (for the capillary fluid it is 26 % above).
pub const DENSE_FLUID_VISCOSITY: Real = 228.1;
/// Standard error of [`DENSE_FLUID_VISCOSITY`].
pub const DENSE_FLUID_VISCOSITY_SE: Real = 0.7;
/// Isothermal sound speed of the dense fluid, c = √(dp/dρ) from the virial pressure at
/// ρ = 9.5 and 10.5 (`dense_fluid_sound_speed` in crates/engine/tests/dense_fluid.rs, 8³ box,
/// 6000 steps each: p = 934.98 ± 0.48 and 1147.16 ± 0.49, c = 14.566 ± 0.024). The
/// Groot–Warren EOS ([`sound_speed`]), fitted at a = 25, gives 14.25 (2 % low).
pub const DENSE_FLUID_SOUND_SPEED: Real = 14.57;
/// Slip length of the dense fluid at a wall of its own frozen particles with bounce-back, rc,
/// measured like [`CAPILLARY_FLUID_WALL_SLIP`] (`dense_fluid_wall_slip` in tests/capillary.rs:
/// 3 seeds × 20 000 sampled steps, the flux 22 % above no-slip, b = 0.277 ± 0.005).
pub const DENSE_FLUID_WALL_SLIP: Real = 0.277;

/// Dissipative coefficient of the viscous fluid ([`PairParams::viscous`]): 10 × the dense
/// fluid's, for a cell in shear at Fischer's rates (up to 260 1/s at 28.9 mPa·s) with κ/kBT
/// exact (docs/units.md, "Choosing the fluid").
pub const VISCOUS_FLUID_GAMMA: Real = 410.0;
/// Time step of the viscous fluid: γΔt = 0.123, the dense fluid's validated friction limit.
/// `viscous_fluid_timestep_scan` (crates/engine/tests/dense_fluid.rs, 8³ box, mean of 4000
/// steps after 1000): kBT 1.0000 ± 0.0003 at 0.0002 and 0.00025, 0.9999 ± 0.0002 at 0.0003,
/// 1.0005 ± 0.0002 at 0.00035 (but the pressure 9 % high: 1097 ± 7 against 1009 ± 8), 0.0004
/// blows up at step 105: the friction's cliff sits at the same γΔt as the dense fluid's.
pub const VISCOUS_FLUID_TIMESTEP: Real = 0.0003;
/// Kinetic kBT of the viscous fluid at rest at [`VISCOUS_FLUID_TIMESTEP`], relative to the
/// thermostat's (`viscous_fluid_timestep_scan`).
pub const VISCOUS_FLUID_KBT_AT_TIMESTEP: Real = 0.9999;
/// Shear viscosity of the viscous fluid at [`VISCOUS_FLUID_TIMESTEP`], by reverse Poiseuille
/// flow as for the dense fluid (`viscosity_viscous_long` in crates/engine/tests/viscosity.rs:
/// 6 × 6 × 16, g = 13 (centre velocity ≈ 0.5), 4 seeds × 2 halves × 40 000 steps: 1977.0 ±
/// 6.3, SD 17.8 per half). 8.7 × the dense fluid's for 10 × its γ: not proportional (the
/// conservative and kinetic parts do not scale with γ, and pair correlations change); kinetic
/// theory says 2021.
pub const VISCOUS_FLUID_VISCOSITY: Real = 1977.0;
/// Standard error of [`VISCOUS_FLUID_VISCOSITY`].
pub const VISCOUS_FLUID_VISCOSITY_SE: Real = 6.3;
/// η(γ) of the dense fluid's family (n = 10, a = 100, s = 1/8, rc = 1: the dense and viscous
/// fluids differ only in γ and step), (γ, η), measured by reverse Poiseuille flow at γΔt ≤ 0.123.
/// η is not proportional to γ here: η/γ falls from 6.4 at γ = 4.25 to 4.8 at γ = 410 (η ∝
/// γ^0.94), so a cytosol made by scaling γ by λ misses λ by 7–9 % (λ = 5: η_in/η_out = 4.645 ±
/// 0.008). [`gamma_for_viscosity`] interpolates it. The points:
/// - γ = 4.25 and 8.51 (Δt = 0.003): 27.32 ± 0.27 and 52.30 ± 0.22, 2 seeds × 2 halves of
///   40 000 steps in 6 × 6 × 16 (`dense_family_low_gamma_viscosity` in
///   crates/engine/tests/viscosity.rs; an earlier single 4 × 4 × 16 run of 12 000 steps had
///   read 50.6 at 8.51);
/// - γ = 41: [`DENSE_FLUID_VISCOSITY`];
/// - γ = 205 (Δt = 0.0006): 1059.5 ± 1.8, and γ = 222.5 (Δt = 0.00055): 1154.0 ± 1.3, each
///   2 seeds × 2 halves of 120 000 steps in 6 × 6 × 16 (`viscosity_cytosol_lambda5_long`);
/// - γ = 410: [`VISCOUS_FLUID_VISCOSITY`].
pub const DENSE_FAMILY_VISCOSITY_BY_GAMMA: [(Real, Real); 6] = [
    (4.25, 27.32),
    (8.51, 52.30),
    (41.0, DENSE_FLUID_VISCOSITY),
    (205.0, 1059.5),
    (222.5, 1154.0),
    (VISCOUS_FLUID_GAMMA, VISCOUS_FLUID_VISCOSITY),
];

/// The γ at which a fluid of measured η(γ) `table` ((γ, η), γ ascending, at least two points)
/// has the viscosity `eta`: log–log interpolation between neighbouring points, the end
/// segments' power laws beyond the table.
pub fn gamma_for_viscosity(table: &[(Real, Real)], eta: Real) -> Real {
    assert!(table.len() >= 2, "a viscosity table needs two points");
    let target = eta.ln();
    let last = table.len() - 2;
    let k = (0..last).find(|&i| table[i + 1].1.ln() >= target).unwrap_or(last);
    let (g0, e0) = (table[k].0.ln(), table[k].1.ln());
    let (g1, e1) = (table[k + 1].0.ln(), table[k + 1].1.ln());
    (g0 + (target - e0) * (g1 - g0) / (e1 - e0)).exp()
}

/// Slip length of the viscous fluid at a wall of its own frozen particles with bounce-back, rc,
/// measured like [`CAPILLARY_FLUID_WALL_SLIP`] (`viscous_fluid_wall_slip` in
/// tests/capillary.rs: 3 seeds × 20 000 sampled steps, the flux 16.0–17.7 % above no-slip,
/// b = 0.212 ± 0.008).
pub const VISCOUS_FLUID_WALL_SLIP: Real = 0.212;

/// α of the Groot–Warren equation of state p = ρ kBT + α a ρ² (fitted for ρ ≥ 2, rc = 1).
pub const GROOT_WARREN_EOS_ALPHA: Real = 0.101;

/// Isothermal sound speed of a DPD fluid from the Groot–Warren equation of state
/// p = ρkBT + α a ρ² (α = [`GROOT_WARREN_EOS_ALPHA`], number density ρ, particle mass m):
/// c² = dp/d(mρ) = kBT/m + 2αaρ/m. For the standard and the capillary fluid (a = 25, kBT = 1,
/// ρ = 3, m = 1): c = √16.15 ≈ 4.02. The EOS was fitted for s = 1; a softer weight (s < 1)
/// changes only the dissipative and random forces, not the conservative one, so the
/// equilibrium structure and pressure, hence c, are the same.
pub fn sound_speed(pair: &PairParams, density: Real, mass: Real) -> Real {
    ((pair.kbt + 2.0 * GROOT_WARREN_EOS_ALPHA * pair.a * density * pair.rc.powi(4)) / mass).sqrt()
}

/// Kinetic-theory estimate of the shear viscosity (Groot & Warren 1997 for a general weight,
/// no pair correlations, g(r) = 1): η = ρ m D/2 + 16π γ ρ² rc⁵/(5(s'+1)(s'+2)(s'+3)(s'+4)(s'+5)),
/// D = 3kBT(s'+1)(s'+2)(s'+3)/(8π ρ γ rc³), with s' = 2s the exponent of w^D. Standard fluid:
/// 0.957; capillary fluid: 33.43. The measured values are lower (correlations; see
/// [`STANDARD_FLUID_VISCOSITY`], [`CAPILLARY_FLUID_VISCOSITY`]).
pub fn kinetic_theory_viscosity(pair: &PairParams, density: Real, mass: Real) -> Real {
    let sp = 2.0 * pair.s;
    let (g, n, rc) = (pair.gamma, density, pair.rc);
    let d = 3.0 * pair.kbt * (sp + 1.0) * (sp + 2.0) * (sp + 3.0) / (8.0 * std::f64::consts::PI * n * g * rc.powi(3));
    let diss = 16.0 * std::f64::consts::PI * g * n * n * rc.powi(5)
        / (5.0 * (sp + 1.0) * (sp + 2.0) * (sp + 3.0) * (sp + 4.0) * (sp + 5.0));
    n * mass * d / 2.0 + diss
}

impl PairParams {
    /// The capillary fluid: a = 25, γ = 120, kBT = 1, rc = 1, s = 1/4 (w^D = (1 − r/rc)^½),
    /// at ρ = [`CAPILLARY_FLUID_DENSITY`], m = 1, Δt = [`CAPILLARY_FLUID_TIMESTEP`]. Its
    /// viscosity ([`CAPILLARY_FLUID_VISCOSITY`]) is ≈ 32× the standard fluid's at the same
    /// sound speed (same a, ρ, kBT), so an RBC at the physical capillary number moves at a
    /// model velocity closer to the speed of sound (docs/units.md).
    pub const fn capillary() -> Self {
        Self {
            a: 25.0,
            gamma: 120.0,
            kbt: 1.0,
            rc: 1.0,
            s: 0.25,
        }
    }

    /// The dense fluid: a = 100, γ = 41, kBT = 1, rc = 1, s = 1/8 (w^D = (1 − r/rc)^¼), at
    /// ρ = [`DENSE_FLUID_DENSITY`], m = 1, Δt = [`DENSE_FLUID_TIMESTEP`]: the density,
    /// repulsion and weight of the Mirheo/dpdprops pipe-flow fluids, with γ at the largest
    /// explicit friction its step tolerates. Its η·c ([`DENSE_FLUID_VISCOSITY`] ×
    /// [`DENSE_FLUID_SOUND_SPEED`]) is ≈ 30× the capillary fluid's, which lets a cell at
    /// capillary speeds run with κ/kBT exact (docs/units.md, "Choosing the fluid").
    pub const fn dense() -> Self {
        Self {
            a: 100.0,
            gamma: 41.0,
            kbt: 1.0,
            rc: 1.0,
            s: 0.125,
        }
    }

    /// The viscous fluid: the dense fluid ([`PairParams::dense`]) with γ =
    /// [`VISCOUS_FLUID_GAMMA`] (10 ×), at ρ = [`DENSE_FLUID_DENSITY`] and Δt =
    /// [`VISCOUS_FLUID_TIMESTEP`]. Its conservative force, hence its equilibrium structure,
    /// pressure and sound speed, are the dense fluid's; its viscosity
    /// ([`VISCOUS_FLUID_VISCOSITY`]) is ≈ 10× larger, its step 10× shorter.
    pub const fn viscous() -> Self {
        Self {
            gamma: VISCOUS_FLUID_GAMMA,
            ..Self::dense()
        }
    }

    /// The Groot–Warren standard fluid: a = 25, γ = 4.5, kBT = 1, rc = 1, s = 1.
    pub const fn groot_warren() -> Self {
        Self {
            a: 25.0,
            gamma: 4.5,
            kbt: 1.0,
            rc: 1.0,
            s: 1.0,
        }
    }

    /// A pair that does not interact at all.
    pub const fn none() -> Self {
        Self {
            a: 0.0,
            gamma: 0.0,
            kbt: 0.0,
            rc: 0.0,
            s: 1.0,
        }
    }

    /// σ = √(2γ kBT).
    pub fn sigma(&self) -> Real {
        (2.0 * self.gamma * self.kbt).sqrt()
    }

    fn validate(&self, what: &str) -> Result<(), EngineError> {
        let ok = self.a.is_finite()
            && self.gamma.is_finite()
            && self.gamma >= 0.0
            && self.kbt.is_finite()
            && self.kbt >= 0.0
            && self.rc.is_finite()
            && self.rc >= 0.0
            && self.s.is_finite()
            && self.s > 0.0;
        if ok {
            Ok(())
        } else {
            Err(EngineError::invalid(
                what,
                format!("need finite a, γ ≥ 0, kBT ≥ 0, rc ≥ 0, s > 0; got {self:?}"),
            ))
        }
    }
}

/// Properties of one particle type.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TypeSpec {
    /// Name for messages and output (e.g. "solvent", "wall", "membrane").
    pub name: String,
    /// Particle mass (mass units). Default 1.
    pub mass: Real,
    /// Frozen particles are never moved by the integrator (wall particles). They still exert
    /// pair forces on mobile particles; frozen–frozen pairs are skipped. Default false.
    pub frozen: bool,
    /// Constant external force on every particle of this type (force units). Default 0.
    pub body_force: DVec3,
    /// Integrated by an extension, not by the engine (membrane vertices sub-stepped by their
    /// cell, `hemodpd_membrane::coupling`): the engine neither kicks nor drifts nor wraps them,
    /// and their velocity is their predicted velocity in the pair forces; their pair forces and
    /// body force are still computed into the force array, for the extension to apply. Unlike frozen particles they interact with every type (frozen ones included), and
    /// walls neither move nor reflect them. Default false (absent in old checkpoints).
    #[serde(default)]
    pub integrated_by_extension: bool,
}

impl TypeSpec {
    /// A mobile type of unit mass and no body force.
    pub fn new(name: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            mass: 1.0,
            frozen: false,
            body_force: DVec3::ZERO,
            integrated_by_extension: false,
        }
    }

    /// Same, frozen (wall particles).
    pub fn frozen(name: impl Into<String>) -> Self {
        Self {
            frozen: true,
            ..Self::new(name)
        }
    }

    /// Whether the engine's integrator leaves this type alone (frozen, or integrated by an
    /// extension).
    pub fn held(&self) -> bool {
        self.frozen || self.integrated_by_extension
    }
}

/// Types and the symmetric per-type-pair parameter table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ForceField {
    types: Vec<TypeSpec>,
    /// Row-major `ntypes × ntypes`, kept symmetric.
    pairs: Vec<PairParams>,
}

impl ForceField {
    /// One mobile type "solvent" with parameters `p`.
    pub fn single(p: PairParams) -> Self {
        Self {
            types: vec![TypeSpec::new("solvent")],
            pairs: vec![p],
        }
    }

    /// The given types; every pair starts as `default`.
    pub fn new(types: Vec<TypeSpec>, default: PairParams) -> Result<Self, EngineError> {
        if types.is_empty() || types.len() > u16::MAX as usize {
            return Err(EngineError::invalid(
                "types",
                format!("need 1..=65535 types, got {}", types.len()),
            ));
        }
        let n = types.len();
        let f = Self {
            types,
            pairs: vec![default; n * n],
        };
        f.validate()?;
        Ok(f)
    }

    /// Sets the parameters of the pair (i, j) and (j, i).
    pub fn set_pair(&mut self, i: usize, j: usize, p: PairParams) -> Result<(), EngineError> {
        let n = self.types.len();
        if i >= n || j >= n {
            return Err(EngineError::invalid(
                "pair types",
                format!("({i}, {j}) out of range for {n} types"),
            ));
        }
        p.validate(&format!("pair ({i}, {j})"))?;
        self.pairs[i * n + j] = p;
        self.pairs[j * n + i] = p;
        Ok(())
    }

    /// Mutable access to a type's properties (mass, frozen, body force).
    pub fn type_mut(&mut self, t: usize) -> Option<&mut TypeSpec> {
        self.types.get_mut(t)
    }

    /// Sets the body force of type `t`.
    pub fn set_body_force(&mut self, t: usize, f: DVec3) -> Result<(), EngineError> {
        if !f.is_finite() {
            return Err(EngineError::invalid("body force", format!("{f}")));
        }
        let n = self.types.len();
        self.types
            .get_mut(t)
            .ok_or_else(|| EngineError::invalid("type", format!("{t} out of range for {n} types")))?
            .body_force = f;
        Ok(())
    }

    /// Number of types.
    pub fn ntypes(&self) -> usize {
        self.types.len()
    }

    /// The types.
    pub fn types(&self) -> &[TypeSpec] {
        &self.types
    }

    /// Parameters of the pair (i, j).
    pub fn pair(&self, i: usize, j: usize) -> &PairParams {
        &self.pairs[i * self.types.len() + j]
    }

    /// Largest cutoff over all pairs that can interact (not frozen–frozen).
    pub fn max_cutoff(&self) -> Real {
        let n = self.types.len();
        let mut rc: Real = 0.0;
        for i in 0..n {
            for j in 0..n {
                if !(self.types[i].frozen && self.types[j].frozen) {
                    rc = rc.max(self.pairs[i * n + j].rc);
                }
            }
        }
        rc
    }

    /// Checks every value.
    pub fn validate(&self) -> Result<(), EngineError> {
        let n = self.types.len();
        if n == 0 || self.pairs.len() != n * n {
            return Err(EngineError::invalid("force field", "pair table size"));
        }
        for (t, ty) in self.types.iter().enumerate() {
            if !(ty.mass.is_finite() && ty.mass > 0.0) {
                return Err(EngineError::invalid(
                    format!("mass of type {t} ({})", ty.name),
                    format!("must be finite and > 0, got {}", ty.mass),
                ));
            }
            if !ty.body_force.is_finite() {
                return Err(EngineError::invalid(
                    format!("body force of type {t}"),
                    format!("{}", ty.body_force),
                ));
            }
        }
        for i in 0..n {
            for j in 0..n {
                self.pairs[i * n + j].validate(&format!("pair ({i}, {j})"))?;
                if self.pairs[i * n + j] != self.pairs[j * n + i] {
                    return Err(EngineError::invalid(
                        format!("pair ({i}, {j})"),
                        "parameter table must be symmetric",
                    ));
                }
            }
        }
        if self.max_cutoff() <= 0.0 {
            return Err(EngineError::invalid("force field", "no pair has a cutoff > 0"));
        }
        Ok(())
    }
}

/// How the pair loop is organised. Both give bit-identical results for any thread count.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum ForceScheme {
    /// Each pair once (half shell of 13 neighbour cells); Newton's third law applied on the spot.
    /// Threads work on z-slabs of cells in two colours (even, odd slabs), so no two threads ever
    /// write the same particle; the slab partition does not depend on the thread count.
    #[default]
    HalfShell,
    /// Each particle sums its own pairs over all 27 neighbour cells (every pair computed twice).
    Gather,
}

/// Box, time step, integrator and noise settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimConfig {
    /// Box edge lengths (length units). No default; each ≥ 3 × the largest cutoff.
    pub box_lengths: DVec3,
    /// Time step Δt (time units). Standard fluid: 0.01.
    pub dt: Real,
    /// λ of the Groot–Warren modified velocity-Verlet (predicted velocity v + λΔt f/m).
    /// Default 0.5 (= plain velocity Verlet with the predicted velocity).
    pub lambda: Real,
    /// Seed of the pair noise (and nothing else).
    pub seed: u64,
    /// Pair loop organisation. Default [`ForceScheme::HalfShell`].
    pub scheme: ForceScheme,
    /// Lees–Edwards shear rate γ̇ (1/time): simple shear u = γ̇ y x̂ imposed through the y
    /// boundaries (see [`crate::PeriodicBox`]). Default 0: an ordinary periodic box.
    #[serde(default)]
    pub shear_rate: Real,
    /// Every `sort_every` steps (0: never) the particles are put into cell order in storage, so
    /// that the per-step cell sort and the force scatter read memory nearly in sequence. It runs
    /// only when the extension allows storage indices to change
    /// ([`crate::Extension::allows_reordering`]: a plain fluid does); it is a deterministic
    /// function of the positions, so thread-count independence and bit-identical restarts hold.
    /// When the extension also adds no forces, the sort costs little: it is done in the pass that
    /// returns the forces to storage order, which then writes the storage in cell order.
    /// Default 0 (off; `docs/performance.md` has what it gains).
    #[serde(default = "default_sort_every")]
    pub sort_every: u64,
}

fn default_sort_every() -> u64 {
    0
}

impl SimConfig {
    /// A config with λ = 0.5 and the default scheme.
    pub fn new(box_lengths: DVec3, dt: Real, seed: u64) -> Self {
        Self {
            box_lengths,
            dt,
            lambda: 0.5,
            seed,
            scheme: ForceScheme::default(),
            shear_rate: 0.0,
            sort_every: default_sort_every(),
        }
    }

    /// The same config with Lees–Edwards boundaries at shear rate `shear_rate` (1/time).
    pub fn with_shear_rate(mut self, shear_rate: Real) -> Self {
        self.shear_rate = shear_rate;
        self
    }

    /// Checks dt and λ (the box is checked against the cutoff by the simulation).
    pub fn validate(&self) -> Result<(), EngineError> {
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(EngineError::invalid(
                "time step dt",
                format!("must be finite and > 0, got {}", self.dt),
            ));
        }
        if !self.shear_rate.is_finite() {
            return Err(EngineError::invalid(
                "shear rate",
                format!("must be finite, got {}", self.shear_rate),
            ));
        }
        if !(self.lambda.is_finite() && (0.0..=1.0).contains(&self.lambda)) {
            return Err(EngineError::invalid(
                "lambda",
                format!("must be in [0, 1], got {}", self.lambda),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The interpolation returns each measured point's γ for its η, lies between neighbours,
    /// and follows the end segment's power law beyond the table.
    #[test]
    fn gamma_for_viscosity_interpolates_the_measured_table() {
        let t = DENSE_FAMILY_VISCOSITY_BY_GAMMA;
        for (g, eta) in t {
            assert!((gamma_for_viscosity(&t, eta) / g - 1.0).abs() < 1e-12, "{g} {eta}");
        }
        // between 41 and 205: η ∝ γ^p with p = ln(1059.5/228.1)/ln 5
        let p = (1059.5f64 / DENSE_FLUID_VISCOSITY).ln() / 5f64.ln();
        let g = gamma_for_viscosity(&t, 3.0 * DENSE_FLUID_VISCOSITY);
        assert!((g / 41.0 - 3f64.powf(1.0 / p)).abs() < 1e-12, "{g}");
        // λ = 5 of the dense fluid lies between the 205 and 222.5 points
        let g = gamma_for_viscosity(&t, 5.0 * DENSE_FLUID_VISCOSITY);
        assert!(g > 205.0 && g < 222.5, "{g}");
        // below the table: the first segment's law
        let p0 = (52.30f64 / 27.32).ln() / (8.51f64 / 4.25).ln();
        let g = gamma_for_viscosity(&t, 13.66);
        assert!((g / 4.25 - 0.5f64.powf(1.0 / p0)).abs() < 1e-12, "{g}");
    }
}
