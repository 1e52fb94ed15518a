//! The shipped experiments of `hemodpd fit`: each a scenario of the repository, the overrides
//! that put it at the conditions an `[[experiment]]` gives, and its observables against the data
//! in `../shared/reference/` (copied into the crates).

use super::{format_value, ObservableSpec};

/// A shipped experiment: a scenario of the repository, its overrides, how the known parameters
/// reach it, and its observables against the data in `../shared/reference/` (copied into the
/// crates).
pub(super) struct Shipped {
    pub(super) name: &'static str,
    pub(super) file_name: &'static str,
    pub(super) scenario: &'static str,
    pub(super) sets: &'static [&'static str],
    pub(super) parameters: &'static [(&'static str, &'static str)],
    /// The overrides and observables of the experiment at the conditions the fit file gives.
    pub(super) observables: fn(&Conditions) -> Result<Conditioned, Refusal>,
    pub(super) about: &'static str,
}

/// A shipped experiment at its conditions: the overrides of its runs and its observables.
type Conditioned = (Vec<String>, Vec<ObservableSpec>);

/// The conditions an `[[experiment]]` gives a shipped experiment.
#[derive(Default)]
pub(super) struct Conditions {
    pub(super) shear_rate_per_s: Option<f64>,
    pub(super) outer_viscosity_mpa_s: Option<f64>,
    pub(super) side: Option<String>,
}

/// A condition refused: the key (under the experiment), the value and what is allowed.
pub(super) struct Refusal {
    pub(super) key: &'static str,
    pub(super) value: String,
    pub(super) allowed: String,
}

impl Conditions {
    /// Refuses every condition: for the experiments that take none.
    fn none(&self) -> Result<(), Refusal> {
        let given = [
            ("shear_rate_per_s", self.shear_rate_per_s.map(|v| v.to_string())),
            (
                "outer_viscosity_mpa_s",
                self.outer_viscosity_mpa_s.map(|v| v.to_string()),
            ),
            ("side", self.side.clone()),
        ];
        match given.into_iter().find(|(_, v)| v.is_some()) {
            Some((key, v)) => Err(Refusal {
                key,
                value: v.unwrap_or_default(),
                allowed: "nothing: this shipped experiment takes no conditions".into(),
            }),
            None => Ok(()),
        }
    }
}

/// The names of the shipped experiments.
pub fn shipped_experiments() -> Vec<&'static str> {
    SHIPPED.iter().map(|s| s.name).collect()
}

pub(super) const SHIPPED: &[Shipped] = &[Shipped {
    name: "mills2004",
    file_name: "stretching.toml",
    scenario: include_str!("../../scenarios/stretching.toml"),
    sets: &["output.shapes=false"],
    parameters: &[
        ("reduced_volume", "membrane.reference={ spheroid = { reduced_volume = % } }"),
        ("persistence_scale", "membrane.persistence_scale"),
        ("max_extension_ratio", "membrane.max_extension_ratio"),
    ],
    observables: |c| c.none().map(|_| (Vec::new(), mills2004_observables())),
    about: "Mills et al. 2004 optical-tweezers stretching: the axial and transverse diameters at each of the 13 forces against the measured means, σ = half the error bar",
},
Shipped {
    name: "hochmuth1979",
    file_name: "recovery.toml",
    scenario: include_str!("../../scenarios/recovery.toml"),
    sets: &["output.shapes=false"],
    parameters: &[
        ("reduced_volume", "membrane.reference={ spheroid = { reduced_volume = % } }"),
        ("persistence_scale", "membrane.persistence_scale"),
        ("max_extension_ratio", "membrane.max_extension_ratio"),
        ("membrane_viscosity", "recovery.membrane_viscosity_pa_s_m"),
    ],
    observables: |c| c.none().map(|_| (Vec::new(), hochmuth1979_observables())),
    about: "Hochmuth et al. 1979 recovery after release: the Kelvin–Voigt recovery time t_c of the recovery scenario against the mean of his four cells, σ = their SD",
},
Shipped {
    name: "fischer_ttf",
    file_name: "shear-sweep.toml",
    scenario: include_str!("../../scenarios/shear-sweep.toml"),
    sets: SHEAR_SETS,
    parameters: CELL_PARAMETERS,
    observables: fischer_ttf,
    about: "Fischer's tank-treading frequency at 28.9 mPa·s (the donors' cells behind Fischer & Korzeniewski 2015, Fig. S11): the membrane's rotation over γ̇ in scenarios/shear-sweep.toml at `shear_rate_per_s`, against the mean of the cells within ×1.25 of that rate, σ = their SD",
},
Shipped {
    name: "fischer2015_inclination",
    file_name: "shear-sweep.toml",
    scenario: include_str!("../../scenarios/shear-sweep.toml"),
    sets: SHEAR_SETS,
    parameters: CELL_PARAMETERS,
    observables: fischer2015_inclination,
    about: "Fischer & Korzeniewski 2015's inclination of tank-treading cells: the mean inclination in scenarios/shear-sweep.toml at `shear_rate_per_s` and `outer_viscosity_mpa_s` (10.7, 23.9, 55.9 or 104), against the mean of the cells within ×1.25 of that rate, σ = their SD",
},
Shipped {
    name: "fischer2013_threshold",
    file_name: "shear-sweep.toml",
    scenario: include_str!("../../scenarios/shear-sweep.toml"),
    sets: SHEAR_SETS,
    parameters: CELL_PARAMETERS,
    observables: fischer2013_threshold,
    about: "Fischer & Korzeniewski 2013's tumbling → tank-treading threshold at `outer_viscosity_mpa_s` (10.7, 23.9 or 104): the fraction of the time spent tumbling in scenarios/shear-sweep.toml at the stress 1.25 × below their lowest threshold (`side = \"below\"`, target 1) or 1.25 × above their highest (`side = \"above\"`, target 0), σ = 0.25",
}];

/// The overrides of every shipped shear run: the window of docs/validation.md §8 (30 strain,
/// analysed from 10), no trajectory.
const SHEAR_SETS: &[&str] = &[
    "shear.duration_strain=30.0",
    "shear.analysis_start_strain=10.0",
    "output.frame_every_strain=0.0",
];

/// How the cell's parameters reach a capillary or shear scenario (`[cell]`).
const CELL_PARAMETERS: &[(&str, &str)] = &[
    ("reduced_volume", "cell.reference={ spheroid = { reduced_volume = % } }"),
    ("persistence_scale", "cell.persistence_scale"),
    ("max_extension_ratio", "cell.max_extension_ratio"),
    ("membrane_viscosity", "cell.membrane_viscosity_pa_s_m"),
];

/// Fischer's data behind the shear experiments (copies of `../shared/reference/`).
const FISCHER_TTF_CSV: &str = include_str!("../../tests/data/shear_ttf_fischer_28.9mPas.csv");
const FISCHER_INCLINATION_CSV: &str = include_str!("../../tests/data/shear_inclination_angle_fischer2015.csv");
const FISCHER_THRESHOLD_CSV: &str = include_str!("../../tests/data/shear_tt_tb_threshold_stress.csv");

/// The data rows of a reference CSV (comments and the header skipped), split at commas.
fn csv_rows(text: &str) -> Vec<Vec<&str>> {
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .skip(1)
        .map(|l| l.split(',').map(str::trim).collect())
        .collect()
}

/// The mean and sample SD of the values `(rate, value)` whose rate is within ×1.25 of `rate`;
/// refused when fewer than 3 cells are that close (the rates that have 3 are listed).
fn cells_near(data: &[(f64, f64)], rate: f64, what: &str) -> Result<(f64, f64), Refusal> {
    let near = |r: f64| {
        data.iter()
            .filter(|(g, _)| (g / r).ln().abs() < 1.25f64.ln())
            .map(|p| p.1)
            .collect::<Vec<_>>()
    };
    let v = near(rate);
    if !(rate.is_finite() && rate > 0.0) || v.len() < 3 {
        let mut rates: Vec<f64> = data.iter().map(|p| p.0).collect();
        rates.sort_by(f64::total_cmp);
        let mut have: Vec<String> = Vec::new();
        let mut last = 0.0;
        for &r in &rates {
            if r > 1.25 * last && near(r).len() >= 3 {
                have.push(format!("{r:.3}"));
                last = r;
            }
        }
        return Err(Refusal {
            key: "shear_rate_per_s",
            value: rate.to_string(),
            allowed: format!(
                "a rate with at least 3 of {what} within ×1.25 (the data start near {} 1/s)",
                have.join(", ")
            ),
        });
    }
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    Ok((m, sd))
}

/// The rate of a shear experiment, required.
fn required_rate(c: &Conditions) -> Result<f64, Refusal> {
    c.shear_rate_per_s.ok_or_else(|| Refusal {
        key: "shear_rate_per_s",
        value: "(missing)".into(),
        allowed: "the shear rate of the run, 1/s".into(),
    })
}

/// The overrides that run the shear scenario at `stress_pa` in a medium of `eta_mpa_s`.
fn shear_condition(eta_mpa_s: f64, stress_pa: f64) -> Vec<String> {
    // six significant digits, so the run's file shows 0.49997, not 0.49996999999999997
    let six = |x: f64| format_value(format!("{x:.5e}").parse().unwrap_or(x));
    vec![
        format!("fluid.outer_viscosity_pa_s={}", six(eta_mpa_s * 1e-3)),
        format!("shear.shear_stress_pa={}", six(stress_pa)),
    ]
}

/// Fischer's TTF at 28.9 mPa·s: the membrane's fitted rotation over γ̇ (defined whatever the
/// class; a tumbling cell's is its small residual rotation).
fn fischer_ttf(c: &Conditions) -> Result<Conditioned, Refusal> {
    if c.side.is_some() {
        return Err(Refusal {
            key: "side",
            value: c.side.clone().unwrap_or_default(),
            allowed: "nothing (only fischer2013_threshold takes a side)".into(),
        });
    }
    if let Some(eta) = c.outer_viscosity_mpa_s.filter(|e| (e - 28.9).abs() > 1e-9) {
        return Err(Refusal {
            key: "outer_viscosity_mpa_s",
            value: eta.to_string(),
            allowed: "28.9 (the only viscosity of Fischer's TTF data) or nothing".into(),
        });
    }
    let rate = required_rate(c)?;
    let data: Vec<(f64, f64)> = csv_rows(FISCHER_TTF_CSV)
        .iter()
        .filter_map(|r| Some((r.get(1)?.parse().ok()?, r.get(2)?.parse().ok()?)))
        .collect();
    let (m, sd) = cells_near(&data, rate, "Fischer's cells")?;
    Ok((
        shear_condition(28.9, rate * 28.9e-3),
        vec![ObservableSpec {
            pointer: "/membrane_rotation/over_shear_rate".into(),
            target: m,
            sigma: sd,
        }],
    ))
}

/// The viscosity of a Fischer experiment, one of `allowed`.
fn viscosity_of(c: &Conditions, allowed: &[f64]) -> Result<f64, Refusal> {
    let list = allowed.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(", ");
    match c.outer_viscosity_mpa_s {
        Some(e) if allowed.iter().any(|a| (a - e).abs() < 1e-9) => Ok(e),
        other => Err(Refusal {
            key: "outer_viscosity_mpa_s",
            value: other.map(|v| v.to_string()).unwrap_or_else(|| "(missing)".into()),
            allowed: format!("one of the experiment's viscosities, mPa·s: {list}"),
        }),
    }
}

/// Fischer 2015: the mean inclination of the tank-treading cell (absent for a tumbling one).
fn fischer2015_inclination(c: &Conditions) -> Result<Conditioned, Refusal> {
    if c.side.is_some() {
        return Err(Refusal {
            key: "side",
            value: c.side.clone().unwrap_or_default(),
            allowed: "nothing (only fischer2013_threshold takes a side)".into(),
        });
    }
    let eta = viscosity_of(c, &[10.7, 23.9, 55.9, 104.0])?;
    let rate = required_rate(c)?;
    let data: Vec<(f64, f64)> = csv_rows(FISCHER_INCLINATION_CSV)
        .iter()
        .filter(|r| {
            r.first()
                .and_then(|v| v.parse::<f64>().ok())
                .is_some_and(|v| (v - eta).abs() < 1e-9)
        })
        .filter_map(|r| Some((r.get(2)?.parse().ok()?, r.get(3)?.parse().ok()?)))
        .collect();
    let (m, sd) = cells_near(&data, rate, &format!("Fischer's cells at {eta} mPa·s"))?;
    Ok((
        shear_condition(eta, rate * eta * 1e-3),
        vec![ObservableSpec {
            pointer: "/motion/mean_inclination_deg".into(),
            target: m,
            sigma: sd,
        }],
    ))
}

/// Fischer 2013's threshold as two runs that bracket it: at 1/1.25 of their lowest threshold
/// stress the cell should tumble (fraction 1), at 1.25 × their highest tank-tread (fraction 0).
fn fischer2013_threshold(c: &Conditions) -> Result<Conditioned, Refusal> {
    if c.shear_rate_per_s.is_some() {
        return Err(Refusal {
            key: "shear_rate_per_s",
            value: c.shear_rate_per_s.unwrap_or_default().to_string(),
            allowed: "nothing: the stress follows from the threshold data and `side`".into(),
        });
    }
    let eta = viscosity_of(c, &[10.7, 23.9, 104.0])?;
    let stresses: Vec<f64> = csv_rows(FISCHER_THRESHOLD_CSV)
        .iter()
        .filter(|r| r.first() == Some(&"Fischer2013"))
        .filter(|r| {
            r.get(1)
                .and_then(|v| v.parse::<f64>().ok())
                .is_some_and(|v| (v - eta).abs() < 1e-9)
        })
        .filter_map(|r| r.get(2)?.parse().ok())
        .collect();
    let lo = stresses.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = stresses.iter().copied().fold(0.0, f64::max);
    let (stress, target) = match c.side.as_deref() {
        Some("below") => (lo / 1.25, 1.0),
        Some("above") => (hi * 1.25, 0.0),
        other => {
            return Err(Refusal {
                key: "side",
                value: other.map(|v| format!("{v:?}")).unwrap_or_else(|| "(missing)".into()),
                allowed: "\"below\" (the cell should tumble) or \"above\" (it should tank-tread)".into(),
            })
        }
    };
    Ok((
        shear_condition(eta, stress),
        vec![ObservableSpec {
            pointer: "/motion/tumbling_fraction".into(),
            target,
            sigma: 0.25,
        }],
    ))
}

/// Hochmuth 1979: t_c against the mean of the four cells fitted the same way, σ = their SD.
fn hochmuth1979_observables() -> Vec<ObservableSpec> {
    let r = hemodpd_scenario::stretching::recovery::hochmuth_reference();
    vec![ObservableSpec {
        pointer: "/recovery/t_c_s".into(),
        target: r["mean_t_c_s"].as_f64().unwrap_or(f64::NAN),
        sigma: r["sd_t_c_s"].as_f64().unwrap_or(f64::NAN),
    }]
}

/// Mills 2004: D_A and D_T at each force of the shipped stretching scenario (the order of its
/// `results.mills2004.per_force`), σ = half of each error bar.
fn mills2004_observables() -> Vec<ObservableSpec> {
    let mut out = Vec::new();
    let rows = hemodpd_scenario::stretching::MILLS_2004_CSV
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("force"))
        .filter_map(|l| {
            let c: Vec<f64> = l.split(',').filter_map(|x| x.trim().parse().ok()).collect();
            (c.len() == 7).then_some(c)
        });
    for (k, c) in rows.enumerate() {
        out.push(ObservableSpec {
            pointer: format!("/mills2004/per_force/{k}/axial_diameter_um"),
            target: c[2],
            sigma: 0.5 * (c[6] - c[5]),
        });
        out.push(ObservableSpec {
            pointer: format!("/mills2004/per_force/{k}/transverse_diameter_um"),
            target: c[1],
            sigma: 0.5 * (c[4] - c[3]),
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(rate: Option<f64>, eta: Option<f64>, side: Option<&str>) -> Conditions {
        Conditions {
            shear_rate_per_s: rate,
            outer_viscosity_mpa_s: eta,
            side: side.map(str::to_string),
        }
    }

    /// The targets are the data's: at 17.3 1/s the 59 cells measured at 15.6–18.0 1/s
    /// (mean 0.0368, SD 0.0050, computed from the CSV by hand), run at η γ̇ = 0.49997 Pa.
    #[test]
    fn fischer_ttf_targets_the_cells_near_the_rate() {
        let (sets, obs) = fischer_ttf(&at(Some(17.3), None, None)).ok().unwrap();
        assert_eq!(
            sets,
            ["fluid.outer_viscosity_pa_s=0.0289", "shear.shear_stress_pa=0.49997"]
        );
        assert_eq!(obs[0].pointer, "/membrane_rotation/over_shear_rate");
        assert!((obs[0].target - 0.0368).abs() < 1e-4, "{}", obs[0].target);
        assert!((0.0049..0.0052).contains(&obs[0].sigma), "{}", obs[0].sigma);
        // 260 1/s: 19 cells at 254–267 1/s, mean 0.0254
        let (_, obs) = fischer_ttf(&at(Some(260.0), Some(28.9), None)).ok().unwrap();
        assert!((obs[0].target - 0.0254).abs() < 1e-4, "{}", obs[0].target);
    }

    #[test]
    fn fischer_inclination_and_threshold_take_their_viscosity() {
        // 23.9 mPa·s, 17.6 1/s: the 7 cells at 17.631 1/s (12.2–16.7°), mean 13.666°
        let (sets, obs) = fischer2015_inclination(&at(Some(17.6), Some(23.9), None)).ok().unwrap();
        assert_eq!(sets[0], "fluid.outer_viscosity_pa_s=0.0239");
        assert!((obs[0].target - 13.666).abs() < 0.01, "{}", obs[0].target);
        assert_eq!(obs[0].pointer, "/motion/mean_inclination_deg");
        // 10.7 mPa·s: their thresholds 0.584–0.921 Pa
        let (sets, obs) = fischer2013_threshold(&at(None, Some(10.7), Some("below")))
            .ok()
            .unwrap();
        assert_eq!(sets[1], "shear.shear_stress_pa=0.467256");
        assert_eq!((obs[0].target, obs[0].sigma), (1.0, 0.25));
        let (sets, obs) = fischer2013_threshold(&at(None, Some(10.7), Some("above")))
            .ok()
            .unwrap();
        assert_eq!(sets[1], "shear.shear_stress_pa=1.15075");
        assert_eq!(obs[0].target, 0.0);
    }

    #[test]
    fn bad_conditions_name_the_key_and_what_is_allowed() {
        let cases: Vec<(Result<Conditioned, Refusal>, &str, &str)> = vec![
            (fischer_ttf(&at(None, None, None)), "shear_rate_per_s", "(missing)"),
            (
                fischer_ttf(&at(Some(1000.0), None, None)),
                "shear_rate_per_s",
                "the data start near 7.610, 15.646",
            ),
            (
                fischer_ttf(&at(Some(17.3), Some(23.9), None)),
                "outer_viscosity_mpa_s",
                "28.9",
            ),
            (
                fischer2015_inclination(&at(Some(17.6), None, None)),
                "outer_viscosity_mpa_s",
                "10.7, 23.9, 55.9, 104",
            ),
            (
                fischer2015_inclination(&at(Some(17.6), Some(28.9), None)),
                "outer_viscosity_mpa_s",
                "23.9",
            ),
            (
                fischer2013_threshold(&at(None, Some(10.7), Some("middle"))),
                "side",
                "\"below\"",
            ),
            (
                fischer2013_threshold(&at(None, Some(55.9), Some("below"))),
                "outer_viscosity_mpa_s",
                "10.7, 23.9, 104",
            ),
            (
                fischer2013_threshold(&at(Some(5.0), Some(10.7), Some("below"))),
                "shear_rate_per_s",
                "the stress follows",
            ),
            (
                at(Some(5.0), None, None).none().map(|_| (Vec::new(), Vec::new())),
                "shear_rate_per_s",
                "takes no conditions",
            ),
        ];
        for (k, (r, key, allowed)) in cases.into_iter().enumerate() {
            let Err(e) = r else { panic!("case {k} accepted") };
            assert_eq!(e.key, key, "case {k}");
            assert!(
                e.allowed.contains(allowed) || e.value.contains(allowed),
                "case {k}: {} / {}",
                e.value,
                e.allowed
            );
        }
    }
}
