#!/usr/bin/env bash
# The largest stable time step (docs/stability.md), printed as markdown tables.
# 1. The standard fluid (scenarios/dpd-fluid.toml: ρ = 3, a = 25, γ = 4.5, kBT = 1, λ = 0.5,
#    L = 10): FLUID_EQ + FLUID_STEPS steps at each Δt of FLUID_DTS. Stable: no engine error and
#    |⟨T⟩ − 1| ≤ TBOUND (⟨T⟩ over the FLUID_STEPS steps, sampled every 10).
# 2. A cell at rest in the capillary (scenarios/capillary.toml, rest stage only) at each N of NS
#    and each thermal factor of FS ("exact" = 1: the stiffest membrane the mapping allows;
#    10.841: the driven default's), CELL_STEPS steps, scanning CELL_DTS from the largest down and
#    stopping at the first stable one. Stable: no error (neither the membrane dry run nor the
#    engine), |membrane kBT / fluid kBT − 1| ≤ TBOUND over the last quarter, area and volume
#    within 5 % at every sample, no fluid on the wrong side of the membrane.
#   NS="100 500 1000 5000" scripts/bench_stability.sh      (about 10 min on 1 thread)
set -euo pipefail
cd "$(dirname "$0")/.."
FLUID_DTS=${FLUID_DTS:-"0.04 0.05 0.06 0.07 0.08 0.09 0.1 0.12 0.15 0.2"}
FLUID_EQ=${FLUID_EQ:-200}; FLUID_STEPS=${FLUID_STEPS:-500}; TBOUND=${TBOUND:-0.1}
NS=${NS:-"100 500 1000 5000"}; FS=${FS:-"exact 10.841"}
CELL_DTS=${CELL_DTS:-"0.004 0.0035 0.003 0.0025 0.00225 0.002 0.0015 0.001 0.0005"}; CELL_STEPS=${CELL_STEPS:-1000}
THREADS=${THREADS:-1}; OUT=${OUT:-$(mktemp -d)}
nice -n 10 cargo build --release --quiet -j 2
H="nice -n 10 ./target/release/hemodpd"
mkdir -p "$OUT"
verdict() { # run directory, kind, bound -> the row's verdict columns (stderr in DIR.err)
  python3 - "$@" <<'PY'
import json, sys, os, re
d, kind, tb = sys.argv[1], sys.argv[2], float(sys.argv[3])
path = d + "/summary.json"
err = open(d + ".err").read().strip().splitlines() if os.path.exists(d + ".err") else []
if not os.path.exists(path):
    msg = (err[-1] if err else "no summary").replace("|", "/")
    m = re.search(r"dry run .*?unstable at step (\d+) of (\d+)", msg)
    e = re.search(r"instability at step (\d+): (.*?particle id \d+ \(index \d+, type \d+\)) (moved [\d.]+ in one step|has non-finite \w+)", msg)
    msg = (f"refused: the membrane's dry run failed at step {m[1]} of {m[2]}" if m
           else f"engine error at step {e[1]}: {e[2]} {e[3]}" if e else msg[:200])
    print(f"unstable | — | {msg}"); sys.exit()
r = json.load(open(path))["results"]
if kind == "fluid":
    t = r["temperature"]["mean"]
    ok = abs(t - 1) <= tb
    print(f"{'stable' if ok else 'too hot'} | T = {t:.3f} | p = {r['pressure']['mean']:.2f}")
else:
    st = r["stages"][0]; q = st["final_quarter_means"]
    t = q["membrane_temperature_ratio"]; a, v = st["max_abs_area_deviation"], st["max_abs_volume_deviation"]
    bad = r["crossings"]["misplaced_total"]
    ok = abs(t - 1) <= tb and a <= 0.05 and v <= 0.05 and bad == 0
    print(f"{'stable' if ok else 'drifts'} | T_m/T = {t:.3f} | area {100*a:.2f} %, volume {100*v:.2f} %, misplaced {bad}, {r['performance']['steps_per_second']:.0f} steps/s")
PY
}
echo "### The standard fluid (L = 10, $FLUID_EQ + $FLUID_STEPS steps, stable: no error and |⟨T⟩ − 1| ≤ $TBOUND)"
echo; echo "| Δt | verdict | ⟨T⟩ | ⟨p⟩ or error |"; echo "|---|---|---|---|"
for dt in $FLUID_DTS; do
  d="$OUT/fluid-$dt"
  $H run scenarios/dpd-fluid.toml --threads "$THREADS" --quiet --out "$d" --set run.timestep="$dt" \
    --set run.equilibration_steps="$FLUID_EQ" --set run.steps="$FLUID_STEPS" --set run.sample_every=10 \
    >/dev/null 2>"$d.err" || true
  echo "| $dt | $(verdict "$d" fluid "$TBOUND") |"
done
echo; echo "### A cell at rest in the capillary ($CELL_STEPS steps; stable: no error, |T_m/T − 1| ≤ $TBOUND, area and volume within 5 %)"
echo; echo "| N | thermal factor f | Δt | verdict | membrane T / fluid T | area, volume, misplaced fluid, speed, or the error |"
echo "|---|---|---|---|---|---|"
for n in $NS; do for f in $FS; do
  fset="model.thermal_factor=$f"; [ "$f" = exact ] && fset='model.thermal_factor="exact"'
  tau=$(./target/release/hemodpd run scenarios/capillary.toml --set cell.parameters=paper --explain-units --set "$fset" --set 'stage=[{name = "rest", duration_s = 0.001}]' | sed -n 's/.*time τ=[^0-9]*\([0-9.e+-]*\) s.*/\1/p')
  for dt in $CELL_DTS; do
    d="$OUT/cell-n$n-f$f-dt$dt"
    dur=$(python3 -c "print($CELL_STEPS * $dt * $tau)")
    $H run scenarios/capillary.toml --set cell.parameters=paper --threads "$THREADS" --quiet --out "$d" --set cell.vertices="$n" --set "$fset" \
      --set model.timestep="$dt" --set output.frame_every_s=0 --set output.sample_every_steps=10 \
      --set model.crossing_check_every_steps=100 --set "stage=[{name = \"rest\", duration_s = $dur}]" \
      >/dev/null 2>"$d.err" || true
    v=$(verdict "$d" cell "$TBOUND")
    echo "| $n | $f | $dt | $v |"
    case "$v" in stable*) break;; esac
  done
done; done
