#!/usr/bin/env bash
# What a Tomaiuolo point costs (docs/performance.md, "Narrow tubes"): scenarios/capillary-tomaiuolo.toml
# as shipped (6.6 µm, 1 µm per rc, N = 500, 10 mmHg/mm, 6.1 ms) and its 4.7 µm variant (0.5 µm
# per rc, N = 2000), each run once on THREADS threads; prints the wall time, the steps and the
# pressing of the cell from summary.json. Take it on a quiet machine.
#   THREADS=2 OUT=/tmp/bench_tomaiuolo scripts/bench_tomaiuolo.sh
set -euo pipefail
cd "$(dirname "$0")/.."
THREADS=${THREADS:-2}; OUT=${OUT:-/tmp/bench_tomaiuolo}
cargo build --release --quiet
rm -rf "$OUT"; mkdir -p "$OUT"
run() {
  local name=$1; shift
  ./target/release/hemodpd run scenarios/capillary-tomaiuolo.toml --set cell.parameters=paper --threads "$THREADS" --quiet \
    --out "$OUT/$name" --set output.frame_every_s=0 "$@"
}
run d6.6
run d4.7 --set tube.diameter_um=4.7 --set model.length_um_per_rc=0.5 --set cell.vertices=2000
python3 - "$OUT" "$THREADS" <<'PY'
import json, sys
out, threads = sys.argv[1], sys.argv[2]
print(f"| tube | wall time (s) | steps | steps/s | pressing (s) | cell velocity (cm/s) | threads |")
print("|---|---|---|---|---|---|---|")
for name in ("d6.6", "d4.7"):
    s = json.load(open(f"{out}/{name}/summary.json"))
    r = s["results"]
    perf = r["performance"]
    print(f"| {name[1:]} µm | {s['wall_time_s']:.0f} | {int(perf.get('steps', 0))} | {perf.get('steps_per_second', 0):.0f} | "
          f"{r['mesh']['placement']['seconds']:.1f} | {r['driven']['cell_velocity_m_per_s'] * 100:.4f} | {threads} |")
PY
