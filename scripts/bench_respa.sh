#!/usr/bin/env bash
# Membrane sub-stepping (r-RESPA, model.membrane_substeps = k) against the error it introduces
# and its cost (docs/performance.md, "Membrane sub-stepping: k against error and cost"). The
# capillary scenario, N = 500, a 0.5 ms rest, then FLOW_S s at 1 mm/s from rest (the parachute
# forming); means over the last quarter of the flow, relative to the largest k of each series,
# same seed:
#  - with the physiological membrane viscosity η_m = 6.3e-7 N·s/m (KS_VISC; "auto" is 50 here);
#  - without membrane viscosity (KS_PLAIN): the splitting error alone.
#   KS_VISC="1 5 25 50 100" KS_PLAIN="1 2 4" FLOW_S=0.005 THREADS=1 scripts/bench_respa.sh
set -euo pipefail
cd "$(dirname "$0")/.."
KS_VISC=${KS_VISC:-"1 5 25 50 100"}; KS_PLAIN=${KS_PLAIN:-"1 2 4"}; FLOW_S=${FLOW_S:-0.005}
THREADS=${THREADS:-1}; OUT=${OUT:-/tmp/bench_respa}
nice -n 10 cargo build --release --quiet -j 2
mkdir -p "$OUT"
go() { # dir, η_m, k
  [ -f "$1/summary.json" ] && return
  nice -n 10 ./target/release/hemodpd run scenarios/capillary.toml --set cell.parameters=paper --threads "$THREADS" --quiet --out "$1" \
    --set cell.membrane_viscosity_pa_s_m="$2" --set model.membrane_substeps="$3" --set output.frame_every_s=0 \
    --set model.thermal_factor=10.841 \
    --set "stage=[{name = \"rest\", duration_s = 0.0005}, {name = \"flow\", duration_s = $FLOW_S, mean_velocity_m_per_s = 1e-3}]"
}
for k in $KS_VISC; do go "$OUT/visc-k$k" 6.3e-7 "$k"; done
for k in $KS_PLAIN; do go "$OUT/plain-k$k" 0 "$k"; done
python3 - "$OUT" "$KS_VISC" "$KS_PLAIN" <<'PY'
import json, sys
out, kv, kp = sys.argv[1], sys.argv[2].split(), sys.argv[3].split()
def table(name, ks):
    r = {k: json.load(open(f"{out}/{name}-k{k}/summary.json"))["results"] for k in ks}
    ref = r[ks[-1]]["driven"]
    print(f"| k | γ_eff/γ | DI | DI − DI(k = {ks[-1]}) | length (µm) | cell velocity (mm/s) | membrane T / fluid T | steps/s | membrane share (forces + viscosity) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for k in ks:
        x = r[k]; d = x["driven"]; p = x["performance"]; s = p["this_session"]["share"]
        ef = x["membrane_viscosity"].get("effective_friction_fraction")
        ddi = "—" if k == ks[-1] else f"{d['deformation_index'] - ref['deformation_index']:+.3f}"
        print(f"| {k} | {'—' if ef is None else f'{ef:.2f}'} | {d['deformation_index']:.3f} | {ddi} | "
              f"{d['axial_length_um']:.2f} | {1e3 * d['cell_velocity_m_per_s']:.3f} | {d['membrane_temperature_ratio']:.3f} | "
              f"{p['steps_per_second']:.0f} | {100 * (s['membrane_forces'] + s['membrane_viscosity']):.0f} % |")
print("With η_m = 6.3e-7 N·s/m:\n"); table("visc", kv)
print("\nWithout membrane viscosity:\n"); table("plain", kp)
PY
