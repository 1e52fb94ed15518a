//! The grid of a sweep: `--vary KEY=V1,V2,...` axes combined as a cartesian product (the first
//! axis varies slowest) or, with `--zip`, element by element. Every check that needs no scenario
//! happens here, before any file is read or written.

use serde::{Deserialize, Serialize};

/// Above this many points a sweep needs `--yes`.
pub const MAX_POINTS_WITHOUT_YES: usize = 100;

/// Point directory names longer than this are cut and given a hash suffix.
const MAX_DIR_NAME: usize = 150;

/// A bad `--vary`/`--set`/`--zip` combination. Each message names the key and the value.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GridError {
    #[error("--vary `{arg}`: expected KEY=V1,V2,... (e.g. --vary membrane.vertices=100,162)")]
    Syntax { arg: String },
    #[error("--vary {key}=: no values, so the grid is empty; give at least one value (KEY=V1,V2,...)")]
    Empty { key: String },
    #[error("--vary {key}: the value `{value}` is listed twice; the points of a sweep need distinct values")]
    DuplicateValue { key: String, value: String },
    #[error("--vary {key} is given twice; list all its values in one --vary {key}=V1,V2,...")]
    DuplicateKey { key: String },
    #[error("key `{key}` is both set (--set {key}={value}) and varied (--vary {key}=...); drop one of them")]
    SetAndVaried { key: String, value: String },
    #[error("--zip pairs the i-th values of every axis, so the axes need the same number of values: {lengths}")]
    ZipLengths { lengths: String },
    #[error(
        "the grid has {points} points ({shape}); a sweep of more than {max} points needs --yes (check the values, then add --yes)"
    )]
    TooLarge { points: String, shape: String, max: usize },
    #[error("points {first} and {second} would write to the same directory `{dir}`; make the values differ in more than spaces, slashes, brackets or quotes")]
    DirCollision { first: String, second: String, dir: String },
}

/// One varied key and its values, in the order given.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Axis {
    pub key: String,
    pub values: Vec<String>,
}

/// One point of the grid.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Point {
    /// Position in the grid (the Slurm array task index).
    pub index: usize,
    /// `key=value,key=value` in axis order.
    pub label: String,
    /// Directory name inside the sweep directory.
    pub dir: String,
    /// (key, value) in axis order.
    pub values: Vec<(String, String)>,
}

impl Point {
    /// The `--set` overrides of this point: the sweep's `--set`s, then its varied values.
    pub fn overrides(&self, sets: &[String]) -> Vec<String> {
        sets.iter()
            .cloned()
            .chain(self.values.iter().map(|(k, v)| format!("{k}={v}")))
            .collect()
    }
}

/// Parses the `--vary` arguments into axes and checks them against each other and the `--set`s.
pub fn parse_axes(vary: &[String], sets: &[String]) -> Result<Vec<Axis>, GridError> {
    let mut axes: Vec<Axis> = Vec::new();
    for arg in vary {
        let Some((key, values)) = arg.split_once('=') else {
            return Err(GridError::Syntax { arg: arg.clone() });
        };
        let key = key.trim().to_string();
        if key.is_empty() {
            return Err(GridError::Syntax { arg: arg.clone() });
        }
        if axes.iter().any(|a| a.key == key) {
            return Err(GridError::DuplicateKey { key });
        }
        let values = split_values(values);
        if values.is_empty() {
            return Err(GridError::Empty { key });
        }
        for (i, v) in values.iter().enumerate() {
            if values[..i].contains(v) {
                return Err(GridError::DuplicateValue { key, value: v.clone() });
            }
        }
        if let Some(value) = sets.iter().find_map(|s| {
            let (k, v) = s.split_once('=')?;
            (k.trim() == key).then(|| v.trim().to_string())
        }) {
            return Err(GridError::SetAndVaried { key, value });
        }
        axes.push(Axis { key, values });
    }
    Ok(axes)
}

/// The number of points (`None` on overflow).
pub fn point_count(axes: &[Axis], zip: bool) -> Option<usize> {
    if zip {
        Some(axes.first().map_or(0, |a| a.values.len()))
    } else {
        axes.iter().try_fold(1usize, |n, a| n.checked_mul(a.values.len()))
    }
}

/// Checks the shape of the grid (zip lengths, size) and lists its points.
pub fn points(axes: &[Axis], zip: bool, yes: bool) -> Result<Vec<Point>, GridError> {
    if zip {
        let n = axes.first().map_or(0, |a| a.values.len());
        if axes.iter().any(|a| a.values.len() != n) {
            let lengths = axes
                .iter()
                .map(|a| format!("{} has {}", a.key, a.values.len()))
                .collect::<Vec<_>>()
                .join(", ");
            return Err(GridError::ZipLengths { lengths });
        }
    }
    let count = point_count(axes, zip);
    if !yes && count.is_none_or(|n| n > MAX_POINTS_WITHOUT_YES) {
        let shape = axes
            .iter()
            .map(|a| format!("{} with {} values", a.key, a.values.len()))
            .collect::<Vec<_>>()
            .join(if zip { " zipped with " } else { " x " });
        return Err(GridError::TooLarge {
            points: count.map_or_else(|| "more than usize::MAX".to_string(), |n| n.to_string()),
            shape,
            max: MAX_POINTS_WITHOUT_YES,
        });
    }
    let combos: Vec<Vec<(String, String)>> = if zip {
        let n = axes.first().map_or(0, |a| a.values.len());
        (0..n)
            .map(|i| axes.iter().map(|a| (a.key.clone(), a.values[i].clone())).collect())
            .collect()
    } else {
        let mut combos: Vec<Vec<(String, String)>> = vec![vec![]];
        for a in axes {
            combos = combos
                .iter()
                .flat_map(|c| {
                    a.values.iter().map(move |v| {
                        let mut c = c.clone();
                        c.push((a.key.clone(), v.clone()));
                        c
                    })
                })
                .collect();
        }
        combos
    };
    let mut out: Vec<Point> = Vec::with_capacity(combos.len());
    for (index, values) in combos.into_iter().enumerate() {
        let label = values
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect::<Vec<_>>()
            .join(",");
        let dir = dir_name(&label);
        if let Some(other) = out.iter().find(|p| p.dir == dir) {
            return Err(GridError::DirCollision {
                first: other.label.clone(),
                second: label,
                dir,
            });
        }
        out.push(Point {
            index,
            label,
            dir,
            values,
        });
    }
    Ok(out)
}

/// The directory name of a point: its label with `/`, spaces, brackets and quotes replaced by `_`
/// (the names `hemodpd sweep` has always used); a very long label is cut and given a hash.
pub fn dir_name(label: &str) -> String {
    let name = label.replace(['/', ' ', '[', ']', '"', '\'', '\\', '\n', '\t'], "_");
    if name.len() <= MAX_DIR_NAME {
        return name;
    }
    let mut cut = MAX_DIR_NAME - 17;
    while !name.is_char_boundary(cut) {
        cut -= 1;
    }
    format!("{}-{:016x}", &name[..cut], fnv1a64(label.as_bytes()))
}

/// FNV-1a, 64 bits: the content hash of the scenario file in the manifest (change detection, not
/// security).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// Splits "a,b,[1, 2],c" at top-level commas.
pub fn split_values(s: &str) -> Vec<String> {
    let (mut out, mut cur, mut depth) = (Vec::new(), String::new(), 0i32);
    for ch in s.chars() {
        match ch {
            '[' => depth += 1,
            ']' => depth -= 1,
            ',' if depth == 0 => {
                if !cur.trim().is_empty() {
                    out.push(cur.trim().to_string());
                }
                cur.clear();
                continue;
            }
            _ => {}
        }
        cur.push(ch);
    }
    if !cur.trim().is_empty() {
        out.push(cur.trim().to_string());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(v: &[&str]) -> Vec<String> {
        v.iter().map(|x| x.to_string()).collect()
    }

    #[test]
    fn product_first_axis_slowest_and_zip_pairs() {
        let axes = parse_axes(&s(&["a=1,2", "b=x,y,z"]), &[]).unwrap();
        let p = points(&axes, false, false).unwrap();
        let labels: Vec<&str> = p.iter().map(|p| p.label.as_str()).collect();
        assert_eq!(
            labels,
            ["a=1,b=x", "a=1,b=y", "a=1,b=z", "a=2,b=x", "a=2,b=y", "a=2,b=z"]
        );
        assert_eq!(p[4].index, 4);
        let axes = parse_axes(&s(&["a=1,2", "b=x,y"]), &[]).unwrap();
        let z = points(&axes, true, false).unwrap();
        assert_eq!(
            z.iter().map(|p| p.label.as_str()).collect::<Vec<_>>(),
            ["a=1,b=x", "a=2,b=y"]
        );
        let axes = parse_axes(&s(&["a=1,2", "b=x,y,z"]), &[]).unwrap();
        assert_eq!(
            points(&axes, true, false).unwrap_err(),
            GridError::ZipLengths {
                lengths: "a has 2, b has 3".into()
            }
        );
    }

    #[test]
    fn bad_grids_name_the_key_and_value() {
        assert_eq!(
            parse_axes(&s(&["a="]), &[]).unwrap_err(),
            GridError::Empty { key: "a".into() }
        );
        assert_eq!(
            parse_axes(&s(&["a=1,1"]), &[]).unwrap_err(),
            GridError::DuplicateValue {
                key: "a".into(),
                value: "1".into()
            }
        );
        assert_eq!(
            parse_axes(&s(&["a=1", "a=2"]), &[]).unwrap_err(),
            GridError::DuplicateKey { key: "a".into() }
        );
        assert_eq!(
            parse_axes(&s(&["a=1"]), &s(&["a=3"])).unwrap_err(),
            GridError::SetAndVaried {
                key: "a".into(),
                value: "3".into()
            }
        );
        assert!(matches!(
            parse_axes(&s(&["novalues"]), &[]).unwrap_err(),
            GridError::Syntax { .. }
        ));
        let big: Vec<String> = (0..11).map(|i| i.to_string()).collect();
        let axes = parse_axes(&[format!("a={}", big.join(",")), format!("b={}", big.join(","))], &[]).unwrap();
        let e = points(&axes, false, false).unwrap_err();
        assert!(
            e.to_string().contains("121 points") && e.to_string().contains("--yes"),
            "{e}"
        );
        assert_eq!(points(&axes, false, true).unwrap().len(), 121);
    }

    #[test]
    fn directory_names_are_safe_and_distinct() {
        let axes = parse_axes(&s(&["fluid.box_size=[4.0, 4.0, 4.0],[5.0, 5.0, 5.0]"]), &[]).unwrap();
        let p = points(&axes, false, false).unwrap();
        assert_eq!(p[0].dir, "fluid.box_size=_4.0,_4.0,_4.0_");
        let axes = parse_axes(&s(&["k=a b,a/b"]), &[]).unwrap();
        assert!(matches!(
            points(&axes, false, false).unwrap_err(),
            GridError::DirCollision { .. }
        ));
        let long = "x".repeat(400);
        let d = dir_name(&long);
        assert!(d.len() <= 150 && d != dir_name(&"x".repeat(401)));
    }
}
