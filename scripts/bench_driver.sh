#!/usr/bin/env bash
# What the scenario path costs over the bare engine: `fluid_bench` against `hemodpd run
# scenarios/dpd-fluid.toml` on the same 20³ box (24,000 particles, 1000 timed steps after 200 of
# equilibration), the scenario sampling ⟨T⟩ and p every 10 steps (its default) and every 100 (the
# bench's cadence). The three are alternated ROUNDS times, so a slow spell of the host hits all
# three alike; prints each round, then the median and best of each and the median of the
# per-round ratios scenario/bench. docs/performance.md, "The scenario path against the bench".
#
# Usage: scripts/bench_driver.sh [ROUNDS=8] [THREADS=2]
set -euo pipefail
cd "$(dirname "$0")/.."
ROUNDS=${1:-8}
THREADS=${2:-2}
cargo build -q --release --bin hemodpd
cargo build -q --release -p hemodpd-engine --example fluid_bench
B=target/release/examples/fluid_bench
H=target/release/hemodpd
OUT=$(mktemp -d /tmp/hemodpd-bench-driver.XXXXXX)
trap 'rm -rf "$OUT"' EXIT
scenario() { # SAMPLE_EVERY
  "$H" run scenarios/dpd-fluid.toml --set "fluid.box_size=[20.0,20.0,20.0]" --set run.equilibration_steps=200 \
    --set run.steps=1000 --set "run.sample_every=$1" --threads "$THREADS" --quiet --out "$OUT/s$1"
  python3 -c "import json,sys; print('%.4e' % json.load(open(sys.argv[1]))['results']['throughput_particle_steps_per_s'])" "$OUT/s$1/summary.json"
}
echo "round  bench       scenario/10  scenario/100   (particle-steps/s, $THREADS threads)"
for r in $(seq "$ROUNDS"); do
  b=$("$B" 20 "$THREADS" 1000 200 | grep -o '[0-9.]*e[0-9]* particle-steps/s' | cut -d' ' -f1)
  printf '%5d  %s  %s  %s\n' "$r" "$b" "$(scenario 10)" "$(scenario 100)"
done | tee "$OUT/rounds.txt"
python3 - "$OUT/rounds.txt" <<'PY'
import statistics as st, sys
rows = [list(map(float, l.split()[1:4])) for l in open(sys.argv[1])]
for i, name in enumerate(["bench", "scenario, sample every 10", "scenario, sample every 100"]):
    v = [r[i] for r in rows]
    line = "%-27s median %.3e  best %.3e" % (name, st.median(v), max(v))
    if i:
        line += "  median ratio to bench %.3f" % st.median(r[i] / r[0] for r in rows)
    print(line)
PY
