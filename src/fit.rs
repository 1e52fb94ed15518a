//! `hemodpd fit FIT.toml`: calibrates model parameters against experiments. Each experiment is a
//! scenario (a shipped one by name, e.g. `mills2004`, or any scenario file) and the observables
//! of its results with a target and an uncertainty; the misfit is χ² = Σ ((value − target)/σ)².
//! The design is a grid over the parameters' bounds, run as one `hemodpd sweep` per experiment
//! (so a fit resumes where it stopped and can go to Slurm); each observable is then fitted by a
//! quadratic response surface in its experiment's parameters (least squares by faer's QR), Σ χ²
//! of the surfaces is minimised in the bounds (a grid, then Gauss–Newton), and the uncertainties
//! are those of Δχ² = 1 (covariance (JᵀJ)⁻¹ of the weighted residuals). Writes `calibrated.toml` (`hemodpd run --params` applies it) and
//! `fit.json`. docs/fit.md.

use crate::sweep::{self, slurm::SlurmOptions, SweepArgs};
use anyhow::{bail, Context, Result};
use faer::linalg::solvers::{DenseSolveCore, SolveLstsqCore};
use serde::Deserialize;
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

mod shipped;
pub use shipped::shipped_experiments;
use shipped::{Conditions, SHIPPED};

/// The fit file (`format_version = 1`).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FitFile {
    format_version: i64,
    #[serde(default)]
    parameter: Vec<ParameterSpec>,
    #[serde(default)]
    experiment: Vec<ExperimentSpec>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ParameterSpec {
    name: String,
    lower: Option<f64>,
    upper: Option<f64>,
    /// Design points across [lower, upper], both ends included.
    #[serde(default = "d_points")]
    points: i64,
}

fn d_points() -> i64 {
    5
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ExperimentSpec {
    name: String,
    /// A scenario file (relative to the fit file); none: a shipped experiment, `shipped` or
    /// else `name`.
    scenario: Option<String>,
    /// The shipped experiment this one runs (default: `name`); lets one fit run a shipped
    /// experiment at several conditions under different names.
    shipped: Option<String>,
    /// The condition of a shipped shear experiment: shear rate, 1/s.
    shear_rate_per_s: Option<f64>,
    /// The condition of a shipped shear experiment: the suspending medium's viscosity, mPa·s.
    outer_viscosity_mpa_s: Option<f64>,
    /// The side of the tumbling → tank-treading threshold (`fischer2013_threshold`).
    side: Option<String>,
    /// `--set` overrides of every run of the experiment.
    #[serde(default)]
    set: Vec<String>,
    /// How each parameter reaches the scenario: its key, or `KEY=TEMPLATE` with `%` standing
    /// for the value (no commas).
    #[serde(default)]
    parameters: BTreeMap<String, String>,
    #[serde(default)]
    observable: Vec<ObservableSpec>,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ObservableSpec {
    /// JSON pointer into the run's `results`.
    pointer: String,
    target: f64,
    sigma: f64,
}

/// A parameter, checked.
#[derive(Clone, Debug)]
pub struct Parameter {
    pub name: String,
    pub lower: f64,
    pub upper: f64,
    pub points: usize,
}

impl Parameter {
    /// The design values, evenly spaced, both bounds included.
    pub fn values(&self) -> Vec<f64> {
        (0..self.points)
            .map(|k| self.lower + (self.upper - self.lower) * k as f64 / (self.points - 1) as f64)
            .collect()
    }
}

/// An experiment, checked: its scenario file, overrides, parameter keys and observables.
#[derive(Clone, Debug)]
struct Experiment {
    name: String,
    scenario: PathBuf,
    sets: Vec<String>,
    /// (parameter index, key, template with `%`).
    keys: Vec<(usize, String, String)>,
    observables: Vec<ObservableSpec>,
    /// A shipped experiment's scenario text, written to `scenario` when the fit starts.
    text: Option<&'static str>,
}

impl Experiment {
    /// The override that sets parameter `k` of `keys` to `v`.
    fn assignment(&self, k: usize, v: f64) -> String {
        let (_, key, template) = &self.keys[k];
        format!("{key}={}", template.replace('%', &format_value(v)))
    }
}

/// A value as the sweep and the scenario see it: shortest round-trip form, always with a point.
fn format_value(v: f64) -> String {
    let s = format!("{v:?}");
    if s.contains('.') || s.contains('e') || s.contains("inf") || s.contains("NaN") {
        s
    } else {
        format!("{s}.0")
    }
}

fn fail(file: &Path, key: &str, value: impl std::fmt::Display, allowed: &str) -> anyhow::Error {
    anyhow::anyhow!("{}: key `{key}` = {value} is not allowed: {allowed}", file.display())
}

/// Reads and checks a fit file: every key, bound, experiment and parameter mapping, and every
/// experiment's scenario at the corners of the design, before any work. Shipped scenarios are
/// written into `out`.
fn load(path: &Path, out: &Path) -> Result<(Vec<Parameter>, Vec<Experiment>)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading the fit file {}", path.display()))?;
    let f: FitFile = toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    if f.format_version != 1 {
        return Err(fail(path, "format_version", f.format_version, "1"));
    }
    if f.parameter.is_empty() {
        bail!(
            "{}: no [[parameter]]: give at least one, with name, lower and upper",
            path.display()
        );
    }
    let mut params = Vec::new();
    for (i, p) in f.parameter.iter().enumerate() {
        let key = |k: &str| format!("parameter[{i}].{k}");
        if p.name.is_empty() || params.iter().any(|q: &Parameter| q.name == p.name) {
            return Err(fail(path, &key("name"), format!("{:?}", p.name), "a name given once"));
        }
        let lower = p
            .lower
            .ok_or_else(|| fail(path, &key("lower"), "(missing)", "a finite lower bound"))?;
        let upper = p
            .upper
            .ok_or_else(|| fail(path, &key("upper"), "(missing)", "a finite upper bound above `lower`"))?;
        if !lower.is_finite() {
            return Err(fail(path, &key("lower"), lower, "a finite number"));
        }
        if !(upper.is_finite() && upper > lower) {
            return Err(fail(
                path,
                &key("upper"),
                upper,
                &format!("a finite number above lower = {lower}"),
            ));
        }
        if !(3..=21).contains(&p.points) {
            return Err(fail(
                path,
                &key("points"),
                p.points,
                "an integer 3–21 (a quadratic needs 3 per parameter)",
            ));
        }
        params.push(Parameter {
            name: p.name.clone(),
            lower,
            upper,
            points: p.points as usize,
        });
    }
    if f.experiment.is_empty() {
        bail!(
            "{}: no [[experiment]]: give one by name ({}) or with a scenario file",
            path.display(),
            shipped_experiments().join(", ")
        );
    }
    let base = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let mut exps: Vec<Experiment> = Vec::new();
    for (i, e) in f.experiment.iter().enumerate() {
        let key = |k: &str| format!("experiment[{i}].{k}");
        let ok_name = !e.name.is_empty()
            && e.name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
        if !ok_name || exps.iter().any(|x| x.name == e.name) {
            return Err(fail(
                path,
                &key("name"),
                format!("{:?}", e.name),
                "a name of letters, digits, _ and -, given once",
            ));
        }
        let (scenario, text, mut sets, mut mapping, mut observables) = match &e.scenario {
            Some(s) => (base.join(s), None, Vec::new(), BTreeMap::new(), Vec::new()),
            None => {
                let (shipped_key, shipped_name) = match &e.shipped {
                    Some(n) => ("shipped", n),
                    None => ("name", &e.name),
                };
                let Some(s) = SHIPPED.iter().find(|s| s.name == shipped_name) else {
                    return Err(fail(
                        path,
                        &key(shipped_key),
                        format!("{shipped_name:?}"),
                        &format!(
                            "a shipped experiment ({}), or any name with `scenario` = a scenario file",
                            SHIPPED
                                .iter()
                                .map(|s| format!("{}: {}", s.name, s.about))
                                .collect::<Vec<_>>()
                                .join("; ")
                        ),
                    ));
                };
                let conditions = Conditions {
                    shear_rate_per_s: e.shear_rate_per_s,
                    outer_viscosity_mpa_s: e.outer_viscosity_mpa_s,
                    side: e.side.clone(),
                };
                let (condition_sets, observables) = (s.observables)(&conditions)
                    .map_err(|r| fail(path, &key(r.key), r.value, &format!("{} ({})", r.allowed, s.name)))?;
                let mut sets: Vec<String> = s.sets.iter().map(|x| x.to_string()).collect();
                sets.extend(condition_sets);
                (
                    out.join(format!("{}-{}", e.name, s.file_name)),
                    Some(s.scenario),
                    sets,
                    s.parameters
                        .iter()
                        .map(|(a, b)| (a.to_string(), b.to_string()))
                        .collect::<BTreeMap<_, _>>(),
                    observables,
                )
            }
        };
        if e.scenario.is_some() {
            let given = [
                ("shipped", e.shipped.is_some()),
                ("shear_rate_per_s", e.shear_rate_per_s.is_some()),
                ("outer_viscosity_mpa_s", e.outer_viscosity_mpa_s.is_some()),
                ("side", e.side.is_some()),
            ];
            if let Some((k, _)) = given.iter().find(|g| g.1) {
                return Err(fail(
                    path,
                    &key(k),
                    "(given with `scenario`)",
                    "only for a shipped experiment (no `scenario`); a scenario file takes its conditions in `set`",
                ));
            }
        }
        if text.is_none() && !scenario.exists() {
            return Err(fail(
                path,
                &key("scenario"),
                scenario.display(),
                "an existing scenario file (relative to the fit file)",
            ));
        }
        sets.extend(e.set.iter().cloned());
        mapping.extend(e.parameters.clone());
        if !e.observable.is_empty() {
            observables = e.observable.clone();
        }
        if observables.is_empty() {
            return Err(fail(
                path,
                &key("observable"),
                "(none)",
                "at least one [[experiment.observable]] with pointer, target and sigma",
            ));
        }
        for (k, o) in observables.iter().enumerate() {
            if !o.pointer.starts_with('/') {
                return Err(fail(
                    path,
                    &format!("experiment[{i}].observable[{k}].pointer"),
                    &o.pointer,
                    "a JSON pointer into the run's results, e.g. \"/pressure/mean\"",
                ));
            }
            if !o.target.is_finite() {
                return Err(fail(
                    path,
                    &format!("experiment[{i}].observable[{k}].target"),
                    o.target,
                    "a finite number",
                ));
            }
            if !(o.sigma.is_finite() && o.sigma > 0.0) {
                return Err(fail(
                    path,
                    &format!("experiment[{i}].observable[{k}].sigma"),
                    o.sigma,
                    "a finite number above 0",
                ));
            }
        }
        let mut keys = Vec::new();
        for p in params.iter() {
            if let Some(m) = mapping.get(&p.name) {
                let (k, t) = match m.split_once('=') {
                    Some((k, t)) => (k.trim().to_string(), t.trim().to_string()),
                    None => (m.trim().to_string(), "%".to_string()),
                };
                if k.is_empty() || !t.contains('%') || t.contains(',') {
                    return Err(fail(
                        path,
                        &key(&format!("parameters.{}", p.name)),
                        format!("{m:?}"),
                        "a scenario key, or KEY=TEMPLATE with % for the value and no commas",
                    ));
                }
                keys.push((params.iter().position(|q| q.name == p.name).unwrap(), k, t));
            }
        }
        if let Some(unknown) = e.parameters.keys().find(|n| !params.iter().any(|p| &p.name == *n)) {
            return Err(fail(
                path,
                &key(&format!("parameters.{unknown}")),
                format!("{:?}", e.parameters[unknown]),
                &format!(
                    "a declared [[parameter]] ({})",
                    params.iter().map(|p| p.name.as_str()).collect::<Vec<_>>().join(", ")
                ),
            ));
        }
        if keys.is_empty() {
            return Err(fail(
                path,
                &key("parameters"),
                format!(
                    "{{{}}}",
                    mapping
                        .iter()
                        .map(|(k, v)| format!("{k} = {v:?}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
                &format!(
                    "a mapping of at least one declared parameter ({}) to a key of this experiment's scenario",
                    params.iter().map(|p| p.name.as_str()).collect::<Vec<_>>().join(", ")
                ),
            ));
        }
        let exp = Experiment {
            name: e.name.clone(),
            scenario,
            sets,
            keys,
            observables,
            text,
        };
        // the scenario at the design's two corners, so a bad key or range fails now
        for corner in [0, 1] {
            let mut s = exp.sets.clone();
            for k in 0..exp.keys.len() {
                let p = &params[exp.keys[k].0];
                s.push(exp.assignment(k, if corner == 0 { p.lower } else { p.upper }));
            }
            match exp.text {
                Some(t) => hemodpd_scenario::load_str(t, &exp.scenario.display().to_string(), &s).map(|_| ()),
                None => hemodpd_scenario::load(&exp.scenario, &s).map(|_| ()),
            }
            .with_context(|| {
                format!(
                    "{}: experiment {:?} at the design's corner {s:?}",
                    path.display(),
                    exp.name
                )
            })?;
        }
        exps.push(exp);
    }
    if let Some(p) = params
        .iter()
        .enumerate()
        .find(|(i, _)| !exps.iter().any(|e| e.keys.iter().any(|k| k.0 == *i)))
    {
        bail!(
            "{}: parameter {:?} reaches no experiment: map it in an experiment's `parameters` (shipped experiments map: {})",
            path.display(),
            p.1.name,
            SHIPPED.iter().map(|s| format!("{}: {}", s.name, s.parameters.iter().map(|k| k.0).collect::<Vec<_>>().join(", "))).collect::<Vec<_>>().join("; ")
        );
    }
    Ok((params, exps))
}

/// The arguments of `hemodpd fit`.
pub struct FitArgs {
    pub file: PathBuf,
    pub out: Option<PathBuf>,
    pub jobs: usize,
    pub threads_per_job: Option<usize>,
    pub quiet: bool,
    pub emit_slurm: bool,
    pub slurm: SlurmOptions,
}

/// A quadratic in the normalised parameters u ∈ [−1, 1]: 1, u_i, u_i u_j (i ≤ j).
struct Quadratic {
    coef: Vec<f64>,
}

impl Quadratic {
    fn features(u: &[f64]) -> Vec<f64> {
        let mut f = vec![1.0];
        f.extend_from_slice(u);
        for i in 0..u.len() {
            for j in i..u.len() {
                f.push(u[i] * u[j]);
            }
        }
        f
    }

    /// Least squares over the samples (u, y).
    fn fit(samples: &[(Vec<f64>, f64)]) -> Quadratic {
        let rows: Vec<Vec<f64>> = samples.iter().map(|s| Self::features(&s.0)).collect();
        let n = rows[0].len();
        let a = faer::Mat::<f64>::from_fn(rows.len(), n, |i, j| rows[i][j]);
        let mut b = faer::Mat::<f64>::from_fn(rows.len(), 1, |i, _| samples[i].1);
        a.qr().solve_lstsq_in_place_with_conj(faer::Conj::No, b.as_mut());
        Quadratic {
            coef: (0..n).map(|i| b[(i, 0)]).collect(),
        }
    }

    fn eval(&self, u: &[f64]) -> f64 {
        Self::features(u).iter().zip(&self.coef).map(|(f, c)| f * c).sum()
    }
}

/// `hemodpd fit`: the design runs (resumed where they stopped), then the fit.
pub fn fit(a: FitArgs) -> Result<Value> {
    let out = a.out.clone().unwrap_or_else(|| {
        let stem = a
            .file
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_else(|| "fit".into());
        PathBuf::from("runs").join(stem)
    });
    let (params, exps) = load(&a.file, &out)?;
    for e in &exps {
        if let Some(t) = e.text {
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            std::fs::write(&e.scenario, t).with_context(|| format!("writing {}", e.scenario.display()))?;
        }
    }
    let runs: usize = exps
        .iter()
        .map(|e| e.keys.iter().map(|k| params[k.0].points).product::<usize>())
        .sum();
    if !a.quiet {
        eprintln!(
            "hemodpd fit {}: {} parameter(s), {} experiment(s), {runs} runs in {}",
            a.file.display(),
            params.len(),
            exps.len(),
            out.display()
        );
    }
    // 1. the design: one sweep per experiment (finished points are kept on a rerun)
    for e in &exps {
        let vary: Vec<String> = (0..e.keys.len())
            .map(|k| {
                let p = &params[e.keys[k].0];
                let vals: Vec<String> = p
                    .values()
                    .iter()
                    .map(|v| e.assignment(k, *v).split_once('=').unwrap().1.to_string())
                    .collect();
                format!("{}={}", e.keys[k].1, vals.join(","))
            })
            .collect();
        let dir = out.join(&e.name);
        let args = SweepArgs {
            scenario: e.scenario.clone(),
            vary,
            sets: e.sets.clone(),
            zip: false,
            jobs: a.jobs,
            threads_per_job: a.threads_per_job,
            yes: true,
            out: if a.emit_slurm { None } else { Some(dir.clone()) },
            quiet: a.quiet,
            emit_slurm: a.emit_slurm.then(|| dir.clone()),
            slurm: a.slurm.clone(),
        };
        sweep::sweep(args).with_context(|| format!("experiment {:?} (sweep in {})", e.name, dir.display()))?;
    }
    if a.emit_slurm {
        let msg = format!(
            "wrote one Slurm job array per experiment ({}); submit each `sbatch DIR/sweep.sbatch`, then run the same `hemodpd fit` without --emit-slurm to fit (finished points are kept)",
            exps.iter().map(|e| out.join(&e.name).display().to_string()).collect::<Vec<_>>().join(", ")
        );
        eprintln!("{msg}");
        return Ok(json!({ "emitted_slurm": true, "message": msg }));
    }
    // 2. every observable of every run, per experiment, and a quadratic surface of each
    let norm = |i: usize, v: f64| 2.0 * (v - params[i].lower) / (params[i].upper - params[i].lower) - 1.0;
    // (parameter indices, observables, one surface per observable)
    let mut surfaces: Vec<(Vec<usize>, Vec<ObservableSpec>, Vec<Quadratic>)> = Vec::new();
    let mut experiments_json = Vec::new();
    for e in &exps {
        let dir = out.join(&e.name);
        let table = sweep::table_json(&dir)?;
        let mut samples: Vec<(Vec<f64>, Vec<Option<f64>>)> = Vec::new();
        for r in table["runs"].as_array().into_iter().flatten() {
            if r["status"] != "done" {
                bail!(
                    "experiment {:?}: point {} ({}) is {}: rerun `hemodpd fit` to finish it",
                    e.name,
                    r["index"],
                    r["label"],
                    r["status"]
                );
            }
            let rdir = PathBuf::from(r["dir"].as_str().unwrap_or_default());
            let summary = hemodpd_io::summary::read_summary_json(&rdir)
                .with_context(|| format!("reading {}", rdir.join("summary.json").display()))?;
            // a number, or none where the run does not define it (e.g. the inclination of a
            // tumbling cell): that run is left out of this observable's surface
            let mut obs = Vec::new();
            for o in &e.observables {
                obs.push(summary["results"].pointer(&o.pointer).and_then(Value::as_f64));
            }
            // the parameter values of this run, from its overrides
            let mut u = Vec::new();
            for (k, (i, key, _)) in e.keys.iter().enumerate() {
                let given = r["values"][key].as_str().unwrap_or_default();
                let v = params[*i]
                    .values()
                    .into_iter()
                    .find(|v| e.assignment(k, *v).split_once('=').unwrap().1 == given)
                    .ok_or_else(|| {
                        anyhow::anyhow!(
                            "experiment {:?}: run {} has {key} = {given}, not a design value",
                            e.name,
                            r["index"]
                        )
                    })?;
                u.push(norm(*i, v));
            }
            samples.push((u, obs));
        }
        let n_coef = Quadratic::features(&vec![0.0; e.keys.len()]).len();
        let mut missing = Vec::new();
        let mut quads = Vec::new();
        for (k, o) in e.observables.iter().enumerate() {
            let present: Vec<(Vec<f64>, f64)> = samples
                .iter()
                .filter_map(|(u, v)| v[k].map(|v| (u.clone(), v)))
                .collect();
            // the design's distinct values per parameter must still carry a quadratic
            let distinct_ok = (0..e.keys.len()).all(|i| {
                let mut vals: Vec<f64> = present.iter().map(|p| p.0[i]).collect();
                vals.sort_by(f64::total_cmp);
                vals.dedup();
                vals.len() >= 3
            });
            if present.len() < n_coef || !distinct_ok {
                bail!(
                    "experiment {:?}: only {} of {} runs have a number at {} (see their summary.json), too few for a quadratic in {} parameter(s): narrow the bounds to where the model defines it, or drop the observable",
                    e.name,
                    present.len(),
                    samples.len(),
                    o.pointer,
                    e.keys.len()
                );
            }
            missing.push(samples.len() - present.len());
            quads.push(Quadratic::fit(&present));
        }
        // how well the surfaces reproduce the runs, in units of each observable's σ
        let resid = samples
            .iter()
            .flat_map(|(u, o)| {
                e.observables
                    .iter()
                    .zip(&quads)
                    .zip(o)
                    .filter_map(move |((spec, q), v)| v.map(|v| ((q.eval(u) - v) / spec.sigma).abs()))
            })
            .fold(0.0, f64::max);
        // a run without a number at an observable counts as the surface's value there
        let chi2 = |u: &[f64], o: &[Option<f64>]| {
            e.observables
                .iter()
                .zip(o)
                .zip(&quads)
                .map(|((s, v), q)| ((v.unwrap_or_else(|| q.eval(u)) - s.target) / s.sigma).powi(2))
                .sum::<f64>()
        };
        let best = samples.iter().map(|(u, o)| chi2(u, o)).fold(f64::INFINITY, f64::min);
        experiments_json.push(json!({
            "name": e.name, "scenario": e.scenario, "sweep_dir": dir, "runs": samples.len(),
            "observables": e.observables.iter().zip(&missing).map(|(o, m)| json!({"pointer": o.pointer, "target": o.target, "sigma": o.sigma, "runs_without_a_number": m})).collect::<Vec<_>>(),
            "surface_max_residual_sigmas": resid, "best_design_chi2": best,
        }));
        surfaces.push((e.keys.iter().map(|k| k.0).collect(), e.observables.clone(), quads));
    }
    // 3. the minimum of Σ χ² in the bounds: a grid over the normalised box, then Gauss–Newton
    // steps that stay inside
    let residuals = |u: &[f64]| -> Vec<f64> {
        surfaces
            .iter()
            .flat_map(|(idx, obs, quads)| {
                let uu: Vec<f64> = idx.iter().map(|&i| u[i]).collect();
                obs.iter()
                    .zip(quads)
                    .map(move |(o, q)| (q.eval(&uu) - o.target) / o.sigma)
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    let total = |u: &[f64]| residuals(u).iter().map(|r| r * r).sum::<f64>();
    let p = params.len();
    let per_dim = match p {
        1 => 2001,
        2 => 201,
        3 => 41,
        _ => 11,
    };
    let mut best_u = vec![0.0; p];
    let mut best = f64::INFINITY;
    let cells = (per_dim as u64).pow(p as u32);
    for c in 0..cells {
        let mut r = c;
        let u: Vec<f64> = (0..p)
            .map(|_| {
                let k = (r % per_dim as u64) as f64;
                r /= per_dim as u64;
                -1.0 + 2.0 * k / (per_dim - 1) as f64
            })
            .collect();
        let v = total(&u);
        if v < best {
            best = v;
            best_u = u;
        }
    }
    // the Jacobian of the weighted residuals, numerically (the surfaces are quadratics)
    let jacobian = |u: &[f64]| -> Vec<Vec<f64>> {
        (0..p)
            .map(|i| {
                let h = 1e-5;
                let mut a_ = u.to_vec();
                let mut b_ = u.to_vec();
                a_[i] += h;
                b_[i] -= h;
                residuals(&a_)
                    .iter()
                    .zip(residuals(&b_))
                    .map(|(x, y)| (x - y) / (2.0 * h))
                    .collect()
            })
            .collect()
    };
    let fisher = |u: &[f64]| -> faer::Mat<f64> {
        let j = jacobian(u);
        faer::Mat::<f64>::from_fn(p, p, |a_, b_| j[a_].iter().zip(&j[b_]).map(|(x, y)| x * y).sum())
    };
    for _ in 0..20 {
        let f = fisher(&best_u);
        if f.llt(faer::Side::Lower).is_err() {
            break;
        }
        let j = jacobian(&best_u);
        let r = residuals(&best_u);
        let g: Vec<f64> = (0..p)
            .map(|i| j[i].iter().zip(&r).map(|(a_, b_)| a_ * b_).sum())
            .collect();
        let inv = f.partial_piv_lu().inverse();
        let cand: Vec<f64> = (0..p)
            .map(|i| best_u[i] - (0..p).map(|k| inv[(i, k)] * g[k]).sum::<f64>())
            .collect();
        if cand.iter().all(|u| (-1.0..=1.0).contains(u)) && total(&cand) < best {
            best = total(&cand);
            best_u = cand;
        } else {
            break;
        }
    }
    let f = fisher(&best_u);
    let positive = f.llt(faer::Side::Lower).is_ok();
    let scale: Vec<f64> = params.iter().map(|q| 0.5 * (q.upper - q.lower)).collect();
    let values: Vec<f64> = (0..p).map(|i| params[i].lower + (best_u[i] + 1.0) * scale[i]).collect();
    // Δχ² = 1: the covariance of the parameters is (JᵀJ)⁻¹ of the weighted residuals
    let sigmas: Vec<Option<f64>> = if positive {
        let inv = f.partial_piv_lu().inverse();
        (0..p)
            .map(|i| {
                let var = inv[(i, i)] * scale[i] * scale[i];
                (var > 0.0).then(|| var.sqrt())
            })
            .collect()
    } else {
        vec![None; p]
    };
    let at_bound: Vec<bool> = best_u.iter().map(|u| u.abs() > 1.0 - 1e-9).collect();
    for (e, (idx, obs, quads)) in experiments_json.iter_mut().zip(&surfaces) {
        let uu: Vec<f64> = idx.iter().map(|&i| best_u[i]).collect();
        let values: Vec<f64> = quads.iter().map(|q| q.eval(&uu)).collect();
        e["chi2_at_fit"] = json!(obs
            .iter()
            .zip(&values)
            .map(|(o, v)| ((v - o.target) / o.sigma).powi(2))
            .sum::<f64>());
        e["observables_at_fit"] = json!(values);
    }
    // 4. report and files
    let params_json: Vec<Value> = (0..p)
        .map(|i| {
            json!({
                "name": params[i].name, "value": values[i], "sigma": sigmas[i],
                "lower": params[i].lower, "upper": params[i].upper, "points": params[i].points,
                "at_bound": at_bound[i],
            })
        })
        .collect();
    let mut sets: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for e in &exps {
        let scenario = hemodpd_scenario::load(&e.scenario, &e.sets)?;
        let kind = scenario.kind().to_string();
        let mut assigned = Vec::new();
        for (k, (i, _, _)) in e.keys.iter().enumerate() {
            assigned.push(e.assignment(k, values[*i]));
        }
        // a membrane calibrated in a stretching scenario is the cell of the capillary and shear
        // kinds: the same keys under [cell], with the recovery's viscosity form
        if let hemodpd_scenario::Scenario::Stretching(st) = &scenario {
            let form = st.recovery.as_ref().map(|r| r.membrane_viscosity_form);
            let cell = cell_overrides(&assigned, form);
            for kind in ["capillary", "shear"] {
                let list = sets.entry(kind.to_string()).or_default();
                for s in &cell {
                    if !list.contains(s) {
                        list.push(s.clone());
                    }
                }
            }
        }
        // a cell calibrated in shear is the capillary's cell too, and the other way round
        if matches!(kind.as_str(), "capillary" | "shear") {
            let other = if kind == "capillary" { "shear" } else { "capillary" };
            let list = sets.entry(other.to_string()).or_default();
            for s in assigned.iter().filter(|s| s.starts_with("cell.")) {
                if !list.contains(s) {
                    list.push(s.clone());
                }
            }
        }
        let list = sets.entry(kind).or_default();
        for s in assigned {
            if !list.contains(&s) {
                list.push(s);
            }
        }
    }
    let result = json!({
        "fit_file": a.file, "out": out, "parameters": params_json, "experiments": experiments_json,
        "chi2_total": best, "constrained": positive, "sets": sets,
        "method": "grid design through hemodpd sweep; a quadratic response surface of each observable in its experiment's parameters (least squares, faer QR); Σχ² of the surfaces minimised in the bounds (grid, then Gauss–Newton); σ from Δχ² = 1, the covariance (JᵀJ)⁻¹ of the weighted residuals",
    });
    hemodpd_io::summary::write_json_atomic(out.join("fit.json"), &result).context("writing fit.json")?;
    let mut toml_text = format!(
        "# hemodpd fit {}: calibrated parameters (apply with `hemodpd run SCENARIO --params {}`)\n# Σχ² = {best:.4} at the fit; fit.json has the details.\nformat_version = 1\n\n[parameters]\n",
        a.file.display(),
        out.join("calibrated.toml").display()
    );
    for i in 0..p {
        toml_text += &format!(
            "{} = {{ value = {}, sigma = {} }}\n",
            params[i].name,
            format_value(values[i]),
            sigmas[i].map(format_value).unwrap_or_else(|| "nan".into())
        );
    }
    toml_text += "\n# the overrides per scenario kind\n[sets]\n";
    for (kind, list) in &sets {
        toml_text += &format!(
            "{kind:?} = [{}]\n",
            list.iter().map(|s| format!("{s:?}")).collect::<Vec<_>>().join(", ")
        );
    }
    std::fs::write(out.join("calibrated.toml"), &toml_text).context("writing calibrated.toml")?;
    println!("| parameter | value | σ (Δχ² = 1) | bounds |");
    println!("|---|---|---|---|");
    for i in 0..p {
        println!(
            "| {} | {} | {} | {}–{}{} |",
            params[i].name,
            if values[i] != 0.0 && values[i].abs() < 1e-3 {
                format!("{:.4e}", values[i])
            } else {
                format!("{:.6}", values[i])
            },
            sigmas[i]
                .map(|s| format!("{s:.3e}"))
                .unwrap_or_else(|| "not constrained".into()),
            params[i].lower,
            params[i].upper,
            if at_bound[i] { " (at a bound)" } else { "" }
        );
    }
    println!("\n| experiment | runs | χ² at the fit | best design point χ² | surface's largest miss (σ) |");
    println!("|---|---|---|---|---|");
    for e in &experiments_json {
        println!(
            "| {} | {} | {:.4} | {:.4} | {:.2e} |",
            e["name"].as_str().unwrap_or_default(),
            e["runs"],
            e["chi2_at_fit"].as_f64().unwrap_or(f64::NAN),
            e["best_design_chi2"].as_f64().unwrap_or(f64::NAN),
            e["surface_max_residual_sigmas"].as_f64().unwrap_or(f64::NAN)
        );
    }
    eprintln!(
        "wrote {} and {}",
        out.join("calibrated.toml").display(),
        out.join("fit.json").display()
    );
    Ok(result)
}

/// The stretching scenario's membrane overrides `assigned` as overrides of a cell kind's `[cell]`
/// (`membrane.reference`, `membrane.persistence_scale`, `membrane.max_extension_ratio`,
/// `recovery.membrane_viscosity_pa_s_m`
/// with the viscosity `form`); other keys have no counterpart and are left out.
fn cell_overrides(assigned: &[String], form: Option<hemodpd_scenario::cell::ViscosityForm>) -> Vec<String> {
    let mut out = Vec::new();
    for s in assigned {
        if let Some(v) = s.strip_prefix("membrane.reference=") {
            out.push(format!("cell.reference={v}"));
        } else if let Some(v) = s.strip_prefix("membrane.persistence_scale=") {
            out.push(format!("cell.persistence_scale={v}"));
        } else if let Some(v) = s.strip_prefix("membrane.max_extension_ratio=") {
            out.push(format!("cell.max_extension_ratio={v}"));
        } else if let Some(v) = s.strip_prefix("recovery.membrane_viscosity_pa_s_m=") {
            out.push(format!("cell.membrane_viscosity_pa_s_m={v}"));
            if let Some(f) = form {
                let name = match f {
                    hemodpd_scenario::cell::ViscosityForm::Fedosov => "fedosov",
                    hemodpd_scenario::cell::ViscosityForm::Central => "central",
                };
                out.push(format!("cell.membrane_viscosity_form=\"{name}\""));
            }
        }
    }
    out
}

/// The overrides of a `calibrated.toml` for a scenario of `kind` (`hemodpd run --params`).
pub fn params_sets(path: &Path, kind: &str) -> Result<Vec<String>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let v: toml::Table = text.parse().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let sets = v.get("sets").and_then(|s| s.as_table()).ok_or_else(|| {
        anyhow::anyhow!(
            "{}: no [sets] table (not a calibrated.toml of `hemodpd fit`?)",
            path.display()
        )
    })?;
    let list = sets.get(kind).and_then(|l| l.as_array()).ok_or_else(|| {
        anyhow::anyhow!(
            "{}: no calibrated overrides for a {kind} scenario (it has: {})",
            path.display(),
            sets.keys().cloned().collect::<Vec<_>>().join(", ")
        )
    })?;
    Ok(list.iter().filter_map(|s| s.as_str().map(str::to_string)).collect())
}
