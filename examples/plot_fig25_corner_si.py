"""
Figures 25-26: self-illumination at a corner, and its correction
================================================================

Two painted plates at 90 degrees, the case ``selfillum corner`` runs: each plate's paint
lights the other, and next to the fold about 30 % of what a camera sees is light reflected
from the other plate. The measurement is simulated from converged closed-form view factors;
the correction uses view factors cast by Embree (RQMC rays, averaged over the corner's
symmetries). The profile across the corner: the true emission, the radiosity a camera sees
(with SI) and the corrected emission.

This runs a coarser corner than the command's default (16 squares a side instead of 40):
the same method, a larger residual.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

from selfillum.corner import plot_corner, run_corner

result = run_corner(resolution=16)
n = result.numbers
print(f"{n.faces} faces, {n.rays_per_face} rays a face; self-illumination up to "
      f"{100 * n.max_si_fraction:.1f} % of the signal; after correction the largest "
      f"residual is {100 * n.max_residual_fraction:.2f} %, "
      f"the RMS {100 * n.rms_residual_fraction:.2f} %")

with tempfile.TemporaryDirectory() as tmp:
    png = plot_corner(result, Path(tmp) / "corner_profile.png")
    picture = plt.imread(png)
fig = plt.figure(figsize=(picture.shape[1] / 100, picture.shape[0] / 100), dpi=100)
ax = fig.add_axes((0, 0, 1, 1))
ax.imshow(picture)
ax.set_axis_off()
