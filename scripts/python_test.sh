#!/usr/bin/env bash
# The Python package's tests (part of the README's test command, so of CI): makes a virtual
# environment in target/python-venv, installs the package from python/ the way a user does
# (`pip install ./python`, built by maturin) plus pytest, pandas and matplotlib, and runs
# python/tests/ (which also runs examples/). The native module is built with the `dev` profile
# (Cargo.toml: the same settings as the `test` profile) into target/debug, so it reuses the
# crates that the test build (`cargo nextest run`, run before this in the README's test
# command) compiled: only pyo3 and the module itself compile here (the root Cargo.toml requests
# the features the suite's dev-dependencies turn on, so the two builds share one feature set).
# A user's `pip install ./python` builds a release wheel. The sweep test uses the CLI that the
# test build makes (target/debug/hemodpd), so run this after it.
#   HEMODPD_VENV   where the environment goes (default target/python-venv)
#   PYTHON         the interpreter that makes it (default python3; 3.9 or newer)
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
VENV="${HEMODPD_VENV:-$ROOT/target/python-venv}"
if [ ! -x "$VENV/bin/python" ]; then
  "${PYTHON:-python3}" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --disable-pip-version-check pytest numpy pandas matplotlib
CARGO_TARGET_DIR="$ROOT/target" MATURIN_PEP517_ARGS="--profile dev" \
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check --force-reinstall --no-deps "$ROOT/python"
cd "$ROOT"
# nothing written into the source tree: no pytest cache, no bytecode beside the tests
export PYTHONDONTWRITEBYTECODE=1
exec "$VENV/bin/python" -m pytest -q -p no:cacheprovider python/tests "$@"
