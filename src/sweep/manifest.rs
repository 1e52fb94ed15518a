//! `DIR/sweep-manifest.json`: what a sweep directory holds, written before any point runs. A
//! rerun (or a Slurm task, or `sweep-collect`) reads it back; a rerun with a different scenario
//! file content, `--set`s, axes or zip mode is refused, so old and new results never mix.

use super::grid::{fnv1a64, Axis, Point};
use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub const MANIFEST_FILE: &str = "sweep-manifest.json";
pub const MANIFEST_VERSION: u32 = 1;

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Manifest {
    pub manifest_version: u32,
    /// The hemodpd version that wrote the manifest (informational).
    pub hemodpd_version: String,
    /// Absolute path of the scenario file.
    pub scenario_file: PathBuf,
    /// FNV-1a 64 of the scenario file's bytes, hex.
    pub scenario_fnv1a64: String,
    /// The scenario file's text, compared on every rerun.
    pub scenario_content: String,
    /// The scenario's kind (the table's columns depend on it).
    pub scenario_kind: String,
    /// `--set` overrides applied to every point.
    pub sets: Vec<String>,
    pub axes: Vec<Axis>,
    pub zip: bool,
    pub points: Vec<Point>,
}

impl Manifest {
    pub fn new(
        scenario_file: PathBuf,
        content: String,
        kind: String,
        sets: Vec<String>,
        axes: Vec<Axis>,
        zip: bool,
        points: Vec<Point>,
    ) -> Self {
        Manifest {
            manifest_version: MANIFEST_VERSION,
            hemodpd_version: env!("CARGO_PKG_VERSION").to_string(),
            scenario_file,
            scenario_fnv1a64: format!("{:016x}", fnv1a64(content.as_bytes())),
            scenario_content: content,
            scenario_kind: kind,
            sets,
            axes,
            zip,
            points,
        }
    }

    /// Reads `dir/sweep-manifest.json`.
    pub fn read(dir: &Path) -> Result<Manifest> {
        let path = dir.join(MANIFEST_FILE);
        let text = std::fs::read_to_string(&path).with_context(|| {
            format!(
                "reading {} (is {} a sweep directory? `hemodpd sweep` writes this file first)",
                path.display(),
                dir.display()
            )
        })?;
        let m: Manifest =
            serde_json::from_str(&text).with_context(|| format!("{} is not a sweep manifest", path.display()))?;
        if m.manifest_version != MANIFEST_VERSION {
            bail!(
                "{}: manifest_version {} is not supported (this hemodpd reads {MANIFEST_VERSION})",
                path.display(),
                m.manifest_version
            );
        }
        Ok(m)
    }

    pub fn write(&self, dir: &Path) -> Result<()> {
        hemodpd_io::summary::write_json_atomic(dir.join(MANIFEST_FILE), self)
            .with_context(|| format!("writing {}", dir.join(MANIFEST_FILE).display()))
    }

    /// What differs between the sweep recorded in `self` and the one asked for now (empty when
    /// they are the same sweep). The scenario file's path may differ, its content may not.
    pub fn differences(&self, now: &Manifest) -> Vec<String> {
        let mut d = Vec::new();
        if self.scenario_content != now.scenario_content {
            let line = self
                .scenario_content
                .lines()
                .zip(now.scenario_content.lines())
                .position(|(a, b)| a != b)
                .unwrap_or_else(|| {
                    self.scenario_content
                        .lines()
                        .count()
                        .min(now.scenario_content.lines().count())
                });
            d.push(format!(
                "the scenario file's content changed (hash {} when the sweep began, {} now; first difference at line {}): {}",
                self.scenario_fnv1a64,
                now.scenario_fnv1a64,
                line + 1,
                now.scenario_file.display()
            ));
        }
        if self.sets != now.sets {
            d.push(format!(
                "the --set overrides changed (was [{}], now [{}])",
                self.sets.join(" "),
                now.sets.join(" ")
            ));
        }
        if self.axes != now.axes {
            let show = |axes: &[Axis]| {
                axes.iter()
                    .map(|a| format!("--vary {}={}", a.key, a.values.join(",")))
                    .collect::<Vec<_>>()
                    .join(" ")
            };
            d.push(format!(
                "the grid changed (was `{}`, now `{}`)",
                show(&self.axes),
                show(&now.axes)
            ));
        }
        if self.zip != now.zip {
            d.push(format!(
                "the combination mode changed (was {}, now {})",
                zip_word(self.zip),
                zip_word(now.zip)
            ));
        }
        d
    }
}

fn zip_word(zip: bool) -> &'static str {
    if zip {
        "--zip"
    } else {
        "the cartesian product"
    }
}

/// Opens the sweep directory for the sweep `now`: a new or empty directory gets the manifest;
/// one with the same sweep's manifest is continued; anything else is refused before any work.
/// Returns true when the sweep continues an earlier one.
pub fn open_or_create(dir: &Path, now: &Manifest) -> Result<bool> {
    if dir.join(MANIFEST_FILE).exists() {
        let old = Manifest::read(dir)?;
        let diff = old.differences(now);
        if !diff.is_empty() {
            bail!(
                "{} holds a different sweep, begun with other settings: {}. Its results are kept as they are; \
                 choose a new --out for this sweep (or delete {} to start it over)",
                dir.display(),
                diff.join("; "),
                dir.display()
            );
        }
        if old.scenario_file != now.scenario_file {
            // the same content at another path (the file moved): the points run from the new one
            Manifest {
                scenario_file: now.scenario_file.clone(),
                ..old
            }
            .write(dir)?;
        }
        return Ok(true);
    }
    if dir.exists() {
        let nonempty = std::fs::read_dir(dir)
            .with_context(|| format!("reading {}", dir.display()))?
            .next()
            .is_some();
        if nonempty {
            bail!(
                "{} exists and is not a sweep directory (no {MANIFEST_FILE}); choose a new --out",
                dir.display()
            );
        }
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    now.write(dir)?;
    Ok(false)
}
