#!/usr/bin/env bash
# Compares fluid_bench binaries and thread counts on a noisy machine: runs every entry in turn,
# RUNS times over (so that slow and fast spells of the host fall on all of them alike), and prints
# for each entry the mean of its fastest quarter of runs and its median, with their ratios to the
# first entry. Entries are BINARY:THREADS; an entry given as :THREADS uses this checkout's
# fluid_bench (built here). The same binary at 1 and 2 threads gives the 2-thread efficiency
# (ratio / 2). docs/performance.md ("The fifth pass", "The sixth pass") explains why these two
# statistics.
#
# Usage: scripts/bench_alternate.sh RUNS L STEPS NEQ ENTRY...
#   e.g. scripts/bench_alternate.sh 10 40 200 60 :1 :2            (2-thread efficiency, 192,000)
#        scripts/bench_alternate.sh 16 20 600 100 /tmp/old:2 :2   (an old binary against this one)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
if [[ $# -lt 5 ]]; then
  sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//'
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
    line=$("$bin" "$L" "$t" "$STEPS" "$NEQ")
    rate=$(sed 's/.*: \([0-9.e+]*\) particle-steps.*/\1/' <<<"$line")
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
