"""Open this hemodpd run in ParaView: the cell, the tube (capillary runs) and the binned fluid
velocity (or the fluid particles), at the last frame.

  paraview --state=view_in_paraview.py   the ParaView GUI, set up (also: `paraview
                                         view_in_paraview.py` from this directory, or, in a
                                         running ParaView, View > Python Shell > Run Script)
  pvpython view_in_paraview.py           the same scene in a plain interactive window
  pvpython view_in_paraview.py --screenshot out.png [--frame K] [--size W H]
                                         render frame K (default -1, the last) to a PNG and exit

hemodpd writes this file beside trajectory.h5. It reads, from its own directory (else the working
directory), trajectory.xmf (the XDMF 2 description, with ParaView's "XDMF Reader", which keeps
the block names `membrane`, `field_velocity`...) and summary.json (the scenario). Lengths in the
files are metres, times seconds, velocities m/s. Needs only ParaView's Python (5.11 or newer).
"""
import argparse
import json
import os
import sys
import xml.etree.ElementTree as ET

import paraview
import paraview.simple as pv

# Inside the ParaView application sys.argv is [""] (and pvpython's is this script and its options).
IN_GUI = paraview.fromGUI or not sys.argv[0]


def fail(message):
    if IN_GUI:  # sys.exit would close ParaView: show the message in its output window instead
        raise RuntimeError("view_in_paraview: " + message)
    sys.stderr.write("view_in_paraview: error: %s\n" % message)
    sys.exit(1)


def find_run_dir():
    """The directory holding trajectory.xmf: this script's, else the working directory."""
    dirs = []
    if "__file__" in globals():  # set by pvpython, paraview --state=... and Run Script
        dirs.append(os.path.dirname(os.path.abspath(__file__)))
    elif os.path.isfile("/proc/self/cmdline"):  # `paraview [--script=]DIR/x.py` sets no __file__
        args = open("/proc/self/cmdline").read().split("\0")
        dirs += [os.path.dirname(a.split("=")[-1]) for a in args if a.endswith(".py")]
    dirs.append(os.getcwd())
    for d in dirs:
        if os.path.isfile(os.path.join(d, "trajectory.xmf")):
            return os.path.abspath(d)
    fail("no trajectory.xmf in %s (did the run write frames?)" % " or ".join(dirs))


def read_scenario(run_dir):
    """(kind, scenario as a dict): from summary.json, or, while the run is still going (no
    summary yet), from trajectory.h5's attributes if h5py is importable."""
    path = os.path.join(run_dir, "summary.json")
    if os.path.isfile(path):
        with open(path) as f:
            summary = json.load(f)
        return summary.get("scenario_kind"), summary.get("scenario", {})
    try:
        import h5py
        import tomllib  # Python 3.11+
        with h5py.File(os.path.join(run_dir, "trajectory.h5"), "r", locking=False) as f:
            return f.attrs["scenario_name"], tomllib.loads(f.attrs["scenario"])
    except Exception as e:  # no h5py, an older Python, a file being written...
        print("view_in_paraview: no summary.json and no scenario from trajectory.h5 (%s)" % e)
        return None, {}


def bounds_of(source, time):
    source.UpdatePipeline(time)
    return source.GetDataInformation().GetBounds()  # (xmin, xmax, ymin, ymax, zmin, zmax)


# -- arguments (the GUI has none of ours) ----------------------------------------------------------
parser = argparse.ArgumentParser(description="Open this hemodpd run in ParaView.", allow_abbrev=False)
parser.add_argument("--screenshot", metavar="PNG", help="render to this PNG and exit")
parser.add_argument("--frame", type=int, default=-1, help="frame index (default -1: the last)")
parser.add_argument("--size", type=int, nargs=2, default=[1280, 720], metavar=("W", "H"),
                    help="screenshot size in pixels (default 1280 720)")
args = parser.parse_args([] if IN_GUI else sys.argv[1:])

run_dir = find_run_dir()
xmf = os.path.join(run_dir, "trajectory.xmf")
if not os.path.isfile(os.path.join(run_dir, "trajectory.h5")):  # the .xmf only points into it
    fail("%s has trajectory.xmf but no trajectory.h5" % run_dir)
kind, scenario = read_scenario(run_dir)
# The top-level grids of the XDMF file: "membrane", "field_velocity", "field_density", "fluid"...
grids = [g.get("Name") for g in ET.parse(xmf).getroot().find("Domain").findall("Grid")]
print("view_in_paraview: %s run in %s, blocks %s" % (kind or "unknown", run_dir, ", ".join(grids)))
print("(the XDMF Reader may log 'Cannot find DataItem element in geometry xml': harmless)")

# -- the data and the frame ------------------------------------------------------------------------
reader = pv.XDMFReader(registrationName="trajectory.xmf", FileNames=[xmf])
reader.UpdatePipelineInformation()
times = list(reader.TimestepValues) or [0.0]
if not -len(times) <= args.frame < len(times):
    fail("--frame %d: the trajectory has %d frames (0 to %d)" % (args.frame, len(times), len(times) - 1))
TIME = times[args.frame]
scene = pv.GetAnimationScene()
scene.UpdateAnimationUsingDataTimeSteps()
scene.AnimationTime = TIME


def block(name):
    """One top-level grid of the file (the reader itself when the file has only that one)."""
    if name not in grids:
        return None
    if len(grids) == 1:
        return reader
    return pv.ExtractBlock(registrationName=name, Input=reader, Selectors=["/Root/" + name])


membrane, velocity_field, fluid = block("membrane"), block("field_velocity"), block("fluid")
everything = bounds_of(reader, TIME)
if everything[0] > everything[1]:  # empty bounds: nothing readable
    fail("frame %d of %s holds no data (is trajectory.h5 complete?)" % (args.frame, xmf))
# Fields may start a frame after the membrane: where the frame has none, the box and the colour
# range come from the last frame.
field_time = TIME
if velocity_field is not None:
    velocity_field.UpdatePipeline(TIME)
    if velocity_field.GetDataInformation().GetNumberOfCells() == 0:
        field_time = times[-1]

# -- geometry of the run: flow axis, box, tube (all in the files' unit, metres) --------------------
tube = scenario.get("tube", {})
if velocity_field is not None:  # the binned fields cover the simulation box
    b = bounds_of(velocity_field, field_time)
    box_lo, box_hi = [b[0], b[2], b[4]], [b[1], b[3], b[5]]
elif "shear" in scenario and "box_um" in scenario["shear"]:  # the shear box starts at 0
    box_lo, box_hi = [0.0, 0.0, 0.0], [1e-6 * s for s in scenario["shear"]["box_um"]]
else:  # anything else: around what the frame holds
    box_lo, box_hi = list(everything[0::2]), list(everything[1::2])
centre = [(lo + hi) / 2 for lo, hi in zip(box_lo, box_hi)]
side = [hi - lo for lo, hi in zip(box_lo, box_hi)]
if max(everything[1::2]) > 1e-2:  # a run over 1 cm: not metres
    print("view_in_paraview: warning: the positions do not look like metres; the tube will be off")

# Flow along x (hemodpd's convention), except in a tube: along its axis, the box side that
# differs from the two equal transverse ones (z in today's capillary scenario).
flow = 0
if "diameter_um" in tube:
    flow = 2
    for i in range(3):
        a, c = [side[j] for j in range(3) if j != i]
        if abs(a - c) < 1e-3 * a and abs(side[i] - a) > 1e-3 * a:
            flow = i

# The camera looks along `look` with `up` pointing up, so the flow runs left to right:
# shear runs are seen along the vorticity (z, y up); tubes from the side.
up = [0.0, 1.0, 0.0] if flow != 1 else [0.0, 0.0, 1.0]
axis = [1.0 if i == flow else 0.0 for i in range(3)]
look = [up[1] * axis[2] - up[2] * axis[1], up[2] * axis[0] - up[0] * axis[2], up[0] * axis[1] - up[1] * axis[0]]

# Membrane positions are unwrapped: a cell carried along a periodic tube leaves the box, and the
# binned fluid around it, after one box length. Shift it back by whole box lengths along the
# flow, in every frame, so that it sits in the fluid it moves through.
if membrane is not None and "diameter_um" in tube and velocity_field is not None:
    # (A Python Calculator and a warp, not a Programmable Filter: that one star-imports numpy
    # into this script's namespace, replacing max, abs...)
    shift = pv.PythonCalculator(Input=pv.MergeBlocks(Input=membrane), ArrayName="wrap shift")
    shift.Expression = "(inputs[0].Points * 0 + %r) * (-%r * floor((mean(inputs[0].Points[:, %d]) - %r) / %r))" % (
        axis, side[flow], flow, box_lo[flow], side[flow])
    membrane = pv.WarpByVector(registrationName="cell in the box", Input=shift, Vectors=["POINTS", "wrap shift"])

# -- the scene -------------------------------------------------------------------------------------
view = pv.GetActiveViewOrCreate("RenderView")
view.OrientationAxesVisibility = 1
view.CameraParallelProjection = 1
component = "XYZ"[flow]  # colour by the velocity component along the flow

# The cell: its surface coloured by the vertex velocity along the flow.
if membrane is not None:
    cell = pv.Show(membrane, view)
    cell.Representation = "Surface"
if membrane is not None and "velocity" in membrane.PointData.keys():
    # Its own colour map (the fluid's is also called "velocity"): vertex velocities are noisier.
    cell.UseSeparateColorMap = 1
    cell_lut = pv.GetColorTransferFunction("velocity", cell, separate=True)
    pv.ColorBy(cell, ("POINTS", "velocity", component))
    cell.LookupTable = cell_lut
    cell_lut.VectorMode, cell_lut.VectorComponent = "Component", flow
    cell_lut.ApplyPreset("Cool to Warm", True)
    cell_lut.AutomaticRescaleRangeMode = "Clamp and update every timestep"  # as the time changes
    cell.RescaleTransferFunctionToDataRange(False, True)
    cell.SetScalarBarVisibility(view, True)
    bar = pv.GetScalarBar(cell_lut, view)
    bar.Title, bar.ComponentTitle = "cell velocity (m/s)", component
    bar.WindowLocation = "Upper Right Corner"

# The tube (capillary runs): a translucent cylinder along the flow axis through the box centre,
# as long as the box (the tube is periodic along its axis).
if "diameter_um" in tube:
    p1, p2 = list(centre), list(centre)
    p1[flow], p2[flow] = box_lo[flow], box_hi[flow]
    wall = pv.Tube(registrationName="tube", Input=pv.Line(Point1=p1, Point2=p2))
    wall.Radius = 0.5e-6 * tube["diameter_um"]  # µm -> m, the unit of the files
    wall.NumberofSides, wall.Capping = 96, 0
    tube_rep = pv.Show(wall, view)
    tube_rep.DiffuseColor = tube_rep.AmbientColor = [0.75, 0.75, 0.8]
    tube_rep.Opacity = 0.3
elif kind == "shear" or "shear" in scenario:  # the sheared periodic box, as an outline
    box = pv.Box(registrationName="box", Center=centre, XLength=side[0], YLength=side[1], ZLength=side[2])
    pv.Show(box, view).Representation = "Outline"

# The binned fluid velocity: a slice through the box centre facing the camera, coloured by the
# component along the flow, with arrows (length ∝ speed) on its bins.
if velocity_field is not None:
    cut = pv.Slice(registrationName="velocity slice", Input=velocity_field)
    cut.SliceType = "Plane"
    cut.SliceType.Origin, cut.SliceType.Normal = centre, look
    cut_rep = pv.Show(cut, view)
    pv.ColorBy(cut_rep, ("CELLS", "velocity", component))
    fluid_lut = pv.GetColorTransferFunction("velocity")
    fluid_lut.ApplyPreset("Viridis (matplotlib)", True)
    fluid_lut.AutomaticRescaleRangeMode = "Clamp and update every timestep"
    cut.UpdatePipeline(field_time)
    fluid_lut.RescaleTransferFunction(*cut.CellData["velocity"].GetRange(flow))
    cut_rep.SetScalarBarVisibility(view, True)
    bar = pv.GetScalarBar(fluid_lut, view)
    bar.Title, bar.ComponentTitle = "fluid velocity (m/s)", component
    bar.WindowLocation = "Lower Right Corner"
    if "diameter_um" in tube:  # the wall where the slice meets it: two lines
        wall_cut = pv.Slice(registrationName="tube wall in the slice", Input=wall)
        wall_cut.SliceType = "Plane"
        wall_cut.SliceType.Origin, wall_cut.SliceType.Normal = centre, look
        wall_rep = pv.Show(wall_cut, view)
        wall_rep.DiffuseColor = wall_rep.AmbientColor = [0.9, 0.9, 0.9]
        wall_rep.LineWidth, wall_rep.Ambient, wall_rep.Diffuse = 3, 1.0, 0.0  # unlit: evenly grey
    vmax = max(abs(v) for v in cut.CellData["velocity"].GetRange(-1)) or 1.0
    arrows = pv.Glyph(registrationName="velocity arrows", Input=cut, GlyphType="Arrow")
    arrows.OrientationArray, arrows.ScaleArray = ["CELLS", "velocity"], ["CELLS", "velocity"]
    n_bins = velocity_field.GetDataInformation().GetNumberOfCells()
    bin_size = (side[0] * side[1] * side[2] / n_bins) ** (1 / 3)
    arrows.ScaleFactor = 1.5 * bin_size / vmax  # the fastest bin's arrow: 1.5 bins long
    arrows.GlyphMode = "All Points"
    arrows_rep = pv.Show(arrows, view)
    arrows_rep.ColorArrayName = ["POINTS", ""]  # plain white arrows
    arrows_rep.DiffuseColor = arrows_rep.AmbientColor = [1.0, 1.0, 1.0]

# Fluid particles (fluid-only runs): points coloured like the binned velocity.
if fluid is not None:
    particles = pv.Show(fluid, view)
    particles.Representation, particles.PointSize = "Points", 2
    if "velocity" in fluid.PointData.keys():
        pv.ColorBy(particles, ("POINTS", "velocity", component))
        if velocity_field is None:
            particles.RescaleTransferFunctionToDataRange(False, True)
        particles.SetScalarBarVisibility(view, True)
        pv.GetScalarBar(pv.GetColorTransferFunction("velocity"), view).Title = "fluid velocity (m/s)"

# Frame time, top left.
clock = pv.AnnotateTimeFilter(registrationName="time", Input=reader, Format="t = {time:.4g} ms", Scale=1e3)
pv.Show(clock, view).WindowLocation = "Upper Left Corner"

# Camera: along `look`, centred on the box, fitted to what is shown.
view.CameraFocalPoint = centre
view.CameraPosition = [c - 10 * max(side) * l for c, l in zip(centre, look)]
view.CameraViewUp = up
view.ResetCamera(False)
# Parallel projection: fit the box (or tube) with a small margin rather than its bounding sphere.
width, height = view.ViewSize if not args.screenshot else args.size
view.CameraParallelScale = 0.6 * max(side[up.index(1.0)], side[flow] * height / width)
pv.SetActiveSource(membrane or reader)

if args.screenshot:
    view.ViewSize = args.size  # fonts sized for the image
    pv.SaveScreenshot(args.screenshot, view, ImageResolution=args.size)
    print("view_in_paraview: wrote %s (frame %d of %d, t = %g s)" % (args.screenshot, args.frame % len(times), len(times), TIME))
elif IN_GUI:
    pv.Render(view)
else:  # plain pvpython: an interactive window (close it to quit)
    pv.Render(view)
    pv.Interact(view)
