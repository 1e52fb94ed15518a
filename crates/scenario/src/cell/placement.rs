//! Placing a cell in a tube: the orientation it enters with and, where the tube is narrower
//! than the resting cell, the membrane pressed into it before any fluid exists
//! ([`hemodpd_membrane::confine`]). The fluid is then cut by the pressed shape, so the cytosol
//! starts at the fluid's density and no particle starts on the wrong side (docs/capillary.md,
//! "Narrow tubes").

use crate::context::RunError;
use glam::{DQuat, DVec3};
use hemodpd_membrane::confine::{self, ConfineOptions};
use hemodpd_membrane::MembraneModel;
use serde::{Deserialize, Serialize};
use serde_json::json;

/// How the resting cell faces the tube's axis as it enters (`tube.cell_orientation`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum CellOrientation {
    /// The axis is the cell's symmetry axis: the flow meets the cell's face (the paper's start).
    #[default]
    FaceOn,
    /// The axis lies in the cell's plane: the flow meets the cell's rim.
    EdgeOn,
    /// A rotation drawn uniformly from the seed (the same seed, the same rotation).
    Random,
}

impl CellOrientation {
    /// True for the default (it is then not written back into a scenario).
    pub fn is_face_on(&self) -> bool {
        *self == CellOrientation::FaceOn
    }

    /// The map taking a point of the generated mesh (symmetry axis y) to this orientation
    /// about a tube whose axis is z; face-on and edge-on exactly (a permutation, no round-off),
    /// random by the seed's rotation, drawn once.
    pub fn turn(&self, seed: u64) -> impl Fn(DVec3) -> DVec3 {
        let (o, q) = (*self, self.rotation(seed));
        move |v| match o {
            CellOrientation::FaceOn => DVec3::new(v.x, -v.z, v.y),
            CellOrientation::EdgeOn => v,
            CellOrientation::Random => q * v,
        }
    }

    /// The rotation taking the generated mesh (symmetry axis y) to this orientation about a
    /// tube whose axis is z.
    pub fn rotation(&self, seed: u64) -> DQuat {
        match self {
            // (x, y, z) → (x, −z, y): the symmetry axis onto z
            CellOrientation::FaceOn => DQuat::from_rotation_x(std::f64::consts::FRAC_PI_2),
            CellOrientation::EdgeOn => DQuat::IDENTITY,
            CellOrientation::Random => {
                // Shoemake's uniform rotation from three uniform numbers of the seed
                let mut z = seed ^ 0x6f72_6965_6e74_6174;
                let mut u = || {
                    z = hemodpd_engine::rng::mix64(z.wrapping_add(0x9E37_79B9_7F4A_7C15));
                    ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
                };
                let (u1, u2, u3) = (u(), u(), u());
                let tau = std::f64::consts::TAU;
                let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
                DQuat::from_xyzw(
                    a * (tau * u2).sin(),
                    a * (tau * u2).cos(),
                    b * (tau * u3).sin(),
                    b * (tau * u3).cos(),
                )
                .normalize()
            }
        }
    }
}

/// Clearance, rc, kept between a pressed cell and the wall's repulsion zone.
pub const CLEARANCE_RC: f64 = 0.25;

/// The narrowest radius a closed surface of `area` and `volume` can pass: the capsule
/// (cylinder with hemispherical caps) of that area and volume, V = rA/2 − 2πr³/3, its smaller
/// root (any length unit).
pub fn capsule_radius(area: f64, volume: f64) -> f64 {
    let f = |r: f64| r * area / 2.0 - 2.0 / 3.0 * std::f64::consts::PI * r.powi(3) - volume;
    // f rises from −V at r = 0 to its top at r* = √(A/4π) (the sphere's radius when f(r*) = 0)
    let top = (area / (4.0 * std::f64::consts::PI)).sqrt();
    if f(top) < -1e-12 * volume {
        return f64::NAN;
    }
    let (mut lo, mut hi) = (0.0, top);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if f(mid) < 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Margin over the capsule radius a pressed cell is allowed: at 1.15 the N = 500 cell folds
/// into the tube with its area and volume within 0.5 % (tests in `hemodpd_membrane::confine`).
pub const CAPSULE_MARGIN: f64 = 1.15;

/// Presses `start` (the resting cell, oriented and centred on the axis through `centre` along
/// z) into radius `radius` when it is wider, and says what was done (for `summary.json`).
pub(crate) fn press_into_tube(
    model: &MembraneModel,
    start: &[DVec3],
    centre: [f64; 2],
    radius: f64,
) -> Result<(Vec<DVec3>, serde_json::Value), RunError> {
    let c = model.constants();
    let widest = confine::widest(start, centre);
    let opts = ConfineOptions {
        centre,
        radius,
        radius_step: 0.05 * widest,
        // k_a is ≈ 240 μ0 by default: a wall of ≈ 6 μ0, a tolerance of ≈ 0.01 pN at N = 500
        stiffness: c.k_area / 40.0,
        tolerance: 1e-5 * c.k_area * c.l0,
        max_iterations: 500,
    };
    let t = std::time::Instant::now();
    let r = confine::confine(model, start, &opts).map_err(|e| {
        let hint = match e {
            confine::ConfineError::SelfIntersecting { .. } => {
                "; the tube (tube.diameter_um) is too narrow for the cell at this mesh (cell.vertices): a finer mesh or a wider tube"
            }
            _ => "",
        };
        RunError::Output(format!("placing the cell: {e}{hint}"))
    })?;
    if r.area_deviation.abs() > 0.01 || r.volume_deviation.abs() > 0.01 {
        return Err(RunError::Output(format!(
            "placing the cell: pressed into radius {radius:.3} rc it keeps its area within {:.2} % and its volume within {:.2} %, more than 1 %: the tube is too narrow for this cell (tube.diameter_um) or the resolution too coarse (model.length_um_per_rc)",
            100.0 * r.area_deviation.abs(),
            100.0 * r.volume_deviation.abs()
        )));
    }
    let info = json!({
        "pressed": r.stages > 0,
        "radius_rc": radius,
        "widest_at_rest_rc": r.widest_start,
        "widest_rc": r.widest,
        "axial_length_rc": r.axial_length,
        "stages": r.stages,
        "iterations": r.iterations,
        "residual_force": r.residual,
        "area_deviation": r.area_deviation,
        "volume_deviation": r.volume_deviation,
        "closest_self_contact": r.closest_contact,
        "seconds": t.elapsed().as_secs_f64(),
    });
    Ok((r.positions, info))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn capsule_radius_of_a_sphere_and_of_the_cell() {
        // a sphere is its own capsule (length 0)
        let r = 2.0f64;
        let (a, v) = (
            4.0 * std::f64::consts::PI * r * r,
            4.0 / 3.0 * std::f64::consts::PI * r.powi(3),
        );
        assert!((capsule_radius(a, v) - r).abs() < 1e-6, "{}", capsule_radius(a, v));
        // the Evans–Fung cell (134.1 µm², 94.1 µm³): ≈ 1.51 µm, the ≈ 3 µm critical tube
        let rc = capsule_radius(134.1, 94.1);
        assert!((rc - 1.51).abs() < 0.01, "{rc}");
        // a volume no surface of that area holds
        assert!(capsule_radius(10.0, 100.0).is_nan());
    }

    #[test]
    fn orientations_put_the_symmetry_axis_where_they_say() {
        let y = DVec3::Y;
        assert!((CellOrientation::FaceOn.rotation(1) * y - DVec3::Z).length() < 1e-12);
        assert_eq!(CellOrientation::EdgeOn.rotation(1) * y, y);
        let (a, b) = (CellOrientation::Random.rotation(1), CellOrientation::Random.rotation(2));
        assert_eq!(a, CellOrientation::Random.rotation(1));
        assert!((a * y - b * y).length() > 1e-3);
        assert!((a.length() - 1.0).abs() < 1e-12);
        for o in [
            CellOrientation::FaceOn,
            CellOrientation::EdgeOn,
            CellOrientation::Random,
        ] {
            let v = DVec3::new(0.3, -1.2, 2.1);
            assert!((o.turn(7)(v) - o.rotation(7) * v).length() < 1e-12);
        }
    }
}
