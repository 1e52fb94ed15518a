#!/usr/bin/env bash
# ParaView opens hemodpd's XDMF files (a longer validation, not part of `cargo test`: ParaView is
# ~400 MB and CI does not install it). It
#   1. writes the fixture trajectory of crates/io/examples/paraview_fixture.rs and checks, with
#      `xvfb-run pvpython scripts/check_paraview.py`, that the XDMF 2 (.xmf, XDMF Reader) and
#      XDMF 3 (.xmf3, Xdmf3ReaderS) files give every frame, block, point, cell and array value
#      expected, and renders a screenshot of frame 2 (checked to be a non-empty PNG);
#   2. runs a small `hemodpd run scenarios/dpd-fluid.toml` and checks its trajectory's frames
#      and particle count in ParaView;
#   3. runs a short capillary scenario and checks its frames, the membrane (500 vertices, 996
#      triangles, velocities) and the binned fluid fields (density, velocity) in ParaView.
# Needs pvpython and xvfb-run (Debian: apt-get install paraview python3-paraview xvfb xauth).
# Without them it prints "NOT RUN" and exits with status 2 (not 0: it did not check anything).
# Everything is written under a temporary directory (or $1 if given), never into the source tree.
# CARGO_PROFILE selects the cargo profile used to build (default release).
set -euo pipefail
cd "$(dirname "$0")/.."
for tool in pvpython xvfb-run; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "check_paraview: NOT RUN: $tool not found (Debian: apt-get install paraview python3-paraview xvfb xauth)" >&2
    exit 2
  fi
done
work="${1:-$(mktemp -d "${TMPDIR:-/tmp}/hemodpd-paraview.XXXXXX")}"
mkdir -p "$work"
profile="${CARGO_PROFILE:-release}"
echo "check_paraview: writing into $work (cargo profile $profile)"
counts=$(cargo run -q --profile "$profile" -p hemodpd-io --example paraview_fixture -- "$work/pv.h5")
read -r nv nt nf <<<"$counts"
cargo build -q --profile "$profile" --bin hemodpd
target_dir=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])')
case "$profile" in dev|test) bindir=debug ;; *) bindir="$profile" ;; esac
"$target_dir/$bindir/hemodpd" run scenarios/dpd-fluid.toml --quiet --threads 2 --out "$work/fluid" \
  --set 'fluid.box_size=[4.0, 4.0, 4.0]' --set run.equilibration_steps=10 --set run.steps=40 \
  --set run.sample_every=10 --set output.trajectory_every_steps=10
# 4 x 4 x 4 rc at density 3: 192 particles; frames at production steps 0, 10, ..., 40
xvfb-run -a pvpython scripts/check_paraview.py "$work/pv" "$nv" "$nt" "$nf" "$work/frame2.png" \
  "$work/fluid/trajectory.xmf" 5 192 >"$work/pvpython.log" 2>&1 || true
# 3. a short capillary run: membrane frames and the binned fluid fields
"$target_dir/$bindir/hemodpd" run scenarios/capillary.toml --quiet --threads 2 --out "$work/capillary" \
  --set 'stage=[{name = "rest", duration_s = 0.001}, {name = "flow", duration_s = 0.002, mean_velocity_m_per_s = 1e-3}]' \
  --set output.frame_every_s=0.001
# frames at 0, 1, 2, 3 ms (199 steps each; 597 steps in all)
xvfb-run -a -s "-screen 0 1024x768x24" pvpython scripts/check_paraview_capillary.py "$work/capillary/trajectory.xmf" 4 500 996 \
  "$work/capillary.png" >>"$work/pvpython.log" 2>&1 || true
cat "$work/pvpython.log"
if grep -q '^PV-OK' "$work/pvpython.log" && grep -q '^PV-CAPILLARY-OK' "$work/pvpython.log"; then
  echo "check_paraview: PASSED (screenshot $work/frame2.png)"
else
  echo "check_paraview: FAILED (log in $work/pvpython.log)" >&2
  exit 1
fi
