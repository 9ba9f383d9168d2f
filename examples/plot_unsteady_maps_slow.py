"""
Unsteady PSP: the dCp RMS and PSD maps
======================================

The maps ``selfillum unsteady`` makes of a run, here of the synthetic run of
:func:`scenes.unsteady_run.make_unsteady_run` (a plate with a block on it, vibrating; a
120 Hz tone and a 70 Hz convected wave on the plate, a 200 Hz tone on the block) read
from its uPSP deck (with the options uPSP decks use): the dCp RMS over the run at every grid
node, and the power spectral density of dCp per node in log-spaced frequency bands.
"""

import tempfile
from pathlib import Path

import h5py
import numpy as np

from resection import plot_surface, read_camera
from resection.io.upsp_inputs import read_deck
from scenes.unsteady_run import make_unsteady_run
from selfillum.unsteady import config_from_deck, run_unsteady
from selfillum.unsteady.grid import load_run_grid
from selfillum.unsteady.plots import node_to_faces, plot_rms

tmp = tempfile.TemporaryDirectory()
work = Path(tmp.name)
run = make_unsteady_run(work / "run", frames=96, faces=1200)
config = config_from_deck(read_deck(run.deck), paint_calibration=run.paint, steady=run.steady,
                          fps=run.fps, out=work / "out.h5", plots=False)
result = run_unsteady(config)

grid = load_run_grid(run.grid)
camera = read_camera(run.calibration)
with h5py.File(work / "out.h5") as f:
    rms = f["stats/dcp_rms"][...]
    band_psd = f["psd/band_psd"][...]
    edges = f["psd/band_edges"][...]

# %%
# The dCp RMS over the run, seen from the camera: the block's strong tone, the plate's
# weaker tone and wave.
rms_map = plot_rms(grid, rms, None, camera=camera)

# %%
# The PSD of dCp per node in two of the bands: the one holding the plate's 120 Hz tone,
# and the one holding the block's 200 Hz tone.
psd_maps = []
for tone in (120.0, 200.0):
    b = int(np.clip(np.searchsorted(edges, tone) - 1, 0, len(edges) - 2))
    faces = node_to_faces(grid.triangles, band_psd[:, b])
    psd_maps.append(plot_surface(grid.mesh, np.log10(faces), camera, cmap="magma",
                                 label="log10 PSD of dCp (1/Hz)",
                                 title=f"band {edges[b]:.0f}-{edges[b + 1]:.0f} Hz"))
tmp.cleanup()
