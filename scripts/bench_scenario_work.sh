#!/usr/bin/env bash
# What each shipped scenario computes (docs/performance.md, "What each scenario computes"): a
# short run of each under `perf record` (1 thread), then the share of the samples per module of
# our crates (from the symbol names; closures run by rayon are pooled as "rayon closures"),
# the modules at or above MIN %.
#   MIN=0.5 scripts/bench_scenario_work.sh [scenario ...]       (needs perf; ~3 min)
set -euo pipefail
cd "$(dirname "$0")/.."
MIN=${MIN:-0.5}; OUT=${OUT:-$(mktemp -d)}
nice -n 10 cargo build --release --quiet -j 2
declare -A SETS=(
  [stretching]="--set output.shapes=false --set membrane.vertices=5000"
  [dpd-fluid]="--set run.equilibration_steps=200 --set run.steps=2000"
  [poiseuille-tube]="--set walls.adapt_iterations=1 --set run.equilibration_steps=100 --set run.flow_steps=300 --set run.steps=600"
  [couette]="--set walls.adapt_iterations=1 --set run.equilibration_steps=100 --set run.flow_steps=300 --set run.steps=600"
  [capillary]="--set output.frame_every_s=0.0005 --set stage=[{name=\"rest\",duration_s=0.0005},{name=\"flow\",duration_s=0.001,mean_velocity_m_per_s=1e-3}]"
  [shear]="--set shear.duration_strain=0.4 --set output.frame_every_strain=0.2"
)
mkdir -p "$OUT"
names=("${@:-stretching dpd-fluid poiseuille-tube couette capillary shear}")
for s in ${names[@]}; do
  d="$OUT/$s"
  # shellcheck disable=SC2086
  nice -n 10 perf record -q -F 499 -o "$d.perf" ./target/release/hemodpd run "scenarios/$s.toml" --threads 1 --quiet \
    --out "$d" ${SETS[$s]} >/dev/null 2>"$d.err"
  echo "### $s ($(perf report -i "$d.perf" --stdio 2>/dev/null | sed -n 's/^# Samples: \([^ ]*\) .*/\1/p' | head -1) samples at 499 Hz)"
  echo
  echo "| module | share of samples |"
  echo "|---|---|"
  perf report -q -i "$d.perf" --no-children --sort dso,sym --stdio 2>/dev/null | python3 -c '
import re, sys, collections
share = collections.Counter()
for line in sys.stdin:
    m = re.match(r"\s*([\d.]+)%\s+(\S+)\s+\[.\]\s+(.*)", line)
    if not m:
        continue
    pct, dso, sym = float(m[1]), m[2], m[3]
    k = re.search(r"hemodpd_(\w+)::(\w+)", sym)
    if k: key = f"{k[1]}::{k[2]}"
    elif "hdf5" in dso or sym.startswith("H5"): key = "HDF5"
    elif "rayon" in sym: key = "rayon closures (the O(N) passes: integrator, sorted copies, gathers)"
    elif dso != "hemodpd": key = f"{dso}"
    else: key = "other (std, glam, serde, ...)"
    share[key] += pct
for key, pct in share.most_common():
    if pct >= float(sys.argv[1]):
        print(f"| {key} | {pct:.1f} % |")
' "$MIN"
  echo
done
