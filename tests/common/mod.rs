//! Helpers the end-to-end tests of the cell-in-flow kinds (`capillary.rs`, `shear.rs`) share.

// each test file uses its own subset
#![allow(dead_code)]

use hemodpd_scenario::{run, RunContext, RunError, Scenario};
use serde_json::Value;
use std::path::Path;

/// A JSON number as f64 (NaN when it is not one).
pub fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

/// Runs `s` in `ctx`'s directory interrupted at step `stops[0]`, resumes it interrupted at
/// `stops[1]`, then resumes it to the end.
pub fn run_in_three_parts(s: &Scenario, ctx: &mut RunContext, stops: [u64; 2]) {
    ctx.stop_at_step = Some(stops[0]);
    let first = run(s, ctx);
    assert!(
        matches!(first, Err(RunError::Interrupted { step, .. }) if step == stops[0]),
        "{first:?}"
    );
    ctx.stop_at_step = Some(stops[1]);
    let second = hemodpd_scenario::resume(&ctx.out_dir, ctx);
    assert!(
        matches!(second, Err(RunError::Interrupted { step, .. }) if step == stops[1]),
        "{second:?}"
    );
    ctx.stop_at_step = None;
    hemodpd_scenario::resume(&ctx.out_dir, ctx).unwrap();
}

/// Two runs of one scenario ended in the same state: the same time series `series` (a CSV of
/// the run directory; `what` names it in the failure), the same step, positions and velocities
/// in the final checkpoint, and each scheduled trajectory frame once.
pub fn assert_same_end(whole: &Path, parts: &Path, series: &str, what: &str) {
    let a = std::fs::read_to_string(whole.join(series)).unwrap();
    let b = std::fs::read_to_string(parts.join(series)).unwrap();
    assert_eq!(a, b, "{what} differ");
    let ck = |d: &Path| hemodpd_io::checkpoint::Checkpoint::load(d.join("checkpoint.h5")).unwrap();
    let (ca, cb) = (ck(whole), ck(parts));
    assert_eq!(ca.step, cb.step);
    assert_eq!(
        ca.vec3s("positions", None).unwrap(),
        cb.vec3s("positions", None).unwrap()
    );
    assert_eq!(
        ca.vec3s("velocities", None).unwrap(),
        cb.vec3s("velocities", None).unwrap()
    );
    let t = hemodpd_io::TrajectoryReader::open(parts.join("trajectory.h5")).unwrap();
    let u = hemodpd_io::TrajectoryReader::open(whole.join("trajectory.h5")).unwrap();
    assert_eq!(t.membrane_steps().unwrap(), u.membrane_steps().unwrap());
}

/// The text `hemodpd run SCENARIO --explain-units` prints (the command must succeed).
pub fn explain_units(scenario: &Path) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_hemodpd"))
        .args(["run", scenario.to_str().unwrap(), "--explain-units"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

/// `text` contains every one of `keys`, and its line containing `group` ends in the same
/// number twice (the group in SI and in model units, as printed).
pub fn assert_explained(text: &str, keys: &[&str], group: &str) {
    for key in keys {
        assert!(text.contains(key), "no {key} in\n{text}");
    }
    let line = text.lines().find(|l| l.contains(group)).unwrap();
    let nums: Vec<&str> = line.split_whitespace().rev().take(2).collect();
    assert_eq!(nums[0], nums[1], "{line}");
}
