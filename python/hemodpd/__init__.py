"""hemodpd from Python: run scenarios, read their results as numpy arrays, analyse them.

    import hemodpd
    run = hemodpd.run("scenarios/capillary.toml", {"tube.diameter_um": 6.6}, out="runs/cap66")
    run.summary["results"]              # summary.json as a dict (SI units)
    series = run.time_series()          # cell.csv / motion.csv as a dict of numpy arrays
    traj = run.trajectory()             # trajectory.h5, read frame by frame
    x = traj.positions(-1)              # (N, 3) vertex positions of the last frame, m
    hemodpd.explain_units("scenarios/shear.toml")["mapping"]["groups_si"]

Everything is SI (m, s, Pa·s, N/m), as in the CLI's files. Runs go through the same code as
`hemodpd run` (docs/python.md); the first Ctrl-C asks the run to checkpoint and stop, then
raises KeyboardInterrupt with the command that resumes it (`hemodpd.resume(dir)`).
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Union

import numpy as np

from . import _hemodpd

__version__: str = _hemodpd.__version__

PathLike = Union[str, "os.PathLike[str]"]
Overrides = Union[Mapping[str, Any], Sequence[str], None]

__all__ = [
    "Run",
    "Trajectory",
    "run",
    "resume",
    "open_run",
    "open_trajectory",
    "explain_units",
    "analyze",
    "capillary_measures",
    "shear_motion",
    "read_sweep",
]


def _toml_value(v: Any) -> str:
    """A Python value as a TOML literal (for `--set KEY=VALUE`)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float, np.integer, np.floating)):
        f = float(v)
        if not np.isfinite(f):
            raise ValueError(f"override value {v!r} is not a finite number")
        return repr(int(v)) if isinstance(v, (int, np.integer)) else repr(f)
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string: JSON's escapes are valid TOML
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"override value {v!r} of type {type(v).__name__} has no TOML form")


def _sets(overrides: Overrides) -> List[str]:
    """Overrides as the CLI's `--set` arguments: a dict {"tube.diameter_um": 6.6} or a list of
    "KEY=VALUE" strings."""
    if overrides is None:
        return []
    if isinstance(overrides, Mapping):
        return [f"{k}={_toml_value(v)}" for k, v in overrides.items()]
    if isinstance(overrides, str):
        raise TypeError('overrides: a dict or a list of "KEY=VALUE" strings, not one string')
    return [str(s) for s in overrides]


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _columns(rows: List[Dict[str, Any]]) -> Dict[str, np.ndarray]:
    """A list of records as a dict of numpy arrays (nested lists become 2-D arrays)."""
    if not rows:
        return {}
    return {k: np.asarray([r[k] for r in rows]) for k in rows[0]}


class Trajectory:
    """A trajectory file (`trajectory.h5`, a stretching run's `shapes.h5`), read frame by frame:
    nothing is loaded until asked for. SI units (m, m/s, s)."""

    def __init__(self, path: PathLike):
        self.path = Path(path)
        info = json.loads(_hemodpd.trajectory_info(str(self.path)))
        self.scenario_kind: str = info["scenario_kind"]
        self.scenario_toml: str = info["scenario_toml"]
        self.steps = np.asarray(info["membrane_steps"], dtype=np.uint64)
        self.times = np.asarray(info["membrane_times_s"], dtype=np.float64)
        self.n_vertices: int = info["vertices"]
        self.n_triangles: int = info["triangles"]
        self.membrane_scalars: List[str] = info["membrane_scalars"]
        self.fluid_frames: int = info["fluid_frames"]
        self.fields: Dict[str, Dict[str, Any]] = info["fields"]
        self.has_membrane: bool = info["has_membrane"]

    def __len__(self) -> int:
        """The number of membrane frames."""
        return len(self.times)

    def __repr__(self) -> str:
        return (f"Trajectory({str(self.path)!r}: {self.scenario_kind}, {len(self)} membrane frames, "
                f"{self.n_vertices} vertices, fields {sorted(self.fields)})")

    def _index(self, i: int, n: int) -> int:
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"frame {i} out of range: {n} frames")
        return i

    def triangles(self) -> np.ndarray:
        """(M, 3) vertex indices of the membrane's triangles (uint32)."""
        b = _hemodpd.triangles(str(self.path))
        return np.frombuffer(b, dtype=np.uint32).reshape(-1, 3).copy()

    def frame(self, i: int) -> Dict[str, Any]:
        """Membrane frame i (negative counts from the end): step, time_s, positions (N, 3) m and
        velocities (N, 3) m/s or None."""
        step, time, x, v = _hemodpd.membrane_frame(str(self.path), self._index(i, len(self)))
        return {
            "step": step,
            "time_s": time,
            "positions": np.frombuffer(x, dtype=np.float64).reshape(-1, 3).copy(),
            "velocities": None if v is None else np.frombuffer(v, dtype=np.float64).reshape(-1, 3).copy(),
        }

    def positions(self, i: int) -> np.ndarray:
        """(N, 3) vertex positions of membrane frame i, m."""
        return self.frame(i)["positions"]

    def velocities(self, i: int) -> Optional[np.ndarray]:
        """(N, 3) vertex velocities of membrane frame i, m/s (None when the run stored none)."""
        return self.frame(i)["velocities"]

    def scalar(self, name: str) -> np.ndarray:
        """A per-frame membrane scalar (see `membrane_scalars`), one value per frame."""
        return np.frombuffer(_hemodpd.membrane_scalar(str(self.path), name), dtype=np.float64).copy()

    def field(self, name: str, i: int) -> np.ndarray:
        """Frame i of binned field `name` (e.g. "velocity", "density") as an array of shape
        (nz, ny, nx, components), SI; `fields[name]` has its grid (origin_m, spacing_m)."""
        info = self.fields.get(name)
        if info is None:
            raise KeyError(f"no field {name!r}; the file has {sorted(self.fields)}")
        _, _, b = _hemodpd.field_frame(str(self.path), name, self._index(i, info["frames"]))
        nx, ny, nz = info["shape"]
        return np.frombuffer(b, dtype=np.float64).reshape(nz, ny, nx, info["components"]).copy()

    def fluid(self, i: int) -> Dict[str, Any]:
        """Fluid frame i (when the run stored particles): positions, velocities, types."""
        step, time, x, v, t = _hemodpd.fluid_frame(str(self.path), self._index(i, self.fluid_frames))
        return {
            "step": step,
            "time_s": time,
            "positions": np.frombuffer(x, dtype=np.float64).reshape(-1, 3).copy(),
            "velocities": None if v is None else np.frombuffer(v, dtype=np.float64).reshape(-1, 3).copy(),
            "types": None if t is None else np.frombuffer(t, dtype=np.uint8).copy(),
        }

    def analyze(self) -> Dict[str, Any]:
        """`hemodpd analyze`'s shape metrics per frame (see `analyze`)."""
        return analyze(self.path)


class Run:
    """A run directory: `summary.json`, the time series and the trajectory."""

    def __init__(self, dir: PathLike):
        self.dir = Path(dir)
        if not self.dir.is_dir():
            raise FileNotFoundError(f"{self.dir}: no such run directory")

    def __repr__(self) -> str:
        return f"Run({str(self.dir)!r})"

    @property
    def summary(self) -> Dict[str, Any]:
        """summary.json (written when the run finished) as a dict."""
        path = self.dir / "summary.json"
        if not path.exists():
            raise FileNotFoundError(f"{path}: the run has not finished (resume it with hemodpd.resume)")
        return json.loads(path.read_text())

    @property
    def kind(self) -> str:
        return self.summary["scenario_kind"]

    def time_series(self) -> Dict[str, np.ndarray]:
        """The run's time series as numpy arrays, one per column: cell.csv (capillary),
        motion.csv (shear) or velocity_profile.csv (the wall scenarios). A stretching run has
        none: its force curve is in `summary["results"]`."""
        for name in ("cell.csv", "motion.csv", "velocity_profile.csv"):
            path = self.dir / name
            if path.exists():
                return _read_csv(path)
        raise FileNotFoundError(
            f"{self.dir}: no time series (cell.csv, motion.csv or velocity_profile.csv); "
            "a stretching run's curve is in summary['results']")

    def trajectory(self, name: str = "trajectory.h5") -> Trajectory:
        """The run's trajectory (`shapes.h5` for a stretching run)."""
        path = self.dir / name
        if not path.exists() and name == "trajectory.h5" and (self.dir / "shapes.h5").exists():
            path = self.dir / "shapes.h5"
        return Trajectory(path)


def _read_csv(path: Path) -> Dict[str, np.ndarray]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    out: Dict[str, np.ndarray] = {}
    for k, name in enumerate(header):
        col = [r[k] for r in body]
        try:
            out[name] = np.asarray([float(c) if c != "" else np.nan for c in col])
        except ValueError:
            out[name] = np.asarray(col)
    return out


def run(
    scenario: Union[PathLike, Mapping[str, Any]],
    overrides: Overrides = None,
    *,
    out: Optional[PathLike] = None,
    threads: Optional[int] = None,
    progress: bool = True,
) -> Run:
    """Runs a scenario in this process, as `hemodpd run` does, and returns its run directory.

    scenario: a scenario file, or the scenario as a dict (the TOML file's tables as dicts; it is
      written to OUT/scenario.toml, so `out` is required and relative paths in it are taken
      from OUT).
    overrides: {"tube.diameter_um": 6.6, "stage.1.duration_s": 0.01} or ["KEY=VALUE", ...].
    out: the run directory (default runs/STEM for a file); locked while the run holds it.
    threads: worker threads (default: every core). progress: the CLI's progress bars (stderr).
    Bad input raises ValueError naming the key, the value and the allowed range.
    """
    sets = _sets(overrides)
    if isinstance(scenario, Mapping):
        if out is None:
            raise ValueError("a scenario dict needs out= (its TOML is written there)")
        text = _hemodpd.scenario_toml_from_json(json.dumps(_jsonable(scenario)), sets)
        Path(out).mkdir(parents=True, exist_ok=True)
        path = Path(out) / "scenario.toml"
        path.write_text(text)
    else:
        path = Path(scenario)
    _, dir = _hemodpd.run_scenario(str(path), sets, None if out is None else str(out), threads, not progress)
    return Run(dir)


def resume(dir: PathLike, *, threads: Optional[int] = None, progress: bool = True) -> Run:
    """Resumes an interrupted run from its checkpoint (`hemodpd run --resume DIR`)."""
    _hemodpd.resume_run(str(dir), threads, not progress)
    return Run(dir)


def open_run(dir: PathLike) -> Run:
    """A finished or interrupted run directory."""
    return Run(dir)


def open_trajectory(path: PathLike) -> Trajectory:
    """A trajectory file, or the trajectory of a run directory."""
    p = Path(path)
    return Run(p).trajectory() if p.is_dir() else Trajectory(p)


def explain_units(scenario: Union[PathLike, Mapping[str, Any]], overrides: Overrides = None) -> Dict[str, Any]:
    """The mapping of a scenario's SI onto the DPD model, before any run: `kind`, `text` (what
    `hemodpd run --explain-units` prints) and `mapping` (None for kinds in model units):
    length_m, energy_j, time_s, thermal_factor, warnings, fluid (parameters and measured
    properties), fluid_reason, groups_si and groups_model (Reynolds, Mach, capillary number,
    kappa/kBT, ...)."""
    sets = _sets(overrides)
    if isinstance(scenario, Mapping):
        text = _hemodpd.scenario_toml_from_json(json.dumps(_jsonable(scenario)), sets)
        return json.loads(_hemodpd.explain_units(None, text, sets))
    return json.loads(_hemodpd.explain_units(str(scenario), None, sets))


def analyze(trajectory: PathLike) -> Dict[str, Any]:
    """`hemodpd analyze`: per-frame shape metrics as arrays (`frames`: step, time, centroid (F, 3),
    velocity, diameters, gyration eigenvalues, inclination, asphericity, deformation index, area
    and volume deviations, ...) and, for shear runs, `rotation` (tumbling and tank-treading
    rates). Definitions: docs/output.md, "Analysis"."""
    a = json.loads(_hemodpd.analyze(str(trajectory)))
    return {"frames": _columns(a["frames"]), "rotation": a["rotation"]}


def capillary_measures(trajectory: PathLike) -> Dict[str, np.ndarray]:
    """The capillary measures of every frame of a capillary trajectory (the columns of the run's
    cell.csv: cell velocity, axial length, deformation index, ...), recomputed from the file."""
    return _columns(json.loads(_hemodpd.capillary_measures(str(trajectory))))


def shear_motion(trajectory: PathLike, start_strain: Optional[float] = None) -> Dict[str, Any]:
    """A shear run's motion per frame (`frames`: time, centroid, inclination_deg,
    in_plane_anisotropy, tt_phase_rad) and its `classification` (tumbling, swinging,
    tank-treading, with rates) over the strain window from `start_strain`."""
    m = json.loads(_hemodpd.shear_motion(str(trajectory), start_strain))
    return {"frames": _columns(m["frames"]), "classification": m["classification"]}


def read_sweep(dir: PathLike, *, as_pandas: Optional[bool] = None) -> Any:
    """The table of a sweep directory (what `hemodpd sweep-collect` prints), one row per point:
    index, label, each varied key (as a number when it is one), status, the kind's figures,
    wall_time_s, dir. A pandas DataFrame when pandas is installed (or as_pandas=True), else a
    dict of numpy arrays."""
    t = json.loads(_hemodpd.sweep_table(str(dir)))
    keys = [a["key"] for a in t["axes"]]
    table: Dict[str, List[Any]] = {c: [] for c in ["index", "label", *keys, "status", *t["columns"], "wall_time_s", "dir"]}
    for r in t["runs"]:
        table["index"].append(r["index"])
        table["label"].append(r["label"])
        for k in keys:
            table[k].append(r["values"].get(k))
        table["status"].append(r["status"])
        for c in t["columns"]:
            table[c].append(r["metrics"].get(c))
        table["wall_time_s"].append(r["wall_time_s"])
        table["dir"].append(r["dir"])
    arrays = {k: _as_array(v) for k, v in table.items()}
    arrays["index"] = np.asarray(table["index"], dtype=np.int64)
    if as_pandas is None:
        try:
            import pandas  # noqa: F401
            as_pandas = True
        except ImportError:
            as_pandas = False
    if as_pandas:
        import pandas as pd
        return pd.DataFrame(arrays)
    return arrays


def _as_array(values: List[Any]) -> np.ndarray:
    """Numbers (with None as NaN) as float64, anything else as an object array."""
    try:
        return np.asarray([np.nan if v is None else float(v) for v in values], dtype=np.float64)
    except (TypeError, ValueError):
        return np.asarray(values, dtype=object)
