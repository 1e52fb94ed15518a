#!/usr/bin/env bash
# Throughput of the hemodpd engine on the Groot-Warren standard DPD fluid (rho=3, a=25,
# gamma=4.5, kBT=1, rc=1, dt=0.01) at 24,000 (L=20) and 192,000 (L=40) particles on 1 and 2
# threads. Prints one line per configuration with particle-steps/s, <T> and <p>.
#
# Knobs: STEPS20 (default 2000), STEPS40 (default 500; 0 skips L=40), NEQ (default 200),
#        THREADS (default "1 2"), SCHEME (half | gather, default half).
# The machine is shared: numbers taken while other jobs run are noisy (compare ratios taken
# back to back, e.g. with scripts/bench_vs_lammps.sh).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
STEPS20="${STEPS20:-2000}"
STEPS40="${STEPS40:-500}"
NEQ="${NEQ:-200}"
THREADS="${THREADS:-1 2}"
SCHEME="${SCHEME:-half}"
cargo build --release -q -p hemodpd-engine --example fluid_bench
BIN=target/release/examples/fluid_bench
echo "# host: $(nproc) cpus, $(lscpu | sed -n 's/^Model name:[[:space:]]*//p' | head -1); load: $(cut -d' ' -f1-3 /proc/loadavg)"
for t in $THREADS; do
  "$BIN" 20 "$t" "$STEPS20" "$NEQ" "$SCHEME"
done
if [[ "$STEPS40" -gt 0 ]]; then
  for t in $THREADS; do
    "$BIN" 40 "$t" "$STEPS40" "$NEQ" "$SCHEME"
  done
fi
