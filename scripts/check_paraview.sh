#!/usr/bin/env bash
# ParaView opens hemodpd's XDMF files (a longer validation, not part of `cargo test`: ParaView is
# ~400 MB and CI does not install it).
#
#   scripts/check_paraview.sh [WORK_DIR]        the full check, written under WORK_DIR (default: a
#                                               new temporary directory), never the source tree:
#   1. writes the fixture trajectory of crates/io/examples/paraview_fixture.rs and checks, with
#      `xvfb-run pvpython scripts/check_paraview.py`, that the XDMF 2 (.xmf, XDMF Reader) and
#      XDMF 3 (.xmf3, Xdmf3ReaderS) files give every frame, block, point, cell and array value
#      expected, and renders a screenshot of frame 2 (checked to be a non-empty PNG);
#   2. runs a small `hemodpd run scenarios/dpd-fluid.toml` and checks its trajectory's frames
#      and particle count in ParaView;
#   3. runs a short capillary scenario and checks its frames, the membrane (500 vertices, 996
#      triangles, velocities) and the binned fluid fields (density, velocity) in ParaView;
#   4. checks the run's view_in_paraview.py (below) on that capillary run.
#
#   scripts/check_paraview.sh RUN_DIR [PNG]     only step 4, on an existing run directory (one
#                                               holding trajectory.xmf), e.g. a shear run:
#   `xvfb-run -a pvpython RUN_DIR/view_in_paraview.py --screenshot PNG` must render the last frame
#   (cell, tube, fluid velocity) into a 1280 x 720 PNG that is not blank (checked with pvpython's
#   PNG reader: the centre of the image has many colours and differs from the background).
#
# Needs pvpython and xvfb-run: when missing they are installed with apt-get (Debian: paraview
# python3-paraview xvfb xauth; with sudo unless root). Where that is impossible it prints
# "NOT RUN" and exits with status 2 (not 0: it did not check anything).
# CARGO_PROFILE selects the cargo profile used to build (default release).
set -euo pipefail
cd "$(dirname "$0")/.."

have_tools() { command -v pvpython >/dev/null 2>&1 && command -v xvfb-run >/dev/null 2>&1 && command -v xauth >/dev/null 2>&1; }
if ! have_tools && command -v apt-get >/dev/null 2>&1; then
  sudo=()
  if [ "$(id -u)" -ne 0 ]; then sudo=(sudo); fi
  packages=(paraview python3-paraview xvfb xauth)
  echo "check_paraview: installing ${packages[*]} with apt-get (about 400 MB, a few minutes)"
  export DEBIAN_FRONTEND=noninteractive
  "${sudo[@]}" apt-get install -y "${packages[@]}" ||
    { "${sudo[@]}" apt-get update && "${sudo[@]}" apt-get install -y "${packages[@]}"; } ||
    echo "check_paraview: apt-get could not install ${packages[*]}" >&2
fi
if ! have_tools; then
  echo "check_paraview: NOT RUN: pvpython, xvfb-run or xauth not found (Debian: apt-get install paraview python3-paraview xvfb xauth)" >&2
  exit 2
fi

# check_view RUN_DIR PNG: the run directory's view_in_paraview.py renders a non-blank screenshot.
check_view() {
  local dir=$1 png=$2 width=1280 height=720
  if [ ! -f "$dir/view_in_paraview.py" ]; then
    echo "check_paraview: FAILED: no view_in_paraview.py in $dir (every run writes one beside trajectory.h5)" >&2
    return 1
  fi
  rm -f "$png"
  local try
  for try in 1 2; do  # a second try: the X server of xvfb-run can fail to start
    if xvfb-run -a -s "-screen 0 1600x1000x24" pvpython "$dir/view_in_paraview.py" \
        --screenshot "$png" --size "$width" "$height"; then
      break
    elif [ "$try" = 2 ]; then
      echo "check_paraview: FAILED: $dir/view_in_paraview.py --screenshot exited with an error" >&2
      return 1
    fi
    echo "check_paraview: $dir/view_in_paraview.py failed; trying once more"
  done
  if [ ! -s "$png" ]; then
    echo "check_paraview: FAILED: no screenshot $png" >&2
    return 1
  fi
  # Size, then, in the central half of the image (where the scene is; the colour bars and labels
  # are at the edges): the number of distinct colours and the fraction of pixels unlike the
  # top-left corner (the background).
  local stats
  stats=$(pvpython - "$png" <<'EOF'
import sys
import numpy as np
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkIOImage import vtkPNGReader
r = vtkPNGReader()
r.SetFileName(sys.argv[1])
r.Update()
w, h, _ = r.GetOutput().GetDimensions()
rgb = vtk_to_numpy(r.GetOutput().GetPointData().GetScalars())[:, :3].astype(np.int64).reshape(h, w, 3)
background = rgb[-1, 0]  # VTK images start at the bottom row
centre = rgb[h // 4:3 * h // 4, w // 4:3 * w // 4].reshape(-1, 3)
colours = len(np.unique(centre[:, 0] << 16 | centre[:, 1] << 8 | centre[:, 2]))
print(w, h, colours, round(float(np.any(centre != background, axis=1).mean()), 3))
EOF
)
  local w h colours covered
  read -r w h colours covered <<<"$(tail -n 1 <<<"$stats")"
  echo "check_paraview: $png: ${w} x ${h}; its centre: $colours colours, $covered of the pixels not background"
  if [ "$w" != "$width" ] || [ "$h" != "$height" ]; then
    echo "check_paraview: FAILED: the screenshot is ${w} x ${h}, expected ${width} x ${height}" >&2
    return 1
  fi
  if [ "$colours" -lt 200 ] || ! awk -v c="$covered" 'BEGIN { exit !(c >= 0.1) }'; then
    echo "check_paraview: FAILED: the screenshot looks blank" >&2
    return 1
  fi
}

# A run directory given: check its view script only.
if [ $# -ge 1 ] && [ -f "$1/trajectory.xmf" ]; then
  png="${2:-$(mktemp -d "${TMPDIR:-/tmp}/hemodpd-paraview.XXXXXX")/shot.png}"
  if check_view "$1" "$png"; then
    echo "check_paraview: PASSED (screenshot $png)"
  else
    exit 1
  fi
  exit 0
fi

if [ $# -ge 1 ] && { [ -f "$1/trajectory.h5" ] || [ -f "$1/summary.json" ]; }; then
  echo "check_paraview: FAILED: $1 is a run directory without trajectory.xmf (no frames written?)" >&2
  exit 1
fi

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
# 3. a short capillary run (a 20 µm tube): membrane frames and the binned fluid fields
"$target_dir/$bindir/hemodpd" run scenarios/capillary.toml --quiet --threads 2 --out "$work/capillary" \
  --set tube.length_um=20 \
  --set 'stage=[{name = "rest", duration_s = 0.001}, {name = "flow", duration_s = 0.002, mean_velocity_m_per_s = 1e-3}]' \
  --set output.frame_every_s=0.001
# frames at 0, 1, 2, 3 ms (199 steps each; 597 steps in all)
xvfb-run -a -s "-screen 0 1024x768x24" pvpython scripts/check_paraview_capillary.py "$work/capillary/trajectory.xmf" 4 500 996 \
  "$work/capillary.png" >>"$work/pvpython.log" 2>&1 || true
cat "$work/pvpython.log"
# 4. the run's own view script
view_ok=yes
check_view "$work/capillary" "$work/capillary_view.png" || view_ok=no
if grep -q '^PV-OK' "$work/pvpython.log" && grep -q '^PV-CAPILLARY-OK' "$work/pvpython.log" && [ "$view_ok" = yes ]; then
  echo "check_paraview: PASSED (screenshots $work/frame2.png, $work/capillary_view.png)"
else
  echo "check_paraview: FAILED (log in $work/pvpython.log)" >&2
  exit 1
fi
