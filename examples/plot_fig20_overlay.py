"""
Figure 20: the resection check picture
======================================

What ``resection pose --plot`` draws after a pose is solved: the model's outline through
the solved camera, the detected markers and where the camera puts them, the residual
vectors magnified, and the RMS in the title. Here on the synthetic PSP panel of
:func:`scenes.psp_pair.psp_pair`, with markers "detected" at their true projections plus
0.15 px of noise and a camera whose pose is slightly off.
"""

import numpy as np

from resection import plot_resection
from scenes.psp_pair import HALF_X, HALF_Y, psp_pair, render

rng = np.random.default_rng(0)
pair = psp_pair(seed=0)
K = np.array(pair.camera_off.K)
K[0, 0] = K[1, 1] = 380.0  # a wider view than the pair's camera: the panel's outline shows
camera = pair.camera_off.replace(K=K)
image = render(camera, noise=0.005, rng=rng)
gx, gy = np.meshgrid(np.linspace(-0.8 * HALF_X, 0.8 * HALF_X, 6),
                     np.linspace(-0.8 * HALF_Y, 0.8 * HALF_Y, 4))
markers = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
detected = camera.project(markers) + 0.15 * rng.standard_normal((len(markers), 2))
solved = camera.with_pose(rvec=camera.rvec + [0.0, 0.0, 0.0005])
fig = plot_resection(np.nan_to_num(image), solved, markers, detected, mesh=pair.mesh,
                     ids=[f"M{k}" for k in range(len(markers))], title="wind-off")
