#!/usr/bin/env bash
# Compares fluid_bench binaries and thread counts on a noisy machine: runs every entry in turn,
# RUNS times over (so that slow and fast spells of the host fall on all of them alike), and prints
# for each entry the mean of its fastest quarter of runs and its median, with their ratios to the
# first entry. Entries are BINARY:THREADS; an entry given as :THREADS uses this checkout's
# fluid_bench (built here). The same binary at 1 and 2 threads gives the 2-thread efficiency
# (ratio / 2). THREADS may be TxM: M copies of T threads each run at the same time, and their
# rates are summed: `:1x2` is what two independent processes get out of the machine, the ceiling
# for one process on 2 threads. docs/performance.md ("The machine and how to measure on it")
# explains why these two statistics.
#
# Usage: scripts/bench_alternate.sh RUNS L STEPS NEQ ENTRY...
#   e.g. scripts/bench_alternate.sh 10 40 200 60 :1 :2            (2-thread efficiency, 192,000)
#        scripts/bench_alternate.sh 16 20 600 100 /tmp/old:2 :2   (an old binary against this one)
#        scripts/bench_alternate.sh 20 20 600 100 :1 :2 :1x2      (2 threads against 2 processes)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
if [[ $# -lt 5 ]]; then
  sed -n '2,15p' "$0" | sed 's/^# \{0,1\}//'
  exit 2
fi
RUNS=$1 L=$2 STEPS=$3 NEQ=$4
shift 4
for e in "$@"; do
  if [[ "$e" == :* ]]; then
    cargo build --release -q -p hemodpd-engine --example fluid_bench
    break
  fi
done
OUT=$(mktemp)
trap 'rm -f "$OUT"' EXIT
echo "# host: $(nproc) cpus, $(lscpu | sed -n 's/^Model name:[[:space:]]*//p' | head -1); load: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "# $RUNS rounds of: fluid_bench $L THREADS $STEPS $NEQ for each of: $*"
for r in $(seq 1 "$RUNS"); do
  for e in "$@"; do
    bin=${e%:*} t=${e##*:}
    [[ -z "$bin" ]] && bin=target/release/examples/fluid_bench
    copies=1
    if [[ "$t" == *x* ]]; then copies=${t#*x} t=${t%x*}; fi
    rate=0
    for c in $(seq 1 "$copies"); do "$bin" "$L" "$t" "$STEPS" "$NEQ" >"$OUT.$c" & done
    wait
    for c in $(seq 1 "$copies"); do
      r=$(sed 's/.*: \([0-9.e+]*\) particle-steps.*/\1/' "$OUT.$c")
      rate=$(python3 -c "print($rate + $r)")
    done
    rm -f "$OUT".*
    echo "$e $rate" >>"$OUT"
  done
done
python3 - "$OUT" "$@" <<'PY'
import statistics, sys
path, entries = sys.argv[1], sys.argv[2:]
runs = {}
for line in open(path):
    e, v = line.split()
    runs.setdefault(e, []).append(float(v))
print("| entry | runs | fastest quarter (particle-steps/s) | ratio | median | ratio |")
print("|---|---|---|---|---|---|")
base = None
for e in entries:
    v = sorted(runs[e], reverse=True)
    top = statistics.mean(v[: max(1, len(v) // 4)])
    med = statistics.median(v)
    base = base or (top, med)
    print(f"| {e} | {len(v)} | {top:.4g} | {top / base[0]:.3f} | {med:.4g} | {med / base[1]:.3f} |")
PY
