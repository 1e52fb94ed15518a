#!/usr/bin/env bash
# Run time against error in the capillary scenario (docs/performance.md, "The capillary
# scenario"): N and Δt against the steady cell velocity, axial length and deformation index,
# relative to the finest run of the grid (largest N, then smallest Δt), with the wall clock per
# simulated ms. Protocol: scenarios/capillary.toml with a 2 ms rest, then FLOW_S seconds at
# 0.3 mm/s; means over the last quarter of the flow stage, averaged over the seeds.
#   NS="500" DTS="0.0025 0.00125" SEEDS="1 2" FLOW_S=0.1 THREADS=1 OUT=/tmp/bench_capillary \
#     scripts/bench_capillary.sh
# Finished points (OUT/n*-dt*-s*/summary.json) are reused; delete OUT to start over.
set -euo pipefail
cd "$(dirname "$0")/.."
NS=${NS:-500}; DTS=${DTS:-"0.0025 0.00125"}; SEEDS=${SEEDS:-"1 2"}; FLOW_S=${FLOW_S:-0.1}
THREADS=${THREADS:-1}; OUT=${OUT:-/tmp/bench_capillary}
nice -n 10 cargo build --release --quiet -j 2
mkdir -p "$OUT"
for n in $NS; do for dt in $DTS; do for s in $SEEDS; do
  d="$OUT/n$n-dt$dt-s$s"
  [ -f "$d/summary.json" ] && continue
  nice -n 10 ./target/release/hemodpd run scenarios/capillary.toml --set cell.parameters=paper --threads "$THREADS" --out "$d" --quiet \
    --set cell.vertices="$n" --set model.timestep="$dt" --set seed="$s" --set output.frame_every_s=0 \
    --set "stage=[{name = \"rest\", duration_s = 0.002}, {name = \"parachute\", duration_s = $FLOW_S, mean_velocity_m_per_s = 3e-4}]"
done; done; done
python3 - "$OUT" "$NS" "$DTS" "$SEEDS" <<'PY'
import json, sys, statistics as st
out, ns, dts, seeds = sys.argv[1], sys.argv[2].split(), sys.argv[3].split(), sys.argv[4].split()
rows = {}
for n in ns:
    for dt in dts:
        runs = [json.load(open(f"{out}/n{n}-dt{dt}-s{s}/summary.json"))["results"] for s in seeds]
        q = [r["driven"] for r in runs]
        perf = [r["performance"] for r in runs]
        sim_ms = [1e3 * r["unit_mapping"]["timestep_s"] * p["steps"] for r, p in zip(runs, perf)]
        rows[(n, dt)] = dict(
            v=st.mean(x["cell_velocity_m_per_s"] for x in q),
            l=st.mean(x["axial_length_um"] for x in q),
            di=st.mean(x["deformation_index"] for x in q),
            ls=[x["axial_length_um"] for x in q], dis=[x["deformation_index"] for x in q],
            wc=st.mean(p["stepping_seconds"] / t for p, t in zip(perf, sim_ms)),
            sps=st.mean(p["steps_per_second"] for p in perf), th=perf[0]["threads"])
ref = rows[(ns[-1], min(dts, key=float))]
rel = lambda a, b: f"{100 * (a / b - 1):+.1f} %"
print("| N | Δt | cell velocity | length | DI | seeds' lengths (µm) | seeds' DI | steps/s | wall clock per simulated ms (threads) |")
print("|---|---|---|---|---|---|---|---|---|")
for (n, dt), r in rows.items():
    if r is ref:
        c = [f"(reference) {1e3 * r['v']:.4f} mm/s", f"(reference) {r['l']:.2f} µm", f"(reference) {r['di']:.3f}"]
    else:
        c = [rel(r["v"], ref["v"]), rel(r["l"], ref["l"]), rel(r["di"], ref["di"])]
    print(f"| {n} | {dt} | {' | '.join(c)} | {', '.join(f'{x:.2f}' for x in r['ls'])} | "
          f"{', '.join(f'{x:.3f}' for x in r['dis'])} | {r['sps']:.0f} | {r['wc']:.2f} s ({r['th']}) |")
PY
