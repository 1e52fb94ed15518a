//! The kinds this build knows, in one list, and loading a scenario file: parsing, `--set`
//! overrides, the kind's validation and its files. The top floor of the crate: it names every
//! kind, and no kind names it.

use std::path::{Path, PathBuf};

use crate::file::{syntax, ScenarioError, FORMAT_VERSION};

// The kinds of this build: one line each.
crate::kind::scenario_kinds! {
    Stretching(crate::stretching::StretchingScenario),
    DpdFluid(crate::fluid::FluidScenario),
    PoiseuilleTube(crate::channel::TubeScenario),
    Couette(crate::channel::CouetteScenario),
    Capillary(crate::capillary::CapillaryScenario),
    Shear(crate::shear::ShearScenario),
}

impl Scenario {
    /// The resolved scenario (defaults filled in, overrides applied) as TOML text.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }
}

/// `"a", "b" or "c"`: the kind names for messages.
pub fn kind_list() -> String {
    let quoted: Vec<String> = KIND_NAMES.iter().map(|k| format!("{k:?}")).collect();
    match quoted.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("one of {} or {last}", rest.join(", ")),
        Some((last, _)) => last.clone(),
        None => String::new(),
    }
}

/// Reads, overrides (`key=value`, dotted keys) and validates a scenario file.
pub fn load(path: &Path, sets: &[String]) -> Result<Scenario, ScenarioError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Read {
        file: file.clone(),
        source,
    })?;
    let mut s = load_str(&text, &file, sets)?;
    // absolute, so that a checkpoint resumed from another working directory still finds the
    // files the scenario names
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let dir = std::path::absolute(&dir).unwrap_or(dir);
    s.set_base_dir(dir);
    // the files a scenario names must exist and fit it
    s.check_files(&file)?;
    Ok(s)
}

/// As [`load`], from text; `file` names it in messages.
pub fn load_str(text: &str, file: &str, sets: &[String]) -> Result<Scenario, ScenarioError> {
    let mut table: toml::Table = text.parse().map_err(|e| syntax(file, e))?;
    for a in sets {
        apply_set(&mut table, a)?;
    }
    let version = match table.get("format_version") {
        None => {
            return Err(ScenarioError::Missing {
                file: file.into(),
                key: "format_version".into(),
                what: format!("the file format version, {FORMAT_VERSION} for this build"),
            })
        }
        Some(v) => v.as_integer(),
    };
    if version != Some(FORMAT_VERSION as i64) {
        return Err(ScenarioError::Value {
            file: file.into(),
            key: "format_version".into(),
            value: table["format_version"].to_string(),
            allowed: format!("{FORMAT_VERSION} (the only version this build reads)"),
        });
    }
    let kind = match table.get("kind").and_then(|k| k.as_str()) {
        Some(k) => k.to_string(),
        None => {
            return Err(ScenarioError::Missing {
                file: file.into(),
                key: "kind".into(),
                what: kind_list(),
            })
        }
    };
    // a named membrane parameter set fills the keys the file does not give
    crate::parameter_sets::expand(&mut table, &kind, file)?;
    Scenario::parse(&kind, toml::Value::Table(table), file).unwrap_or_else(|| {
        Err(ScenarioError::Value {
            file: file.into(),
            key: "kind".into(),
            value: format!("{kind:?}"),
            allowed: kind_list(),
        })
    })
}

/// Applies `a.b.c=value` to the table. The value is parsed as TOML (numbers, booleans, arrays,
/// quoted strings); anything that does not parse is taken as a bare string. A number in the path
/// indexes an array of tables: `stage.1.mean_velocity_m_per_s=2e-3` sets the second `[[stage]]`.
fn apply_set(table: &mut toml::Table, assignment: &str) -> Result<(), ScenarioError> {
    let bad = |m: &str| ScenarioError::Override {
        assignment: assignment.to_string(),
        message: m.to_string(),
    };
    let (key, raw) = assignment.split_once('=').ok_or_else(|| bad("expected key=value"))?;
    let key = key.trim();
    if key.is_empty() || key.split('.').any(str::is_empty) {
        return Err(bad("empty key"));
    }
    let value = match format!("v = {}", raw.trim()).parse::<toml::Table>() {
        Ok(mut t) => t.remove("v").unwrap(),
        Err(_) => toml::Value::String(raw.trim().to_string()),
    };
    let parts: Vec<&str> = key.split('.').collect();
    // walk the path: a table key, or a key and an index into an array of tables
    // (`stage.1.duration_s`: the second [[stage]])
    let mut cur = table;
    let last = parts.len() - 1;
    let mut k = 0;
    while k < last {
        let p = parts[k];
        if k + 1 < last {
            if let Ok(i) = parts[k + 1].parse::<usize>() {
                let arr = cur
                    .get_mut(p)
                    .and_then(|v| v.as_array_mut())
                    .ok_or_else(|| bad(&format!("`{p}` is not an array (of [[{p}]] tables) to index")))?;
                let len = arr.len();
                cur = arr
                    .get_mut(i)
                    .ok_or_else(|| bad(&format!("`{p}` has {len} entries, no entry {i} (indices start at 0)")))?
                    .as_table_mut()
                    .ok_or_else(|| bad(&format!("`{p}.{i}` is not a table")))?;
                k += 2;
                continue;
            }
        }
        cur = cur
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
            .ok_or_else(|| bad(&format!("`{p}` is not a table")))?;
        k += 1;
    }
    cur.insert(parts[parts.len() - 1].to_string(), value);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use hemodpd_membrane::ReferenceState;

    const GOOD: &str = r#"
format_version = 1
kind = "stretching"
seed = 3
[membrane]
vertices = 500
[stretching]
forces_pn = [0, 100, 200]
"#;

    #[test]
    fn good_file_and_overrides() {
        let s = load_str(
            GOOD,
            "good.toml",
            &[
                "membrane.vertices=800".into(),
                "stretching.forces_pn=[0, 50]".into(),
                "membrane.reference=uniform".into(),
            ],
        )
        .unwrap();
        let Scenario::Stretching(s) = s else { panic!() };
        assert_eq!(s.membrane.vertices, 800);
        assert_eq!(s.stretching.forces_pn, vec![0.0, 50.0]);
        assert_eq!(s.membrane.reference, ReferenceState::Uniform);
        assert_eq!(s.membrane.temperature_k, 300.0);
    }

    #[test]
    fn resolved_scenario_round_trips() {
        let s = load_str(GOOD, "good.toml", &[]).unwrap();
        let again = load_str(&s.to_toml(), "resolved.toml", &[]).unwrap();
        assert_eq!(s.to_toml(), again.to_toml());
    }
}

#[cfg(test)]
mod kind_tests {
    use super::*;

    #[test]
    fn every_kind_is_registered_once_with_columns_and_a_shipped_scenario() {
        let mut names = KIND_NAMES.to_vec();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), KIND_NAMES.len(), "a kind name is registered twice");
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios");
        let mut shipped = std::collections::BTreeSet::new();
        for e in std::fs::read_dir(&root).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "toml") {
                let s = load(&p, &[]).unwrap();
                assert!(!s.sweep_columns().is_empty(), "{}", s.kind());
                assert_eq!(s.sweep_columns(), sweep_columns(s.kind()));
                shipped.insert(s.kind());
            }
        }
        for k in KIND_NAMES {
            assert!(shipped.contains(k), "no shipped scenario of kind {k}");
        }
        assert!(sweep_columns("wormhole").is_empty());
        assert_eq!(
            kind_list(),
            r#"one of "stretching", "dpd-fluid", "poiseuille-tube", "couette", "capillary" or "shear""#
        );
    }
}
