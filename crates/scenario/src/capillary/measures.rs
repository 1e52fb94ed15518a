//! The capillary measures that stand apart from the run: the cell's length over width, the
//! Hochmuth (1979) fit of a recovery and a decay time, the plasma's density on either side of
//! the cell, and the measures of every frame of a capillary trajectory (`hemodpd analyze`).

use super::*;

/// The cell's length over width in the plane across the tube (x, y; the plane of the resting
/// disc and of the stretch), as seen face on, the way Hochmuth et al. measured it: the extents
/// of the vertices along the principal axes of their (x, y) covariance, the larger over the
/// smaller (so it does not depend on how the cell has turned about the tube axis).
pub fn length_over_width(x: &[DVec3]) -> f64 {
    let n = x.len().max(1) as f64;
    let c = x.iter().fold(DVec3::ZERO, |a, p| a + *p) / n;
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    for p in x {
        let d = *p - c;
        sxx += d.x * d.x;
        syy += d.y * d.y;
        sxy += d.x * d.y;
    }
    let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let (u, w) = (
        DVec3::new(theta.cos(), theta.sin(), 0.0),
        DVec3::new(-theta.sin(), theta.cos(), 0.0),
    );
    let extent = |a: DVec3| {
        let (lo, hi) = x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.dot(a)), hi.max(p.dot(a)))
        });
        hi - lo
    };
    let (l, w) = (extent(u), extent(w));
    l.max(w) / l.min(w)
}

/// The shape a driven cell settles in, from its final-quarter means (docs/capillary.md, "The
/// measures"): `"disc"` when it is still within [`DISC_DISTANCE_UM`] of its resting shape (a
/// slow cell that kept the pose it entered with); else `"slipper"` when its centroid is off the
/// tube axis by at least [`SLIPPER_OFFSET`] of the tube radius; on the axis, `"parachute"` when
/// it is round seen along the tube (cross-section roundness ≥ [`PARACHUTE_ROUNDNESS`]) and
/// `"croissant"` (folded, two-fold rather than axisymmetric) when it is not. The names follow
/// Fedosov et al. (Soft Matter 2014) and Guckenberger et al. (Soft Matter 2018); the
/// thresholds are ours.
pub fn shape_class(axis_offset: f64, tube_radius: f64, roundness: f64, distance_from_rest_um: f64) -> &'static str {
    if !(axis_offset.is_finite() && roundness.is_finite() && distance_from_rest_um.is_finite() && tube_radius > 0.0) {
        "unknown"
    } else if distance_from_rest_um < DISC_DISTANCE_UM {
        "disc"
    } else if axis_offset >= SLIPPER_OFFSET * tube_radius {
        "slipper"
    } else if roundness >= PARACHUTE_ROUNDNESS {
        "parachute"
    } else {
        "croissant"
    }
}

/// RMS distance from the resting shape (µm) below which a driven cell is still a disc: about
/// twice the thermal roughness of the N = 500 cell at rest at f = 10.8 (0.084 µm; 0.050 at
/// f = 1); an edge-on cell at 0.2 mm/s in the 10 µm tube stays at 0.13 µm.
pub const DISC_DISTANCE_UM: f64 = 0.2;

/// Off-axis distance of the centroid, as a fraction of the tube radius, from which a cell is a
/// slipper (thermal wandering of an axisymmetric parachute stays below it: ≈ 0.02–0.06 R).
pub const SLIPPER_OFFSET: f64 = 0.1;

/// Cross-section roundness from which an on-axis cell counts as an axisymmetric parachute.
pub const PARACHUTE_ROUNDNESS: f64 = 0.9;

/// A fit of Hochmuth's Kelvin–Voigt recovery to L/W = λ(t):
/// ((λ² − λ∞²)(λ0² + λ∞²)) / ((λ² + λ∞²)(λ0² − λ∞²)) = exp(−t/t_c).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct HochmuthFit {
    /// Recovery time t_c (the unit of `t`).
    pub t_c: f64,
    /// λ0 = λ(t0), the first point.
    pub lambda_0: f64,
    /// λ∞, fitted.
    pub lambda_inf: f64,
    /// Root-mean-square residual of λ.
    pub rms: f64,
}

/// Fits Hochmuth's recovery (see [`HochmuthFit`]) to `lambda` at times `t` (from `t[0]`):
/// λ0 is the first point; t_c and λ∞ minimise Σ(λ_model − λ)², λ∞ searched over
/// [0.8, min λ] on a grid refined three times, t_c by golden section on ln t_c for each λ∞.
/// `None` with fewer than 4 points, or when λ does not fall.
pub fn fit_hochmuth(t: &[f64], lambda: &[f64]) -> Option<HochmuthFit> {
    let n = t.len().min(lambda.len());
    if n < 4 || !t[..n].iter().chain(&lambda[..n]).all(|v| v.is_finite()) {
        return None;
    }
    let l0 = lambda[0];
    let lmin = lambda[..n].iter().cloned().fold(f64::INFINITY, f64::min);
    if lmin >= l0 {
        return None;
    }
    let model = |tt: f64, tc: f64, li: f64| {
        let k = (l0 * l0 - li * li) / (l0 * l0 + li * li);
        let y = k * (-(tt - t[0]) / tc).exp();
        li * ((1.0 + y) / (1.0 - y)).sqrt()
    };
    let sse = |tc: f64, li: f64| (0..n).map(|i| (model(t[i], tc, li) - lambda[i]).powi(2)).sum::<f64>();
    let span = (t[n - 1] - t[0]).max(1e-300);
    let best_tc = |li: f64| {
        // golden section on ln t_c over [span/1e4, span·100]
        let (mut a, mut b) = ((span * 1e-4).ln(), (span * 1e2).ln());
        let g = 0.5 * (5f64.sqrt() - 1.0);
        let f = |x: f64| sse(x.exp(), li);
        let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
        let (mut fc, mut fd) = (f(c), f(d));
        for _ in 0..80 {
            if fc < fd {
                b = d;
                d = c;
                fd = fc;
                c = b - g * (b - a);
                fc = f(c);
            } else {
                a = c;
                c = d;
                fc = fd;
                d = a + g * (b - a);
                fd = f(d);
            }
        }
        let x = 0.5 * (a + b);
        (x.exp(), f(x))
    };
    let (mut lo, mut hi) = (0.8f64.min(lmin * 0.9), lmin.min(l0 * (1.0 - 1e-9)));
    let mut best = (f64::NAN, f64::NAN, f64::INFINITY);
    for _ in 0..4 {
        let m = 40;
        for k in 0..=m {
            let li = lo + (hi - lo) * k as f64 / m as f64;
            if li >= l0 {
                continue;
            }
            let (tc, e) = best_tc(li);
            if e < best.2 {
                best = (tc, li, e);
            }
        }
        let h = (hi - lo) / 40.0;
        lo = (best.1 - 2.0 * h).max(lo);
        hi = (best.1 + 2.0 * h).min(hi);
    }
    best.2.is_finite().then(|| HochmuthFit {
        t_c: best.0,
        lambda_0: l0,
        lambda_inf: best.1,
        rms: (best.2 / n as f64).sqrt(),
    })
}

/// Time constant of the decay of `y(t)` towards its final level (the mean of the last fifth):
/// the first time y − y_end falls below e⁻¹ (y(0) − y_end), linearly interpolated. NaN when it
/// does not decay.
pub fn decay_time(t: &[f64], y: &[f64]) -> f64 {
    let n = y.len();
    if n < 5 {
        return f64::NAN;
    }
    let tail = &y[n - (n / 5).max(1)..];
    let end = tail.iter().sum::<f64>() / tail.len() as f64;
    let a0 = y[0] - end;
    if a0.abs() < 1e-12 {
        return f64::NAN;
    }
    let level = a0 * (-1.0f64).exp();
    for k in 1..n {
        let (p, q) = (y[k - 1] - end, y[k] - end);
        if (q / a0) <= (level / a0) {
            let w = ((p - level) / (p - q)).clamp(0.0, 1.0);
            return t[k - 1] + w * (t[k] - t[k - 1]) - t[0];
        }
    }
    f64::NAN
}

/// The capillary measures of one trajectory frame, SI (µm for lengths), as `hemodpd analyze`
/// writes them (`capillary.csv`, the columns of the run's `cell.csv`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FrameMeasures {
    pub step: u64,
    pub time_s: f64,
    pub stage: f64,
    pub cell_velocity_m_per_s: f64,
    pub fluid_velocity_m_per_s: f64,
    pub axial_length_um: f64,
    pub max_radius_um: f64,
    pub deformation_index: f64,
    pub concavity_depth_um: f64,
    pub distance_from_rest_um: f64,
    pub area_deviation: f64,
    pub volume_deviation: f64,
    pub membrane_temperature_ratio: f64,
    pub silhouette_width_um: f64,
    pub silhouette_deformation_index: f64,
    pub symmetry_axis_tilt_deg: f64,
}

/// Computes [`FrameMeasures`] for every membrane frame of a capillary trajectory (the same
/// definitions as the run's time series: [`cellshape`], the tube along z).
pub fn analyze_trajectory(path: &std::path::Path) -> Result<Vec<FrameMeasures>, RunError> {
    use hemodpd_io::TrajectoryReader;
    let r = TrajectoryReader::open(path).map_err(out_err)?;
    let meta = r.metadata();
    if meta.scenario_name != "capillary" {
        return Err(RunError::Output(format!(
            "{}: a {} trajectory, not a capillary one",
            path.display(),
            meta.scenario_name
        )));
    }
    let units = meta.units.clone();
    let triangles = r.triangles().map_err(out_err)?;
    let reference = r.membrane_reference().map_err(out_err)?;
    let profile = RestProfile::new(&EvansFung::healthy_um(), 400);
    let scalar = |name: &str| r.membrane_scalar(name).unwrap_or_default();
    let (fluid_v, stage) = (scalar("fluid_velocity"), scalar("stage"));
    let mut out = Vec::new();
    for i in 0..r.membrane_frames().map_err(out_err)? {
        let fr = r.membrane_frame(i).map_err(out_err)?;
        let x_um: Vec<DVec3> = fr.positions.iter().map(|p| *p * 1e6).collect();
        let m = cellshape::metrics(&x_um, AXIS, &profile);
        let mesh = Mesh::new(fr.positions.clone(), triangles.clone())?;
        let (a, v) = (mesh.area(), mesh.volume());
        let (a0, v0) = reference.unwrap_or((a, v));
        let (uc, kbt) = match &fr.velocities {
            Some(vel) => {
                let n = vel.len() as f64;
                let mean = vel.iter().fold(DVec3::ZERO, |s, v| s + *v) / n;
                let kin: f64 = vel.iter().map(|v| (*v - mean).length_squared()).sum();
                // vertex mass = one model mass unit; the fluid's kBT = one model energy unit
                (mean[AXIS], units.mass_kg() * kin / (3.0 * (n - 1.0)) / units.energy_j)
            }
            None => (f64::NAN, f64::NAN),
        };
        out.push(FrameMeasures {
            step: fr.step,
            time_s: fr.time,
            stage: stage.get(i).copied().unwrap_or(f64::NAN),
            cell_velocity_m_per_s: uc,
            fluid_velocity_m_per_s: fluid_v.get(i).copied().unwrap_or(f64::NAN),
            axial_length_um: m.axial_length,
            max_radius_um: m.max_radius,
            deformation_index: m.deformation_index,
            concavity_depth_um: m.concavity_depth,
            distance_from_rest_um: m.distance_from_rest,
            area_deviation: a / a0 - 1.0,
            volume_deviation: v / v0 - 1.0,
            membrane_temperature_ratio: kbt,
            silhouette_width_um: m.silhouette_width,
            silhouette_deformation_index: m.silhouette_deformation_index,
            symmetry_axis_tilt_deg: m.symmetry_axis_tilt_deg,
        });
    }
    Ok(out)
}

/// Writes [`FrameMeasures`] as CSV.
pub fn write_measures_csv(path: &std::path::Path, rows: &[FrameMeasures]) -> Result<(), RunError> {
    let mut s = String::from("step,time_s,stage,cell_velocity_m_per_s,fluid_velocity_m_per_s,axial_length_um,max_radius_um,deformation_index,concavity_depth_um,distance_from_rest_um,area_deviation,volume_deviation,membrane_temperature_ratio,silhouette_width_um,silhouette_deformation_index,symmetry_axis_tilt_deg\n");
    for r in rows {
        s += &format!(
            "{},{:e},{},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e}\n",
            r.step,
            r.time_s,
            r.stage,
            r.cell_velocity_m_per_s,
            r.fluid_velocity_m_per_s,
            r.axial_length_um,
            r.max_radius_um,
            r.deformation_index,
            r.concavity_depth_um,
            r.distance_from_rest_um,
            r.area_deviation,
            r.volume_deviation,
            r.membrane_temperature_ratio,
            r.silhouette_width_um,
            r.silhouette_deformation_index,
            r.symmetry_axis_tilt_deg
        );
    }
    std::fs::write(path, s).map_err(|source| RunError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Near end and length of the slabs of [`density_across_cell`], rc from the cell's rear or
/// front.
const SLAB_START_RC: f64 = 2.0;
const SLAB_LENGTH_RC: f64 = 4.0;

/// Plasma number density over the fluid's in two slabs of the tube, 2–6 rc behind the cell's
/// rear and 2–6 rc ahead of its front (across the periodic end): (behind, ahead); NaN when the
/// tube is too short for them. A cell that fills the tube holds the part of the drive its
/// resistance takes as a pressure difference across it, and the DPD fluid, compressible, shows
/// it as a density difference (docs/capillary.md, "Compression across the cell"): 1 on both
/// sides for an incompressible flow.
///
/// `tube` is the tube's length and wall radius (rc) and the fluid's number density.
pub fn density_across_cell(tube: (f64, f64, f64), pos: &[DVec3], ptype: &[u16], vertices: &[DVec3]) -> (f64, f64) {
    let (l, wall_radius, density) = tube;
    let (rear, front) = vertices.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v[AXIS]), hi.max(v[AXIS]))
    });
    if front - rear + 2.0 * (SLAB_START_RC + SLAB_LENGTH_RC) > l {
        return (f64::NAN, f64::NAN);
    }
    let in_slab = |d: f64| (SLAB_START_RC..SLAB_START_RC + SLAB_LENGTH_RC).contains(&d.rem_euclid(l));
    let (mut behind, mut ahead) = (0usize, 0usize);
    for (x, &t) in pos.iter().zip(ptype) {
        if t == OUTER {
            behind += usize::from(in_slab(rear - x[AXIS]));
            ahead += usize::from(in_slab(x[AXIS] - front));
        }
    }
    let per_slab = std::f64::consts::PI * wall_radius * wall_radius * SLAB_LENGTH_RC * density;
    (behind as f64 / per_slab, ahead as f64 / per_slab)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each class at a point just inside its bounds, and the order of the tests: a barely
    /// deformed cell is a disc wherever it sits; off the axis beats roundness.
    #[test]
    fn shape_classes() {
        let r = 5.0;
        assert_eq!(shape_class(0.02 * r, r, 0.42, 0.13), "disc");
        assert_eq!(shape_class(0.3 * r, r, 0.99, 0.19), "disc");
        assert_eq!(shape_class(0.04 * r, r, 0.98, 0.6), "parachute");
        assert_eq!(shape_class(0.04 * r, r, 0.8, 0.6), "croissant");
        assert_eq!(shape_class(0.1 * r, r, 0.98, 0.6), "slipper");
        assert_eq!(shape_class(f64::NAN, r, 0.98, 0.6), "unknown");
        assert_eq!(shape_class(0.0, 0.0, 0.98, 0.6), "unknown");
    }

    /// Plasma filling the tube uniformly at the fluid's density reads 1 on both sides of the
    /// cell, also when the cell lies across the periodic end; 30 % more plasma in the slab
    /// behind reads 1.3 there; cytosol is not counted; a tube too short for the slabs gives NaN.
    #[test]
    fn density_across_cell_counts_the_plasma_beside_the_cell() {
        let (l, rw, n) = (100.0, 4.5, 3.0);
        // uniform numbers in [0, 1) from a counter (the engine's mixer)
        let mut k = 0u64;
        let mut uniform = move || {
            k += 1;
            (hemodpd_engine::rng::mix64(k) >> 11) as f64 / (1u64 << 53) as f64
        };
        let count = (std::f64::consts::PI * rw * rw * l * n) as usize;
        let mut pos: Vec<DVec3> = Vec::new();
        let in_tube = |rng: &mut dyn FnMut() -> f64, z0: f64, dz: f64| loop {
            let (x, y) = (rw * (2.0 * rng() - 1.0), rw * (2.0 * rng() - 1.0));
            if x * x + y * y < rw * rw {
                break DVec3::new(x, y, z0 + dz * rng());
            }
        };
        let rng = &mut uniform;
        for _ in 0..count {
            pos.push(in_tube(rng, 0.0, l));
        }
        let mut ptype = vec![OUTER; pos.len()];
        // cytosol is not plasma
        pos.extend((0..5000).map(|_| in_tube(rng, 0.0, l)));
        ptype.resize(pos.len(), INNER);
        // the sampling error of one slab (≈ 760 particles) is ≈ 3.6 %
        for cell in [[40.0, 52.0], [95.0, 107.0]] {
            let v: Vec<DVec3> = cell.iter().map(|&z| DVec3::new(0.0, 0.0, z)).collect();
            let (b, a) = density_across_cell((l, rw, n), &pos, &ptype, &v);
            assert!((b - 1.0).abs() < 0.12 && (a - 1.0).abs() < 0.12, "{cell:?}: {b} {a}");
        }
        let v = [DVec3::new(0.0, 0.0, 40.0), DVec3::new(0.0, 0.0, 52.0)];
        let (b0, a0) = density_across_cell((l, rw, n), &pos, &ptype, &v);
        let extra = (0.3 * std::f64::consts::PI * rw * rw * SLAB_LENGTH_RC * n) as usize;
        for _ in 0..extra {
            pos.push(in_tube(rng, 40.0 - SLAB_START_RC - SLAB_LENGTH_RC, SLAB_LENGTH_RC));
            ptype.push(OUTER);
        }
        let (b, a) = density_across_cell((l, rw, n), &pos, &ptype, &v);
        assert!((b - b0 - 0.3).abs() < 0.01 && a == a0, "{b0} → {b}, {a0} → {a}");
        let long = [DVec3::new(0.0, 0.0, 0.0), DVec3::new(0.0, 0.0, 90.0)];
        assert!(density_across_cell((l, rw, n), &pos, &ptype, &long).0.is_nan());
    }
}
