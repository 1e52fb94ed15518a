//! Model parameters in SI: the fine model of the paper and its coarse-graining to any N
//! (Pivkin & Karniadakis 2008, Eqs. 4 and 8–12).

use serde::Serialize;

/// Boltzmann constant, J/K (exact, SI 2019).
pub const BOLTZMANN_J_PER_K: f64 = 1.380649e-23;

/// The fine model (N = 23867, one vertex per spectrin junction complex).
pub mod fine {
    /// Number of vertices.
    pub const N: usize = 23867;
    /// Mean link length, m.
    pub const L0_M: f64 = 75e-9;
    /// Persistence length, m.
    pub const P_M: f64 = 7.5e-9;
    /// Spontaneous angle, degrees.
    pub const THETA0_DEG: f64 = 1.0;
    /// Bending constant in units of kBT.
    pub const K_BEND_KBT: f64 = 200.0;
    /// Maximum link extension over L0 (the same at every level of coarse-graining).
    pub const LMAX_OVER_L0: f64 = 3.17;
}

/// Smallest number of vertices we coarse-grain to (the paper: N > 100 is needed for accuracy).
pub const MIN_VERTICES: usize = 100;

/// Parameters of one level of coarse-graining, all in SI.
///
/// Invariants: `lmax_m = LMAX_OVER_L0 · l0_m` unless [`ModelParams::with_max_extension`] sets
/// another ratio; μ0 and K are the same at every N (Eq. 12).
#[derive(Clone, Debug, Serialize)]
pub struct ModelParams {
    /// Number of vertices.
    pub n: usize,
    /// Temperature, K.
    pub temperature_k: f64,
    /// Thermal energy kBT, J.
    pub kbt_j: f64,
    /// Equilibrium link length L0 (Eq. 8), m.
    pub l0_m: f64,
    /// Maximum link extension Lmax, m.
    pub lmax_m: f64,
    /// Persistence length p (Eq. 12), m.
    pub persistence_length_m: f64,
    /// C of the C/A term (Eq. 4), J·m².
    pub c_j_m2: f64,
    /// Spontaneous angle θ0 (Eq. 9), degrees.
    pub theta0_deg: f64,
    /// Bending constant k_bend, J (200 kBT at every N).
    pub k_bend_j: f64,
    /// Shear modulus μ0 (Eq. 10), N/m.
    pub shear_modulus_n_per_m: f64,
    /// Area-compression modulus K (Eq. 11), N/m.
    pub area_modulus_n_per_m: f64,
    /// Young's modulus Y = 4Kμ0/(K + μ0), N/m.
    pub young_modulus_n_per_m: f64,
}

/// Error for parameters outside their domain.
#[derive(Debug, thiserror::Error)]
pub enum ParamsError {
    #[error("n = {0} vertices is too few: the coarse-grained model needs n >= {MIN_VERTICES}")]
    TooFewVertices(usize),
    #[error("{name} = {value} is outside its allowed range ({allowed})")]
    OutOfRange {
        name: &'static str,
        value: f64,
        allowed: &'static str,
    },
}

/// C of Eq. (4): the value that makes an equilateral triangle of side L0 stress-free.
pub fn c_eq4(kbt: f64, lmax: f64, p: f64, x0: f64) -> f64 {
    3.0 * 3f64.sqrt() * kbt * lmax.powi(3) * x0.powi(4) / (64.0 * p) * (4.0 * x0 * x0 - 9.0 * x0 + 6.0)
        / (1.0 - x0).powi(2)
}

/// Shear modulus μ0 of Eq. (10).
pub fn shear_modulus_eq10(kbt: f64, lmax: f64, p: f64, x0: f64) -> f64 {
    3f64.sqrt() * kbt / (4.0 * p * lmax * x0)
        * (3.0 / (4.0 * (1.0 - x0).powi(2)) - 0.75 + 4.0 * x0 + x0 / (2.0 * (1.0 - x0).powi(3)))
}

/// Area-compression modulus K of Eq. (11).
pub fn area_modulus_eq11(kbt: f64, lmax: f64, p: f64, x0: f64) -> f64 {
    3f64.sqrt() * kbt / (4.0 * p * lmax * (1.0 - x0).powi(2))
        * (1.5 * (6.0 - 9.0 * x0 + 4.0 * x0 * x0) + (1.0 + 2.0 * (1.0 - x0).powi(3)) / (1.0 - x0))
}

impl ModelParams {
    /// The model coarse-grained to `n` vertices at temperature `temperature_k`, with the
    /// persistence length from Eq. (12).
    pub fn coarse_grained(n: usize, temperature_k: f64) -> Result<Self, ParamsError> {
        Self::with_persistence_scale(n, temperature_k, 1.0)
    }

    /// As [`coarse_grained`](Self::coarse_grained) with p multiplied by `p_scale`
    /// (the paper's ±10 % sensitivity study).
    pub fn with_persistence_scale(n: usize, temperature_k: f64, p_scale: f64) -> Result<Self, ParamsError> {
        if n < MIN_VERTICES {
            return Err(ParamsError::TooFewVertices(n));
        }
        if !(temperature_k > 0.0 && temperature_k < 1000.0) {
            return Err(ParamsError::OutOfRange {
                name: "temperature_k",
                value: temperature_k,
                allowed: "0 < T < 1000 K",
            });
        }
        if !(p_scale > 0.0 && p_scale.is_finite()) {
            return Err(ParamsError::OutOfRange {
                name: "persistence scale",
                value: p_scale,
                allowed: "> 0",
            });
        }
        let ratio = (fine::N as f64 / n as f64).sqrt(); // L0c / L0f, Eq. 8
        let l0 = fine::L0_M * ratio;
        let p = fine::P_M / ratio * p_scale; // Eq. 12
        Ok(Self::from_parts(
            n,
            temperature_k,
            l0,
            p,
            fine::THETA0_DEG * ratio,
            fine::LMAX_OVER_L0,
        ))
    }

    /// The same level with the links' maximum extension Lmax = `lmax_over_l0`·L0 instead of the
    /// paper's 3.17 (x0 = 1/`lmax_over_l0`): C (Eq. 4), μ0 and K (Eqs. 10, 11) follow it at the
    /// same persistence length. A smaller ratio stiffens the links sooner as they stretch.
    pub fn with_max_extension(self, lmax_over_l0: f64) -> Result<Self, ParamsError> {
        if !(lmax_over_l0 > 1.0 && lmax_over_l0.is_finite()) {
            return Err(ParamsError::OutOfRange {
                name: "Lmax / L0",
                value: lmax_over_l0,
                allowed: "> 1",
            });
        }
        Ok(Self::from_parts(
            self.n,
            self.temperature_k,
            self.l0_m,
            self.persistence_length_m,
            self.theta0_deg,
            lmax_over_l0,
        ))
    }

    /// Parameters with an explicit persistence length (e.g. the fine p = 7.5 nm at N = 500,
    /// which the paper shows to be wrong).
    pub fn with_persistence_length(n: usize, temperature_k: f64, p_m: f64) -> Result<Self, ParamsError> {
        let base = Self::coarse_grained(n, temperature_k)?;
        if !(p_m > 0.0 && p_m.is_finite()) {
            return Err(ParamsError::OutOfRange {
                name: "persistence_length_m",
                value: p_m,
                allowed: "> 0",
            });
        }
        Ok(Self::from_parts(
            n,
            temperature_k,
            base.l0_m,
            p_m,
            base.theta0_deg,
            fine::LMAX_OVER_L0,
        ))
    }

    fn from_parts(n: usize, temperature_k: f64, l0: f64, p: f64, theta0_deg: f64, lmax_over_l0: f64) -> Self {
        let kbt = BOLTZMANN_J_PER_K * temperature_k;
        let lmax = lmax_over_l0 * l0;
        let x0 = l0 / lmax;
        let mu0 = shear_modulus_eq10(kbt, lmax, p, x0);
        let k = area_modulus_eq11(kbt, lmax, p, x0);
        Self {
            n,
            temperature_k,
            kbt_j: kbt,
            l0_m: l0,
            lmax_m: lmax,
            persistence_length_m: p,
            c_j_m2: c_eq4(kbt, lmax, p, x0),
            theta0_deg,
            k_bend_j: fine::K_BEND_KBT * kbt,
            shear_modulus_n_per_m: mu0,
            area_modulus_n_per_m: k,
            young_modulus_n_per_m: 4.0 * k * mu0 / (k + mu0),
        }
    }

    /// x0 = L0 / Lmax.
    pub fn x0(&self) -> f64 {
        self.l0_m / self.lmax_m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Table I of the paper, which prints 3 significant figures and truncates in places:
    /// we require agreement to ±1 in the last printed digit.
    #[test]
    fn matches_table_one() {
        // (N, L0 m, p m, theta0 deg, decimal unit of the last printed digit for L0, p, theta0)
        let table = [
            (23867, 7.50e-8, 7.50e-9, 1.00, 1e-10, 1e-11, 0.01),
            (5000, 1.63e-7, 3.43e-9, 2.18, 1e-9, 1e-11, 0.01),
            (500, 5.18e-7, 1.08e-9, 6.90, 1e-9, 1e-11, 0.01),
            (100, 1.15e-6, 4.85e-10, 15.44, 1e-8, 1e-12, 0.01),
        ];
        for (n, l0, p, th, dl, dp, dth) in table {
            let m = ModelParams::coarse_grained(n, 300.0).unwrap();
            assert!((m.l0_m - l0).abs() <= dl * 1.0001, "N={n}: L0 {} vs {}", m.l0_m, l0);
            assert!(
                (m.persistence_length_m - p).abs() <= dp * 1.0001,
                "N={n}: p {} vs {}",
                m.persistence_length_m,
                p
            );
            assert!(
                (m.theta0_deg - th).abs() <= dth * 1.0001,
                "N={n}: theta0 {} vs {}",
                m.theta0_deg,
                th
            );
            assert!((m.lmax_m / m.l0_m - 3.17).abs() < 1e-12);
        }
    }

    /// C from Eq. 4 for the fine model, and Table I's value which is ~4x larger (see docs/model.md).
    #[test]
    fn c_from_eq4_and_the_table_discrepancy() {
        let m = ModelParams::coarse_grained(23867, 300.0).unwrap();
        assert!((m.c_j_m2 / 4.532e-35 - 1.0).abs() < 1e-3, "C = {}", m.c_j_m2);
        let table_c = 1.81e-34;
        assert!((table_c / m.c_j_m2 - 4.0).abs() < 0.01 * 4.0);
    }

    /// Eq. 4 makes an equilateral triangle of side L0 force-free: 1.5 links per triangle,
    /// (3/2) f_WLC(L0) = -(d/dL)(C/A) at L0 with A = √3 L²/4.
    #[test]
    fn eq4_balances_an_equilateral_triangle() {
        let m = ModelParams::coarse_grained(500, 300.0).unwrap();
        let (kbt, lmax, p, l0) = (m.kbt_j, m.lmax_m, m.persistence_length_m, m.l0_m);
        let x = l0 / lmax;
        let f_wlc = kbt / p * (0.25 / (1.0 - x).powi(2) - 0.25 + x);
        let f_ca = 8.0 * m.c_j_m2 / (3f64.sqrt() * l0.powi(3));
        assert!((1.5 * f_wlc / f_ca - 1.0).abs() < 1e-12);
    }

    /// μ0 and K do not depend on N (Eq. 12), K = 2μ0 and Y = 8μ0/3 at x0 = 1/3.17.
    #[test]
    fn moduli_are_invariant() {
        let f = ModelParams::coarse_grained(23867, 300.0).unwrap();
        assert!((f.shear_modulus_n_per_m / 8.3030e-6 - 1.0).abs() < 1e-4);
        assert!((f.area_modulus_n_per_m / 1.6606e-5 - 1.0).abs() < 1e-4);
        assert!((f.young_modulus_n_per_m / 2.2141e-5 - 1.0).abs() < 1e-4);
        for n in [100, 500, 5000] {
            let c = ModelParams::coarse_grained(n, 300.0).unwrap();
            assert!((c.shear_modulus_n_per_m / f.shear_modulus_n_per_m - 1.0).abs() < 1e-12);
            assert!((c.area_modulus_n_per_m / f.area_modulus_n_per_m - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn rejects_bad_input() {
        assert!(matches!(
            ModelParams::coarse_grained(99, 300.0),
            Err(ParamsError::TooFewVertices(99))
        ));
        assert!(ModelParams::coarse_grained(500, -1.0).is_err());
        assert!(ModelParams::coarse_grained(500, f64::NAN).is_err());
        assert!(ModelParams::with_persistence_length(500, 300.0, 0.0).is_err());
    }
}
