//! The membrane free energy (Pivkin & Karniadakis 2008, Eq. 1) and its exact gradient:
//!
//! F = Σ_links V_WLC(L_i) + Σ_triangles C_α/A_α               (in-plane, Eqs. 2–3)
//!   + Σ_link-pairs k_bend [1 − cos(θ_i − θ0)]                 (bending, Eq. 5)
//!   + k_a (A − A0)²/(2 A0) + k_v (V − V0)²/(2 V0)             (global area and volume)
//!
//! with V_WLC(L) = kBT·Lmax/(4p)·(3x² − 2x³)/(1 − x), x = L/Lmax. Two reference states
//! ([`ReferenceState`]): the paper's uniform L0 ([`MembraneModel::uniform`]) and a stress-free
//! resting mesh ([`MembraneModel::stress_free`]); see `docs/model.md`.
//!
//! Unit-agnostic: every number is in the caller's consistent system (µm, pN, pN·µm for the
//! stretching driver). [`MembraneConstants::from_params`] converts the SI [`ModelParams`].
//!
//! [`MembraneModel::add_forces`] loops serially over links, triangles and link pairs in a fixed
//! order: deterministic, no allocation. [`MembraneModel::add_forces_parallel`] is the rayon
//! version for large meshes (per-element slots, then a per-vertex gather): bit-identical for
//! any thread count.

// `!(x < y)` is deliberate throughout: it is also true for NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub(crate) mod hessian;
pub mod kernels;
mod parallel;

pub use parallel::ForceWorkspace;

#[cfg(test)]
pub(crate) mod tests;

use crate::mesh::Topology;
use crate::params::{c_eq4, ModelParams};
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Relative area below which a triangle counts as degenerate (A < this × its reference area).
pub const DEGENERATE_AREA_FRACTION: f64 = 1e-12;

/// Bounds on the per-link C/A tension ratio T_i/f_WLC(L0) of the stress-free reference (1 on an
/// equilateral mesh). A relaxed cell mesh has 0.07–1.7: links whose two opposite angles sum to
/// nearly 180° carry almost no C/A tension. Outside these bounds the resting mesh is too far
/// from equilateral for the construction to mean anything (e.g. a vertex squashed onto another).
pub const TENSION_RATIO_BOUNDS: (f64, f64) = (-3.0, 5.0);

/// Failures of the force evaluation or of building a model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ForceError {
    #[error("link {link} ({}-{}) is overstretched: length {length} >= Lmax {lmax}", vertices[0], vertices[1])]
    LinkOverstretched {
        link: usize,
        vertices: [u32; 2],
        length: f64,
        lmax: f64,
    },
    #[error("triangle {triangle} ({}-{}-{}) is degenerate: area {area}", vertices[0], vertices[1], vertices[2])]
    DegenerateTriangle {
        triangle: usize,
        vertices: [u32; 3],
        area: f64,
    },
    #[error("link pair {pair} (link {}-{}) has a degenerate dihedral", vertices[1], vertices[2])]
    DegenerateDihedral { pair: usize, vertices: [u32; 4] },
    #[error("vertex {vertex} has a non-finite position {position:?}")]
    NonFinitePosition { vertex: usize, position: [f64; 3] },
    #[error("{what} has length {got}, the model has {expected} vertices")]
    WrongLength {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("constant {name} = {value} is invalid ({allowed})")]
    BadConstant {
        name: &'static str,
        value: f64,
        allowed: &'static str,
    },
    #[error(
        "stress-free reference: link {link} ({}-{}) carries a C/A tension of {ratio} times the WLC tension at L0, outside [{}, {}]; the resting mesh is badly shaped",
        vertices[0], vertices[1], TENSION_RATIO_BOUNDS.0, TENSION_RATIO_BOUNDS.1
    )]
    BadlyShapedMesh {
        link: usize,
        vertices: [u32; 2],
        ratio: f64,
    },
}

/// Which reference state the in-plane energy uses. In a scenario file: `"stress-free"`,
/// `"uniform"`, or `{ spheroid = { reduced_volume = 0.95 } }`.
#[derive(Clone, Copy, Debug, PartialEq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReferenceState {
    /// The paper's convention: one L0 for every link, Lmax = 3.17 L0, one C from Eq. 4.
    Uniform,
    /// Every link and triangle unstrained in the resting mesh (per-link L0 and p_i,
    /// per-triangle C): the in-plane force at rest is zero to round-off.
    #[default]
    StressFree,
    /// Every link and triangle unstrained on the oblate spheroid of the resting cell's area and
    /// this reduced volume (0 < v ≤ 1; the biconcave cell's is 0.64): the stress-free
    /// construction on [`crate::reference::spheroid_reference`], with A0 and V0 still the resting
    /// cell's. The cell at rest is then what bending, this reference and the constraints settle
    /// on.
    #[serde(rename_all = "snake_case")]
    Spheroid { reduced_volume: f64 },
}

/// Membrane constants in the caller's units.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MembraneConstants {
    /// Thermal energy kBT (energy).
    pub kbt: f64,
    /// Uniform reference link length L0 (length); used by [`MembraneModel::uniform`].
    pub l0: f64,
    /// Lmax/L0 (3.17 in the paper), the same for every link.
    pub lmax_over_l0: f64,
    /// WLC persistence length p (length).
    pub persistence_length: f64,
    /// Bending constant k_bend (energy).
    pub k_bend: f64,
    /// Spontaneous angle θ0 between adjacent outward normals, radians (> 0 favours outward bending).
    pub theta0_rad: f64,
    /// Global area constant k_a (energy/length²): E_A = k_a (A − A0)²/(2 A0).
    pub k_area: f64,
    /// Global volume constant k_v (energy/length³): E_V = k_v (V − V0)²/(2 V0).
    pub k_volume: f64,
}

/// Default global area constant k_a, N/m: 2 mN/m = 2000 pN/µm ≈ 240 μ0. With it the N = 500
/// cell keeps its area within 0.25 % at 200 pN stretching and 0.015 % at rest, while the
/// rank-one stiffness it adds, k_a|∇A|²/A0 ≈ 0.2 k_a at N = 500 (∝ 1/N), stays a few times the
/// membrane's own largest Hessian eigenvalue (130 pN/µm). See docs/model.md.
pub const DEFAULT_K_AREA_N_PER_M: f64 = 2e-3;
/// Default global volume constant k_v, N/m² (= J/m³): 1000 pN/µm². Volume within 0.1 % at
/// 200 pN and 0.03 % at rest (N = 500); adds k_v|∇V|²/V0 ≈ 0.38 k_v to the stiffness.
pub const DEFAULT_K_VOLUME_N_PER_M2: f64 = 1e3;

impl MembraneConstants {
    /// Converts the SI [`ModelParams`] into constants in the caller's units: one length unit is
    /// `unit_length_m` metres, one energy unit `unit_energy_j` joules (µm and pN·µm:
    /// 1e-6 and 1e-18). `k_area_n_per_m` (N/m) and `k_volume_n_per_m2` (N/m² = J/m³) are the
    /// global area and volume constants in SI ([`DEFAULT_K_AREA_N_PER_M`],
    /// [`DEFAULT_K_VOLUME_N_PER_M2`]).
    pub fn from_params(
        p: &ModelParams,
        unit_length_m: f64,
        unit_energy_j: f64,
        k_area_n_per_m: f64,
        k_volume_n_per_m2: f64,
    ) -> Self {
        let (lu, eu) = (unit_length_m, unit_energy_j);
        Self {
            kbt: p.kbt_j / eu,
            l0: p.l0_m / lu,
            lmax_over_l0: p.lmax_m / p.l0_m,
            persistence_length: p.persistence_length_m / lu,
            k_bend: p.k_bend_j / eu,
            theta0_rad: p.theta0_deg.to_radians(),
            k_area: k_area_n_per_m * lu * lu / eu,
            k_volume: k_volume_n_per_m2 * lu * lu * lu / eu,
        }
    }

    /// As [`from_params`](Self::from_params) in µm and pN·µm (forces in pN) with the default
    /// k_a and k_v.
    pub fn from_params_um_pn(p: &ModelParams) -> Self {
        Self::from_params(p, 1e-6, 1e-18, DEFAULT_K_AREA_N_PER_M, DEFAULT_K_VOLUME_N_PER_M2)
    }

    /// x0 = L0/Lmax.
    pub fn x0(&self) -> f64 {
        1.0 / self.lmax_over_l0
    }

    /// C of Eq. 4 for a reference link length `l0`.
    pub fn c_eq4_for(&self, l0: f64) -> f64 {
        c_eq4(self.kbt, self.lmax_over_l0 * l0, self.persistence_length, self.x0())
    }

    fn validate(&self) -> Result<(), ForceError> {
        let pos = |name, v: f64| {
            if v > 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(ForceError::BadConstant {
                    name,
                    value: v,
                    allowed: "finite and > 0",
                })
            }
        };
        let nonneg = |name, v: f64| {
            if v >= 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(ForceError::BadConstant {
                    name,
                    value: v,
                    allowed: "finite and >= 0",
                })
            }
        };
        pos("kbt", self.kbt)?;
        pos("l0", self.l0)?;
        pos("persistence_length", self.persistence_length)?;
        if !(self.lmax_over_l0 > 1.0 && self.lmax_over_l0.is_finite()) {
            return Err(ForceError::BadConstant {
                name: "lmax_over_l0",
                value: self.lmax_over_l0,
                allowed: "> 1",
            });
        }
        nonneg("k_bend", self.k_bend)?;
        nonneg("k_area", self.k_area)?;
        nonneg("k_volume", self.k_volume)?;
        if !self.theta0_rad.is_finite() {
            return Err(ForceError::BadConstant {
                name: "theta0_rad",
                value: self.theta0_rad,
                allowed: "finite",
            });
        }
        Ok(())
    }
}

/// The energy terms of Eq. 1, in the caller's energy unit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EnergyTerms {
    /// Σ_links V_WLC.
    pub wlc: f64,
    /// Σ_triangles C/A.
    pub c_over_a: f64,
    /// Σ_link-pairs k_bend [1 − cos(θ − θ0)].
    pub bending: f64,
    /// k_a (A − A0)²/(2 A0).
    pub area: f64,
    /// k_v (V − V0)²/(2 V0).
    pub volume: f64,
}

impl EnergyTerms {
    /// Sum of all terms.
    pub fn total(&self) -> f64 {
        self.wlc + self.c_over_a + self.bending + self.area + self.volume
    }

    /// In-plane part (WLC + C/A).
    pub fn in_plane(&self) -> f64 {
        self.wlc + self.c_over_a
    }
}

/// Which terms an evaluation includes (all by default).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TermSet {
    pub wlc: bool,
    pub c_over_a: bool,
    pub bending: bool,
    pub area: bool,
    pub volume: bool,
}

impl TermSet {
    /// Every term.
    pub const ALL: Self = Self {
        wlc: true,
        c_over_a: true,
        bending: true,
        area: true,
        volume: true,
    };
    /// No term.
    pub const NONE: Self = Self {
        wlc: false,
        c_over_a: false,
        bending: false,
        area: false,
        volume: false,
    };
    /// WLC + C/A.
    pub const IN_PLANE: Self = Self {
        wlc: true,
        c_over_a: true,
        bending: false,
        area: false,
        volume: false,
    };
}

impl Default for TermSet {
    fn default() -> Self {
        Self::ALL
    }
}

/// Mean, minimum and maximum of a per-link quantity.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Distribution {
    pub mean: f64,
    pub min: f64,
    pub max: f64,
    /// Relative standard deviation (sd / mean).
    pub rel_sd: f64,
}

impl Distribution {
    fn of(v: &[f64]) -> Self {
        let n = v.len().max(1) as f64;
        let mean = v.iter().sum::<f64>() / n;
        let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
        Self {
            mean,
            min: v.iter().cloned().fold(f64::INFINITY, f64::min),
            max: v.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
            rel_sd: sd / mean,
        }
    }
}

/// The membrane model of one cell: topology plus per-link, per-triangle and global constants.
#[derive(Clone, Debug)]
pub struct MembraneModel {
    reference: ReferenceState,
    constants: MembraneConstants,
    n_vertices: usize,
    links: Vec<[u32; 2]>,
    triangles: Vec<[u32; 3]>,
    dihedrals: Vec<[u32; 4]>,
    /// Per link: reference length ℓ_i, Lmax_i, and the WLC prefactor w_i = kBT/(4p).
    link_l0: Vec<f64>,
    link_lmax: Vec<f64>,
    link_w: Vec<f64>,
    /// Per link: constant tension offset τ_i (force); the link energy is V_WLC(L) − τ_i (L − ℓ_i).
    /// 0 for the uniform reference.
    link_tau: Vec<f64>,
    /// Per link: C/A tension at rest over the WLC tension at rest, T_i/f_i (1 on an equilateral mesh).
    link_tension_ratio: Vec<f64>,
    /// Per triangle: C_α, and the area below which it counts as degenerate.
    tri_c: Vec<f64>,
    tri_amin: Vec<f64>,
    k_bend: f64,
    theta0: f64,
    cos_theta0: f64,
    sin_theta0: f64,
    k_area: f64,
    area0: f64,
    k_volume: f64,
    volume0: f64,
}

impl MembraneModel {
    /// The paper's convention: one L0 for every link, Lmax = `lmax_over_l0`·L0, one C from
    /// Eq. 4, and the given A0, V0.
    pub fn uniform(topology: &Topology, c: &MembraneConstants, area0: f64, volume0: f64) -> Result<Self, ForceError> {
        c.validate()?;
        for (name, v) in [("area0", area0), ("volume0", volume0)] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(ForceError::BadConstant {
                    name,
                    value: v,
                    allowed: "finite and > 0",
                });
            }
        }
        let ns = topology.links.len();
        let nt = topology.triangles.len();
        let lmax = c.lmax_over_l0 * c.l0;
        let cc = c.c_eq4_for(c.l0);
        let a_ref = 3f64.sqrt() / 4.0 * c.l0 * c.l0;
        Ok(Self {
            reference: ReferenceState::Uniform,
            constants: *c,
            n_vertices: topology.n_vertices,
            links: topology.links.clone(),
            triangles: topology.triangles.clone(),
            dihedrals: topology.dihedrals.clone(),
            link_l0: vec![c.l0; ns],
            link_lmax: vec![lmax; ns],
            link_w: vec![c.kbt / (4.0 * c.persistence_length); ns],
            link_tau: vec![0.0; ns],
            link_tension_ratio: vec![1.0; ns],
            tri_c: vec![cc; nt],
            tri_amin: vec![DEGENERATE_AREA_FRACTION * a_ref; nt],
            k_bend: c.k_bend,
            theta0: c.theta0_rad,
            cos_theta0: c.theta0_rad.cos(),
            sin_theta0: c.theta0_rad.sin(),
            k_area: c.k_area,
            area0,
            k_volume: c.k_volume,
            volume0,
        })
    }

    /// The stress-free reference built from the resting positions `rest` (docs/model.md):
    /// 1. link i: ℓ_i = its rest length, Lmax_i = `lmax_over_l0`·ℓ_i, the model's p;
    /// 2. triangle α: C_α from Eq. 4 with L0_α = √(4A_α/√3) (the equilateral side of its rest
    ///    area) and Lmax_α = `lmax_over_l0`·L0_α;
    /// 3. link i: the C/A tensions T_i = Σ_α (C_α/A_α²) ∂A_α/∂L_i of its two triangles balance its
    ///    WLC tension f_i = V_WLC'(ℓ_i) exactly on an equilateral mesh; the remainder
    ///    τ_i = f_i − T_i of a non-equilateral mesh is removed by a constant tension offset, the
    ///    link energy being V_WLC(L) − τ_i (L − ℓ_i). This leaves every link's stiffness as the
    ///    paper's (τ_i = 0 on an equilateral mesh);
    /// 4. A0, V0 = area and volume of `rest`.
    ///
    /// `c.l0` is not used. Fails if some T_i/f_i is outside [`TENSION_RATIO_BOUNDS`] (a badly
    /// shaped mesh) or a rest triangle is degenerate.
    pub fn stress_free(topology: &Topology, rest: &[DVec3], c: &MembraneConstants) -> Result<Self, ForceError> {
        c.validate()?;
        let n = topology.n_vertices;
        check_positions(rest, n, "rest positions")?;
        let x0 = c.x0();
        let ns = topology.links.len();
        let nt = topology.triangles.len();

        // Per-link rest lengths.
        let link_l0: Vec<f64> = topology
            .links
            .iter()
            .map(|l| (rest[l[1] as usize] - rest[l[0] as usize]).length())
            .collect();
        let link_lmax: Vec<f64> = link_l0.iter().map(|l| c.lmax_over_l0 * l).collect();

        // Per-triangle C and its tension on each side. Side k of triangle (v0, v1, v2) is the
        // link opposite vertex k, i.e. (v_{k+1}, v_{k+2}).
        let mut tri_c = Vec::with_capacity(nt);
        let mut tri_amin = Vec::with_capacity(nt);
        let mut tension = vec![0.0; ns];
        let link_index = link_lookup(topology);
        for (t, tri) in topology.triangles.iter().enumerate() {
            let p = tri.map(|v| rest[v as usize]);
            let area = crate::mesh::triangle_area(p[0], p[1], p[2]);
            if !(area > 0.0) {
                return Err(ForceError::DegenerateTriangle {
                    triangle: t,
                    vertices: *tri,
                    area,
                });
            }
            let l0a = (4.0 * area / 3f64.sqrt()).sqrt();
            let ca = c.c_eq4_for(l0a);
            tri_c.push(ca);
            tri_amin.push(DEGENERATE_AREA_FRACTION * area);
            let sides = [(p[2] - p[1]).length(), (p[0] - p[2]).length(), (p[1] - p[0]).length()];
            for k in 0..3 {
                let (s, s1, s2) = (sides[k], sides[(k + 1) % 3], sides[(k + 2) % 3]);
                let dadl = kernels::heron_dadl(s, s1, s2, area);
                let li = link_index(tri[(k + 1) % 3], tri[(k + 2) % 3]);
                tension[li] += ca / (area * area) * dadl;
            }
        }

        // Per-link tension offset: every link is at x0 = ℓ_i/Lmax_i at rest, so its WLC tension
        // there is w g'(x0) with the model's w = kBT/(4p).
        let w = c.kbt / (4.0 * c.persistence_length);
        let f_rest = w * kernels::wlc_dg(x0);
        let mut link_tau = Vec::with_capacity(ns);
        let mut link_tension_ratio = Vec::with_capacity(ns);
        for (i, l) in topology.links.iter().enumerate() {
            let ratio = tension[i] / f_rest;
            if !(ratio >= TENSION_RATIO_BOUNDS.0 && ratio <= TENSION_RATIO_BOUNDS.1) {
                return Err(ForceError::BadlyShapedMesh {
                    link: i,
                    vertices: *l,
                    ratio,
                });
            }
            link_tau.push(f_rest - tension[i]);
            link_tension_ratio.push(ratio);
        }
        let link_w = vec![w; ns];

        let model = Self {
            reference: ReferenceState::StressFree,
            constants: *c,
            n_vertices: n,
            links: topology.links.clone(),
            triangles: topology.triangles.clone(),
            dihedrals: topology.dihedrals.clone(),
            link_l0,
            link_lmax,
            link_w,
            link_tau,
            link_tension_ratio,
            tri_c,
            tri_amin,
            k_bend: c.k_bend,
            theta0: c.theta0_rad,
            cos_theta0: c.theta0_rad.cos(),
            sin_theta0: c.theta0_rad.sin(),
            k_area: c.k_area,
            area0: 1.0,
            k_volume: c.k_volume,
            volume0: 1.0,
        };
        model.with_rest_area_volume(rest)
    }

    /// The model with A0 and V0 taken from `rest`; refuses a mesh whose volume is not positive
    /// (inward triangles).
    fn with_rest_area_volume(mut self, rest: &[DVec3]) -> Result<Self, ForceError> {
        (self.area0, self.volume0) = self.area_volume(rest)?;
        if !(self.volume0 > 0.0) {
            return Err(ForceError::BadConstant {
                name: "volume0",
                value: self.volume0,
                allowed: "> 0 (outward triangles)",
            });
        }
        Ok(self)
    }

    /// The stress-free construction ([`Self::stress_free`]) on the reference positions
    /// `reference` (the zero of the in-plane energy), with A0 and V0 those of `rest`, the
    /// resting cell. Both must be positions of the same mesh.
    pub fn stress_free_on(
        topology: &Topology,
        reference: &[DVec3],
        rest: &[DVec3],
        c: &MembraneConstants,
    ) -> Result<Self, ForceError> {
        let model = Self::stress_free(topology, reference, c)?;
        check_positions(rest, topology.n_vertices, "rest positions")?;
        model.with_rest_area_volume(rest)
    }

    /// The model with the spheroidal reference of reduced volume `reduced_volume`
    /// ([`ReferenceState::Spheroid`]) for the resting cell `rest`.
    pub fn spheroidal(
        topology: &Topology,
        rest: &[DVec3],
        c: &MembraneConstants,
        reduced_volume: f64,
    ) -> Result<Self, ForceError> {
        check_positions(rest, topology.n_vertices, "rest positions")?;
        let reference = crate::reference::spheroid_reference(rest, &topology.triangles, reduced_volume).ok_or(
            ForceError::BadConstant {
                name: "reduced_volume",
                value: reduced_volume,
                allowed: "0 < v <= 1, on a mesh with an area",
            },
        )?;
        let mut model = Self::stress_free_on(topology, &reference, rest, c)?;
        model.reference = ReferenceState::Spheroid { reduced_volume };
        Ok(model)
    }

    /// Builds the model of `reference` from the resting positions `rest`; for
    /// [`ReferenceState::Uniform`] A0 and V0 are those of `rest` and L0 is `c.l0`.
    pub fn new(
        topology: &Topology,
        rest: &[DVec3],
        c: &MembraneConstants,
        reference: ReferenceState,
    ) -> Result<Self, ForceError> {
        match reference {
            ReferenceState::StressFree => Self::stress_free(topology, rest, c),
            ReferenceState::Spheroid { reduced_volume } => Self::spheroidal(topology, rest, c, reduced_volume),
            ReferenceState::Uniform => {
                check_positions(rest, topology.n_vertices, "rest positions")?;
                let mut model = Self::uniform(topology, c, 1.0, 1.0)?;
                (model.area0, model.volume0) = model.area_volume(rest)?;
                if !(model.volume0 > 0.0) {
                    return Err(ForceError::BadConstant {
                        name: "volume0",
                        value: model.volume0,
                        allowed: "> 0 (outward triangles)",
                    });
                }
                Ok(model)
            }
        }
    }

    /// The energy terms at `x`.
    pub fn energy(&self, x: &[DVec3]) -> Result<EnergyTerms, ForceError> {
        self.energy_terms(x, TermSet::ALL)
    }

    /// The energy terms at `x`, restricted to `terms` (the others are 0).
    pub fn energy_terms(&self, x: &[DVec3], terms: TermSet) -> Result<EnergyTerms, ForceError> {
        check_positions(x, self.n_vertices, "positions")?;
        let mut e = EnergyTerms::default();
        if terms.area || terms.volume || terms.c_over_a {
            let (area, volume) = self.area_volume(x)?;
            if terms.area {
                e.area = 0.5 * self.k_area * (area - self.area0).powi(2) / self.area0;
            }
            if terms.volume {
                e.volume = 0.5 * self.k_volume * (volume - self.volume0).powi(2) / self.volume0;
            }
        }
        if terms.wlc {
            for (i, l) in self.links.iter().enumerate() {
                let len = (x[l[1] as usize] - x[l[0] as usize]).length();
                let (v, _) =
                    kernels::wlc(len, self.link_lmax[i], self.link_w[i]).ok_or_else(|| self.overstretched(i, len))?;
                e.wlc += v - self.link_tau[i] * (len - self.link_l0[i]);
            }
        }
        if terms.c_over_a {
            for (t, tri) in self.triangles.iter().enumerate() {
                let [a, b, c] = tri.map(|v| x[v as usize]);
                let area = 0.5 * (b - a).cross(c - a).length();
                e.c_over_a += self.tri_c[t] / area;
            }
        }
        if terms.bending && self.k_bend != 0.0 {
            for (k, d) in self.dihedrals.iter().enumerate() {
                let [a, b, c, dd] = d.map(|v| x[v as usize]);
                let (cos_t, sin_t) = kernels::dihedral_cos_sin(a, b, c, dd)
                    .ok_or(ForceError::DegenerateDihedral { pair: k, vertices: *d })?;
                // 1 − cos(θ − θ0) = 1 − cos θ cos θ0 − sin θ sin θ0
                e.bending += self.k_bend * (1.0 - cos_t * self.cos_theta0 - sin_t * self.sin_theta0);
            }
        }
        Ok(e)
    }

    /// ADDS the forces −∂F/∂x to `f` (length N) and returns the energy terms.
    /// On error `f` may be partly updated: discard it.
    pub fn add_forces(&self, x: &[DVec3], f: &mut [DVec3]) -> Result<EnergyTerms, ForceError> {
        self.add_forces_terms(x, f, TermSet::ALL)
    }

    /// As [`add_forces`](Self::add_forces), restricted to `terms`.
    pub fn add_forces_terms(&self, x: &[DVec3], f: &mut [DVec3], terms: TermSet) -> Result<EnergyTerms, ForceError> {
        check_positions(x, self.n_vertices, "positions")?;
        if f.len() != self.n_vertices {
            return Err(ForceError::WrongLength {
                what: "force buffer",
                expected: self.n_vertices,
                got: f.len(),
            });
        }
        let mut e = EnergyTerms::default();

        // Global area and volume first (a reduction), then their forces in the triangle loop.
        let (mut da, mut dv) = (0.0, 0.0);
        if terms.area || terms.volume || terms.c_over_a {
            let (area, volume) = self.area_volume(x)?;
            if terms.area {
                e.area = 0.5 * self.k_area * (area - self.area0).powi(2) / self.area0;
                da = self.k_area * (area - self.area0) / self.area0; // dE_A/dA
            }
            if terms.volume {
                e.volume = 0.5 * self.k_volume * (volume - self.volume0).powi(2) / self.volume0;
                dv = self.k_volume * (volume - self.volume0) / self.volume0; // dE_V/dV
            }
        }

        if terms.wlc {
            for (i, l) in self.links.iter().enumerate() {
                let (ia, ib) = (l[0] as usize, l[1] as usize);
                let d = x[ib] - x[ia];
                let len = d.length();
                let (v, t) =
                    kernels::wlc(len, self.link_lmax[i], self.link_w[i]).ok_or_else(|| self.overstretched(i, len))?;
                let tau = self.link_tau[i];
                e.wlc += v - tau * (len - self.link_l0[i]);
                // tension t − τ = dE/dL > 0 pulls the two ends together
                let fv = d * ((t - tau) / len);
                f[ia] += fv;
                f[ib] -= fv;
            }
        }

        let do_ca = terms.c_over_a;
        let do_area = terms.area && da != 0.0;
        let do_vol = terms.volume && dv != 0.0;
        if do_ca || do_area || do_vol {
            let origin = x[0];
            let vcoef = -dv / 6.0;
            for (t, tri) in self.triangles.iter().enumerate() {
                let [ia, ib, ic] = tri.map(|v| v as usize);
                let (a, b, c) = (x[ia], x[ib], x[ic]);
                if do_ca || do_area {
                    let n = (b - a).cross(c - a);
                    let nl = n.length();
                    let area = 0.5 * nl;
                    // force = −dE/dA_α · ∂A_α/∂x, dE/dA_α = −C/A² + dE_A/dA
                    let mut coef = -da;
                    if do_ca {
                        let ca = self.tri_c[t] / area;
                        e.c_over_a += ca;
                        coef += ca / area;
                    }
                    let g = kernels::area_gradient(n / nl, a, b, c);
                    f[ia] += g[0] * coef;
                    f[ib] += g[1] * coef;
                    f[ic] += g[2] * coef;
                }
                if do_vol {
                    let (ra, rb, rc) = (a - origin, b - origin, c - origin);
                    f[ia] += rb.cross(rc) * vcoef;
                    f[ib] += rc.cross(ra) * vcoef;
                    f[ic] += ra.cross(rb) * vcoef;
                }
            }
        }

        if terms.bending && self.k_bend != 0.0 {
            for k in 0..self.dihedrals.len() {
                let (idx, cos_t, sin_t, g) = self.dihedral_at(k, x)?;
                // E = k [1 − cos(θ − θ0)], −dE/dθ = −k sin(θ − θ0) = −k (sin θ cos θ0 − cos θ sin θ0)
                e.bending += self.k_bend * (1.0 - cos_t * self.cos_theta0 - sin_t * self.sin_theta0);
                let s = -self.k_bend * (sin_t * self.cos_theta0 - cos_t * self.sin_theta0);
                for j in 0..4 {
                    f[idx[j]] += g[j] * s;
                }
            }
        }
        Ok(e)
    }

    /// Dihedral k at `x`: its vertex indices, cos θ, sin θ and ∂θ/∂(its four vertices).
    #[inline(always)]
    pub(crate) fn dihedral_at(&self, k: usize, x: &[DVec3]) -> Result<([usize; 4], f64, f64, [DVec3; 4]), ForceError> {
        let d = &self.dihedrals[k];
        let idx = d.map(|v| v as usize);
        let [a, b, c, dd] = idx.map(|v| x[v]);
        let (cos_t, sin_t, g) =
            kernels::dihedral(a, b, c, dd).ok_or(ForceError::DegenerateDihedral { pair: k, vertices: *d })?;
        Ok((idx, cos_t, sin_t, g))
    }

    /// Total area and enclosed volume of `x` (flat triangles); checks for degenerate triangles.
    /// The volume is computed about vertex 0 (exactly equal for a closed surface, and
    /// accurate for cells far from the origin).
    pub fn area_volume(&self, x: &[DVec3]) -> Result<(f64, f64), ForceError> {
        let origin = x[0];
        let (mut area, mut vol6) = (0.0, 0.0);
        for t in 0..self.triangles.len() {
            let (at, v6) = self.triangle_area_vol6(t, x, origin)?;
            area += at;
            vol6 += v6;
        }
        Ok((area, vol6 / 6.0))
    }

    /// Area of triangle `t` and 6 × the signed volume of its tetrahedron with `origin`; a
    /// triangle below its degenerate-area threshold is an error.
    #[inline]
    pub(crate) fn triangle_area_vol6(&self, t: usize, x: &[DVec3], origin: DVec3) -> Result<(f64, f64), ForceError> {
        let tri = &self.triangles[t];
        let [a, b, c] = tri.map(|v| x[v as usize] - origin);
        let at = 0.5 * (b - a).cross(c - a).length();
        if !(at > self.tri_amin[t]) {
            return Err(ForceError::DegenerateTriangle {
                triangle: t,
                vertices: *tri,
                area: at,
            });
        }
        Ok((at, a.dot(b.cross(c))))
    }

    fn overstretched(&self, i: usize, length: f64) -> ForceError {
        ForceError::LinkOverstretched {
            link: i,
            vertices: self.links[i],
            length,
            lmax: self.link_lmax[i],
        }
    }

    /// Which reference state this model was built with.
    pub fn reference(&self) -> ReferenceState {
        self.reference
    }
    /// The constants it was built from.
    pub fn constants(&self) -> &MembraneConstants {
        &self.constants
    }
    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.n_vertices
    }
    /// Links, `[a, b]` with a < b (the topology's order).
    pub fn links(&self) -> &[[u32; 2]] {
        &self.links
    }
    /// Triangles, outward-oriented.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// Link pairs `[a, b, c, d]` (triangles (a,b,c) and (d,c,b)), the links' order.
    pub fn dihedrals(&self) -> &[[u32; 4]] {
        &self.dihedrals
    }
    /// Reference area A0.
    pub fn area0(&self) -> f64 {
        self.area0
    }
    /// Reference volume V0.
    pub fn volume0(&self) -> f64 {
        self.volume0
    }
    /// Per-link reference (stress-free or uniform) lengths.
    pub fn link_rest_lengths(&self) -> &[f64] {
        &self.link_l0
    }
    /// Per-link maximum extensions Lmax_i.
    pub fn link_lmax(&self) -> &[f64] {
        &self.link_lmax
    }
    /// Per-link tension offsets τ_i (force; all 0 for the uniform reference).
    pub fn link_tension_offsets(&self) -> &[f64] {
        &self.link_tau
    }
    /// Per-link C/A tension at rest over the WLC tension at rest, T_i/f_i (all 1 for the uniform
    /// reference and for an equilateral mesh); τ_i = f_i (1 − T_i/f_i).
    pub fn link_tension_ratios(&self) -> &[f64] {
        &self.link_tension_ratio
    }
    /// Distribution of T_i/f_i over the links.
    pub fn tension_ratio_distribution(&self) -> Distribution {
        Distribution::of(&self.link_tension_ratio)
    }
    /// Distribution of the per-link rest lengths.
    pub fn rest_length_distribution(&self) -> Distribution {
        Distribution::of(&self.link_l0)
    }
    /// Per-triangle C_α.
    pub fn triangle_c(&self) -> &[f64] {
        &self.tri_c
    }
    /// Spontaneous angle θ0, radians.
    pub fn theta0(&self) -> f64 {
        self.theta0
    }
    /// Bending constant k_bend.
    pub fn k_bend(&self) -> f64 {
        self.k_bend
    }
    /// Global area constant k_a.
    pub fn k_area(&self) -> f64 {
        self.k_area
    }
    /// Global volume constant k_v.
    pub fn k_volume(&self) -> f64 {
        self.k_volume
    }
    /// Signed dihedral angles θ (radians, > 0 convex) of every link pair at `x` (allocates;
    /// for diagnostics). Degenerate pairs give NaN.
    pub fn dihedral_angles(&self, x: &[DVec3]) -> Vec<f64> {
        self.dihedrals
            .iter()
            .map(|d| {
                let [a, b, c, dd] = d.map(|v| x[v as usize]);
                kernels::dihedral_angle(a, b, c, dd).unwrap_or(f64::NAN)
            })
            .collect()
    }
    /// Largest L_i/Lmax_i at `x` and its link (how close the mesh is to a failure).
    pub fn max_extension(&self, x: &[DVec3]) -> (f64, usize) {
        let mut best = (0.0, 0);
        for (i, l) in self.links.iter().enumerate() {
            let r = (x[l[1] as usize] - x[l[0] as usize]).length() / self.link_lmax[i];
            if r > best.0 {
                best = (r, i);
            }
        }
        best
    }
}

/// Checks length and finiteness of a position array.
fn check_positions(x: &[DVec3], n: usize, what: &'static str) -> Result<(), ForceError> {
    if x.len() != n {
        return Err(ForceError::WrongLength {
            what,
            expected: n,
            got: x.len(),
        });
    }
    if let Some(v) = x.iter().position(|p| !p.is_finite()) {
        return Err(ForceError::NonFinitePosition {
            vertex: v,
            position: x[v].to_array(),
        });
    }
    Ok(())
}

/// A lookup (a, b) → link index (order-independent), built once.
fn link_lookup(topology: &Topology) -> impl Fn(u32, u32) -> usize + '_ {
    let map: std::collections::HashMap<(u32, u32), usize> = topology
        .links
        .iter()
        .enumerate()
        .map(|(i, l)| ((l[0], l[1]), i))
        .collect();
    move |a, b| map[&(a.min(b), a.max(b))]
}
