//! `hemodpd sweep ... --emit-slurm DIR`: a Slurm job-array script with one array task per point.
//! Each task runs `hemodpd sweep-task DIR INDEX`, which skips a finished point, resumes a point
//! with a checkpoint and runs any other point from the start.

use super::manifest::Manifest;
use std::fmt::Write as _;
use std::path::Path;

pub const SCRIPT_FILE: &str = "sweep.sbatch";
/// Slurm writes each task's stdout and stderr here, inside the sweep directory.
pub const LOG_DIR: &str = "slurm";

/// The per-task resources of the emitted script.
#[derive(Clone, Debug)]
pub struct SlurmOptions {
    /// `--time` (Slurm's formats: MM, MM:SS, HH:MM:SS, D-HH, D-HH:MM, D-HH:MM:SS).
    pub time: String,
    /// `--mem` (e.g. 2G); none leaves the cluster's default.
    pub mem: Option<String>,
    /// `--partition`; none leaves the cluster's default.
    pub partition: Option<String>,
    /// `--account`; none leaves the user's default.
    pub account: Option<String>,
    /// `--cpus-per-task`, also the threads of each point.
    pub cpus: usize,
}

/// A bad `--slurm-*` value.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SlurmError {
    #[error("--slurm-time {value}: not a Slurm time limit; allowed: MM, MM:SS, HH:MM:SS, D-HH, D-HH:MM or D-HH:MM:SS (e.g. 02:00:00)")]
    Time { value: String },
    #[error("--slurm-mem {value}: not a Slurm memory size; allowed: a positive integer with an optional K, M, G or T suffix (e.g. 4G)")]
    Mem { value: String },
    #[error("--{option} {value}: allowed: letters, digits, `_`, `-` and `.`")]
    Name { option: &'static str, value: String },
    #[error("--slurm-cpus {value}: allowed: an integer from 1 to 4096")]
    Cpus { value: usize },
    #[error("--emit-slurm {value}: the sweep directory's path must not contain whitespace (Slurm's #SBATCH lines cannot hold it)")]
    Dir { value: String },
}

impl SlurmOptions {
    /// Checks every option before anything is written.
    pub fn validate(&self) -> Result<(), SlurmError> {
        if !valid_time(&self.time) {
            return Err(SlurmError::Time {
                value: self.time.clone(),
            });
        }
        if let Some(m) = &self.mem {
            let digits = m.trim_end_matches(['K', 'M', 'G', 'T', 'k', 'm', 'g', 't']);
            let suffix_len = m.len() - digits.len();
            if digits.is_empty() || suffix_len > 1 || !digits.bytes().all(|b| b.is_ascii_digit()) || digits == "0" {
                return Err(SlurmError::Mem { value: m.clone() });
            }
        }
        for (option, v) in [("slurm-partition", &self.partition), ("slurm-account", &self.account)] {
            if let Some(v) = v {
                if v.is_empty() || !v.chars().all(|c| c.is_ascii_alphanumeric() || "_-.".contains(c)) {
                    return Err(SlurmError::Name {
                        option,
                        value: v.clone(),
                    });
                }
            }
        }
        if self.cpus == 0 || self.cpus > 4096 {
            return Err(SlurmError::Cpus { value: self.cpus });
        }
        Ok(())
    }
}

fn valid_time(t: &str) -> bool {
    let num = |s: &str| !s.is_empty() && s.len() <= 4 && s.bytes().all(|b| b.is_ascii_digit());
    let (days, rest) = match t.split_once('-') {
        Some((d, r)) => (Some(d), r),
        None => (None, t),
    };
    if let Some(d) = days {
        if !num(d) {
            return false;
        }
    }
    let parts: Vec<&str> = rest.split(':').collect();
    let ok = parts.iter().all(|p| num(p));
    match days {
        Some(_) => ok && (1..=3).contains(&parts.len()),
        None => ok && (1..=3).contains(&parts.len()) && t != "0",
    }
}

/// A Slurm time limit in seconds (formats as in [`valid_time`]; `None` when it is not one).
pub fn time_limit_seconds(t: &str) -> Option<u64> {
    if !valid_time(t) {
        return None;
    }
    let (days, rest) = match t.split_once('-') {
        Some((d, r)) => (d.parse::<u64>().ok()?, r),
        None => (0, t),
    };
    let v: Vec<u64> = rest.split(':').map(|p| p.parse().ok()).collect::<Option<_>>()?;
    let secs = if t.contains('-') {
        // D-HH, D-HH:MM, D-HH:MM:SS
        match v.as_slice() {
            [h] => h * 3600,
            [h, m] => h * 3600 + m * 60,
            [h, m, s] => h * 3600 + m * 60 + s,
            _ => return None,
        }
    } else {
        // MM, MM:SS, HH:MM:SS
        match v.as_slice() {
            [m] => m * 60,
            [m, s] => m * 60 + s,
            [h, m, s] => h * 3600 + m * 60 + s,
            _ => return None,
        }
    };
    Some(days * 86_400 + secs)
}

/// How long before its time limit a task is sent SIGTERM (`#SBATCH --signal=B:TERM@LEAD`), in
/// seconds: a twentieth of the limit, at least 60 s and at most 600 s, and never more than half
/// the limit. hemodpd needs only the current step and one checkpoint (seconds for the shipped
/// scenarios); Slurm may send the signal up to 60 s earlier than asked.
pub fn signal_lead_seconds(limit_s: u64) -> u64 {
    (limit_s / 20).clamp(60, 600).min(limit_s / 2).max(1)
}

/// Checks that `dir` can appear in #SBATCH lines.
pub fn check_dir(dir: &Path) -> Result<(), SlurmError> {
    let s = dir.to_string_lossy();
    if s.chars().any(char::is_whitespace) || s.contains('\'') {
        return Err(SlurmError::Dir { value: s.into_owned() });
    }
    Ok(())
}

/// The job-array script for the sweep in `dir` (an absolute path), running `exe`.
pub fn script(dir: &Path, exe: &Path, m: &Manifest, opts: &SlurmOptions) -> String {
    let d = dir.display();
    let n = m.points.len();
    let name: String = m
        .scenario_file
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "sweep".into())
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "_-.".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect();
    let mut s = String::new();
    let _ = writeln!(s, "#!/bin/bash");
    let _ = writeln!(
        s,
        "# hemodpd sweep of {}: {n} points, one Slurm array task each.",
        m.scenario_file.display()
    );
    let _ = writeln!(s, "# Written by `hemodpd sweep --emit-slurm`; see docs/sweeps.md.");
    let _ = writeln!(s, "#   submit:    sbatch {d}/{SCRIPT_FILE}");
    let _ = writeln!(s, "#   watch:     squeue --me   (or: sacct -j JOBID)");
    let _ = writeln!(s, "#   collect:   hemodpd sweep-collect {d}");
    let _ = writeln!(
        s,
        "#   resubmit:  sbatch --array=3,7 {d}/{SCRIPT_FILE}   (the indices sweep-collect lists)"
    );
    let _ = writeln!(
        s,
        "# A task skips a finished point, resumes a point from its checkpoint, or runs it from the start."
    );
    let _ = writeln!(s, "#SBATCH --job-name=hemodpd-{name}");
    let _ = writeln!(s, "#SBATCH --array=0-{}", n.saturating_sub(1));
    let _ = writeln!(s, "#SBATCH --ntasks=1");
    let _ = writeln!(s, "#SBATCH --cpus-per-task={}", opts.cpus);
    let _ = writeln!(s, "#SBATCH --time={}", opts.time);
    // SIGTERM to the batch shell, which `exec` below makes hemodpd itself: it checkpoints and
    // exits (status 130); sweep-collect lists the point and its resubmit command resumes it
    if let Some(limit) = time_limit_seconds(&opts.time) {
        let _ = writeln!(s, "#SBATCH --signal=B:TERM@{}", signal_lead_seconds(limit));
    }
    if let Some(mem) = &opts.mem {
        let _ = writeln!(s, "#SBATCH --mem={mem}");
    }
    if let Some(p) = &opts.partition {
        let _ = writeln!(s, "#SBATCH --partition={p}");
    }
    if let Some(a) = &opts.account {
        let _ = writeln!(s, "#SBATCH --account={a}");
    }
    let _ = writeln!(s, "#SBATCH --output={d}/{LOG_DIR}/%A_%a.out");
    let _ = writeln!(s, "#SBATCH --open-mode=append");
    let _ = writeln!(s, "set -euo pipefail");
    let _ = writeln!(
        s,
        "HEMODPD=\"${{HEMODPD:-{}}}\"   # set HEMODPD to use another hemodpd binary",
        exe.display()
    );
    let _ = writeln!(
        s,
        "exec \"$HEMODPD\" sweep-task '{d}' \"$SLURM_ARRAY_TASK_ID\" --threads \"${{SLURM_CPUS_PER_TASK:-{}}}\"",
        opts.cpus
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts() -> SlurmOptions {
        SlurmOptions {
            time: "01:00:00".into(),
            mem: Some("2G".into()),
            partition: None,
            account: None,
            cpus: 2,
        }
    }

    #[test]
    fn time_limits_and_signal_leads() {
        for (t, secs) in [
            ("30", 1800),
            ("10:00", 600),
            ("01:00:00", 3600),
            ("1-00", 86_400),
            ("2-12:00", 216_000),
            ("1-00:00:30", 86_430),
            ("1", 60),
        ] {
            assert_eq!(time_limit_seconds(t), Some(secs), "{t}");
        }
        assert_eq!(time_limit_seconds("1h"), None);
        // short limits: half the limit; an hour: 3 minutes; days: 10 minutes
        assert_eq!(signal_lead_seconds(60), 30);
        assert_eq!(signal_lead_seconds(300), 60);
        assert_eq!(signal_lead_seconds(3600), 180);
        assert_eq!(signal_lead_seconds(86_400), 600);
        let text = script(
            Path::new("/sw"),
            Path::new("/bin/hemodpd"),
            &Manifest::new(
                "/s/capillary.toml".into(),
                String::new(),
                "capillary".into(),
                Vec::new(),
                Vec::new(),
                false,
                Vec::new(),
            ),
            &SlurmOptions {
                time: "1".into(),
                ..opts()
            },
        );
        assert!(text.contains("#SBATCH --signal=B:TERM@30\n"), "{text}");
        assert!(
            text.contains("exec \""),
            "the task must be the batch shell to get the signal: {text}"
        );
    }

    #[test]
    fn options_are_checked() {
        assert_eq!(opts().validate(), Ok(()));
        for t in ["30", "10:00", "01:00:00", "1-00", "2-12:00", "1-00:00:00"] {
            assert!(valid_time(t), "{t}");
        }
        for t in ["", "1h", "1:2:3:4", "-1", "a-01", "0"] {
            assert!(!valid_time(t), "{t}");
        }
        let e = SlurmOptions {
            mem: Some("lots".into()),
            ..opts()
        }
        .validate()
        .unwrap_err();
        assert!(e.to_string().contains("--slurm-mem lots"), "{e}");
        let e = SlurmOptions {
            partition: Some("a b".into()),
            ..opts()
        }
        .validate()
        .unwrap_err();
        assert!(e.to_string().contains("--slurm-partition a b"), "{e}");
        assert!(SlurmOptions { cpus: 0, ..opts() }.validate().is_err());
        assert!(check_dir(Path::new("/a b/c")).is_err());
    }
}
