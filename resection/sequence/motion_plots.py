"""Pictures of a tracked sequence: pose against time (the paper's Figure 23)."""

from __future__ import annotations

import os

import numpy as np

from resection.errors import InputError
from resection.sequence import TrackResult

__all__ = ["plot_motion"]


def plot_motion(
    result: TrackResult,
    path: str | os.PathLike | None = None,
    *,
    fps: float | None = None,
    length_unit: str = "m",
    length_scale: float = 1.0,
    truth: tuple[np.ndarray, np.ndarray] | None = None,
    title: str | None = None,
    dpi: int = 120,
):
    """Plot the attitude and position change of every frame against time.

    Three panels sharing the time axis: the three angles (degrees), the three translations
    (``length_unit`` after multiplying by ``length_scale``, e.g. ``"mm"`` and ``1000`` for
    metres), and the RMS reprojection error (pixels). Failed frames are marked by red ticks
    at the bottom of every panel.

    Parameters
    ----------
    result : TrackResult
        From :func:`resection.sequence.track` or :func:`resection.sequence.read_track`.
    path : path-like, optional
        Write the figure there (PNG, or any format matplotlib knows from the suffix).
    fps : float, optional
        Frame rate; the time axis is in seconds, else in frames.
    length_unit, length_scale : str, float
        Unit label and scale of the translations.
    truth : (angles_deg (F, 3), translation (F, 3)), optional
        A known motion drawn as wide grey bands under the measured curves (synthetic
        sequences).
    title : str, optional
    dpi : int

    Returns
    -------
    matplotlib.figure.Figure
    """
    if not isinstance(result, TrackResult):
        raise InputError(f"plot_motion: expected a TrackResult, got {type(result).__name__}")
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise InputError(f"plot_motion: fps must be positive, got {fps}")
    from matplotlib.figure import Figure

    t = result.frame / fps if fps else result.frame.astype(float)
    xlabel = "time (s)" if fps else "frame"
    fig = Figure(figsize=(9.0, 7.0), dpi=dpi, layout="constrained")
    axes = fig.subplots(3, 1, sharex=True, height_ratios=[3, 3, 1.5])
    colors = ("tab:blue", "tab:orange", "tab:green")
    who = "model" if result.fixed_camera else "camera"
    for k, name in enumerate(("roll", "pitch", "yaw")):
        axes[0].plot(t, result.angles[:, k], ".-", ms=2, lw=0.8, color=colors[k], label=name)
    for k, name in enumerate(("dx", "dy", "dz")):
        axes[1].plot(t, result.translation[:, k] * length_scale, ".-", ms=2, lw=0.8,
                     color=colors[k], label=name)
    if truth is not None:
        ta, tt = (np.asarray(a, float) for a in truth)
        if ta.shape != result.angles.shape or tt.shape != result.translation.shape:
            raise InputError("plot_motion: truth arrays must have the shape of the result's")
        for k in range(3):  # a wide grey band under the measured (coloured) curves
            axes[0].plot(t, ta[:, k], "-", color="0.55", lw=3.0, alpha=0.5, zorder=1,
                         label="truth" if k == 0 else None)
            axes[1].plot(t, tt[:, k] * length_scale, "-", color="0.55", lw=3.0, alpha=0.5,
                         zorder=1, label="truth" if k == 0 else None)
    axes[2].plot(t, result.rms, ".", ms=2, color="tab:purple")
    failed = ~result.ok
    for ax in axes:
        if failed.any():
            ax.plot(t[failed], np.zeros(failed.sum()), "|", color="red", ms=12,
                    transform=ax.get_xaxis_transform(), label="failed")
        ax.grid(True, lw=0.3)
    ref = result.reference
    axes[0].set_ylabel(f"{who} attitude (deg)")
    axes[1].set_ylabel(f"{who} displacement ({length_unit})")
    axes[2].set_ylabel("RMS (px)")
    axes[2].set_xlabel(xlabel)
    for ax in axes[:2]:  # outside the axes, so that they never hide data
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, borderaxespad=0)
    n_ok = int(result.ok.sum())
    head = title or f"{who} motion relative to frame {ref}"
    fig.suptitle(f"{head}: {n_ok}/{len(result)} frames solved, median RMS "
                 f"{np.nanmedian(result.rms) if n_ok else float('nan'):.3f} px", fontsize=10)
    from resection.surface.plots import finish_figure

    return finish_figure(fig, path, dpi)
