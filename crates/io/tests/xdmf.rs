//! The XDMF companion file refers only to datasets that exist, with their real shapes, and its
//! hyperslabs, topologies and attributes are consistent with them. Parsed as XML (quick-xml).

mod common;

use std::collections::BTreeMap;
use std::path::Path;

use common::*;
use glam::DVec3;
use hemodpd_io::trajectory::{GridSpec, TrajectoryWriter};
use hemodpd_io::{Quantity, WriterOptions};
use quick_xml::events::Event;

#[derive(Debug, Default)]
struct El {
    name: String,
    attrs: BTreeMap<String, String>,
    children: Vec<El>,
    text: String,
}

impl El {
    fn attr(&self, k: &str) -> &str {
        self.attrs
            .get(k)
            .map(|s| s.as_str())
            .unwrap_or_else(|| panic!("<{}> lacks attribute {k}", self.name))
    }
    fn child(&self, name: &str) -> &El {
        self.children
            .iter()
            .find(|c| c.name == name)
            .unwrap_or_else(|| panic!("<{}> lacks child <{name}>", self.name))
    }
}

fn parse(xml: &str) -> El {
    let mut reader = quick_xml::Reader::from_str(xml);
    let mut stack: Vec<El> = vec![El::default()];
    let open = |e: &quick_xml::events::BytesStart| {
        let mut el = El {
            name: String::from_utf8(e.name().as_ref().to_vec()).unwrap(),
            ..El::default()
        };
        for a in e.attributes() {
            let a = a.unwrap();
            el.attrs.insert(
                String::from_utf8(a.key.as_ref().to_vec()).unwrap(),
                a.unescape_value().unwrap().into_owned(),
            );
        }
        el
    };
    loop {
        match reader.read_event().unwrap() {
            Event::Start(e) => stack.push(open(&e)),
            Event::Empty(e) => {
                let el = open(&e);
                stack.last_mut().unwrap().children.push(el);
            }
            Event::End(_) => {
                let el = stack.pop().unwrap();
                stack.last_mut().unwrap().children.push(el);
            }
            Event::Text(t) => stack.last_mut().unwrap().text.push_str(&t.unescape().unwrap()),
            Event::Eof => break,
            _ => {}
        }
    }
    assert_eq!(stack.len(), 1, "unbalanced XML");
    stack.pop().unwrap()
}

fn dims(s: &str) -> Vec<usize> {
    s.split_whitespace().map(|d| d.parse().unwrap()).collect()
}

/// Resolves a data item to the shape it yields, checking it against the HDF5 file.
fn check_item(item: &El, h5: &hdf5::File, h5name: &str) -> Vec<usize> {
    let declared = dims(item.attr("Dimensions"));
    match item.attrs.get("ItemType").map(|s| s.as_str()) {
        Some("HyperSlab") => {
            assert_eq!(item.children.len(), 2, "hyperslab has a selection and a source");
            let sel = &item.children[0];
            let src = &item.children[1];
            let src_shape = check_item(src, h5, h5name);
            let nd = src_shape.len();
            assert_eq!(dims(sel.attr("Dimensions")), vec![3, nd]);
            let v = dims(&sel.text);
            assert_eq!(v.len(), 3 * nd);
            let (start, stride, count) = (&v[..nd], &v[nd..2 * nd], &v[2 * nd..]);
            for d in 0..nd {
                assert!(count[d] >= 1 && stride[d] >= 1);
                assert!(
                    start[d] + (count[d] - 1) * stride[d] < src_shape[d],
                    "hyperslab out of bounds on axis {d}: {v:?} in {src_shape:?}"
                );
            }
            assert_eq!(count[0], 1, "one frame per grid");
            assert_eq!(
                declared,
                count[1..],
                "hyperslab Dimensions = count without the frame axis"
            );
            declared
        }
        _ => match item.attr("Format") {
            "HDF" => {
                let text = item.text.trim();
                let (file, rest) = text.split_once(':').expect("file:/dataset");
                assert_eq!(file, h5name, "refers to the file beside it");
                // Xdmf3 hyperslab: `/dataset|start:stride:count:dims`.
                let (ds, slab) = match rest.split_once('|') {
                    Some((ds, slab)) => (ds, Some(slab)),
                    None => (rest, None),
                };
                let d = h5.dataset(ds).unwrap_or_else(|_| panic!("dataset {ds} missing"));
                let prec: usize = item.attr("Precision").parse().unwrap();
                assert_eq!(d.dtype().unwrap().size(), prec, "{ds}: Precision");
                let Some(slab) = slab else {
                    assert_eq!(d.shape(), declared, "{ds}: Dimensions vs real shape");
                    return declared;
                };
                let parts: Vec<Vec<usize>> = slab.split(':').map(dims).collect();
                assert_eq!(parts.len(), 4, "start:stride:count:dims");
                let (start, stride, count, full) = (&parts[0], &parts[1], &parts[2], &parts[3]);
                assert_eq!(*full, d.shape(), "{ds}: hyperslab dims vs real shape");
                for k in 0..full.len() {
                    assert!(count[k] >= 1 && stride[k] >= 1);
                    assert!(start[k] + (count[k] - 1) * stride[k] < full[k], "{ds}: out of bounds");
                }
                assert_eq!(count[0], 1, "one frame per grid");
                assert_eq!(declared, count[1..], "{ds}: Dimensions = count without the frame axis");
                declared
            }
            "XML" => {
                let n = item
                    .text
                    .split_whitespace()
                    .filter(|v| v.parse::<f64>().is_ok())
                    .count();
                assert_eq!(n, product(&declared), "inline XML values vs Dimensions");
                declared
            }
            f => panic!("unknown Format {f}"),
        },
    }
}

fn product(v: &[usize]) -> usize {
    v.iter().product()
}

/// Checks both dialects and returns the frame count of each temporal collection.
fn check_xdmf(h5_path: &Path) -> BTreeMap<String, usize> {
    let a = check_xdmf_file(h5_path, &h5_path.with_extension("xmf"), "2.0");
    let b = check_xdmf_file(h5_path, &h5_path.with_extension("xmf3"), "3.0");
    assert_eq!(a, b);
    a
}

fn check_xdmf_file(h5_path: &Path, xmf: &Path, version: &str) -> BTreeMap<String, usize> {
    let xml = std::fs::read_to_string(xmf).unwrap();
    let root = parse(&xml);
    let xdmf = root.child("Xdmf");
    assert_eq!(xdmf.attr("Version"), version);
    let domain = xdmf.child("Domain");
    let h5 = hdf5::File::open(h5_path).unwrap();
    let h5name = h5_path.file_name().unwrap().to_str().unwrap();
    let mut frames = BTreeMap::new();
    for coll in &domain.children {
        assert_eq!(coll.attr("CollectionType"), "Temporal");
        let mut last_t = f64::NEG_INFINITY;
        for grid in &coll.children {
            let t: f64 = grid.child("Time").attr("Value").parse().unwrap();
            assert!(t > last_t, "times increase");
            last_t = t;
            let topo = grid.child("Topology");
            let geom = grid.child("Geometry");
            let (n_points, n_cells) = match topo.attr("TopologyType") {
                "Triangle" => {
                    let shape = check_item(topo.child("DataItem"), &h5, h5name);
                    let n_el: usize = topo.attr("NumberOfElements").parse().unwrap();
                    assert_eq!(shape, vec![n_el, 3]);
                    assert_eq!(geom.attr("GeometryType"), "XYZ");
                    let g = check_item(geom.child("DataItem"), &h5, h5name);
                    (product(&g) / 3, n_el)
                }
                "Polyvertex" => {
                    let n_el: usize = topo.attr("NumberOfElements").parse().unwrap();
                    let g = check_item(geom.child("DataItem"), &h5, h5name);
                    assert_eq!(product(&g), 3 * n_el);
                    (n_el, n_el)
                }
                "3DCoRectMesh" => {
                    let d = dims(topo.attr("Dimensions"));
                    assert_eq!(geom.attr("GeometryType"), "ORIGIN_DXDYDZ");
                    assert_eq!(geom.children.len(), 2);
                    for item in &geom.children {
                        assert_eq!(check_item(item, &h5, h5name), vec![3]);
                    }
                    (product(&d), d.iter().map(|n| n - 1).product())
                }
                other => panic!("unexpected topology {other}"),
            };
            for attr in grid.children.iter().filter(|c| c.name == "Attribute") {
                let shape = check_item(attr.child("DataItem"), &h5, h5name);
                let comps = match attr.attr("AttributeType") {
                    "Scalar" => 1,
                    "Vector" => 3,
                    t => panic!("type {t}"),
                };
                let n = if attr.attr("Center") == "Cell" {
                    n_cells
                } else {
                    n_points
                };
                assert_eq!(product(&shape), n * comps, "{} size", attr.attr("Name"));
            }
        }
        frames.insert(coll.attr("Name").to_string(), coll.children.len());
    }
    frames
}

#[test]
fn xdmf_refers_to_existing_datasets_with_their_shapes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.h5");
    let (sphere, tri) = uv_sphere(6, 8);
    let grid = GridSpec {
        origin: DVec3::new(0.0, -1.0, -2.0),
        spacing: DVec3::new(1.0, 0.5, 0.25),
        shape: [5, 4, 3],
    };
    let options = WriterOptions {
        xdmf_interval: std::time::Duration::ZERO,
        ..Default::default()
    };
    let mut w = TrajectoryWriter::create_with(&path, &meta(), options).unwrap();
    w.write_mesh(&tri).unwrap();
    let mut noise = Noise(3);
    let fluid: Vec<DVec3> = (0..30).map(|_| noise.vec3()).collect();
    for s in 0..6u64 {
        let pos: Vec<DVec3> = sphere.iter().map(|p| *p + DVec3::X * s as f64).collect();
        w.append_membrane_frame(s, s as f64, &pos, Some(&sphere), &[]).unwrap();
        if s % 2 == 0 {
            w.append_fluid_frame(s, s as f64, &fluid, Some(&fluid), Some(&[1u8; 30]))
                .unwrap();
            let v = vec![1.0; grid.len() * 3];
            w.append_field("velocity", s, s as f64, &grid, 3, &v, Quantity::Velocity)
                .unwrap();
            let d = vec![3.0; grid.len()];
            w.append_field("density", s, s as f64, &grid, 1, &d, Quantity::NumberDensity)
                .unwrap();
        }
        // Regenerated after every frame (interval zero): consistent at each stage.
        let frames = check_xdmf(&path);
        assert_eq!(frames["membrane"], s as usize + 1);
    }
    w.close().unwrap();
    let frames = check_xdmf(&path);
    assert_eq!(frames["membrane"], 6);
    assert_eq!(frames["fluid"], 3);
    assert_eq!(frames["field_velocity"], 3);
    assert_eq!(frames["field_density"], 3);

    // Regenerating from the closed file gives the same text.
    let before = std::fs::read_to_string(path.with_extension("xmf")).unwrap();
    hemodpd_io::xdmf::write_xdmf(&path).unwrap();
    assert_eq!(before, std::fs::read_to_string(path.with_extension("xmf")).unwrap());

    // After a resume that drops frames, the XDMF lists only the kept ones.
    let w = TrajectoryWriter::open_append(&path, 2).unwrap();
    w.close().unwrap();
    let frames = check_xdmf(&path);
    assert_eq!(frames["membrane"], 3);
    assert_eq!(frames["fluid"], 2);
}
