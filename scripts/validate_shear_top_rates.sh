#!/usr/bin/env bash
# Fischer's upper shear rates with κ/kBT exact (docs/validation.md §7, "At Fischer's top rate"):
# N = 500 at 28.9 mPa·s in the viscous fluid (`model.fluid = "auto"`, `thermal_factor =
# "exact"`), 10 strain units in a 16 × 14 × 12 µm box, the rotation fitted over strain 3–10, at
# 130 and 260 1/s, elastic and with the membrane viscosity of Hochmuth's recovery (6.3e-7 N·s/m,
# central form). Runs through `hemodpd sweep` (resumable: run it again to continue) and prints
# the table with Fischer's cells at each rate (tests/data/shear_ttf_fischer_28.9mPas.csv).
# About 50 minutes on 2 cores (measured: 7.5 and 22 min at 130 1/s, 10.7 min central at 260 1/s).
#   scripts/validate_shear_top_rates.sh [SWEEP_DIR] [STRAIN]
# STRAIN (default 10) shortens the runs for a quick check of the script itself.
set -euo pipefail
cd "$(dirname "$0")/.."
dir="${1:-${TMPDIR:-/tmp}/hemodpd-shear-top-rates}"
strain="${2:-10}"
cargo build -q --release --bin hemodpd
bin=target/release/hemodpd
common=(--set 'model.fluid="auto"' --set 'model.thermal_factor="exact"' --set 'shear.box_um=[16.0,14.0,12.0]'
  --set "shear.duration_strain=$strain" --set "shear.analysis_start_strain=$(python3 -c "print(0.3 * $strain)")"
  --vary shear.shear_rate_per_s=130,260 --quiet)
"$bin" sweep scenarios/shear.toml --set cell.parameters=paper "${common[@]}" --out "$dir/elastic"
"$bin" sweep scenarios/shear.toml --set cell.parameters=paper "${common[@]}" --out "$dir/central" \
  --set cell.membrane_viscosity_pa_s_m=6.3e-7 --set 'cell.membrane_viscosity_form="central"'
python3 - "$dir" <<'EOF'
import csv, json, statistics, sys
from pathlib import Path
d = Path(sys.argv[1])
cells = []
for row in csv.reader(open("tests/data/shear_ttf_fischer_28.9mPas.csv")):
    try:  # eta_out_mPas, shear_rate_per_s, ttf_over_shear_rate (f/γ̇, f in Hz)
        cells.append((float(row[1]), float(row[2])))
    except (ValueError, IndexError):
        pass
print("| η_m | γ̇ (1/s) | model f/γ̇ (fitted rotation) | Fischer's cells within ±20 %: median (n) | model / Fischer | crossings | wall (s) |")
print("|---|---|---|---|---|---|---|")
for name in ("elastic", "central"):
    for run in json.load(open(d / name / "sweep.json"))["runs"]:
        r = json.load(open(Path(run["dir"]) / "summary.json"))["results"]
        rate = float(run["values"]["shear.shear_rate_per_s"])
        model = r["membrane_rotation"]["over_shear_rate"]
        near = [f for g, f in cells if abs(g / rate - 1) <= 0.2]
        med = statistics.median(near) if near else float("nan")
        print(f"| {'0' if name == 'elastic' else '6.3e-7 (central)'} | {rate:g} | {model:.4f} | {med:.4f} ({len(near)}) "
              f"| {model / med:.2f} | {r['crossings']['misplaced_total']} | {run['wall_time_s']:.0f} |")
EOF
echo "sweeps in $dir"
