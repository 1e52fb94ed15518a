//! Named membrane parameter sets: `cell.parameters` (capillary, shear) and
//! `membrane.parameters` (stretching).
//!
//! A set names the membrane's free parameters at once: the stress-free reference, the scale of
//! the persistence length (μ0 ∝ 1/p), the links' maximum extension Lmax/L0 and the membrane
//! viscosity with its form. [`expand`] writes
//! the set's values into the file's section before it is parsed, for the keys the file (or a
//! `--set`, or `--params`) does not give itself: an explicit key always wins, and a file without
//! `parameters` keeps the meaning it had (the paper's set), so an older scenario file runs as it
//! did. The resolved scenario that a run stores holds the expanded keys.

use crate::file::ScenarioError;

/// One named set.
#[derive(Clone, Copy, Debug)]
pub struct ParameterSet {
    /// The name a scenario file uses.
    pub name: &'static str,
    /// What it is and where it comes from (one line).
    pub origin: &'static str,
    /// Reduced volume of the oblate spheroid the membrane is stress-free on; `None`: stress-free
    /// on the resting biconcave cell.
    pub reduced_volume: Option<f64>,
    /// Multiplies the paper's Eq. 12 persistence length (μ0 ∝ 1/p).
    pub persistence_scale: f64,
    /// Lmax/L0 of the WLC links (the paper's 3.17).
    pub max_extension_ratio: f64,
    /// 2D membrane viscosity η_m, N·s/m (0: none).
    pub membrane_viscosity_pa_s_m: f64,
    /// How η_m becomes link friction: "central" or "fedosov".
    pub membrane_viscosity_form: &'static str,
}

/// Pivkin & Karniadakis 2008 as this project runs it: stress-free on the resting cell, Eq. 12's
/// persistence length, no membrane viscosity. The meaning of a file without `parameters`.
pub const PAPER: ParameterSet = ParameterSet {
    name: "paper",
    origin: "Pivkin & Karniadakis 2008 (stress-free on the resting biconcave cell, Eq. 12's persistence length, no membrane viscosity)",
    reduced_volume: None,
    persistence_scale: 1.0,
    max_extension_ratio: 3.17,
    membrane_viscosity_pa_s_m: 0.0,
    membrane_viscosity_form: "fedosov",
};

/// `hemodpd fit scenarios/fits/cell.toml` (Mills 2004 stretching and Hochmuth 1979 recovery,
/// N = 500): v = 0.972 ± 0.017, p × 1.34 ± 0.15, η_m = 4.74e-7 ± 1.06e-7 N·s/m, central form
/// (docs/fit.md, "Measured").
pub const CALIBRATED: ParameterSet = ParameterSet {
    name: "calibrated",
    origin: "hemodpd fit scenarios/fits/cell.toml against Mills 2004 and Hochmuth 1979 (v = 0.972 ± 0.017, p × 1.34 ± 0.15, η_m = 4.74e-7 ± 1.06e-7 N·s/m, central form; docs/fit.md)",
    reduced_volume: Some(0.972),
    persistence_scale: 1.34,
    max_extension_ratio: 3.17,
    membrane_viscosity_pa_s_m: 4.74e-7,
    membrane_viscosity_form: "central",
};

/// `hemodpd fit scenarios/fits/mills-x0.toml` (Mills 2004 with the links' maximum extension
/// free: v = 0.981 ± 0.008, p × 5.3 ± 2.7, Lmax/L0 = 1.97 ± 0.24), rounded to v 0.98, p × 5,
/// Lmax/L0 2.0 (μ0 = 4.0 µN/m, stiffening sooner), and `scenarios/fits/hochmuth-x0.toml`
/// (Hochmuth 1979 with those held: η_m = 3.90e-7 ± 0.68e-7 N·s/m, central form). docs/fit.md.
pub const CALIBRATED_X0: ParameterSet = ParameterSet {
    name: "calibrated-x0",
    origin: "hemodpd fit scenarios/fits/mills-x0.toml and hochmuth-x0.toml against Mills 2004 and Hochmuth 1979 with the links' maximum extension free (v = 0.98, p × 5, Lmax/L0 = 2.0, η_m = 3.9e-7 N·s/m, central form; docs/fit.md)",
    reduced_volume: Some(0.98),
    persistence_scale: 5.0,
    max_extension_ratio: 2.0,
    membrane_viscosity_pa_s_m: 3.9e-7,
    membrane_viscosity_form: "central",
};

/// Every named set, in the order messages list them.
pub const SETS: &[ParameterSet] = &[PAPER, CALIBRATED, CALIBRATED_X0];

/// The set named `name`.
pub fn find(name: &str) -> Option<&'static ParameterSet> {
    SETS.iter().find(|s| s.name == name)
}

fn allowed_names() -> String {
    let names: Vec<String> = SETS.iter().map(|s| format!("{:?} ({})", s.name, s.origin)).collect();
    format!("one of {}", names.join(", or "))
}

/// Writes the named set of `kind`'s cell section into `table` for the keys it lacks. Kinds
/// without a cell ignore it (their sections refuse an unknown `parameters` key themselves).
pub(crate) fn expand(table: &mut toml::Table, kind: &str, file: &str) -> Result<(), ScenarioError> {
    let (section, viscosity_section) = match kind {
        "capillary" | "shear" => ("cell", "cell"),
        "stretching" => ("membrane", "recovery"),
        _ => return Ok(()),
    };
    let Some(sec) = table.get(section).and_then(|v| v.as_table()) else {
        return Ok(());
    };
    let key = format!("{section}.parameters");
    let set = match sec.get("parameters") {
        None => return Ok(()),
        Some(toml::Value::String(name)) => find(name).ok_or_else(|| ScenarioError::Value {
            file: file.into(),
            key: key.clone(),
            value: format!("{name:?}"),
            allowed: allowed_names(),
        })?,
        Some(other) => {
            return Err(ScenarioError::Value {
                file: file.into(),
                key,
                value: other.to_string(),
                allowed: allowed_names(),
            })
        }
    };
    let reference = match set.reduced_volume {
        None => toml::Value::String("stress-free".into()),
        Some(v) => {
            let mut inner = toml::Table::new();
            inner.insert("reduced_volume".into(), toml::Value::Float(v));
            let mut outer = toml::Table::new();
            outer.insert("spheroid".into(), toml::Value::Table(inner));
            toml::Value::Table(outer)
        }
    };
    let fill = |t: &mut toml::Table, k: &str, v: toml::Value| {
        t.entry(k.to_string()).or_insert(v);
    };
    if let Some(t) = table.get_mut(section).and_then(|v| v.as_table_mut()) {
        fill(t, "reference", reference);
        fill(t, "persistence_scale", toml::Value::Float(set.persistence_scale));
        fill(t, "max_extension_ratio", toml::Value::Float(set.max_extension_ratio));
    }
    // the viscosity: in the cell section of the flow kinds; in the stretching kind, only where
    // the file releases the cell ([recovery]), the one stage in which it acts
    if let Some(t) = table.get_mut(viscosity_section).and_then(|v| v.as_table_mut()) {
        fill(
            t,
            "membrane_viscosity_pa_s_m",
            toml::Value::Float(set.membrane_viscosity_pa_s_m),
        );
        fill(
            t,
            "membrane_viscosity_form",
            toml::Value::String(set.membrane_viscosity_form.into()),
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn expanded(text: &str, kind: &str) -> Result<toml::Table, ScenarioError> {
        let mut t: toml::Table = text.parse().unwrap();
        expand(&mut t, kind, "t.toml")?;
        Ok(t)
    }

    #[test]
    fn a_set_fills_only_the_keys_the_file_lacks() {
        let t = expanded(
            "[cell]\nparameters = \"calibrated\"\npersistence_scale = 1.1\n",
            "capillary",
        )
        .unwrap();
        let cell = t["cell"].as_table().unwrap();
        assert_eq!(cell["persistence_scale"].as_float(), Some(1.1), "an explicit key wins");
        assert_eq!(
            cell["reference"]["spheroid"]["reduced_volume"].as_float(),
            Some(CALIBRATED.reduced_volume.unwrap())
        );
        assert_eq!(cell["membrane_viscosity_pa_s_m"].as_float(), Some(4.74e-7));
        assert_eq!(cell["membrane_viscosity_form"].as_str(), Some("central"));
    }

    #[test]
    fn the_stretching_kind_gets_the_viscosity_only_with_a_release() {
        let plain = expanded("[membrane]\nparameters = \"calibrated\"\n", "stretching").unwrap();
        assert!(!plain.contains_key("recovery"));
        assert_eq!(plain["membrane"]["persistence_scale"].as_float(), Some(1.34));
        let rec = expanded(
            "[membrane]\nparameters = \"paper\"\n[recovery]\nduration_s = 0.1\n",
            "stretching",
        )
        .unwrap();
        assert_eq!(rec["membrane"]["reference"].as_str(), Some("stress-free"));
        assert_eq!(rec["recovery"]["membrane_viscosity_pa_s_m"].as_float(), Some(0.0));
    }

    #[test]
    fn no_key_no_change_and_a_bad_name_is_refused() {
        let t = expanded("[cell]\nvertices = 500\n", "shear").unwrap();
        assert_eq!(t["cell"].as_table().unwrap().len(), 1);
        let e = expanded("[cell]\nparameters = \"best\"\n", "shear")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("cell.parameters") && e.contains("\"best\"") && e.contains("\"calibrated\""),
            "{e}"
        );
        let e = expanded("[membrane]\nparameters = 2\n", "stretching")
            .unwrap_err()
            .to_string();
        assert!(e.contains("membrane.parameters") && e.contains("\"paper\""), "{e}");
    }
}
