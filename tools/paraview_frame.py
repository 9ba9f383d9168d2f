"""Open an XDMF file in ParaView, read one time step of an array and draw it.

It does what File > Open, Apply, the time bar and File > Save Screenshot do in ParaView's
window, in ParaView itself::

    python tools/paraview_frame.py out/run.xdmf --array dCp --step 32 \\
        --reader "Xdmf Reader" --npy frame.npy --png frame.png

Run by any Python (the project's ``.venv``), it runs itself again under ParaView's own
Python, ``pvbatch`` (Debian's ``paraview`` and ``python3-paraview``, which
``tools/setup.sh`` installs when run as root), with the project's environment variables
left out; Debian's ParaView 5.11 draws through X only, so without a display it starts a
virtual one (``Xvfb``, Debian's ``xvfb``) for the run. Under ``pvbatch`` it imports only
``paraview`` and NumPy.

``--reader``: "Xdmf Reader" (ParaView's ``XDMFReader``, VTK's ``vtkXdmfReader``) or
"Xdmf3 Reader" (``Xdmf3ReaderS``, the XDMF 3 library). ``--step``: the time step's index
(a file without time steps: 0). The array is looked for in the point data, then the cell
data, of the one block that has it. ``--npy``: its values at that step, in the file's
order (NaN where the file has NaN). ``--png``: the surface coloured by the array, blue to
red over ``--range`` (default: the step's 1st to 99th percentile), on white, seen from
``--view`` (``px,py,pz,fx,fy,fz,ux,uy,uz,angle``: camera position, focal point, up and the
vertical view angle in degrees) or else from ParaView's reset camera. It prints the number
of time steps, the step's time, the array's size and where it lives. A file, step or array
it cannot find: one line on stderr, exit 2.
"""

import argparse
import os
import shutil
import subprocess
import sys

import numpy as np

try:
    from paraview import simple
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonDataModel import vtkCompositeDataSet
except ImportError:  # not ParaView's Python: run again under pvbatch
    simple = None


def fail(message):
    """One line on stderr, exit 2."""
    print(f"paraview_frame: {message}", file=sys.stderr)
    raise SystemExit(2)


def relaunch(argv):
    """Run this script under ``pvbatch`` (in a virtual display when there is none); its
    exit status."""
    pvbatch = shutil.which("pvbatch")
    if pvbatch is None:
        fail("ParaView's pvbatch is not installed (Debian: apt-get install paraview "
             "python3-paraview xvfb; tools/setup.sh does it when run as root)")
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    xvfb = None
    if not env.get("DISPLAY"):
        if shutil.which("Xvfb") is None:
            fail("no display, and no Xvfb to make one (Debian: apt-get install xvfb)")
        # -displayfd: Xvfb picks a free display and writes its number once it accepts
        # connections; -noreset: ParaView closes its first connection (a probe of OpenGL)
        # and opens another, which failed about 1 time in 12 here ("bad X server
        # connection") while the server reset after its last client left (0 in 36 without)
        read, write = os.pipe()
        xvfb = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0",
                                 "1280x1024x24", "-nolisten", "tcp", "-noreset"],
                                pass_fds=(write,),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(write)
        with os.fdopen(read) as fh:
            number = fh.readline().strip()
        if not number:
            xvfb.kill()
            fail("Xvfb did not start")
        env["DISPLAY"] = f":{number}"
    try:
        return subprocess.run([pvbatch, os.path.abspath(__file__), *argv], env=env).returncode
    finally:
        if xvfb is not None:
            xvfb.terminate()
            xvfb.wait()


#: ParaView's reader by the name its window shows, and its file name property
READERS = {"Xdmf Reader": ("XDMFReader", "FileNames"),
           "Xdmf3 Reader": ("Xdmf3ReaderS", "FileName")}


def blocks(data):
    """The data sets of ``data`` with their block names: itself (name None), or the leaves
    of a composite (multi-block)."""
    if not data.IsA("vtkCompositeDataSet"):
        return [(None, data)]
    out = []
    it = data.NewIterator()
    it.InitTraversal()
    while not it.IsDoneWithTraversal():
        meta = it.GetCurrentMetaData()
        name = meta.Get(vtkCompositeDataSet.NAME()) if meta.Has(vtkCompositeDataSet.NAME()) \
            else None
        out.append((name, it.GetCurrentDataObject()))
        it.GoToNextItem()
    return out


def find_array(data, name, path):
    """Where array ``name`` lives (``POINTS`` or ``CELLS``), the name of the block that has
    it (None: not a multi-block) and its values: point data first, then cell data, in the
    one block that has it (the unsteady run's file has two grids: the statistics' and the
    frames' time series)."""
    found = []
    for block_name, block in blocks(data):
        for where, arrays in (("POINTS", block.GetPointData()),
                              ("CELLS", block.GetCellData())):
            if arrays.GetArray(name) is not None:
                found.append((where, block_name, vtk_to_numpy(arrays.GetArray(name))))
                break
    if len(found) != 1:
        fail(f"{path}: array {name!r} found in {len(found)} blocks, expected 1")
    return found[0]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("xdmf")
    ap.add_argument("--array", required=True)
    ap.add_argument("--reader", choices=sorted(READERS), default="Xdmf Reader")
    ap.add_argument("--step", type=int, default=0)
    ap.add_argument("--npy")
    ap.add_argument("--png")
    ap.add_argument("--size", default="800,600", help="picture width,height in pixels")
    ap.add_argument("--range", help="colour range low,high")
    ap.add_argument("--view", help="px,py,pz,fx,fy,fz,ux,uy,uz,angle")
    a = ap.parse_args()
    if not os.path.isfile(a.xdmf):
        fail(f"{a.xdmf}: no such file")
    proxy, file_property = READERS[a.reader]
    # absolute: the Xdmf3 reader joins a bare name's data file to the name itself
    reader = getattr(simple, proxy)(**{file_property: [os.path.abspath(a.xdmf)]})
    reader.UpdatePipelineInformation()
    steps = list(reader.TimestepValues or [])
    if isinstance(reader.TimestepValues, float):  # one step
        steps = [reader.TimestepValues]
    if not 0 <= a.step < max(1, len(steps)):
        fail(f"{a.xdmf}: no step {a.step} ({len(steps)} time steps)")
    time = steps[a.step] if steps else 0.0
    reader.UpdatePipeline(time)
    data = reader.GetClientSideObject().GetOutputDataObject(0)
    where, block, values = find_array(data, a.array, a.xdmf)
    print(f"paraview_frame: {a.reader}, {len(steps)} time steps, step {a.step} at t = "
          f"{time:.17g}, {values.size} values of {a.array} on the {where.lower()}")
    if a.npy:
        np.save(a.npy, values)
    if a.png:
        view = simple.CreateView("RenderView")
        view.ViewSize = [int(v) for v in a.size.split(",")]
        view.ViewTime = time
        view.UseColorPaletteForBackground = 0
        view.Background = [1.0, 1.0, 1.0]
        view.OrientationAxesVisibility = 0
        source = reader if block is None else \
            simple.ExtractBlock(Input=reader, Selectors=[f"/Root/{block}"])
        surface = simple.ExtractSurface(Input=source)
        shown = simple.Show(surface, view)
        simple.ColorBy(shown, (where, a.array))
        lut = simple.GetColorTransferFunction(a.array)
        lut.ApplyPreset("Rainbow Uniform", True)
        lut.NanColor = [0.6, 0.6, 0.6]
        low, high = ([float(v) for v in a.range.split(",")] if a.range else
                     np.nanpercentile(values, [1, 99]))
        lut.RescaleTransferFunction(float(low), float(high))
        bar = simple.GetScalarBar(lut, view)
        bar.Title = a.array
        bar.ComponentTitle = ""
        bar.TitleColor = bar.LabelColor = [0.0, 0.0, 0.0]
        shown.SetScalarBarVisibility(view, True)
        if a.view:
            v = [float(x) for x in a.view.split(",")]
            view.CameraPosition, view.CameraFocalPoint, view.CameraViewUp = \
                v[0:3], v[3:6], v[6:9]
            view.CameraViewAngle = v[9]
        else:
            view.ResetCamera()
        simple.Render(view)
        simple.SaveScreenshot(a.png, view, ImageResolution=view.ViewSize)


if __name__ == "__main__":
    if simple is None:
        sys.exit(relaunch(sys.argv[1:]))
    main()
