#!/usr/bin/env bash
# The long wall validations of docs/walls.md, each asserting what the docs state:
#  - tube_viscosity_vs_radius: the plateau of eta(r) for R = 5, 6, 8 (4 seeds each) within 3 %
#    of the periodic viscosity, and the wall stress within 1 % of n g R / 2;
#  - wall_figures: the figures of docs/walls.md from longer runs (which assert the same).
# Usage: scripts/validate_walls.sh [FIGURE_DIR]   (default target/validation/walls; pass
# docs/figures to refresh the documentation). About 15 minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
FIG=${1:-target/validation/walls}
mkdir -p "$FIG"
HEMODPD_FIGURES_DIR="$(cd "$FIG" && pwd)" cargo test --test walls -- --ignored --nocapture --test-threads 1
echo "figures in $FIG"
