use hemodpd_membrane::forces::MembraneConstants;
use hemodpd_membrane::meshgen::{self, MeshGenOptions};
use hemodpd_membrane::params::ModelParams;
use hemodpd_membrane::shape::EvansFung;
use hemodpd_membrane::stretch::{self, StretchOptions};
use hemodpd_membrane::MembraneModel;
fn main() {
    let n: usize = std::env::args().nth(1).map(|s| s.parse().unwrap()).unwrap_or(500);
    let p = ModelParams::coarse_grained(n, 300.0).unwrap();
    let c = MembraneConstants::from_params_um_pn(&p);
    let t = std::time::Instant::now();
    let shape = EvansFung::healthy_um();
    let m0 = meshgen::initial_mesh(&shape, n, 1).unwrap();
    println!("initial {:.2}s {:?}", t.elapsed().as_secs_f64(), m0.quality().unwrap());
    let (mesh, rep) = meshgen::generate(&shape, &c, &MeshGenOptions::new(n, 1)).unwrap();
    println!(
        "relaxed {:.2}s {:?}\n{:?}",
        t.elapsed().as_secs_f64(),
        rep,
        mesh.quality().unwrap()
    );
    for stressfree in [true, false] {
        let topo = mesh.topology().unwrap();
        let model = if stressfree {
            match MembraneModel::stress_free(&mesh.topology().unwrap(), &mesh.vertices, &c) {
                Ok(m) => println!("{:?}", m.tension_ratio_distribution()),
                Err(e) => {
                    println!("{e}");
                    continue;
                }
            };
            MembraneModel::stress_free(&topo, &mesh.vertices, &c).unwrap()
        } else {
            MembraneModel::uniform(&topo, &c, mesh.area(), mesh.volume()).unwrap()
        };
        let t = std::time::Instant::now();
        let opts = StretchOptions {
            forces: vec![0.0, 16.0, 30.8, 68.0, 130.5, 192.7],
            end_fraction: 0.05,
            tolerance: 1e-4,
            max_iterations: 200000,
        };
        let pts = stretch::stretch(&model, &mesh.vertices, &opts, |p| {
            println!(
                "F={:.1} DA={:.3} DT={:.3} it={} res={:.2e} dA={:.2e} dV={:.2e}",
                p.force,
                p.axial_diameter,
                p.transverse_diameter,
                p.iterations,
                p.residual,
                p.area_deviation,
                p.volume_deviation
            )
        });
        println!(
            "stress_free={stressfree} {:.2}s ok={}",
            t.elapsed().as_secs_f64(),
            pts.is_ok()
        );
        if let Err(e) = pts {
            println!("{e}");
        }
    }
}
