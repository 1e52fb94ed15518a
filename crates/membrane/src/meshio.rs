//! Mesh files: OFF, ASCII PLY, and a vertices/triangles CSV pair (as in
//! `tests/data/membrane_golden/`). Coordinates are written in the shortest form that reads
//! back to the same f64, so a written mesh reloads bit-for-bit. Lengths are in µm by convention.

use crate::mesh::{Mesh, MeshError};
use glam::DVec3;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn err(path: &Path, msg: impl Into<String>) -> MeshError {
    MeshError::File {
        path: path.display().to_string(),
        msg: msg.into(),
    }
}

/// Reads a mesh from OFF (`.off`), ASCII PLY (`.ply`) or a CSV pair: `NAME.vertices.csv`
/// (header, then x,y,z per line) with `NAME.triangles.csv` beside it (header, then i,j,k,
/// 0-based). Pass either CSV file. The topology is checked (closed, oriented, genus 0).
pub fn read_mesh(path: &Path) -> Result<Mesh, MeshError> {
    let name = path.to_string_lossy();
    let (verts, tris) = if name.ends_with(".off") {
        read_off(path)?
    } else if name.ends_with(".ply") {
        read_ply(path)?
    } else if name.ends_with(".csv") {
        let (vp, tp) = csv_pair(path)?;
        (
            read_csv_rows(&vp, 3)?
                .into_iter()
                .map(|r| DVec3::new(r[0], r[1], r[2]))
                .collect(),
            to_tris(&tp, read_csv_rows(&tp, 3)?)?,
        )
    } else {
        return Err(err(
            path,
            "unknown mesh format: expected .off, .ply, or .vertices.csv/.triangles.csv",
        ));
    };
    let n = verts.len();
    Mesh::new(verts, tris).map_err(|e| err(path, format!("not a closed oriented surface ({n} vertices): {e}")))
}

fn csv_pair(path: &Path) -> Result<(PathBuf, PathBuf), MeshError> {
    let s = path.to_string_lossy();
    let stem = s
        .strip_suffix(".vertices.csv")
        .or_else(|| s.strip_suffix(".triangles.csv"))
        .ok_or_else(|| err(path, "a CSV mesh is a pair NAME.vertices.csv + NAME.triangles.csv"))?;
    Ok((
        PathBuf::from(format!("{stem}.vertices.csv")),
        PathBuf::from(format!("{stem}.triangles.csv")),
    ))
}

fn read_text(path: &Path) -> Result<String, MeshError> {
    std::fs::read_to_string(path).map_err(|e| err(path, e.to_string()))
}

fn read_csv_rows(path: &Path, cols: usize) -> Result<Vec<Vec<f64>>, MeshError> {
    let text = read_text(path)?;
    let mut rows = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let parsed: Result<Vec<f64>, _> = fields.iter().map(|f| f.parse::<f64>()).collect();
        match parsed {
            Ok(v) if v.len() == cols => rows.push(v),
            Ok(v) => {
                return Err(err(
                    path,
                    format!("line {}: expected {cols} columns, found {}", k + 1, v.len()),
                ))
            }
            Err(_) if rows.is_empty() => continue, // header
            Err(_) => return Err(err(path, format!("line {}: not a number: {line:?}", k + 1))),
        }
    }
    if rows.is_empty() {
        return Err(err(path, "no data rows"));
    }
    Ok(rows)
}

fn to_tris(path: &Path, rows: Vec<Vec<f64>>) -> Result<Vec<[u32; 3]>, MeshError> {
    rows.into_iter()
        .enumerate()
        .map(|(k, r)| {
            let mut t = [0u32; 3];
            for (j, &v) in r.iter().enumerate() {
                if v < 0.0 || v.fract() != 0.0 || v > u32::MAX as f64 {
                    return Err(err(
                        path,
                        format!("triangle {k}: index {v} is not a non-negative integer"),
                    ));
                }
                t[j] = v as u32;
            }
            Ok(t)
        })
        .collect()
}

fn tokens_after_comments(text: &str) -> impl Iterator<Item = &str> {
    text.lines()
        .map(|l| l.split('#').next().unwrap_or(""))
        .flat_map(str::split_whitespace)
}

fn read_off(path: &Path) -> Result<(Vec<DVec3>, Vec<[u32; 3]>), MeshError> {
    let text = read_text(path)?;
    let mut tok = tokens_after_comments(&text);
    if tok.next() != Some("OFF") {
        return Err(err(path, "missing OFF header"));
    }
    let mut num = |what: &str| -> Result<f64, MeshError> {
        tok.next()
            .ok_or_else(|| err(path, format!("file ends early, expected {what}")))?
            .parse::<f64>()
            .map_err(|_| err(path, format!("{what} is not a number")))
    };
    let nv = num("vertex count")? as usize;
    let nf = num("face count")? as usize;
    let _ne = num("edge count")?;
    let mut verts = Vec::with_capacity(nv);
    for _ in 0..nv {
        verts.push(DVec3::new(num("x")?, num("y")?, num("z")?));
    }
    let mut tris = Vec::with_capacity(nf);
    for k in 0..nf {
        let c = num("face size")?;
        if c != 3.0 {
            return Err(err(
                path,
                format!("face {k} has {c} vertices; only triangles are supported"),
            ));
        }
        tris.push(to_tris(path, vec![vec![num("index")?, num("index")?, num("index")?]])?[0]);
    }
    Ok((verts, tris))
}

fn read_ply(path: &Path) -> Result<(Vec<DVec3>, Vec<[u32; 3]>), MeshError> {
    let text = read_text(path)?;
    let mut lines = text.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err(err(path, "missing ply header"));
    }
    let (mut nv, mut nf) = (None, None);
    for line in lines.by_ref() {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, ..] if *f != "ascii" => {
                return Err(err(path, format!("PLY format {f} not supported; use ascii")))
            }
            ["element", "vertex", n] => nv = n.parse::<usize>().ok(),
            ["element", "face", n] => nf = n.parse::<usize>().ok(),
            ["end_header"] => break,
            _ => {}
        }
    }
    let (nv, nf) = (
        nv.ok_or_else(|| err(path, "no vertex element"))?,
        nf.ok_or_else(|| err(path, "no face element"))?,
    );
    let body: Vec<&str> = lines.collect();
    if body.len() < nv + nf {
        return Err(err(
            path,
            format!("expected {} data lines, found {}", nv + nf, body.len()),
        ));
    }
    let parse = |line: &str, k: usize| -> Result<Vec<f64>, MeshError> {
        line.split_whitespace()
            .map(|t| {
                t.parse::<f64>()
                    .map_err(|_| err(path, format!("data line {k}: bad number {t:?}")))
            })
            .collect()
    };
    let mut verts = Vec::with_capacity(nv);
    for (k, line) in body[..nv].iter().enumerate() {
        let v = parse(line, k)?;
        if v.len() < 3 {
            return Err(err(path, format!("vertex {k}: fewer than 3 coordinates")));
        }
        verts.push(DVec3::new(v[0], v[1], v[2]));
    }
    let mut rows = Vec::with_capacity(nf);
    for (k, line) in body[nv..nv + nf].iter().enumerate() {
        let v = parse(line, nv + k)?;
        if v.first() != Some(&3.0) || v.len() != 4 {
            return Err(err(path, format!("face {k}: only triangles are supported")));
        }
        rows.push(v[1..].to_vec());
    }
    Ok((verts, to_tris(path, rows)?))
}

/// Writes a mesh as OFF, ASCII PLY or a CSV pair, chosen by the extension of `path`
/// (`.off`, `.ply`, `.csv` → `NAME.vertices.csv` + `NAME.triangles.csv`).
pub fn write_mesh(mesh: &Mesh, path: &Path) -> Result<Vec<PathBuf>, MeshError> {
    let name = path.to_string_lossy().to_string();
    let write = |p: &Path, s: String| std::fs::write(p, s).map_err(|e| err(p, e.to_string()));
    let mut out = String::new();
    if name.ends_with(".off") || name.ends_with(".ply") {
        let (nv, nt) = (mesh.vertices.len(), mesh.triangles.len());
        if name.ends_with(".off") {
            writeln!(out, "OFF\n{nv} {nt} 0").unwrap();
        } else {
            writeln!(
                out,
                "ply\nformat ascii 1.0\ncomment hemodpd RBC mesh, lengths in um\nelement vertex {nv}\nproperty double x\nproperty double y\nproperty double z\nelement face {nt}\nproperty list uchar int vertex_indices\nend_header"
            )
            .unwrap();
        }
        // the same body for both formats: "x y z" lines, then "3 i j k" lines
        for v in &mesh.vertices {
            writeln!(out, "{} {} {}", v.x, v.y, v.z).unwrap();
        }
        for t in &mesh.triangles {
            writeln!(out, "3 {} {} {}", t[0], t[1], t[2]).unwrap();
        }
        write(path, out)?;
        Ok(vec![path.to_path_buf()])
    } else if name.ends_with(".csv") {
        let stem = name
            .strip_suffix(".vertices.csv")
            .or_else(|| name.strip_suffix(".triangles.csv"))
            .or_else(|| name.strip_suffix(".csv"))
            .unwrap();
        let (vp, tp) = (
            PathBuf::from(format!("{stem}.vertices.csv")),
            PathBuf::from(format!("{stem}.triangles.csv")),
        );
        out.push_str("x_um,y_um,z_um\n");
        for v in &mesh.vertices {
            writeln!(out, "{},{},{}", v.x, v.y, v.z).unwrap();
        }
        write(&vp, out)?;
        let mut t_out = String::from("i,j,k\n");
        for t in &mesh.triangles {
            writeln!(t_out, "{},{},{}", t[0], t[1], t[2]).unwrap();
        }
        write(&tp, t_out)?;
        Ok(vec![vp, tp])
    } else {
        Err(err(path, "unknown mesh format: use .off, .ply or .csv"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::tests::octahedron;

    #[test]
    fn formats_round_trip_bit_for_bit() {
        let dir = std::env::temp_dir().join(format!("hemodpd-meshio-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut m = octahedron();
        m.vertices[0] += DVec3::new(1e-17, 1.0 / 3.0, 0.1);
        for name in ["m.off", "m.ply", "m.csv"] {
            let files = write_mesh(&m, &dir.join(name)).unwrap();
            let back = read_mesh(&files[0]).unwrap();
            assert_eq!(back, m, "{name}");
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn reads_the_golden_csv_pair() {
        let p = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../tests/data/membrane_golden/mesh_N500.vertices.csv"
        ));
        let m = read_mesh(p).unwrap();
        assert_eq!(m.vertices.len(), 500);
        assert_eq!(m.triangles.len(), 996);
        // A0, V0 of the golden file
        assert!((m.area() - 132.77700635531912).abs() < 1e-9);
        assert!((m.volume() - 92.43650248801578).abs() < 1e-9);
    }

    #[test]
    fn bad_files_give_errors() {
        let dir = std::env::temp_dir().join(format!("hemodpd-meshio-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("bad.off");
        std::fs::write(&p, "OFF\n4 1 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n").unwrap();
        let e = read_mesh(&p).unwrap_err().to_string();
        assert!(e.contains("bad.off") && e.contains("closed"), "{e}");
        std::fs::write(&p, "OFF\n4 1\n").unwrap();
        assert!(read_mesh(&p).unwrap_err().to_string().contains("ends early"));
        assert!(read_mesh(&dir.join("x.stl"))
            .unwrap_err()
            .to_string()
            .contains("unknown mesh format"));
        std::fs::remove_dir_all(&dir).ok();
    }
}
