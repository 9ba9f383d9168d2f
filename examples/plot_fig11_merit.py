"""
Figure 11: the merit image of marker detection
==============================================

Markers are found by correlating the frame with a template of the marker's size: a
top-hat (the disk's inside minus a ring around it). The correlation, the *merit*, peaks at
each marker; a threshold of a few noise sigmas keeps the candidates, whose positions are
then refined to sub-pixel by fitting a blurred disk (:doc:`/detection`).

The frame is camera 0 of :func:`scenes.real_traits.real_traits`: an 8-bit frame of a
painted plate with vignetting, noise, a saturated glare spot, pressure taps as smaller dark
dots (distractors) and a black unpainted block.
"""

import matplotlib.pyplot as plt
import numpy as np
from scipy.ndimage import correlate

from resection.markers.detect import detect_markers, marker_template
from scenes.real_traits import real_traits

scene = real_traits(scale=1)
frame = np.asarray(scene.images[0], dtype=np.float32)
diameter = 6.0

# The merit as the detector defines it: the frame correlated with the top-hat template
# (dark markers: the frame's negative), borders mirrored.
template = marker_template(diameter, kind="tophat")
merit = correlate(-frame, template, mode="mirror")

found = detect_markers(frame, diameter, polarity="dark")
truth = scene.uv[0]
h, w = frame.shape
in_frame = np.isfinite(truth).all(axis=1) & (truth[:, 0] > 3) & (truth[:, 0] < w - 4) & (
    truth[:, 1] > 3) & (truth[:, 1] < h - 4)
truth = truth[in_frame]
print(f"{len(found.u)} candidates; {len(truth)} targets inside the frame")

fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), layout="constrained")
axes[0].imshow(frame, cmap="gray")
axes[0].set_title("camera 0 (8-bit, glare, taps, unpainted block)", fontsize=9)
im = axes[1].imshow(merit, cmap="magma")
axes[1].plot(found.u, found.v, "o", mfc="none", mec="cyan", ms=9, label="candidates")
axes[1].set_title("merit (top-hat correlation) and the candidates kept", fontsize=9)
axes[1].legend(loc="lower right", fontsize=8)
fig.colorbar(im, ax=axes[1], shrink=0.8, label="merit (counts)")
for ax in axes:
    ax.set_axis_off()

# %%
# Each target's nearest candidate, in pixels from the target's true centre: the detector's
# sub-pixel accuracy on this frame.
uv = np.column_stack([found.u, found.v])
gap = np.hypot(*(uv[None] - truth[:, None]).transpose(2, 0, 1)).min(axis=1)
inside = np.isfinite(gap) & (gap < 2)
print(f"{inside.sum()} of {len(truth)} targets found within 2 px; "
      f"median error {np.median(gap[inside]):.3f} px, largest {gap[inside].max():.3f} px")
