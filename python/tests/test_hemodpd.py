"""The Python package against the CLI's own results (run by scripts/python_test.sh, part of the
README's test command). Runs are tiny versions of the shipped scenarios."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import hemodpd

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "scenarios"

# a capillary of 1.2 ms (rest, flow, recovery) in a 20 µm tube, a frame every 0.2 ms
SHORT_CAPILLARY = {
    "tube.length_um": 20.0,
    "stage.0.duration_s": 0.0002,
    "stage.1.duration_s": 0.0006,
    "stage.2.duration_s": 0.0004,
    "output.frame_every_s": 0.0002,
}
SHORT_SHEAR = {
    "shear.duration_strain": 0.4,
    "output.sample_every_strain": 0.05,
    "output.frame_every_strain": 0.1,
    "cell.vertices": 100,
    "shear.box_um": [12.0, 12.0, 10.0],
}


def hemodpd_cli() -> str:
    """The CLI binary `cargo test` builds (target/debug/hemodpd), or HEMODPD_BIN."""
    path = os.environ.get("HEMODPD_BIN") or str(ROOT / "target" / "debug" / "hemodpd")
    assert Path(path).exists(), f"{path} is missing: run `cargo test --workspace` (or build the CLI) first"
    return path


@pytest.fixture(scope="module")
def capillary(tmp_path_factory):
    out = tmp_path_factory.mktemp("cap") / "run"
    return hemodpd.run(SCENARIOS / "capillary.toml", SHORT_CAPILLARY, out=out, threads=2, progress=False)


def test_run_returns_the_summary_and_the_directory(capillary):
    s = capillary.summary
    assert s["scenario_kind"] == "capillary" == capillary.kind
    assert s["threads"] == 2
    assert Path(s["scenario_file"]) == SCENARIOS / "capillary.toml"
    # the overrides reached the run, as `--set` does
    assert json.loads(json.dumps(s["overrides"])) == [
        "tube.length_um=20.0", "stage.0.duration_s=0.0002", "stage.1.duration_s=0.0006",
        "stage.2.duration_s=0.0004", "output.frame_every_s=0.0002"]
    assert s["scenario"]["tube"]["length_um"] == 20.0
    assert [st["name"] for st in s["results"]["stages"]] == ["rest", "parachute", "recovery"]


def test_trajectory_arrays_match_the_files_own_analysis(capillary):
    t = capillary.trajectory()
    assert t.scenario_kind == "capillary" and t.has_membrane
    assert len(t) == 6  # frames every 0.2 ms (at whole steps) from 0 to 1 ms
    assert np.allclose(t.times, np.arange(6) * 2e-4, rtol=0, atol=1e-5)
    tri = t.triangles()
    assert tri.shape == (t.n_triangles, 3) and tri.dtype == np.uint32
    assert tri.max() == t.n_vertices - 1 == 499
    x = t.positions(-1)
    assert x.shape == (500, 3) and np.all(np.isfinite(x))
    v = t.velocities(-1)
    assert v is not None and v.shape == (500, 3)
    # the enclosed volume and area from our arrays equal the analysis of the same frame (Rust)
    a, b, c = x[tri[:, 0]], x[tri[:, 1]], x[tri[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    frames = hemodpd.analyze(t.path)["frames"]
    assert frames["area"][-1] == pytest.approx(area, rel=1e-12)
    assert frames["volume"][-1] == pytest.approx(volume, rel=1e-12)
    # the cell of Evans–Fung (A ≈ 135 µm², V ≈ 94 µm³) kept within 2 %
    assert np.all(np.abs(frames["area_deviation"]) < 0.02) and np.all(np.abs(frames["volume_deviation"]) < 0.02)
    assert frames["centroid"].shape == (6, 3)


def test_binned_fields_and_time_series(capillary):
    t = capillary.trajectory()
    assert sorted(t.fields) == ["density", "velocity"]
    info = t.fields["velocity"]
    u = t.field("velocity", 3)  # in the flow
    nx, ny, nz = info["shape"]
    assert u.shape == (nz, ny, nx, 3)
    # the flow runs along +z: the mean axial velocity of the bins is positive, the others near 0
    assert u[..., 2].mean() > 0 and abs(u[..., 0].mean()) < u[..., 2].mean()
    with pytest.raises(KeyError, match="pressure"):
        t.field("pressure", 0)
    with pytest.raises(IndexError):
        t.positions(6)
    ts = capillary.time_series()
    assert {"time_s", "cell_velocity_m_per_s", "axial_length_um"} <= set(ts)
    assert np.all(np.diff(ts["time_s"]) > 0)
    # the capillary measures recomputed from the frames: the length at each frame agrees with
    # cell.csv's sample at the same time (both are the extent along the tube)
    m = hemodpd.capillary_measures(t.path)
    assert len(m["time_s"]) == 6
    for tf, length in zip(m["time_s"][1:], m["axial_length_um"][1:]):
        k = np.argmin(np.abs(ts["time_s"] - tf))
        assert abs(ts["time_s"][k] - tf) < 1e-9
        assert length == pytest.approx(ts["axial_length_um"][k], rel=1e-9)


def test_explain_units_agrees_with_the_run(capillary):
    e = hemodpd.explain_units(SCENARIOS / "capillary.toml", SHORT_CAPILLARY)
    assert e["kind"] == "capillary" and "Fluid:" in e["text"]
    r = capillary.summary["results"]
    assert e["mapping"]["groups_si"] == r["groups_si"]
    assert e["mapping"]["groups_model"] == r["groups_model"]
    for k in ("length_m", "energy_j", "time_s", "thermal_factor"):
        assert e["mapping"][k] == r["unit_mapping"][k]
    assert e["mapping"]["groups_si"]["kappa_over_kbt"] == pytest.approx(200.0, rel=1e-9)
    # a kind in model units has no mapping
    assert hemodpd.explain_units(SCENARIOS / "dpd-fluid.toml")["mapping"] is None


def test_a_scenario_dict_runs_like_its_file(tmp_path):
    import tomllib
    d = tomllib.loads((SCENARIOS / "shear.toml").read_text())
    e_dict = hemodpd.explain_units(d, SHORT_SHEAR)
    e_file = hemodpd.explain_units(SCENARIOS / "shear.toml", SHORT_SHEAR)
    assert e_dict["mapping"] == e_file["mapping"]
    run = hemodpd.run(d, SHORT_SHEAR, out=tmp_path / "shear", threads=2, progress=False)
    assert (tmp_path / "shear" / "scenario.toml").exists()
    motion = hemodpd.shear_motion(run.trajectory().path)
    assert len(motion["frames"]["time"]) == len(run.trajectory()) >= 4
    # recomputed from the frames, the class and its window are the run's own
    c, own = motion["classification"], run.summary["results"]["motion"]
    assert c["class"] == own["class"] and c["undetermined_reason"] == own["undetermined_reason"]
    assert c["window_strain"] == pytest.approx(own["window_strain"], rel=1e-12)
    ts = run.time_series()
    assert "inclination_deg" in ts


def test_bad_input_names_the_key(tmp_path):
    with pytest.raises(ValueError, match=r"cell\.vertices.*-5"):
        hemodpd.run(SCENARIOS / "capillary.toml", {"cell.vertices": -5}, out=tmp_path / "bad", progress=False)
    assert not (tmp_path / "bad" / "summary.json").exists()
    with pytest.raises(ValueError, match="unknown field `diametre_um`.*diameter_um"):
        hemodpd.explain_units(SCENARIOS / "capillary.toml", {"tube.diametre_um": 5.0})
    with pytest.raises(ValueError, match="out="):
        hemodpd.run({"kind": "capillary"})
    with pytest.raises(TypeError):
        hemodpd.run(SCENARIOS / "capillary.toml", "tube.length_um=20")
    with pytest.raises(FileNotFoundError):
        hemodpd.open_run(tmp_path / "nowhere")


def test_ctrl_c_checkpoints_and_resume_finishes_as_if_uninterrupted(tmp_path):
    # long enough (≈ 2 s on 2 cores) that the interrupt, 0.3 s after the run starts, lands while it
    # steps on any machine (3000 steps could end first on a quiet one)
    sets = {"fluid.box_size": [8.0, 8.0, 8.0], "run.equilibration_steps": 200, "run.steps": 20000}
    whole = hemodpd.run(SCENARIOS / "dpd-fluid.toml", sets, out=tmp_path / "whole", threads=2, progress=False)
    out = tmp_path / "cut"

    def interrupt_when_stepping():
        # SIGINT as a terminal's Ctrl-C sends it, once the run has started writing
        for _ in range(2000):
            if (out / "hemodpd.lock").exists():
                time.sleep(0.3)
                os.kill(os.getpid(), signal.SIGINT)
                return
            time.sleep(0.005)

    # Python's own Ctrl-C handler, whatever this process inherited: a shell starts a background
    # job (`cmd &`) with SIGINT ignored, and Python then leaves it ignored
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    threading.Thread(target=interrupt_when_stepping, daemon=True).start()
    try:
        with pytest.raises(KeyboardInterrupt, match="resume"):
            hemodpd.run(SCENARIOS / "dpd-fluid.toml", sets, out=out, threads=2, progress=False)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert (out / "checkpoint.h5").exists() and not (out / "summary.json").exists()
    resumed = hemodpd.resume(out, threads=2, progress=False)
    fp = resumed.summary["results"]["final_state_fingerprint"]
    assert fp == whole.summary["results"]["final_state_fingerprint"]
    assert resumed.summary["results"]["resumed_from_step"] > 0


def test_read_sweep_as_a_table(tmp_path):
    out = tmp_path / "sweep"
    cmd = [hemodpd_cli(), "sweep", str(SCENARIOS / "dpd-fluid.toml"), "--vary", "run.timestep=0.01,0.02",
           "--vary", "seed=1,2", "--set", "fluid.box_size=[4.0, 4.0, 4.0]", "--set", "run.equilibration_steps=20",
           "--set", "run.steps=40", "--set", "run.sample_every=2", "--quiet", "--out", str(out)]
    subprocess.run(cmd, check=True, capture_output=True)
    table = hemodpd.read_sweep(out, as_pandas=False)
    assert list(table["index"]) == [0, 1, 2, 3]
    assert table["run.timestep"].dtype == np.float64
    assert sorted(set(table["run.timestep"])) == [0.01, 0.02]
    assert list(table["status"]) == ["done"] * 4
    sweep = json.loads((out / "sweep.json").read_text())
    for k, r in enumerate(sweep["runs"]):
        for c in sweep["columns"]:
            want = r["metrics"][c]
            if isinstance(want, (int, float)):
                assert table[c][k] == pytest.approx(want, rel=1e-15)
    df = hemodpd.read_sweep(out, as_pandas=True)
    assert len(df) == 4 and "kBT" in " ".join(df.columns)
    assert df["status"].tolist() == ["done"] * 4


def test_the_example_runs(tmp_path):
    env = dict(os.environ, MPLBACKEND="Agg")
    png = tmp_path / "velocity.png"
    r = subprocess.run([sys.executable, str(ROOT / "examples" / "capillary_velocity.py"), str(tmp_path / "run"), str(png)],
                       capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    assert png.exists() and png.stat().st_size > 10_000
    assert "mean cell velocity in the flow" in r.stdout
