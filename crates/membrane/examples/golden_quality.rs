fn main() {
    let m = hemodpd_membrane::meshio::read_mesh(std::path::Path::new(
        "../shared/reference/membrane_golden/mesh_N500.vertices.csv",
    ))
    .unwrap();
    println!("{:?}", m.quality().unwrap());
    let p = hemodpd_membrane::params::ModelParams::coarse_grained(500, 300.0).unwrap();
    let c = hemodpd_membrane::forces::MembraneConstants::from_params_um_pn(&p);
    let topo = m.topology().unwrap();
    match hemodpd_membrane::MembraneModel::stress_free(&topo, &m.vertices, &c) {
        Ok(model) => println!("{:?}", model.persistence_ratio_distribution()),
        Err(e) => println!("{e}"),
    }
}
