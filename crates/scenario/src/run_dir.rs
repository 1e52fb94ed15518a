//! A run's output directory, owned by the driver: the names of its files, the lock that gives
//! it to one run at a time, its checkpoints (written atomically, the previous one kept) and the
//! one rule by which a resumed run reopens its trajectory. Every kind goes through here.
//!
//! * **Lock.** [`DirLock::acquire`] takes `DIR/hemodpd.lock` before any file of the directory is
//!   touched. The lock is an advisory `flock` on that file, which the kernel releases when the
//!   process ends however it ends, and the file names the holder (host, process id, process
//!   start, start time, command) for the message a second run gets. A lock file that no process
//!   holds is stale (its run was killed) and is taken over. Within one process the lock is
//!   re-entrant (a sweep task holds it around the run it starts).
//! * **Checkpoints.** [`save_checkpoint`] writes `checkpoint.h5.tmp`, fsyncs it, links the
//!   current `checkpoint.h5` to `checkpoint.prev.h5` and renames the new file over
//!   `checkpoint.h5`: at every instant `checkpoint.h5` is a complete checkpoint, and the one
//!   before it stays until the next is complete. [`load_checkpoint`] falls back to
//!   `checkpoint.prev.h5`, with a warning, when `checkpoint.h5` is damaged: a run is
//!   deterministic, so continuing from the older state gives the same results and costs only
//!   the steps between the two.
//! * **Trajectory.** [`open_trajectory`]: a run from the start creates the file; a resumed run
//!   keeps the frames up to the last scheduled frame at or before its checkpoint's step and
//!   drops the later ones (frames written after the checkpoint, and the off-schedule frame an
//!   interrupt writes), so the resumed trajectory neither repeats nor loses a frame.

use std::collections::HashSet;
use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, Write};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use hemodpd_engine::Particles;
use hemodpd_io::checkpoint::Checkpoint;
use hemodpd_io::TrajectoryWriter;
use serde::{Deserialize, Serialize};

use crate::context::{RunContext, RunError};

/// Name of the checkpoint file in the output directory.
pub const CHECKPOINT_FILE: &str = "checkpoint.h5";
/// The checkpoint before the last, kept until the next one is complete.
pub const PREVIOUS_CHECKPOINT_FILE: &str = "checkpoint.prev.h5";
/// Name of the trajectory file in the output directory.
pub const TRAJECTORY_FILE: &str = "trajectory.h5";
/// The lock file of an output directory.
pub const LOCK_FILE: &str = "hemodpd.lock";

/// An output-file error as a run error.
pub(crate) fn out_err(e: hemodpd_io::IoError) -> RunError {
    RunError::Output(e.to_string())
}

/// An engine error as a run error.
pub(crate) fn engine_err(e: hemodpd_engine::EngineError) -> RunError {
    RunError::Engine(e.to_string())
}

/// The directories this process has locked (canonical paths): a nested acquire is re-entrant.
static HELD: Mutex<Option<HashSet<PathBuf>>> = Mutex::new(None);

/// The lock of an output directory, held until dropped (then the lock file is removed).
#[derive(Debug)]
pub struct DirLock {
    /// The lock file and its open handle; `None` for a nested acquire in the process that holds it.
    held: Option<(PathBuf, PathBuf, File)>,
    /// The holder a stale lock file named, when this acquire took it over.
    took_over: Option<String>,
}

/// The start time of process `pid` in clock ticks since boot (field 22 of `/proc/PID/stat`):
/// with the pid it names a process uniquely, even after the pid is reused.
fn process_start_ticks(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // the command name (field 2) is in parentheses and may hold spaces: count after the last ')'
    let rest = &stat[stat.rfind(')')? + 1..];
    rest.split_whitespace().nth(19)?.parse().ok()
}

/// This machine's host name.
pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|_| "unknown-host".into())
}

fn lock_text() -> String {
    let pid = std::process::id();
    let started = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    let command: Vec<String> = std::env::args().collect();
    let v = serde_json::json!({
        "host": host_name(),
        "pid": pid,
        "process_start_ticks": process_start_ticks(pid),
        "started_unix_s": started,
        "command": command.join(" "),
    });
    format!("{v}\n")
}

/// A one-line description of the holder a lock file names.
fn describe_holder(text: &str) -> String {
    match serde_json::from_str::<serde_json::Value>(text) {
        Ok(v) => {
            let started = v["started_unix_s"].as_u64().map_or("an unknown time".to_string(), |s| {
                let ago = std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map(|d| d.as_secs().saturating_sub(s))
                    .unwrap_or(0);
                format!("{ago} s ago (unix time {s})")
            });
            format!(
                "process {} on host {}, started {}: `{}`",
                v["pid"],
                v["host"].as_str().unwrap_or("?"),
                started,
                v["command"].as_str().unwrap_or("?")
            )
        }
        Err(_) if text.trim().is_empty() => "a process that has not yet written its name".to_string(),
        Err(_) => format!("an unreadable holder ({:?})", text.trim()),
    }
}

impl DirLock {
    /// Locks `dir` (created if missing) for this process, before any other file in it is
    /// touched. Fails with [`RunError::Locked`], having changed nothing, when another process
    /// holds it.
    pub fn acquire(dir: &Path) -> Result<DirLock, RunError> {
        let io = |path: &Path, source| RunError::Io {
            path: path.to_path_buf(),
            source,
        };
        std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
        let key = dir.canonicalize().map_err(|e| io(dir, e))?;
        {
            let mut held = HELD.lock().unwrap_or_else(|p| p.into_inner());
            if held.get_or_insert_with(HashSet::new).contains(&key) {
                return Ok(DirLock {
                    held: None,
                    took_over: None,
                });
            }
        }
        let path = key.join(LOCK_FILE);
        // a lock file unlinked by its releasing holder between our open and our lock is not the
        // lock any more: retry on the file now at the path
        for _ in 0..100 {
            let mut file = OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .map_err(|e| io(&path, e))?;
            match file.try_lock() {
                Ok(()) => {}
                Err(std::fs::TryLockError::WouldBlock) => {
                    let mut text = String::new();
                    let _ = file.read_to_string(&mut text);
                    return Err(RunError::Locked {
                        dir: dir.to_path_buf(),
                        lock_file: path.clone(),
                        holder: describe_holder(&text),
                    });
                }
                Err(std::fs::TryLockError::Error(e)) => return Err(io(&path, e)),
            }
            let same = match (file.metadata(), std::fs::metadata(&path)) {
                (Ok(a), Ok(b)) => a.ino() == b.ino() && a.dev() == b.dev(),
                _ => false,
            };
            if !same {
                continue;
            }
            let mut old = String::new();
            let _ = file.read_to_string(&mut old);
            let took_over = (!old.trim().is_empty()).then(|| describe_holder(&old));
            file.set_len(0).map_err(|e| io(&path, e))?;
            file.rewind().map_err(|e| io(&path, e))?;
            file.write_all(lock_text().as_bytes()).map_err(|e| io(&path, e))?;
            let _ = file.sync_all();
            HELD.lock()
                .unwrap_or_else(|p| p.into_inner())
                .get_or_insert_with(HashSet::new)
                .insert(key.clone());
            return Ok(DirLock {
                held: Some((key, path, file)),
                took_over,
            });
        }
        Err(RunError::Locked {
            dir: dir.to_path_buf(),
            lock_file: path,
            holder: "processes that keep replacing its lock file".into(),
        })
    }

    /// The holder named by a stale lock file this acquire took over (its process was gone).
    pub fn took_over(&self) -> Option<&str> {
        self.took_over.as_deref()
    }

    /// Whether this is the outermost acquire of the process (it removes the lock on drop).
    pub fn is_owner(&self) -> bool {
        self.held.is_some()
    }
}

impl Drop for DirLock {
    fn drop(&mut self) {
        if let Some((key, path, file)) = self.held.take() {
            // unlink while still locked: a waiting process then finds a new file (see acquire);
            // only our own file: if the directory was removed and made again under us, the
            // lock file now at the path is another process's
            let ours = match (file.metadata(), std::fs::metadata(&path)) {
                (Ok(a), Ok(b)) => a.ino() == b.ino() && a.dev() == b.dev(),
                _ => false,
            };
            if ours {
                let _ = std::fs::remove_file(&path);
            }
            drop(file);
            if let Some(h) = HELD.lock().unwrap_or_else(|p| p.into_inner()).as_mut() {
                h.remove(&key);
            }
        }
    }
}

/// Fault injection for tests: with `HEMODPD_FAULT_CHECKPOINT_ABORT=K`, the process aborts while
/// writing its K-th checkpoint (counted from 1 in this process), after the temporary file was
/// partly written and before it replaces anything.
fn fault_abort_in_checkpoint(tmp: &Path) {
    use std::sync::atomic::{AtomicU64, Ordering};
    static WRITES: AtomicU64 = AtomicU64::new(0);
    let Some(k) = std::env::var("HEMODPD_FAULT_CHECKPOINT_ABORT")
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
    else {
        return;
    };
    if WRITES.fetch_add(1, Ordering::SeqCst) + 1 == k {
        // a half-written file, as a kill in the middle of the write leaves it
        if let Ok(len) = std::fs::metadata(tmp).map(|m| m.len()) {
            if let Ok(f) = OpenOptions::new().write(true).open(tmp) {
                let _ = f.set_len(len / 2);
            }
        }
        eprintln!("fault injection: aborting while writing checkpoint {k}");
        std::process::abort();
    }
}

/// Writes `ck` as the directory's checkpoint: the new file complete and synced first, then the
/// current one kept as [`PREVIOUS_CHECKPOINT_FILE`], then the new one renamed into place.
pub fn save_checkpoint(ck: &Checkpoint, ctx: &RunContext) -> Result<(), RunError> {
    save_checkpoint_in(ck, &ctx.out_dir)
}

/// [`save_checkpoint`] into `dir`.
pub fn save_checkpoint_in(ck: &Checkpoint, dir: &Path) -> Result<(), RunError> {
    let path = dir.join(CHECKPOINT_FILE);
    let prev = dir.join(PREVIOUS_CHECKPOINT_FILE);
    let tmp = dir.join(format!("{CHECKPOINT_FILE}.tmp"));
    ck.write_synced(&tmp).map_err(out_err)?;
    fault_abort_in_checkpoint(&tmp);
    let io = |p: &Path, source| RunError::Io {
        path: p.to_path_buf(),
        source,
    };
    if path.exists() {
        match std::fs::remove_file(&prev) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(io(&prev, e)),
        }
        // a hard link keeps `path` in place throughout; a file system without links gets a copy
        if std::fs::hard_link(&path, &prev).is_err() {
            std::fs::copy(&path, &prev).map_err(|e| io(&prev, e))?;
        }
    }
    std::fs::rename(&tmp, &path).map_err(|e| io(&path, e))?;
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// A checkpoint as loaded for a resume, with the warning to show when it is the previous one.
#[derive(Debug)]
pub struct LoadedCheckpoint {
    pub checkpoint: Checkpoint,
    /// Set when `checkpoint.h5` was damaged and `checkpoint.prev.h5` was used.
    pub warning: Option<String>,
}

/// Loads the checkpoint of `dir` for a resume: `checkpoint.h5`, or, when that is missing or
/// damaged (truncated, a bad checksum), the previous one with a warning that says why. The
/// damaged file is left in place for inspection; the next checkpoint replaces it.
pub fn load_checkpoint(dir: &Path) -> Result<LoadedCheckpoint, RunError> {
    let path = dir.join(CHECKPOINT_FILE);
    let prev = dir.join(PREVIOUS_CHECKPOINT_FILE);
    let err = |message: String| RunError::Resume {
        dir: dir.to_path_buf(),
        message,
    };
    let first = if path.exists() {
        match Checkpoint::load(&path) {
            Ok(ck) => {
                return Ok(LoadedCheckpoint {
                    checkpoint: ck,
                    warning: None,
                })
            }
            Err(e) => format!("{CHECKPOINT_FILE} is damaged ({e})"),
        }
    } else {
        format!("there is no {CHECKPOINT_FILE} (runs write it after their first checkpoint interval, at the end and on Ctrl-C)")
    };
    if !prev.exists() {
        return Err(err(format!(
            "{first}, and there is no {PREVIOUS_CHECKPOINT_FILE} to fall back on"
        )));
    }
    match Checkpoint::load(&prev) {
        Ok(ck) => {
            let warning = Some(format!(
                "{first}; continuing from the previous checkpoint {} (step {}), which gives the same results: the steps since it are run again",
                prev.display(),
                ck.step
            ));
            Ok(LoadedCheckpoint {
                checkpoint: ck,
                warning,
            })
        }
        Err(e) => Err(err(format!(
            "{first}, and {PREVIOUS_CHECKPOINT_FILE} is damaged too ({e})"
        ))),
    }
}

/// The trajectory of a run. A run from the start (`resumed` false) creates it with `create`. A
/// resumed run reopens it and keeps the frames up to `last_frame`, the last step at or before its
/// checkpoint at which the kind's schedule writes a frame; the later ones (written after the
/// checkpoint, or off schedule by an interrupt) are dropped. With no frame due yet (`None`), or
/// no file, the resumed run creates the file anew: there is nothing in it to keep.
pub fn open_trajectory(
    ctx: &RunContext,
    resumed: bool,
    last_frame: Option<u64>,
    create: impl FnOnce(&Path) -> Result<TrajectoryWriter, hemodpd_io::IoError>,
) -> Result<TrajectoryWriter, RunError> {
    let writer = open_trajectory_at(&ctx.out_dir.join(TRAJECTORY_FILE), resumed, last_frame, create)?;
    write_paraview_view(&ctx.out_dir)?;
    Ok(writer)
}

/// The script beside every `trajectory.h5` that opens the run in ParaView, set up: the cell,
/// the tube of a capillary run, the binned fluid velocity (docs/output.md, "ParaView").
pub const PARAVIEW_VIEW_FILE: &str = "view_in_paraview.py";

/// Its text: one generic pvpython script, reading the run's `summary.json` (or, while the run
/// goes on, `trajectory.h5`) for the scenario.
pub const PARAVIEW_VIEW_SCRIPT: &str = include_str!("paraview_view.py");

/// Writes [`PARAVIEW_VIEW_FILE`] into `dir` (replacing an older version of it).
pub fn write_paraview_view(dir: &Path) -> Result<(), RunError> {
    let path = dir.join(PARAVIEW_VIEW_FILE);
    std::fs::write(&path, PARAVIEW_VIEW_SCRIPT).map_err(|source| RunError::Io { path, source })
}

/// [`open_trajectory`] for a trajectory file of another name.
pub fn open_trajectory_at(
    path: &Path,
    resumed: bool,
    last_frame: Option<u64>,
    create: impl FnOnce(&Path) -> Result<TrajectoryWriter, hemodpd_io::IoError>,
) -> Result<TrajectoryWriter, RunError> {
    match last_frame {
        Some(cut) if resumed && path.exists() => TrajectoryWriter::open_append(path, cut).map_err(out_err),
        _ => create(path).map_err(out_err),
    }
}

/// The last step at or before `step` of a schedule that writes a frame every `every` steps from
/// step `first` on; `None` when no frame is due yet (or the schedule writes none).
pub fn last_scheduled_frame(step: u64, first: u64, every: u64) -> Option<u64> {
    (every > 0 && step >= first).then(|| first + (step - first) / every * every)
}

/// Stores the particle arrays (positions, velocities, the last forces, types, ids).
pub(crate) fn particles_into_checkpoint(ck: &mut Checkpoint, p: &Particles) {
    ck.insert_vec3("positions", &p.pos);
    ck.insert_vec3("velocities", &p.vel);
    ck.insert_vec3("forces", &p.force);
    ck.insert_u32("types", p.ptype.iter().map(|&t| t as u32).collect());
    ck.insert_u32("ids", p.id.clone());
}

/// Reads the particle arrays back, checking that their lengths agree.
pub(crate) fn particles_from_checkpoint(ck: &Checkpoint) -> Result<Particles, RunError> {
    let bad = |e: hemodpd_io::IoError| RunError::Output(format!("checkpoint: {e}"));
    let pos = ck.vec3s("positions", None).map_err(bad)?;
    let n = pos.len();
    let particles = Particles {
        pos,
        vel: ck.vec3s("velocities", Some(n)).map_err(bad)?,
        force: ck.vec3s("forces", Some(n)).map_err(bad)?,
        ptype: ck.u32s("types").map_err(bad)?.iter().map(|&t| t as u16).collect(),
        id: ck.u32s("ids").map_err(bad)?.to_vec(),
    };
    if particles.ptype.len() != n || particles.id.len() != n {
        return Err(RunError::Output(format!(
            "checkpoint: {n} positions but {} types and {} ids",
            particles.ptype.len(),
            particles.id.len()
        )));
    }
    Ok(particles)
}

/// Stores `value` as JSON bytes under `name`.
pub(crate) fn json_into_checkpoint<T: Serialize>(ck: &mut Checkpoint, name: &str, value: &T) -> Result<(), RunError> {
    let bytes = serde_json::to_vec(value).map_err(|e| RunError::Output(format!("checkpoint {name}: {e}")))?;
    ck.insert_u8(name, bytes);
    Ok(())
}

/// Reads back a value stored by [`json_into_checkpoint`].
pub(crate) fn json_from_checkpoint<T: for<'de> Deserialize<'de>>(ck: &Checkpoint, name: &str) -> Result<T, RunError> {
    let bytes = ck.u8s(name).map_err(|e| RunError::Output(format!("checkpoint: {e}")))?;
    serde_json::from_slice(bytes).map_err(|e| RunError::Output(format!("checkpoint {name}: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmpdir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("hemodpd-rundir-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn lock_names_its_holder_and_is_removed_on_drop() {
        let d = tmpdir("lock");
        let lock = DirLock::acquire(&d).unwrap();
        assert!(lock.is_owner() && lock.took_over().is_none());
        let text = std::fs::read_to_string(d.join(LOCK_FILE)).unwrap();
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["pid"].as_u64(), Some(std::process::id() as u64));
        assert_eq!(v["host"].as_str(), Some(host_name().as_str()));
        assert!(v["process_start_ticks"].as_u64().is_some());
        // re-entrant in the process that holds it; the nested guard leaves the lock in place
        let nested = DirLock::acquire(&d).unwrap();
        assert!(!nested.is_owner());
        drop(nested);
        assert!(d.join(LOCK_FILE).exists());
        drop(lock);
        assert!(!d.join(LOCK_FILE).exists());
        std::fs::remove_dir_all(&d).unwrap();
    }

    /// A run whose directory is deleted and made again under it (and locked there by another
    /// run, whose lock file is a new file at the same path) leaves that lock file alone when it
    /// ends: releasing removes only the file it locked.
    #[test]
    fn release_leaves_another_runs_lock_file_alone() {
        let d = tmpdir("recreated");
        let lock = DirLock::acquire(&d).unwrap();
        std::fs::remove_dir_all(&d).unwrap();
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join(LOCK_FILE), "{\"pid\": 1}").unwrap();
        drop(lock);
        assert_eq!(std::fs::read_to_string(d.join(LOCK_FILE)).unwrap(), "{\"pid\": 1}");
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_lock_file_nobody_holds_is_stale_and_taken_over() {
        let d = tmpdir("stale");
        std::fs::create_dir_all(&d).unwrap();
        let dead = r#"{"host":"node7","pid":4242424,"process_start_ticks":1,"started_unix_s":1,"command":"hemodpd run x.toml"}"#;
        std::fs::write(d.join(LOCK_FILE), dead).unwrap();
        let lock = DirLock::acquire(&d).unwrap();
        let old = lock.took_over().expect("a stale holder is reported");
        assert!(old.contains("4242424") && old.contains("node7"), "{old}");
        drop(lock);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn frame_schedule_cut() {
        assert_eq!(last_scheduled_frame(25, 0, 10), Some(20));
        assert_eq!(last_scheduled_frame(30, 0, 10), Some(30));
        assert_eq!(last_scheduled_frame(5, 10, 4), None);
        assert_eq!(last_scheduled_frame(17, 10, 4), Some(14));
        assert_eq!(last_scheduled_frame(9, 0, 0), None);
    }
}
