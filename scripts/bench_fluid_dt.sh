#!/usr/bin/env bash
# Run time against error for the standard DPD fluid (docs/performance.md, "The fluid: time step
# against error"): ρ = 3, a = 25, γ = 4.5, kBT = 1, λ = 0.5, L = 10 (3000 particles), through
# scenarios/dpd-fluid.toml. At each Δt: EQ_T time units of equilibration, RUN_T of production
# sampled every SAMPLE_T; ⟨T⟩ − 1 and ⟨p⟩ relative to the smallest Δt, with block-average
# standard errors (the scenario's), and the throughput on THREADS threads.
#   DTS="0.005 0.01 0.02 0.04 0.05 0.06" L=10 EQ_T=10 RUN_T=150 SAMPLE_T=0.1 THREADS=1 \
#     scripts/bench_fluid_dt.sh
set -euo pipefail
cd "$(dirname "$0")/.."
DTS=${DTS:-"0.005 0.01 0.02 0.04 0.05 0.06"}; L=${L:-10}; EQ_T=${EQ_T:-10}; RUN_T=${RUN_T:-150}
SAMPLE_T=${SAMPLE_T:-0.1}; THREADS=${THREADS:-1}; OUT=${OUT:-$(mktemp -d)}
nice -n 10 cargo build --release --quiet -j 2
for dt in $DTS; do
  read -r neq nrun every < <(python3 -c "dt=$dt; print(round($EQ_T/dt), round($RUN_T/dt), max(1, round($SAMPLE_T/dt)))")
  nice -n 10 ./target/release/hemodpd run scenarios/dpd-fluid.toml --threads "$THREADS" --out "$OUT/dt$dt" --quiet \
    --set "fluid.box_size=[$L, $L, $L]" --set run.timestep="$dt" --set run.equilibration_steps="$neq" \
    --set run.steps="$nrun" --set run.sample_every="$every" >/dev/null
done
python3 - "$OUT" "$DTS" <<'PY'
import json, sys
out, dts = sys.argv[1], sys.argv[2].split()
r = {dt: json.load(open(f"{out}/dt{dt}/summary.json"))["results"] for dt in dts}
p0 = r[min(dts, key=float)]["pressure"]
print(f"| Δt | ⟨T⟩ − 1 | ⟨p⟩ | ⟨p⟩ − p(Δt = {min(dts, key=float)}) | particle-steps/s | time units per wall s | samples |")
print("|---|---|---|---|---|---|---|")
for dt in dts:
    x = r[dt]; t, p = x["temperature"], x["pressure"]
    dp = p["mean"] - p0["mean"]; sdp = (p["standard_error"] ** 2 + p0["standard_error"] ** 2) ** 0.5
    tu = x["throughput_particle_steps_per_s"] / x["particles"] * float(dt)
    print(f"| {dt} | {t['mean'] - 1:+.4f} ± {t['standard_error']:.4f} | {p['mean']:.3f} ± {p['standard_error']:.3f} | "
          f"{'—' if p is p0 else f'{dp:+.3f} ± {sdp:.3f}'} | {x['throughput_particle_steps_per_s']:.2e} | {tu:.1f} | {t['samples']} |")
PY
