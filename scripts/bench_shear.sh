#!/usr/bin/env bash
# The cost of the shear scenario (docs/performance.md, "The shear scenario"): steps per second,
# seconds per simulated second and per unit strain of the shipped scenario (scenarios/shear.toml,
# 24 × 20 × 16 µm, Lees–Edwards) at N = 500, 1000 and 5000 on 1 and 2 threads, 1.5 strain units
# each (~2300 steps). Take it on a quiet machine.
#   scripts/bench_shear.sh [N ...]
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
ns=("${@:-500 1000 5000}")
tmp=$(mktemp -d)
printf "%-6s %-8s %12s %16s %14s %10s %10s\n" N threads "steps/s" "s per sim. s" "s per strain" "bounce" "membrane"
for n in ${ns[@]}; do
  for t in 1 2; do
    out="$tmp/n$n-t$t"
    ./target/release/hemodpd run scenarios/shear.toml --set cell.parameters=paper --set cell.vertices=$n --set shear.duration_strain=1.5 \
      --set output.frame_every_strain=0 --threads $t --out "$out" --quiet
    python3 - "$out/summary.json" "$n" "$t" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))["results"]["performance"]
s = r["this_session"]["share"]
print(f"{sys.argv[2]:<6} {sys.argv[3]:<8} {r['steps_per_second']:12.1f} {r['seconds_per_simulated_second']:16.1f} {r['seconds_per_unit_strain']:14.2f} {s['bounce_back']:10.3f} {s['membrane_forces']:10.3f}")
PY
  done
done
rm -rf "$tmp"
