# Run by scripts/check_paraview.sh under `xvfb-run pvpython`: ParaView opens hemodpd's XDMF files.
# argv: BASE NV NT NF SCREENSHOT [FLUID_XMF FLUID_FRAMES FLUID_POINTS]
#   BASE.xmf / BASE.xmf3: the fixture of crates/io/examples/paraview_fixture.rs (NV vertices,
#   NT triangles, NF fluid particles, 5 frames, a 4x3x2 density field holding 3 + k per model
#   volume), read with the XDMF Reader (XDMF 2) and Xdmf3ReaderS (XDMF 3).
#   SCREENSHOT: a PNG of frame 2 (all blocks), written and checked to be a non-trivial file.
#   FLUID_XMF: the .xmf of a `hemodpd run` dpd-fluid trajectory, with its frame and particle count.
import os, sys
from paraview.simple import *
from paraview import servermanager as sm

base, nv, nt, nf, shot = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
L = 0.5e-6


def blocks_of(r, t):
    r.UpdatePipeline(t)
    d = sm.Fetch(r)
    out = []
    it = d.NewIterator(); it.InitTraversal()
    while not it.IsDoneWithTraversal():
        out.append(it.GetCurrentDataObject()); it.GoToNextItem()
    return out


for make, ext in [(lambda f: XDMFReader(FileNames=[f]), ".xmf"), (lambda f: Xdmf3ReaderS(FileName=[f]), ".xmf3")]:
    r = make(base + ext)
    r.UpdatePipelineInformation()
    ts = list(r.TimestepValues)
    assert len(ts) == 5, (ext, ts)
    blocks = blocks_of(r, ts[2])
    assert len(blocks) == 3, (ext, len(blocks))
    mem, fluid, field = blocks
    assert mem.GetNumberOfPoints() == nv and mem.GetNumberOfCells() == nt, ext
    assert mem.GetPointData().GetArray("velocity") is not None, ext
    b = mem.GetBounds()
    # frame 2: the unit sphere shifted by 2 model lengths along x, in metres
    assert abs(b[0] - (-1 + 2) * L) < 1e-9 and abs(b[1] - (1 + 2) * L) < 1e-9, (ext, b)
    assert fluid.GetNumberOfPoints() == nf, ext
    rho = field.GetCellData().GetArray("density")
    assert rho is not None and field.GetNumberOfCells() == 24, ext
    lo, hi = rho.GetRange()
    assert abs(lo - 3 / L ** 3) / lo < 1e-12 and abs(hi - 26 / L ** 3) / hi < 1e-12, (lo, hi)
    # x-fastest storage: cell (i=1, j=0, k=0) is value 1 -> density 4
    assert abs(rho.GetValue(1) - 4 / L ** 3) / hi < 1e-12, rho.GetValue(1)
    print("ok %s: %d frames, %d vertices, %d triangles, %d fluid particles, density %.3e..%.3e /m^3"
          % (ext, len(ts), nv, nt, nf, lo, hi))
    Delete(r)

# a rendered picture of frame 2 (all blocks: membrane, fluid, density field coloured by default)
r = XDMFReader(FileNames=[base + ".xmf"])
r.UpdatePipelineInformation()
view = GetActiveViewOrCreate("RenderView")
view.ViewSize = [400, 300]
view.ViewTime = list(r.TimestepValues)[2]
Show(r, view)
ResetCamera(view)
Render(view)
SaveScreenshot(shot, view, ImageResolution=[400, 300])
assert os.path.getsize(shot) > 1000, os.path.getsize(shot)
print("ok screenshot %s (%d bytes)" % (shot, os.path.getsize(shot)))
Delete(r)

if len(sys.argv) > 6:
    xmf, frames, points = sys.argv[6], int(sys.argv[7]), int(sys.argv[8])
    r = XDMFReader(FileNames=[xmf])
    r.UpdatePipelineInformation()
    ts = list(r.TimestepValues)
    assert len(ts) == frames, (xmf, ts)
    blocks = blocks_of(r, ts[-1])
    pts = [bl.GetNumberOfPoints() for bl in blocks if bl is not None and bl.GetNumberOfPoints() == points]
    assert pts, (xmf, [bl.GetNumberOfPoints() for bl in blocks if bl is not None])
    print("ok %s: %d frames, %d fluid particles" % (xmf, len(ts), points))
    Delete(r)
print("PV-OK")
