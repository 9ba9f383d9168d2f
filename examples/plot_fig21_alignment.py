"""
Figure 21: wind-on onto wind-off, aligned through the model
===========================================================

A PSP result is the ratio of the wind-on image to the wind-off one; the model moves between
them, and a 1-pixel misregistration ruins the ratio. :class:`resection.ViewWarp` maps the
wind-off image into the wind-on camera's view through the model's surface. The ratio
image of a synthetic pair (:func:`scenes.psp_pair.psp_pair`), unaligned, with a 1-pixel
shift, aligned through the surface, and perfectly registered (rendered directly in the
wind-on pose), each with its error against the true pressure factor.
"""

import numpy as np
from matplotlib.figure import Figure

from resection import ViewWarp
from scenes.psp_pair import plane_hits, pressure_factor, psp_pair

pair = psp_pair(seed=0)
warp = ViewWarp(pair.mesh, pair.camera_off, pair.camera_on)
P, on = plane_hits(pair.camera_on)
truth = pressure_factor(P)
m = warp.valid & on
m[:3], m[-3:], m[:, :3], m[:, -3:] = False, False, False, False
cases = {
    "unaligned": pair.wind_on / pair.wind_off,
    "1-px shift": pair.wind_on / np.roll(pair.wind_off_in_on_view, 1, axis=1),
    "aligned through the surface": pair.wind_on / warp(pair.wind_off),
    "perfectly registered": pair.wind_on / pair.wind_off_in_on_view,
}
fig = Figure(figsize=(12, 5.4), dpi=100, layout="constrained")
top, bottom = [], []
for k, (name, ratio) in enumerate(cases.items()):
    noise = np.std(ratio[m] / truth[m] - 1)
    ax = fig.add_subplot(2, 4, k + 1)
    top.append(ax)
    im = ax.imshow(np.where(m, ratio, np.nan), cmap="viridis", vmin=0.6, vmax=1.1)
    ax.set_title(f"{name}\nnoise {100 * noise:.2f} %", fontsize=9)
    ax.set_axis_off()
    ax2 = fig.add_subplot(2, 4, k + 5)
    bottom.append(ax2)
    im2 = ax2.imshow(np.where(m, ratio / truth - 1, np.nan), cmap="RdBu_r", vmin=-0.05,
                     vmax=0.05)
    ax2.set_title("ratio / truth - 1", fontsize=9)
    ax2.set_axis_off()
    print(f"{name:30s} ratio noise {100 * noise:.3f} %")
fig.colorbar(im, ax=top, shrink=0.8, label="I_on / I_off")
fig.colorbar(im2, ax=bottom, shrink=0.8, label="relative error")
fig.suptitle("Synthetic PSP pair: ratio image noise (the paper's Figure 21)")
