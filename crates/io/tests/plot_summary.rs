//! Plot helper, run summary and progress reporter.

use hemodpd_io::plot::{line_chart, line_chart_with, ChartOptions, Series};
use hemodpd_io::progress::{Progress, ProgressMode};
use hemodpd_io::summary::{read_summary_json, write_summary_json};

#[test]
fn charts_with_lines_points_and_error_bars() {
    let dir = tempfile::tempdir().unwrap();
    let sim: Vec<(f64, f64)> = (0..=20)
        .map(|i| (i as f64 * 10.0, 7.8 + 0.04 * i as f64 * 10.0))
        .collect();
    let exp = vec![(0.0, 7.8), (67.0, 10.2), (134.0, 13.1), (193.0, 15.0)];
    let path = dir.path().join("chart.png");
    line_chart(
        &path,
        "Axial diameter vs force",
        "force (pN)",
        "diameter (µm)",
        &[
            Series::line("simulation", sim.clone()),
            Series::error_bars("Mills et al. 2004", exp.clone(), vec![0.2, 0.4, 0.6, 0.8]),
            Series::points("points", vec![(50.0, 9.0), (f64::NAN, 1.0)]).with_color(200, 0, 0),
            Series::line_with_points("both", vec![(0.0, 8.0), (200.0, 16.0)]),
        ],
    )
    .unwrap();
    if let Ok(d) = std::env::var("HEMODPD_IO_KEEP_PLOT") {
        std::fs::copy(&path, std::path::Path::new(&d).join("chart.png")).unwrap();
    }
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(&bytes[..4], b"\x89PNG");
    assert!(bytes.len() > 5000);

    // Fixed ranges, a single point and an empty series do not break the auto ranges.
    let p2 = dir.path().join("small.png");
    let opts = ChartOptions {
        width: 400,
        height: 300,
        y_range: Some((0.0, 20.0)),
        ..Default::default()
    };
    line_chart_with(
        &p2,
        "t",
        "x",
        "y",
        &[Series::points("one", vec![(1.0, 1.0)]), Series::line("none", vec![])],
        &opts,
    )
    .unwrap();
    assert!(p2.exists());

    // Mismatched error count: an error naming the file.
    let e = line_chart(
        dir.path().join("bad.png"),
        "t",
        "x",
        "y",
        &[Series::error_bars("e", exp, vec![1.0])],
    )
    .unwrap_err();
    assert!(e.to_string().contains("bad.png"), "{e}");
}

#[test]
fn summary_json_is_written_atomically() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("runs/a");
    let v = serde_json::json!({"scenario": "shear", "tank_treading_hz": 12.5, "frames": 100});
    let p = write_summary_json(&run, &v).unwrap();
    assert_eq!(p, run.join("summary.json"));
    assert!(!run.join("summary.json.tmp").exists());
    assert_eq!(read_summary_json(&run).unwrap(), v);
    let v2 = serde_json::json!({"scenario": "shear", "done": true});
    write_summary_json(&run, &v2).unwrap();
    assert_eq!(read_summary_json(&run).unwrap(), v2);
}

#[test]
fn progress_log_lines() {
    let mut p = Progress::new(1000, 100, ProgressMode::Quiet, 1e-3, "ms");
    let line = p.status_line(550, 2.0);
    assert!(line.starts_with("step 550/1000 (55%)"), "{line}");
    assert!(
        line.contains("ms") && line.contains("steps/s") && line.contains("ETA"),
        "{line}"
    );
    for s in 100..=1000 {
        p.update(s, s as f64);
    }
    p.finish(1000, 1000.0);
    // Log mode writes to stderr without a terminal; it must not panic either.
    let mut p = Progress::new(10, 0, ProgressMode::Log, 1.0, "s");
    for s in 0..=10 {
        p.update(s, s as f64);
    }
    p.println("message");
    p.finish(10, 10.0);
}
