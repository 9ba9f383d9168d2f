"""
From a tunnel's files to a pressure time history
================================================

A high-speed PSP camera films a painted model in the tunnel. What comes out of the tunnel
is what NASA's uPSP works from: the model's surface grid, its targets (``.tgts``), the
camera's internal calibration, a video, the tunnel's conditions (``.wtd``), the paint
calibration, the steady Cp and a ``psp_process`` input deck. This tutorial takes those
files to dCp at every grid node and every frame, with its spectra, using the two commands
``resection`` and ``selfillum`` as you would type them. Each step shows the picture it
makes.

The files here are written by :func:`scenes.unsteady_run.make_unsteady_run`: a painted
plate with a painted block on it, vibrating in pitch and heave, with a known dCp (a 120 Hz
tone and a 70 Hz wave convected along the plate, and the block's own 200 Hz tone that
reaches the plate only as light reflected by the block). So every number below can be
checked against the truth.
"""

# %%
# The tunnel's files
# ------------------
# ``make_unsteady_run`` writes a run as a tunnel would: the grid (Plot3D), the targets
# (``.tgts``), the camera's video (an NPY stack here; ``.cine`` and ``.mraw`` are read the
# same way), its calibration, the ``.wtd``, the paint gain file, the steady Cp and a deck.
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py
import matplotlib.pyplot as plt
import numpy as np
from scipy.signal import welch

import scenes
from resection import read_camera, read_image, read_markers, write_camera, write_image
from scenes.unsteady_run import make_unsteady_run

BIN = Path(sys.executable).parent  # where resection and selfillum are installed
work = Path(tempfile.mkdtemp(prefix="wto-tutorial-"))
run = make_unsteady_run(work / "tunnel", frames=96, faces=1200, width=200, height=150)
for path in sorted(run.folder.iterdir()):
    print(f"{path.name:12s} {path.stat().st_size:>9,d} bytes")


def sh(*args: str) -> str:
    """Run a command as typed in a shell, print it and what it printed."""
    print("$", " ".join(str(a) for a in args))
    done = subprocess.run([str(BIN / args[0]), *map(str, args[1:])], cwd=work,
                          capture_output=True, text=True)
    print((done.stdout + done.stderr).strip())
    if done.returncode != 0:
        raise RuntimeError(f"{args[0]} {args[1]} exited {done.returncode}")
    return done.stdout


def show(png: Path, title: str) -> None:
    """Show a picture a command wrote, at its own size."""
    image = plt.imread(png)
    h, w = image.shape[0] / 100, image.shape[1] / 100
    fig = plt.figure(figsize=(w, h + 0.3), dpi=100)
    ax = fig.add_axes((0, 0, 1, h / (h + 0.3)))
    ax.imshow(image)
    ax.set_axis_off()
    fig.text(0.01, 1 - 0.15 / (h + 0.3), title, va="center", fontsize=9)


# %%
# The first frame, and a camera that knows only its lens
# ------------------------------------------------------
# A new set-up starts from the camera's internal calibration: intrinsics and distortion,
# no pose. We write one as uPSP does (``intrinsics_only``) from the scene's camera, and
# take the first frame out of the video.
video = np.load(run.video, mmap_mode="r")
write_image(work / "frame0.tif", np.asarray(video[0], dtype=np.float32))
write_camera(work / "internal.json", read_camera(run.calibration), format="upsp",
             intrinsics_only=True)
plt.figure(figsize=(4, 3))
plt.imshow(read_image(work / "frame0.tif"), cmap="gray")
plt.title(f"frame 0 of {len(video)} ({video.shape[2]} x {video.shape[1]} px)")

# %%
# Without a pose nothing predicts where the targets fall, and ``pose`` says so rather than
# guessing:
done = subprocess.run([str(BIN / "resection"), "pose", "--image", "frame0.tif", "--camera",
                       "internal.json", "--markers", run.targets, "--out", "pose.json"],
                      cwd=work, capture_output=True, text=True)
print(done.returncode, done.stderr.strip())

# %%
# Link the first frame
# --------------------
# ``resection detect`` finds the dark disks of the targets (about 6 px across here) to
# sub-pixel accuracy, and ``resection link`` draws them numbered over the frame.
sh("resection", "detect", "frame0.tif", "--diameter", "6", "--out", "candidates.csv")
sh("resection", "link", "frame0.tif", "--candidates", "candidates.csv", "--png",
   "candidates.png")
show(work / "candidates.png", "resection link: the candidates, numbered")

# %%
# In the tunnel you would now click four candidates and their targets in the linking page
# (``resection link --serve frame0.tif --camera internal.json --markers model.tgts
# --diameter 6 --save-links links.csv``, see :doc:`/linking`), which writes ``links.csv``,
# one ``id,candidate`` line a click. Here the clicks are made for you: the four targets
# nearest the corners of the frame, linked to the candidate where the scene's true pose in
# frame 0 puts them (the model vibrates: frame 0 is not the calibration's rest pose).
pose0 = run.poses[0, 0]
truth_camera = read_camera(run.calibration).with_pose(R=pose0[:3], t=pose0[3])
targets = read_markers(run.targets)
cand = np.loadtxt(work / "candidates.csv", delimiter=",", skiprows=1, usecols=(0, 1))
uv = truth_camera.project(targets.xyz)
gap = np.hypot(*(cand[None] - uv[:, None]).transpose(2, 0, 1))  # targets x candidates, px
nearest = gap.argmin(axis=1)
found = gap.min(axis=1) < 1.5  # targets with a candidate where the true camera puts them
if targets.taps is not None:
    found &= ~targets.taps
corners = [(0, 0), (200, 0), (0, 150), (200, 150)]
picked = {int(np.argmin(np.where(found, np.hypot(*(uv - c).T), np.inf))) for c in corners}
lines = ["id,candidate"] + [f"{targets.ids[k]},{nearest[k]}" for k in sorted(picked)]
(work / "links.csv").write_text("\n".join(lines) + "\n")
print((work / "links.csv").read_text())

# %%
# Solve the pose
# --------------
# From the four links, ``pose`` solves the camera's pose, then looks again for every other
# target that pose puts in view, solves again from all of them, and judges the residuals
# by the acceptance rule (:doc:`/acceptance`). ``--plot`` draws the paper's Figure 20: the
# model's outline, detected and reprojected targets, residual arrows magnified.
sh("resection", "pose", "--image", "frame0.tif", "--camera", "internal.json", "--markers",
   run.targets, "--links", "links.csv", "--diameter", "6", "--mesh", run.grid, "--out",
   "pose.json", "--plot", "pose.png")
show(work / "pose.png", "resection pose --plot: the overlay (Figure 20)")

# %%
# How far the solved camera puts the targets found in the frame from where the scene's
# true pose puts them:
solved = read_camera(work / "pose.json")
apart = np.hypot(*(solved.project(targets.xyz[found]) - uv[found]).T)
print(f"solved vs true camera, {found.sum()} targets: RMS {np.sqrt(np.mean(apart**2)):.3f} px, "
      f"largest {apart.max():.3f} px")

# %%
# Map the frame onto the grid
# ---------------------------
# ``map`` ties every pixel to the grid faces it sees (Embree visibility, faces seen more
# obliquely than 70 degrees left out) and writes per-node values, here as VTK for
# ParaView; ``view`` draws them from the camera.
sh("resection", "map", "--mesh", run.grid, "--camera", "pose.json", "--image", "frame0.tif",
   "--out", "frame0.vtk")
sh("resection", "view", "--mesh", run.grid, "--values", "frame0.vtk", "--field", "frame0",
   "--camera", "pose.json", "--out", "frame0_view.png")
show(work / "frame0_view.png", "resection view: frame 0 on the grid")

# %%
# Run unsteady
# ------------
# ``selfillum unsteady`` is uPSP's ``psp_process``: it reads the deck as it is, with the
# options uPSP decks use (targets patched by polynomials, pixel registration, cameras
# averaged). We point the deck's camera at the solved pose. Every frame is mapped, the
# self-illumination of the block on the plate is removed frame by frame, and Phase 2 turns
# intensities into dCp with the paint calibration and the tunnel's conditions.
deck = run.deck.read_text()
deck = deck.replace(f"$dir/{run.calibration.name}", str(work / "pose.json"))
(work / "run.inp").write_text(deck)
(work / "out").mkdir()
print(deck)

# %%
sh("selfillum", "unsteady", "run.inp", "--paint-calibration", run.paint, "--steady",
   run.steady, "--fps", run.fps, "--psd", "300,700", "--out", "out/run.h5")
show(work / "out" / "run_rms.png", "selfillum unsteady: the dCp RMS on the model")

# %%
# The spectra
# -----------
# The PSD picture shows Welch's spectra at the probe nodes given with ``--psd``, and their
# mean over the nodes.
show(work / "out" / "run_psd.png", "selfillum unsteady: Welch PSD of dCp")

# %%
# Read the result
# ---------------
# ``run.h5`` holds dCp as one frames x nodes dataset in the grid file's node order, with
# per-node statistics and the spectra; ``run.xdmf`` beside it describes them for ParaView.
# The same file in Python:
with h5py.File(work / "out" / "run.h5") as f:
    f.visit(lambda name: print(name, getattr(f[name], "shape", "")))
    dcp = f["dcp"][...]

# %%
# Open it in ParaView
# -------------------
# In ParaView's window: File > Open, ``out/run.xdmf``, the reader "Xdmf Reader", Apply;
# colour by ``dCp``; the time bar steps through the frames. The same done by ParaView's
# own Python (``pvbatch``) is ``tools/paraview_frame.py`` in the repository: it opens the
# file with that reader, goes to a time step, saves that step's dCp and a picture seen
# from the solved camera. Where ParaView is installed (``tools/setup.sh`` installs
# Debian's when run as root; it is no pip package), this page runs it. Where it is not,
# the page runs instead the reader behind ParaView's "Xdmf Reader", VTK's
# ``vtkXdmfReader`` from the ``vtk`` package, and draws with VTK: the output below says
# which one ran. Either way the values read are checked against row ``k`` of ``/dcp`` in
# ``run.h5``.
k = len(dcp) // 3  # the time step shown
pose = read_camera(work / "pose.json")  # look from where the camera was
angle = float(np.degrees(2 * np.arctan(pose.height / 2 / pose.K[1, 1])))
low, high = np.nanpercentile(dcp, [1, 99])
paraview = shutil.which("pvbatch") and (os.environ.get("DISPLAY") or shutil.which("Xvfb"))
if paraview:
    tool = Path(scenes.__file__).resolve().parents[1] / "tools" / "paraview_frame.py"
    view = [*pose.center, *(pose.center + pose.R[2]), *(-pose.R[1]), angle]
    args = ["out/run.xdmf", "--array", "dCp", "--step", str(k), "--reader", "Xdmf Reader",
            "--view=" + ",".join(f"{v:.6g}" for v in view), f"--range={low:.6g},{high:.6g}",
            "--size", f"{3 * pose.width},{3 * pose.height}", "--npy", "paraview_frame.npy",
            "--png", "paraview_frame.png"]
    print("$ python tools/paraview_frame.py", shlex.join(args))
    done = subprocess.run([sys.executable, str(tool), *args], cwd=work, capture_output=True,
                          text=True)
    print(done.stdout.strip())
    if done.returncode != 0:
        raise RuntimeError(f"tools/paraview_frame.py exited {done.returncode}: "
                           f"{done.stderr.strip()[-500:]}")
    values = np.load(work / "paraview_frame.npy")
    title = f"out/run.xdmf in ParaView (pvbatch), the Xdmf Reader: dCp, frame {k}"
else:
    import vtk
    from vtkmodules.util.numpy_support import vtk_to_numpy

    print("ParaView is not installed here: VTK's vtkXdmfReader (ParaView's Xdmf Reader)")
    reader = vtk.vtkXdmfReader()
    reader.SetFileName(str(work / "out" / "run.xdmf"))
    reader.UpdateInformation()
    steps = reader.GetOutputInformation(0).Get(
        vtk.vtkStreamingDemandDrivenPipeline.TIME_STEPS())
    reader.UpdateTimeStep(steps[k])  # ParaView's time bar
    blocks = reader.GetOutputDataObject(0).NewIterator()  # the grid and its time series
    blocks.InitTraversal()
    while not blocks.IsDoneWithTraversal():
        if blocks.GetCurrentDataObject().GetPointData().GetArray("dCp") is not None:
            frame = blocks.GetCurrentDataObject()  # the time series' grid at step k
        blocks.GoToNextItem()
    surface = vtk.vtkGeometryFilter()
    surface.SetInputData(frame)
    surface.Update()
    grid = surface.GetOutput()
    values = vtk_to_numpy(grid.GetPointData().GetArray("dCp"))
    print(f"{len(steps)} time steps, t = {steps[0]:.4f} .. {steps[-1]:.4f} s; frame {k}: "
          f"{grid.GetNumberOfPoints()} nodes, {grid.GetNumberOfCells()} faces")
    lut = vtk.vtkLookupTable()
    lut.SetHueRange(0.667, 0.0)  # blue to red, ParaView's rainbow
    lut.SetNanColor(0.6, 0.6, 0.6, 1.0)  # nodes no camera saw
    lut.Build()
    mapper = vtk.vtkPolyDataMapper()
    mapper.SetInputData(grid)
    mapper.SetScalarModeToUsePointFieldData()
    mapper.SelectColorArray("dCp")
    mapper.SetLookupTable(lut)
    mapper.SetScalarRange(low, high)
    actor = vtk.vtkActor()
    actor.SetMapper(mapper)
    bar = vtk.vtkScalarBarActor()
    bar.SetLookupTable(lut)
    bar.SetTitle("dCp")
    bar.SetWidth(0.1)
    renderer = vtk.vtkRenderer()
    renderer.AddActor(actor)
    renderer.AddViewProp(bar)
    renderer.SetBackground(1.0, 1.0, 1.0)
    bar.GetTitleTextProperty().SetColor(0, 0, 0)
    bar.GetLabelTextProperty().SetColor(0, 0, 0)
    camera = renderer.GetActiveCamera()
    camera.SetPosition(*pose.center)
    camera.SetFocalPoint(*(pose.center + pose.R[2]))
    camera.SetViewUp(*(-pose.R[1]))
    camera.SetViewAngle(angle)
    renderer.ResetCameraClippingRange()
    window = vtk.vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.AddRenderer(renderer)
    window.SetSize(3 * pose.width, 3 * pose.height)
    window.Render()
    shot = vtk.vtkWindowToImageFilter()
    shot.SetInput(window)
    png = vtk.vtkPNGWriter()
    png.SetFileName(str(work / "paraview_frame.png"))
    png.SetInputConnection(shot.GetOutputPort())
    png.Write()
    window.Finalize()
    title = f"out/run.xdmf through VTK's vtkXdmfReader (no ParaView here): dCp, frame {k}"
print(f"frame {k}'s dCp as in run.h5: {np.array_equal(values, dcp[k], equal_nan=True)}")
show(work / "paraview_frame.png", title)

# %%
# The time history of a plate node near the middle of the seen part, against the truth
# the scene used; and where the spectra of the plate's and the block's seen nodes peak
# (Welch's method, as ``selfillum unsteady`` computes them), against the tones the scene
# put there:
seen = np.isfinite(dcp).all(axis=0)
plate_nodes = np.flatnonzero(run.plate & seen)
node = plate_nodes[len(plate_nodes) // 2]
t = np.arange(len(dcp)) / run.fps
fig, ax = plt.subplots(figsize=(6.5, 3))
ax.plot(1000 * t, run.truth[:, node], color="0.6", lw=4, label="truth")
ax.plot(1000 * t, dcp[:, node], "k", lw=1, label="selfillum unsteady")
ax.set_xlabel("time (ms)")
ax.set_ylabel("dCp")
ax.set_title(f"node {node}")
ax.legend()
err = dcp[:, node] - run.truth[:, node]
print(f"node {node}: dCp RMS error {np.sqrt(np.mean(err**2)):.4f}, "
      f"signal RMS {np.std(run.truth[:, node]):.4f}")
for part, tone in (("plate", "tone"), ("block", "block")):
    nodes = np.flatnonzero(getattr(run, part) & seen)
    f_w, p_w = welch(dcp[:, nodes], fs=run.fps, nperseg=len(dcp), axis=0)
    peak = f_w[1:][np.argmax(p_w[1:].mean(axis=1))]
    print(f"{part}: {len(nodes)} nodes seen, spectrum peak {peak:.0f} Hz "
          f"(the scene's {tone}: {run.freqs[tone]:.0f} Hz, bins {f_w[1]:.1f} Hz apart)")

# %%
shutil.rmtree(work)
