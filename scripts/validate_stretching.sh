#!/usr/bin/env bash
# Reproduces the stretching validation of docs/validation.md:
#   Fig. 1  : D_A, D_T vs force for N = 23867, 5000, 500, 100 (stress-free and uniform references)
#   inset   : N = 500 with p from Eq. 12, p x 0.9, p x 1.1, and the fine model's p = 7.5 nm
#   Fig. 2  : shapes at 0, 90 and 180 pN for N = 23867, 500, 100
#   seeds   : N = 500 with five mesh seeds (mesh dependence of the result)
# and prints the RMS / run-time table. Figures go to docs/figures/, runs to $OUT.
# The full run takes about an hour on 2 cores (N = 23867 dominates); NS="100 500" makes it quick.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-runs/validation-stretching}
NS=${NS:-"100 500 5000 23867"}
FIG=${FIG:-docs/figures}
mkdir -p "$OUT" "$FIG"
# a fresh mesh cache, so the table reports the mesh generation time of each N once
export HEMODPD_CACHE="$OUT/mesh-cache"
rm -rf "$HEMODPD_CACHE"
cargo build --release --quiet
B=target/release/hemodpd
UNIFORM_NS=${UNIFORM_NS:-"100 500 5000"}
list=$(echo $NS | tr ' ' ',')
ulist=$(echo $UNIFORM_NS | tr ' ' ',')

$B sweep scenarios/stretching.toml --set membrane.parameters=paper --vary membrane.vertices=$list --out "$OUT/fig1-stress-free" --quiet
$B plot "$OUT/fig1-stress-free/sweep.json" -o "$FIG/fig1_stretching_stress-free.png" --title "Stretching, stress-free reference (Fig. 1)"
$B sweep scenarios/stretching.toml --set membrane.parameters=paper --vary membrane.vertices=$ulist --set membrane.reference=uniform --out "$OUT/fig1-uniform" --quiet
$B plot "$OUT/fig1-uniform/sweep.json" -o "$FIG/fig1_stretching_uniform.png" --title "Stretching, uniform L0 (the paper's literal convention)"

$B sweep scenarios/stretching.toml --set membrane.parameters=paper --vary membrane.persistence_scale=0.9,1.0,1.1 --out "$OUT/inset" --quiet
$B run scenarios/stretching.toml --set membrane.parameters=paper --set membrane.persistence_length_nm=7.5 --out "$OUT/inset/p=7.5nm" --quiet
$B plot "$OUT/inset/sweep.json" "$OUT/inset/p=7.5nm" -o "$FIG/fig1_inset_persistence.png" --title "N = 500: persistence-length sensitivity (Fig. 1 inset)"

$B sweep scenarios/stretching.toml --set membrane.parameters=paper --vary seed=1,2,3,4,5 --out "$OUT/seeds" --quiet

for n in $NS; do
  case $n in 100|500|23867) ;; *) continue ;; esac
  $B run scenarios/stretching.toml --set membrane.parameters=paper --set membrane.vertices=$n --set 'stretching.forces_pn=[0.0, 90.0, 180.0]' --out "$OUT/fig2-n$n" --quiet
  edges=""; [ "$n" -le 500 ] && edges="--edges"
  $B render "$OUT/fig2-n$n/shapes.h5" $edges --columns 3 -o "$FIG/fig2_shapes_n$n.png"
done

python3 - "$OUT" <<'EOF'
import json, sys, os
out = sys.argv[1]
def rows(sweep):
    sw = json.load(open(os.path.join(out, sweep, "sweep.json")))
    for r in sw["runs"]:
        s = json.load(open(os.path.join(r["dir"], "summary.json")))
        res = s["results"]; m = res["mills2004"]
        f = res["force_pn"]; i = min(range(len(f)), key=lambda k: abs(f[k] - 192.688))
        mesh = res["model"]["mesh"]
        gen = (mesh.get("origin") or {}).get("generate_seconds", 0.0)
        yield (r["label"], s["scenario"]["membrane"]["vertices"], s["scenario"]["membrane"]["reference"],
               gen, res["solve_seconds"], m["rms_axial_um"], m["rms_transverse_um"],
               res["axial_diameter_um"][i], res["transverse_diameter_um"][i],
               max(abs(x) for x in res["area_deviation"]), max(abs(x) for x in res["volume_deviation"]))
print("| run | N | reference | mesh (s) | stretching (s) | RMS D_A (µm) | RMS D_T (µm) | D_A @193 pN | D_T @193 pN | max abs dA/A0 | max abs dV/V0 |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for sweep in ["fig1-stress-free", "fig1-uniform", "inset", "seeds"]:
    if not os.path.exists(os.path.join(out, sweep, "sweep.json")):
        continue
    for r in rows(sweep):
        print("| %s | %d | %s | %.1f | %.1f | %.3f | %.3f | %.2f | %.2f | %.1e | %.1e |" % r)
print("(mesh time 0.0 = taken from the cache; Mills et al. 2004 at 192.7 pN: D_A 15.26 ± 2.35, D_T 4.26 ± 0.83 µm)")
EOF
