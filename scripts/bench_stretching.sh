#!/usr/bin/env bash
# Stretching: cost against accuracy per level of coarse-graining (docs/performance.md,
# "Membrane stretching"). Runs the shipped protocol (scenarios/stretching.toml, 14 forces,
# 0–200 pN) for each N and prints a markdown table: the stretching wall time, the L-BFGS
# iterations, the RMS deviation of D_A and D_T from the N = 23867 run (same forces) and from
# Mills et al. (2004). Meshes come from the cache (the first N = 23867 run generates it, ~40 s,
# not counted). Take it on a quiet machine; give the load.
#   scripts/bench_stretching.sh                 # N = 100 500 1000 5000 23867 (~3 min on 2 cores)
#   SKIP_FINE=1 REF=DIR scripts/bench_stretching.sh   # no N = 23867 run; compare with DIR's
# OUT (default runs/bench-stretching) keeps the runs; THREADS (default 2); PRECONDITIONER
# (default gauss-newton; "none" for the plain L-BFGS).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-runs/bench-stretching}
THREADS=${THREADS:-2}
PRECONDITIONER=${PRECONDITIONER:-gauss-newton}
NS=${NS:-"100 500 1000 5000"}
cargo build --release --quiet
mkdir -p "$OUT"
if [ -z "${SKIP_FINE:-}" ]; then
  NS="$NS 23867"
  REF="$OUT/n23867"
fi
REF=${REF:?with SKIP_FINE set, REF must name an earlier N = 23867 run directory}
echo "preconditioner: $PRECONDITIONER, threads: $THREADS"
echo "load before: $(cat /proc/loadavg)"
for n in $NS; do
  ./target/release/hemodpd run scenarios/stretching.toml --set membrane.parameters=paper --set membrane.vertices=$n --set output.shapes=false \
    --set stretching.preconditioner=\"$PRECONDITIONER\" --threads "$THREADS" --out "$OUT/n$n" --quiet
done
echo "load after: $(cat /proc/loadavg)"
python3 - "$OUT" "$REF" $NS <<'PY'
import json, math, sys
out, ref, ns = sys.argv[1], sys.argv[2], sys.argv[3:]
res = lambda d: json.load(open(d + "/summary.json"))["results"]
r0 = res(ref)
def rms(a, b):
    return math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b)) / len(a))
print("| N | stretching (s) | iterations | RMS D_A vs N = 23867 (µm) | RMS D_T vs N = 23867 (µm) | RMS D_A vs Mills (µm) | RMS D_T vs Mills (µm) |")
print("|---|---|---|---|---|---|---|")
for n in ns:
    r = res(f"{out}/n{n}")
    assert r["force_pn"] == r0["force_pn"], "the runs must share the force list"
    m = r["mills2004"]
    print(f"| {n} | {r['solve_seconds']:.1f} | {sum(r['iterations'])} | "
          f"{rms(r['axial_diameter_um'], r0['axial_diameter_um']):.3f} | {rms(r['transverse_diameter_um'], r0['transverse_diameter_um']):.3f} | "
          f"{m['rms_axial_um']:.3f} | {m['rms_transverse_um']:.3f} |")
PY
