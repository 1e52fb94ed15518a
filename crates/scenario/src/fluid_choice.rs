//! Choosing the DPD fluid of a cell-in-flow run (`model.fluid`, docs/units.md "Choosing the
//! fluid"): a fluid of [`FluidModel::table`] by name, or the one that meets the thermal choice
//! and the Mach and Reynolds bounds at the least cost; what `--explain-units` and summary.json
//! say of it.

use std::fmt::Write as _;

use crate::units::{groups_model, FluidModel, PhysicalSystem, ThermalChoice, UnitMapping, UnitsError, REYNOLDS_LIMIT};
use hemodpd_engine::params;

/// Which fluid a scenario runs with (`model.fluid`).
#[derive(Debug, Clone, PartialEq)]
pub enum FluidChoice {
    /// A fluid of [`FluidModel::table`] by name.
    Named(String),
    /// The fluid of the table that meets the thermal choice and the bounds at the least cost
    /// ([`choose_fluid`]).
    Auto,
}

/// How one fluid of the table fared in [`choose_fluid`].
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// The fluid's name.
    pub name: &'static str,
    /// Its thermal factor, Mach and Reynolds numbers and cost, or why it was ruled out.
    pub outcome: Result<CandidateFit, String>,
}

/// A fluid that meets the bounds: what it gives and what it costs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CandidateFit {
    /// f = E/(kB T).
    pub thermal_factor: f64,
    /// Mach number at the characteristic velocity.
    pub mach: f64,
    /// Reynolds number ρUL/η.
    pub reynolds: f64,
    /// Time step, model units ([`FluidModel::default_timestep`]).
    pub timestep: f64,
    /// Estimated CPU time on 2 threads of the reference machine for one physical millisecond
    /// of 1000 µm³ of this fluid, s: particles n·V/r³ times steps 1 ms/(τΔt) over the fluid's
    /// measured throughput.
    pub cost_s_per_ms_per_1000_um3: f64,
}

/// The fluid a scenario runs with, its unit mapping and why it was chosen.
#[derive(Debug, Clone, PartialEq)]
pub struct FluidDecision {
    pub fluid: FluidModel,
    pub map: UnitMapping,
    /// Every fluid considered (one for a named fluid).
    pub candidates: Vec<Candidate>,
    /// One sentence: why this fluid.
    pub reason: String,
    /// The cytosol's viscosity ratio λ (its γ: [`FluidModel::inner_gamma`]).
    pub viscosity_ratio: f64,
}

/// Estimated CPU seconds (2 threads) per physical ms of 1000 µm³ of `fluid` under `map` at the
/// model time step `dt` ([`CandidateFit::cost_s_per_ms_per_1000_um3`]).
pub fn fluid_cost(fluid: &FluidModel, map: &UnitMapping, dt: f64) -> f64 {
    let particles = fluid.density * 1e-15 / map.length_m.powi(3);
    let steps = 1e-3 / (map.time_s * dt);
    particles * steps / fluid.particle_steps_per_s
}

/// Chooses the fluid and the unit mapping of `sys` at `length_m_per_rc`.
///
/// A named fluid gets [`UnitMapping::choose`] as it is. "auto" tries every fluid of
/// [`FluidModel::table`] under `thermal` and keeps those whose mapping exists with Mach ≤
/// `max_mach` (for every thermal choice, not only "auto") and Reynolds ≤ `max_reynolds`; of
/// those, under [`ThermalChoice::Auto`] the one with the least thermal factor (the most
/// faithful membrane temperature; ties within 1 % go to the cheaper), otherwise the cheapest
/// ([`fluid_cost`]). Errors: an unknown name (key `fluid`), `max_reynolds` outside (0,
/// [`REYNOLDS_LIMIT`]], no fluid meeting the bounds (every fluid's reason in the message), and
/// the errors of [`UnitMapping::choose`].
pub fn choose_fluid(
    sys: &PhysicalSystem,
    length_m_per_rc: f64,
    thermal: ThermalChoice,
    choice: &FluidChoice,
    max_mach: f64,
    max_reynolds: f64,
) -> Result<FluidDecision, UnitsError> {
    let fit = |fluid: &FluidModel, map: &UnitMapping| {
        let g = groups_model(sys, map, fluid);
        let dt = fluid.default_timestep(sys, map);
        CandidateFit {
            thermal_factor: map.thermal_factor,
            mach: g.mach,
            reynolds: g.reynolds,
            timestep: dt,
            cost_s_per_ms_per_1000_um3: fluid_cost(fluid, map, dt),
        }
    };
    match choice {
        FluidChoice::Named(name) => {
            let fluid = FluidModel::by_name(name).ok_or_else(|| UnitsError::UnknownFluid {
                name: name.clone(),
                allowed: FluidModel::names().join(", "),
            })?;
            let map = UnitMapping::choose(sys, &fluid, length_m_per_rc, thermal)?;
            let c = fit(&fluid, &map);
            Ok(FluidDecision {
                candidates: vec![Candidate {
                    name: fluid.name,
                    outcome: Ok(c),
                }],
                reason: format!("named by model.fluid = \"{}\"", fluid.name),
                viscosity_ratio: sys.viscosity_ratio,
                fluid,
                map,
            })
        }
        FluidChoice::Auto => {
            if !(max_reynolds.is_finite() && max_reynolds > 0.0 && max_reynolds <= REYNOLDS_LIMIT) {
                return Err(UnitsError::OutOfRange {
                    key: "max_reynolds",
                    value: max_reynolds,
                    allowed: format!("must be in (0, {REYNOLDS_LIMIT}]"),
                });
            }
            let mut candidates = Vec::new();
            let mut feasible: Vec<(FluidModel, UnitMapping, CandidateFit)> = Vec::new();
            for fluid in FluidModel::table() {
                let outcome = match UnitMapping::choose(sys, &fluid, length_m_per_rc, thermal) {
                    Err(e) => Err(e.to_string()),
                    Ok(map) => {
                        let c = fit(&fluid, &map);
                        if c.mach > max_mach * (1.0 + 1e-12) {
                            Err(format!(
                                "Mach {:.3} at f = {:.3} exceeds max_mach = {max_mach}",
                                c.mach, c.thermal_factor
                            ))
                        } else if c.reynolds > max_reynolds {
                            Err(format!(
                                "Reynolds {:.3} at f = {:.3} exceeds max_reynolds = {max_reynolds}",
                                c.reynolds, c.thermal_factor
                            ))
                        } else {
                            feasible.push((fluid.clone(), map, c));
                            Ok(c)
                        }
                    }
                };
                candidates.push(Candidate {
                    name: fluid.name,
                    outcome,
                });
            }
            let by_thermal = matches!(thermal, ThermalChoice::Auto { .. });
            let best = feasible
                .iter()
                .min_by(|(_, _, a), (_, _, b)| {
                    let f_differs = (a.thermal_factor / b.thermal_factor - 1.0).abs() > 0.01;
                    if by_thermal && f_differs {
                        a.thermal_factor.total_cmp(&b.thermal_factor)
                    } else {
                        a.cost_s_per_ms_per_1000_um3.total_cmp(&b.cost_s_per_ms_per_1000_um3)
                    }
                })
                .cloned();
            let Some((fluid, map, c)) = best else {
                let why: Vec<String> = candidates
                    .iter()
                    .map(|c| format!("{}: {}", c.name, c.outcome.as_ref().err().cloned().unwrap_or_default()))
                    .collect();
                return Err(UnitsError::NoFluid {
                    reasons: why.join("; "),
                });
            };
            let reason = if feasible.len() == 1 {
                format!("the only fluid of the table that meets the bounds (Mach ≤ {max_mach}, Re ≤ {max_reynolds})")
            } else if by_thermal {
                format!(
                    "of the {} fluids that meet the bounds (Mach ≤ {max_mach}, Re ≤ {max_reynolds}), the one with the least thermal factor (f = {:.3}), then the least cost",
                    feasible.len(),
                    c.thermal_factor
                )
            } else {
                format!(
                    "of the {} fluids that meet the bounds (Mach ≤ {max_mach}, Re ≤ {max_reynolds}) at f = {:.3}, the cheapest",
                    feasible.len(),
                    c.thermal_factor
                )
            };
            Ok(FluidDecision {
                fluid,
                map,
                candidates,
                reason,
                viscosity_ratio: sys.viscosity_ratio,
            })
        }
    }
}

/// The fluid of a run for summary.json: its name, pair parameters, density and measured
/// properties (model units), and the run's time step.
pub fn fluid_json(f: &FluidModel, timestep: f64) -> serde_json::Value {
    serde_json::json!({
        "name": f.name, "density": f.density, "a": f.pair.a, "gamma": f.pair.gamma,
        "weight_exponent": f.pair.s, "kbt": f.pair.kbt, "viscosity": f.viscosity,
        "viscosity_se": f.viscosity_se, "sound_speed": f.sound_speed, "wall_slip": f.wall_slip,
        "fluid_timestep": f.timestep, "timestep": timestep,
    })
}

/// The `--explain-units` block on the fluid: the chosen fluid's parameters and measured
/// properties, every candidate with its outcome, and why.
pub fn explain_fluid(d: &FluidDecision) -> String {
    let f = &d.fluid;
    let p = f.pair;
    let mut s = String::new();
    let _ = writeln!(s, "Fluid: \"{}\" ({})", f.name, d.reason);
    let _ = writeln!(
        s,
        "    pair: n = {}, a = {}, γ = {}, kBT = {}, rc = {}, weight exponent s = {} (w^D exponent {}), particle mass {}",
        f.density,
        p.a,
        p.gamma,
        p.kbt,
        p.rc,
        p.s,
        2.0 * p.s,
        f.mass
    );
    let _ = writeln!(
        s,
        "    measured: η = {} ± {} (kinetic theory {:.3}), sound speed c = {:.3}, Δt = {} (kBT at rest {:.4}), wall slip {} rc, {:.2e} particle-steps/s on 2 threads",
        f.viscosity,
        f.viscosity_se,
        params::kinetic_theory_viscosity(&p, f.density, f.mass),
        f.sound_speed,
        f.timestep,
        f.kbt_at_timestep,
        f.wall_slip,
        f.particle_steps_per_s
    );
    let _ = writeln!(
        s,
        "    cytosol: γ = {:.3} for λ = {:.4} ({})",
        f.inner_gamma(d.viscosity_ratio),
        d.viscosity_ratio,
        if f.viscosity_by_gamma.is_empty() {
            "λγ: this fluid's η is proportional to γ"
        } else {
            "read off the fluid's measured η(γ), which grows as γ^0.94, not λγ"
        }
    );
    let _ = writeln!(s, "    re-measured by: {}", f.measured_by);
    let _ = writeln!(
        s,
        "    candidates (f, Mach, Re, Δt, CPU s per physical ms of 1000 µm³ on 2 threads):"
    );
    for c in &d.candidates {
        match &c.outcome {
            Ok(x) => {
                let _ = writeln!(
                    s,
                    "      {:<10} f = {:.3}, Ma = {:.3}, Re = {:.3}, Δt = {:.4}, cost {:.3} s{}",
                    c.name,
                    x.thermal_factor,
                    x.mach,
                    x.reynolds,
                    x.timestep,
                    x.cost_s_per_ms_per_1000_um3,
                    if c.name == f.name { "  ← chosen" } else { "" }
                );
            }
            Err(e) => {
                let _ = writeln!(s, "      {:<10} ruled out: {e}", c.name);
            }
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::units::{fsi_friction, groups_si, MACH_LIMIT, REYNOLDS_WARN};

    fn rel(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs()
    }

    /// The fluid chooser at the worked default (10 µm, 1 mm/s, 1 µm per rc): under thermal
    /// "auto" it takes the dense fluid at f = 1 (the capillary fluid needs f ≈ 10.8); at a
    /// given f both fluids meet the bounds and the cheaper (capillary) wins; "exact" rules the
    /// capillary fluid out by its Mach number. The chosen mapping's groups equal the SI ones
    /// (κ/kBT to the factor f), and a named fluid is taken as named.
    #[test]
    fn units_fluid_chooser() {
        let sys = PhysicalSystem::capillary_default();
        let auto = |thermal| choose_fluid(&sys, 1e-6, thermal, &FluidChoice::Auto, MACH_LIMIT, REYNOLDS_WARN).unwrap();
        let d = auto(ThermalChoice::default());
        assert_eq!(d.fluid.name, "dense", "{}", explain_fluid(&d));
        assert_eq!(d.map.thermal_factor, 1.0);
        let (a, b) = (groups_si(&sys), groups_model(&sys, &d.map, &d.fluid));
        assert!(rel(b.kappa_over_kbt, a.kappa_over_kbt) < 1e-12);
        assert!(rel(b.capillary_number, a.capillary_number) < 1e-12);
        assert!(b.mach < 0.15 && b.reynolds < REYNOLDS_WARN, "{b:?}");
        // the capillary fluid at its f ≈ 10.8 runs at Re 1.13: over the default bound of 1
        let cap = d.candidates.iter().find(|c| c.name == "capillary").unwrap();
        assert!(cap.outcome.as_ref().unwrap_err().contains("Reynolds 1.13"), "{cap:?}");
        let auto = |thermal| choose_fluid(&sys, 1e-6, thermal, &FluidChoice::Auto, MACH_LIMIT, 2.0).unwrap();
        let d = auto(ThermalChoice::default());
        assert_eq!(d.fluid.name, "dense", "{}", explain_fluid(&d));
        let cap = d.candidates.iter().find(|c| c.name == "capillary").unwrap();
        let cf = cap.outcome.as_ref().unwrap();
        assert!((cf.thermal_factor - 10.84).abs() < 0.05, "{cf:?}");
        // a given f (Re ≤ 2): both meet the bounds; the capillary fluid is cheaper
        let d = auto(ThermalChoice::Factor(11.0));
        assert_eq!(d.fluid.name, "capillary", "{}", explain_fluid(&d));
        assert!(d.candidates.iter().all(|c| c.outcome.is_ok()));
        let costs: Vec<f64> = d
            .candidates
            .iter()
            .map(|c| c.outcome.as_ref().unwrap().cost_s_per_ms_per_1000_um3)
            .collect();
        assert!(costs[0] < costs[1], "{costs:?}");
        // exact: the capillary fluid would run at Mach ≈ 2.7
        let d = auto(ThermalChoice::Exact);
        assert_eq!(d.fluid.name, "dense");
        let cap = d.candidates.iter().find(|c| c.name == "capillary").unwrap();
        assert!(cap.outcome.as_ref().unwrap_err().contains("Mach"), "{cap:?}");
        // a named fluid, as named, with the same mapping as UnitMapping::choose
        let named = choose_fluid(
            &sys,
            1e-6,
            ThermalChoice::default(),
            &FluidChoice::Named("capillary".into()),
            MACH_LIMIT,
            REYNOLDS_WARN,
        )
        .unwrap();
        let direct = UnitMapping::choose(&sys, &FluidModel::capillary(), 1e-6, ThermalChoice::default()).unwrap();
        assert_eq!(named.map, direct);
        assert_eq!(named.fluid, FluidModel::capillary());
        // the inner fluid five times more viscous shortens the step five-fold, and the
        // membrane's friction with the dense fluid (γ_fsi ≈ 50 > γ = 41) shortens it further
        let mut visc = sys.clone();
        visc.viscosity_ratio = 5.0;
        let d = choose_fluid(
            &visc,
            1e-6,
            ThermalChoice::Exact,
            &FluidChoice::Auto,
            MACH_LIMIT,
            REYNOLDS_WARN,
        )
        .unwrap();
        let c = d
            .candidates
            .iter()
            .find(|c| c.name == "dense")
            .unwrap()
            .outcome
            .clone()
            .unwrap();
        let dense = FluidModel::dense();
        let n_m = 500.0 / (visc.cell_area_m2 / 1e-12);
        let g_fsi = fsi_friction(dense.viscosity, dense.density, n_m, dense.pair.s, 1.0);
        assert!(g_fsi > dense.pair.gamma, "{g_fsi}");
        assert!(rel(c.timestep, dense.friction_step_limit / (5.0 * g_fsi)) < 1e-12);
        // the capillary fluid (γ = 120 > its γ_fsi ≈ 30, limit 0.48 = 1.6 × its own γΔt): its
        // step is its own at λ = 1 and at N = 100 (γ_fsi ≈ 150), 0.48/600 at λ = 5
        let cap = FluidModel::capillary();
        let map = |s: &PhysicalSystem| UnitMapping::choose(s, &cap, 1e-6, ThermalChoice::default()).unwrap();
        assert_eq!(cap.default_timestep(&sys, &map(&sys)), cap.timestep);
        let mut few = sys.clone();
        few.vertices = 100;
        assert_eq!(cap.default_timestep(&few, &map(&few)), cap.timestep);
        assert!(rel(cap.default_timestep(&visc, &map(&visc)), 0.48 / 600.0) < 1e-12);
        // the dense fluid at f = 1 and λ = 1: the membrane (μ0 ≈ 2004 in model units) sets the
        // step, MEMBRANE_STEP_LIMIT/√μ0 ≈ 0.00134, below the friction bound 0.123/γ_fsi ≈ 0.00244
        let d = auto(ThermalChoice::Exact);
        let mu0 = d.map.modulus_to_model(sys.shear_modulus_n_per_m);
        assert!((mu0 / 2004.6 - 1.0).abs() < 1e-3, "{mu0}");
        assert!(
            rel(
                dense.default_timestep(&sys, &d.map),
                crate::units::MEMBRANE_STEP_LIMIT / mu0.sqrt()
            ) < 1e-12
        );
    }

    /// Bounds no fluid meets, an unknown name and a Reynolds bound out of range fail with the
    /// key `fluid` or `max_reynolds`, each fluid's reason in the message.
    #[test]
    fn units_fluid_chooser_bad_input() {
        let mut sys = PhysicalSystem::capillary_default();
        sys.velocity_m_s = 0.05;
        let e = choose_fluid(
            &sys,
            1e-6,
            ThermalChoice::Exact,
            &FluidChoice::Auto,
            MACH_LIMIT,
            REYNOLDS_WARN,
        )
        .unwrap_err();
        assert_eq!(e.key(), "fluid");
        let m = e.to_string();
        assert!(
            m.contains("capillary:") && m.contains("dense:") && m.contains("allowed"),
            "{m}"
        );
        let e = choose_fluid(
            &sys,
            1e-6,
            ThermalChoice::Exact,
            &FluidChoice::Named("water".into()),
            MACH_LIMIT,
            REYNOLDS_WARN,
        )
        .unwrap_err();
        assert_eq!(e.key(), "fluid");
        assert!(e.to_string().contains("capillary, dense"), "{e}");
        for bad in [0.0, 6.0, f64::NAN] {
            let e = choose_fluid(&sys, 1e-6, ThermalChoice::Exact, &FluidChoice::Auto, MACH_LIMIT, bad).unwrap_err();
            assert_eq!(e.key(), "max_reynolds");
        }
    }
}
