"""ParaView opens a capillary run's trajectory (called by scripts/check_paraview.sh).

Usage: pvpython check_paraview_capillary.py FILE.xmf N_FRAMES N_VERTICES N_TRIANGLES SHOT.png
Checks the number of time steps, the membrane block (vertices, triangles, velocity array) and
the binned fluid fields (density, velocity), renders the last frame, and prints PV-CAPILLARY-OK.
"""
import sys
from paraview.simple import XDMFReader, Show, GetActiveViewOrCreate, ResetCamera, SaveScreenshot, servermanager

path, n_frames, n_vertices, n_triangles, shot = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
reader = XDMFReader(FileNames=[path])
reader.UpdatePipelineInformation()
times = list(reader.TimestepValues or [])
assert len(times) == n_frames, f"{len(times)} time steps, expected {n_frames}"
reader.UpdatePipeline(times[-1])
data = servermanager.Fetch(reader)
blocks = [data.GetBlock(i) for i in range(data.GetNumberOfBlocks())]
membrane = [b for b in blocks if b is not None and b.GetClassName() == "vtkUnstructuredGrid"]
fields = [b for b in blocks if b is not None and b.GetClassName() == "vtkImageData"]
assert len(membrane) == 1, f"membrane blocks: {len(membrane)}"
m = membrane[0]
assert m.GetNumberOfPoints() == n_vertices and m.GetNumberOfCells() == n_triangles, (m.GetNumberOfPoints(), m.GetNumberOfCells())
assert m.GetPointData().GetArray("velocity") is not None
names = sorted(f.GetCellData().GetArrayName(0) for f in fields)
assert names == ["density", "velocity"], names
view = GetActiveViewOrCreate("RenderView")
Show(reader, view)
ResetCamera(view)
SaveScreenshot(shot, view, ImageResolution=[400, 300])
print("PV-CAPILLARY-OK", len(times), "frames,", n_vertices, "vertices, fields", names)
