"""Figure 21 of the paper on a synthetic PSP pair: the wind-on / wind-off ratio image
unaligned, with a 1-pixel misregistration, aligned through the model surface, and with
perfectly registered images.

Run: ``.venv/bin/python examples/figure21_alignment.py [OUT.png]``
"""

import sys

import numpy as np
from matplotlib.figure import Figure

from resection.surface.align import ViewWarp
from scenes.psp_pair import plane_hits, pressure_factor, psp_pair


def main(out: str = "figure21_alignment.png") -> None:
    pp = psp_pair(seed=0)
    warp = ViewWarp(pp.mesh, pp.camera_off, pp.camera_on)
    P, on = plane_hits(pp.camera_on)
    truth = pressure_factor(P)
    m = warp.valid & on
    m[:3], m[-3:], m[:, :3], m[:, -3:] = False, False, False, False
    cases = {
        "unaligned": pp.wind_on / pp.wind_off,
        "1-px shift": pp.wind_on / np.roll(pp.wind_off_in_on_view, 1, axis=1),
        "aligned through the surface": pp.wind_on / warp(pp.wind_off),
        "perfectly registered": pp.wind_on / pp.wind_off_in_on_view,
    }
    fig = Figure(figsize=(12, 5.4), dpi=100, layout="constrained")
    top, bottom = [], []
    for k, (name, ratio) in enumerate(cases.items()):
        noise = np.std(ratio[m] / truth[m] - 1)
        ax = fig.add_subplot(2, 4, k + 1)
        top.append(ax)
        im = ax.imshow(np.where(m, ratio, np.nan), cmap="viridis", vmin=0.6, vmax=1.1)
        ax.set_title(f"{name}\nnoise {100 * noise:.2f} %", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        ax2 = fig.add_subplot(2, 4, k + 5)
        bottom.append(ax2)
        im2 = ax2.imshow(np.where(m, ratio / truth - 1, np.nan), cmap="RdBu_r", vmin=-0.05,
                   vmax=0.05)
        ax2.set_title("ratio / truth - 1", fontsize=9)
        ax2.set_xticks([])
        ax2.set_yticks([])
        print(f"{name:30s} ratio noise {100 * noise:.3f} %")
    fig.colorbar(im, ax=top, shrink=0.8, label="I_on / I_off")
    fig.colorbar(im2, ax=bottom, shrink=0.8, label="relative error")
    fig.suptitle("Synthetic PSP pair: ratio image noise (paper's Figure 21)")
    fig.savefig(out)
    print("wrote", out)


if __name__ == "__main__":
    main(*sys.argv[1:])
