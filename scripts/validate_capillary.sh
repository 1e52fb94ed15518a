#!/usr/bin/env bash
# The capillary validation (docs/validation.md §6, "The cell in the capillary"): the paper's
# protocol at 1 mm/s with the Fig. 3 shapes and the recovery against Hochmuth 1979, a sweep of
# velocities against Hochmuth 1970 (cell length) and Lanotte 2014 (deformation index),
# N = 500 against N = 5000, Tomaiuolo 2009's narrow tubes (velocity against pressure gradient
# at 4.7 and 6.6 µm, DI at 6.6 µm, two seeds) and Hochmuth 1970's eight tubes (cell length,
# two seeds; five ignored tests in tests/capillary.rs). About 85 minutes on 2 cores. The same
# tubes with the dense fluid (capillary_validation_hochmuth_dense, about 2 hours) are not run
# here: `cargo test --test end_to_end -- --ignored --nocapture capillary_validation_hochmuth_dense`.
# Figures go to FIG_DIR (default: a temporary directory).
#   scripts/validate_capillary.sh [FIG_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
fig_dir="${1:-$(mktemp -d)}"
mkdir -p "$fig_dir"
HEMODPD_FIGURES_DIR="$(cd "$fig_dir" && pwd)" \
    cargo test --profile test --test end_to_end -- --ignored --nocapture --test-threads 1 capillary_validation \
    --skip capillary_validation_hochmuth_dense
echo "figures in $fig_dir"
