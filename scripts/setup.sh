#!/usr/bin/env bash
# Installs the system libraries hemodpd builds against, if they are missing (Debian/Ubuntu):
# HDF5 (the io crate links the system libhdf5), fontconfig/freetype with a font (plots), and
# Debian's python3-h5py (crates/io/tests/h5py.rs reads our files with /usr/bin/python3 + h5py; that
# test fails, it does not skip, when h5py cannot be imported), and cargo-nextest if it is missing.
set -euo pipefail
pkgs=(libhdf5-dev pkg-config libfontconfig1-dev libfreetype-dev fonts-dejavu-core python3 python3-numpy python3-h5py python3-venv)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}" >&2
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# cargo-nextest runs the test suite (the README's test command): every test in its own process,
# all test binaries in one pool of threads. If it is missing: the prebuilt binary from the
# project's download address (https://nexte.st/docs/installation/pre-built-binaries/), or, where
# that cannot be reached, `cargo install` from crates.io (a few minutes of compiling).
if ! cargo nextest --version >/dev/null 2>&1; then
  bin="${CARGO_HOME:-$HOME/.cargo}/bin"
  echo "setup: installing cargo-nextest into $bin" >&2
  mkdir -p "$bin"
  if ! { command -v curl >/dev/null 2>&1 \
         && curl -LsSf --max-time 60 https://get.nexte.st/latest/linux | tar zxf - -C "$bin"; }; then
    echo "setup: no prebuilt cargo-nextest; building it with cargo install" >&2
    cargo install --locked cargo-nextest
  fi
  cargo nextest --version >/dev/null
fi
