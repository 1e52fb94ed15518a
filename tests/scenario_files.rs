//! Scenario files: every shipped scenario parses, and every bad file in `tests/bad_scenarios/`
//! fails before any work with a message that names the file and contains each line of the
//! `.expected` file beside it (the key, the value and what is allowed).

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn shipped_scenarios_parse() {
    let mut n = 0;
    for entry in std::fs::read_dir(root().join("scenarios")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            hemodpd_scenario::load(&path, &[]).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            n += 1;
        }
    }
    assert!(n >= 2, "expected the shipped scenarios, found {n}");
}

#[test]
fn bad_scenarios_give_clear_errors() {
    let dir = root().join("tests/bad_scenarios");
    let mut checked = 0;
    let mut entries: Vec<PathBuf> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).collect();
    entries.sort();
    for path in entries.iter().filter(|p| p.extension().is_some_and(|e| e == "toml")) {
        let expected = std::fs::read_to_string(path.with_extension("expected"))
            .unwrap_or_else(|_| panic!("{} has no .expected file", path.display()));
        let err = match hemodpd_scenario::load(path, &[]) {
            Ok(_) => panic!("{} was accepted", path.display()),
            Err(e) => e.to_string(),
        };
        let name = path.file_name().unwrap().to_string_lossy();
        assert!(err.contains(&*name), "{name}: message does not name the file: {err}");
        for line in expected.lines().filter(|l| !l.trim().is_empty()) {
            assert!(err.contains(line.trim()), "{name}: message lacks {line:?}:\n{err}");
        }
        checked += 1;
    }
    assert!(checked >= 15, "only {checked} bad files checked");
}

#[test]
fn bad_override_is_rejected() {
    let path = root().join("scenarios/stretching.toml");
    let e = hemodpd_scenario::load(&path, &["membrane.vertices=50".into()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("membrane.vertices") && e.contains("50"), "{e}");
    let e = hemodpd_scenario::load(&path, &["novalue".into()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("key=value"), "{e}");
}

/// The CLI exits non-zero with the message on stderr, and does no work (no output directory).
#[test]
fn cli_rejects_a_bad_file_before_any_work() {
    let out = std::env::temp_dir().join(format!("hemodpd-badrun-{}", std::process::id()));
    let bad = root().join("tests/bad_scenarios/negative_vertices.toml");
    let res = Command::new(env!("CARGO_BIN_EXE_hemodpd"))
        .args(["run", bad.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet"])
        .output()
        .unwrap();
    assert!(!res.status.success());
    let stderr = String::from_utf8_lossy(&res.stderr);
    assert!(
        stderr.contains("membrane.vertices") && stderr.contains("-500"),
        "{stderr}"
    );
    assert!(
        !Path::new(&out).exists(),
        "a rejected scenario must not create its output directory"
    );
}
