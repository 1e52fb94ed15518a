#!/usr/bin/env bash
# The shear validation (docs/validation.md §7, the paper's Fig. 4): reduced grids run through
# `hemodpd sweep` (resumable: run it again to continue), then compared with the experiments in
# tests/data: the tumbling → tank-treading transition stress per N against Fischer 2013 and
# Abkarian 2007, f_TT/γ̇ against Fischer's cells at 28.9 mPa·s, the inclination against Fischer
# 2015 at 23.9 mPa·s. Grids: N = 500 at 28.9 mPa·s (6 stresses, 36 strain units each), N = 1000
# and N = 5000 (0.2 and 0.5 Pa, 30 strain units), N = 500 at 23.9 mPa·s (3 rates), N = 500 with
# the membrane viscosity 6.3e-7 N·s/m (0.5 and 2 Pa). About 90 minutes on 2 otherwise idle cores.
#   scripts/validate_shear.sh [SWEEP_DIR [FIG_DIR]]
set -euo pipefail
cd "$(dirname "$0")/.."
sweep_dir="${1:-${TMPDIR:-/tmp}/hemodpd-shear-validation}"
fig_dir="${2:-$(mktemp -d)}"
mkdir -p "$sweep_dir" "$fig_dir"
HEMODPD_SHEAR_DIR="$(cd "$sweep_dir" && pwd)" HEMODPD_FIGURES_DIR="$(cd "$fig_dir" && pwd)" \
    cargo test --profile test --test end_to_end -- --ignored --nocapture shear_validation_fig4
echo "sweeps in $sweep_dir, figures in $fig_dir"
