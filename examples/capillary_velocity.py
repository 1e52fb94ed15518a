"""A tiny capillary run from Python, and the cell's velocity against time.

    pip install ./python matplotlib
    python examples/capillary_velocity.py [RUN_DIR] [FIGURE.png]

Runs the shipped capillary scenario shortened to 1.2 ms (rest, flow at 1 mm/s, recovery; about
a minute on 2 cores), reads the run's time series (cell.csv) as numpy arrays and plots the
cell's and the plasma's mean velocity, with the stages shaded. Executed by the package's tests.
"""

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import hemodpd  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("runs/capillary_velocity")
figure = Path(sys.argv[2]) if len(sys.argv) > 2 else out / "velocity.png"

run = hemodpd.run(
    ROOT / "scenarios" / "capillary.toml",
    {
        "tube.length_um": 20.0,
        "stage.0.duration_s": 0.0002,  # rest
        "stage.1.duration_s": 0.0006,  # flow at 1 mm/s
        "stage.2.duration_s": 0.0004,  # recovery
        "output.frame_every_s": 0.0002,
    },
    out=out,
)
series = run.time_series()
t_ms = series["time_s"] * 1e3
cell = series["cell_velocity_m_per_s"] * 1e3
plasma = series["fluid_velocity_m_per_s"] * 1e3

flowing = series["stage"] == 1
print(f"mean cell velocity in the flow: {cell[flowing].mean():.3f} mm/s "
      f"(plasma {plasma[flowing].mean():.3f} mm/s), {len(t_ms)} samples")

fig, ax = plt.subplots(figsize=(6, 3.2))
for k, colour in enumerate(["0.92", "#dbe9f6", "0.92"]):
    inside = series["stage"] == k
    if inside.any():
        ax.axvspan(t_ms[inside].min(), t_ms[inside].max(), color=colour, lw=0)
ax.plot(t_ms, plasma, color="0.4", lw=1, label="plasma (mean)")
ax.plot(t_ms, cell, color="#b2182b", lw=1.5, label="cell")
ax.set_xlabel("time (ms)")
ax.set_ylabel("velocity along the tube (mm/s)")
ax.legend(frameon=False)
ax.set_title(f"{run.summary['scenario']['tube']['diameter_um']} µm capillary: rest, flow, recovery")
fig.tight_layout()
figure.parent.mkdir(parents=True, exist_ok=True)
fig.savefig(figure, dpi=120)
print(f"figure: {figure}")
