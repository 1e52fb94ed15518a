//! XDMF companion file (`FILE.xmf` beside `FILE.h5`) so ParaView opens a trajectory as a time
//! series: the membrane as a triangle surface, fluid particles as points and binned fields as a
//! 3-D image, each a temporal collection. Per-frame data are hyperslabs of the HDF5 datasets, so
//! the XDMF file holds no numbers itself and is rewritten cheaply as frames are appended.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::error::{IoError, Result};
use crate::h5util::{dataset, get_attr, get_attr_array, link_exists, write_atomic};
use crate::layout::{check_format, frame_clock};

/// The two XDMF dialects ParaView reads. They differ only in how a frame of a dataset is
/// selected: XDMF 2 uses a `HyperSlab` data item (ParaView's *XDMF Reader*, VisIt), Xdmf3 a
/// `file.h5:/dataset|start:stride:count:dims` reference (ParaView's *Xdmf3ReaderS/T*), and each
/// reader family ignores the other's form.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flavor {
    /// `FILE.xmf`: XDMF 2 with `ItemType="HyperSlab"` data items.
    Xdmf2,
    /// `FILE.xmf3`: Xdmf3 with `|start:stride:count:dims` hyperslab references.
    Xdmf3,
}

/// `traj.h5` → `traj.xmf` (XDMF 2, *XDMF Reader*).
pub fn xdmf_path(h5_path: &Path) -> PathBuf {
    h5_path.with_extension("xmf")
}

/// `traj.h5` → `traj.xmf3` (Xdmf3, *Xdmf3ReaderS*); ParaView picks the reader from the extension.
pub fn xdmf3_path(h5_path: &Path) -> PathBuf {
    h5_path.with_extension("xmf3")
}

/// Writes `FILE.xmf` and `FILE.xmf3` for the trajectory `h5_path` (opened read-only) and returns
/// the path of `FILE.xmf`.
pub fn write_xdmf(h5_path: impl AsRef<Path>) -> Result<PathBuf> {
    let path = h5_path.as_ref();
    let file = hdf5::File::open(path).map_err(|source| IoError::Open {
        path: path.to_path_buf(),
        action: "open",
        source,
    })?;
    write_xdmf_for(path, &file)
}

/// Writes the XDMF file for an already open trajectory.
pub(crate) fn write_xdmf_for(h5_path: &Path, file: &hdf5::File) -> Result<PathBuf> {
    let text = xdmf_text(h5_path, file, Flavor::Xdmf3)?;
    write_atomic(&xdmf3_path(h5_path), text.as_bytes())?;
    let text = xdmf_text(h5_path, file, Flavor::Xdmf2)?;
    let out = xdmf_path(h5_path);
    write_atomic(&out, text.as_bytes())?;
    Ok(out)
}

/// The XDMF text of an open trajectory in the given dialect.
pub fn xdmf_text_of(h5_path: &Path, file: &hdf5::File, flavor: Flavor) -> Result<String> {
    xdmf_text(h5_path, file, flavor)
}

fn dims(shape: &[usize]) -> String {
    shape.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(" ")
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A data item selecting frame `frame` of the dataset `name` with shape `shape`.
#[allow(clippy::too_many_arguments)]
fn hyperslab(
    out: &mut String,
    flavor: Flavor,
    indent: &str,
    h5name: &str,
    name: &str,
    shape: &[usize],
    frame: usize,
    number: &str,
) {
    let nd = shape.len();
    let mut start = vec![0usize; nd];
    start[0] = frame;
    let stride = vec![1usize; nd];
    let mut count = shape.to_vec();
    count[0] = 1;
    if flavor == Flavor::Xdmf3 {
        let _ = writeln!(
            out,
            "{indent}<DataItem Dimensions=\"{}\" {number} Format=\"HDF\">{}:{name}|{}:{}:{}:{}</DataItem>",
            dims(&count[1..]),
            xml_escape(h5name),
            dims(&start),
            dims(&stride),
            dims(&count),
            dims(shape)
        );
        return;
    }
    // The selected block without its frame axis: what the grid's topology expects.
    let _ = writeln!(
        out,
        "{indent}<DataItem ItemType=\"HyperSlab\" Dimensions=\"{}\" Type=\"HyperSlab\">",
        dims(&count[1..])
    );
    let _ = writeln!(
        out,
        "{indent}  <DataItem Dimensions=\"3 {nd}\" Format=\"XML\">{} {} {}</DataItem>",
        dims(&start),
        dims(&stride),
        dims(&count)
    );
    let _ = writeln!(
        out,
        "{indent}  <DataItem Dimensions=\"{}\" {number} Format=\"HDF\">{}:{name}</DataItem>",
        dims(shape),
        xml_escape(h5name)
    );
    let _ = writeln!(out, "{indent}</DataItem>");
}

const F64: &str = "NumberType=\"Float\" Precision=\"8\"";
const U32: &str = "NumberType=\"UInt\" Precision=\"4\"";
const U8: &str = "NumberType=\"UChar\" Precision=\"1\"";

fn xdmf_text(h5_path: &Path, file: &hdf5::File, flavor: Flavor) -> Result<String> {
    check_format(h5_path, file)?;
    let h5name = h5_path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut out = String::new();
    out.push_str("<?xml version=\"1.0\" ?>\n<!DOCTYPE Xdmf SYSTEM \"Xdmf.dtd\" []>\n");
    let version = match flavor {
        Flavor::Xdmf2 => "2.0",
        Flavor::Xdmf3 => "3.0",
    };
    let _ = writeln!(
        out,
        "<Xdmf Version=\"{version}\" xmlns:xi=\"http://www.w3.org/2001/XInclude\">\n  <Domain>"
    );
    let path = h5_path;

    // Membrane surface.
    if link_exists(file, "/membrane/triangles") && link_exists(file, "/membrane/positions") {
        let g = file
            .group("/membrane")
            .map_err(|e| IoError::hdf5(path, "/membrane", e))?;
        let (times, steps) = frame_clock(path, &g)?;
        let tri = dataset(path, file, "/membrane/triangles")?.shape();
        let pos = dataset(path, file, "/membrane/positions")?.shape();
        let vel = if g.link_exists("velocities") {
            Some(dataset(path, file, "/membrane/velocities")?.shape())
        } else {
            None
        };
        if tri.len() == 2 && pos.len() == 3 {
            out.push_str("    <Grid Name=\"membrane\" GridType=\"Collection\" CollectionType=\"Temporal\">\n");
            for (f, (t, s)) in times.iter().zip(&steps).enumerate() {
                let _ = writeln!(out, "      <Grid Name=\"membrane_{s}\" GridType=\"Uniform\">");
                let _ = writeln!(out, "        <Time Value=\"{t:e}\" />");
                let _ = writeln!(
                    out,
                    "        <Topology TopologyType=\"Triangle\" NumberOfElements=\"{}\">",
                    tri[0]
                );
                let _ = writeln!(
                    out,
                    "          <DataItem Dimensions=\"{}\" {U32} Format=\"HDF\">{}:/membrane/triangles</DataItem>",
                    dims(&tri),
                    xml_escape(&h5name)
                );
                out.push_str("        </Topology>\n        <Geometry GeometryType=\"XYZ\">\n");
                hyperslab(
                    &mut out,
                    flavor,
                    "          ",
                    &h5name,
                    "/membrane/positions",
                    &pos,
                    f,
                    F64,
                );
                out.push_str("        </Geometry>\n");
                if let Some(vel) = &vel {
                    out.push_str("        <Attribute Name=\"velocity\" AttributeType=\"Vector\" Center=\"Node\">\n");
                    hyperslab(
                        &mut out,
                        flavor,
                        "          ",
                        &h5name,
                        "/membrane/velocities",
                        vel,
                        f,
                        F64,
                    );
                    out.push_str("        </Attribute>\n");
                }
                out.push_str("      </Grid>\n");
            }
            out.push_str("    </Grid>\n");
        }
    }

    // Fluid particles.
    if link_exists(file, "/fluid/positions") {
        let g = file.group("/fluid").map_err(|e| IoError::hdf5(path, "/fluid", e))?;
        let (times, steps) = frame_clock(path, &g)?;
        let pos = dataset(path, file, "/fluid/positions")?.shape();
        let vel = g
            .link_exists("velocities")
            .then(|| dataset(path, file, "/fluid/velocities").map(|d| d.shape()))
            .transpose()?;
        let types = g
            .link_exists("types")
            .then(|| dataset(path, file, "/fluid/types").map(|d| d.shape()))
            .transpose()?;
        if pos.len() == 3 {
            out.push_str("    <Grid Name=\"fluid\" GridType=\"Collection\" CollectionType=\"Temporal\">\n");
            for (f, (t, s)) in times.iter().zip(&steps).enumerate() {
                let _ = writeln!(out, "      <Grid Name=\"fluid_{s}\" GridType=\"Uniform\">");
                let _ = writeln!(out, "        <Time Value=\"{t:e}\" />");
                let _ = writeln!(
                    out,
                    "        <Topology TopologyType=\"Polyvertex\" NumberOfElements=\"{}\" NodesPerElement=\"1\" />",
                    pos[1]
                );
                out.push_str("        <Geometry GeometryType=\"XYZ\">\n");
                hyperslab(
                    &mut out,
                    flavor,
                    "          ",
                    &h5name,
                    "/fluid/positions",
                    &pos,
                    f,
                    F64,
                );
                out.push_str("        </Geometry>\n");
                if let Some(vel) = &vel {
                    out.push_str("        <Attribute Name=\"velocity\" AttributeType=\"Vector\" Center=\"Node\">\n");
                    hyperslab(
                        &mut out,
                        flavor,
                        "          ",
                        &h5name,
                        "/fluid/velocities",
                        vel,
                        f,
                        F64,
                    );
                    out.push_str("        </Attribute>\n");
                }
                if let Some(ty) = &types {
                    out.push_str("        <Attribute Name=\"type\" AttributeType=\"Scalar\" Center=\"Node\">\n");
                    hyperslab(&mut out, flavor, "          ", &h5name, "/fluid/types", ty, f, U8);
                    out.push_str("        </Attribute>\n");
                }
                out.push_str("      </Grid>\n");
            }
            out.push_str("    </Grid>\n");
        }
    }

    // Binned fields: one 3-D CoRectMesh per field, cell-centred values.
    if file.link_exists("/fields") {
        let fg = file.group("/fields").map_err(|e| IoError::hdf5(path, "/fields", e))?;
        let mut names = fg.member_names().map_err(|e| IoError::hdf5(path, "/fields", e))?;
        names.sort();
        for name in names {
            let gname = format!("/fields/{name}");
            let g = file.group(&gname).map_err(|e| IoError::hdf5(path, gname.as_str(), e))?;
            if !g.link_exists("values") {
                continue;
            }
            let origin: Vec<f64> = get_attr_array(path, &g, "origin")?;
            let spacing: Vec<f64> = get_attr_array(path, &g, "spacing")?;
            let shape: Vec<u64> = get_attr_array(path, &g, "shape")?;
            let comps: u64 = get_attr(path, &g, "components")?;
            if origin.len() != 3 || spacing.len() != 3 || shape.len() != 3 {
                continue;
            }
            let vshape = dataset(path, &g, "values")?.shape();
            let (times, steps) = frame_clock(path, &g)?;
            let kind = match comps {
                1 => "Scalar",
                3 => "Vector",
                6 => "Tensor6",
                9 => "Tensor",
                _ => "Matrix",
            };
            let ename = xml_escape(&name);
            let _ = writeln!(
                out,
                "    <Grid Name=\"field_{ename}\" GridType=\"Collection\" CollectionType=\"Temporal\">"
            );
            for (f, (t, s)) in times.iter().zip(&steps).enumerate() {
                let _ = writeln!(out, "      <Grid Name=\"{ename}_{s}\" GridType=\"Uniform\">");
                let _ = writeln!(out, "        <Time Value=\"{t:e}\" />");
                // Points are bin corners, z y x order (x fastest), values are per cell.
                let _ = writeln!(
                    out,
                    "        <Topology TopologyType=\"3DCoRectMesh\" Dimensions=\"{} {} {}\" />",
                    shape[2] + 1,
                    shape[1] + 1,
                    shape[0] + 1
                );
                out.push_str("        <Geometry GeometryType=\"ORIGIN_DXDYDZ\">\n");
                let _ = writeln!(
                    out,
                    "          <DataItem Dimensions=\"3\" {F64} Format=\"XML\">{:e} {:e} {:e}</DataItem>",
                    origin[2], origin[1], origin[0]
                );
                let _ = writeln!(
                    out,
                    "          <DataItem Dimensions=\"3\" {F64} Format=\"XML\">{:e} {:e} {:e}</DataItem>",
                    spacing[2], spacing[1], spacing[0]
                );
                out.push_str("        </Geometry>\n");
                let _ = writeln!(
                    out,
                    "        <Attribute Name=\"{ename}\" AttributeType=\"{kind}\" Center=\"Cell\">"
                );
                hyperslab(
                    &mut out,
                    flavor,
                    "          ",
                    &h5name,
                    &format!("{gname}/values"),
                    &vshape,
                    f,
                    F64,
                );
                out.push_str("        </Attribute>\n      </Grid>\n");
            }
            out.push_str("    </Grid>\n");
        }
    }
    out.push_str("  </Domain>\n</Xdmf>\n");
    Ok(out)
}
