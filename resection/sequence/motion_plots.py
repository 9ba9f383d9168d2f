"""Pictures of a tracked sequence: pose against time (the paper's Figure 23).

:func:`motion_figure` draws from plain arrays and needs only NumPy and matplotlib (no
pyplot, no GUI backend, no layout engine): the plot process of ``resection track``
(:mod:`resection.sequence.plot_worker`) imports this module alone.
"""

from __future__ import annotations

import os

import numpy as np

from resection.errors import InputError

__all__ = ["motion_figure", "plot_motion", "save_figure"]

#: the figure's margins (fractions of its size): fixed, so that drawing needs no layout
#: engine (matplotlib's constrained layout measures every text twice: a third of the time
#: of drawing this figure); the legends sit in the right margin, outside the axes
MARGINS = {"left": 0.115, "right": 0.87, "bottom": 0.075, "top": 0.94, "hspace": 0.08}
#: zlib level of the PNG: 1 writes the picture several times faster than the default 6
#: (the PNG encoder took half the time of the whole figure) for a file about 1.5 x larger
PNG_COMPRESS_LEVEL = 1


def plot_motion(
    result,
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
        Write the figure there (PNG, or any format matplotlib knows from the suffix),
        through a temporary file renamed into place.
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
    from resection.sequence.results import TrackResult

    if not isinstance(result, TrackResult):
        raise InputError(f"plot_motion: expected a TrackResult, got {type(result).__name__}")
    fig = motion_figure(**motion_data(result), fps=fps, length_unit=length_unit,
                        length_scale=length_scale, truth=truth, title=title, dpi=dpi)
    if path is not None:
        save_figure(fig, path)
    return fig


def motion_data(result) -> dict:
    """What :func:`motion_figure` draws of a ``TrackResult``, as plain arrays."""
    return {"frame": np.asarray(result.frame), "angles": np.asarray(result.angles, float),
            "translation": np.asarray(result.translation, float),
            "rms": np.asarray(result.rms, float), "ok": np.asarray(result.ok, bool),
            "reference": int(result.reference), "fixed_camera": bool(result.fixed_camera)}


def motion_figure(frame, angles, translation, rms, ok, *, reference: int,
                  fixed_camera: bool = True, fps: float | None = None,
                  length_unit: str = "m", length_scale: float = 1.0,
                  truth: tuple[np.ndarray, np.ndarray] | None = None,
                  title: str | None = None, dpi: int = 120):
    """The figure of :func:`plot_motion` from plain arrays: ``frame`` (F,), ``angles``
    (F, 3) degrees, ``translation`` (F, 3) model units, ``rms`` (F,) pixels, ``ok`` (F,)
    bool, ``reference`` the frame the motion is relative to. Returns a
    ``matplotlib.figure.Figure`` (not saved)."""
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise InputError(f"plot_motion: fps must be positive, got {fps}")
    from matplotlib.figure import Figure

    frame, rms, ok = np.asarray(frame), np.asarray(rms, float), np.asarray(ok, bool)
    angles, translation = np.asarray(angles, float), np.asarray(translation, float)
    t = frame / fps if fps else frame.astype(float)
    xlabel = "time (s)" if fps else "frame"
    fig = Figure(figsize=(9.0, 7.0), dpi=dpi)
    fig.subplots_adjust(**MARGINS)
    axes = fig.subplots(3, 1, sharex=True, height_ratios=[3, 3, 1.5])
    colors = ("tab:blue", "tab:orange", "tab:green")
    who = "model" if fixed_camera else "camera"
    for k, name in enumerate(("roll", "pitch", "yaw")):
        axes[0].plot(t, angles[:, k], ".-", ms=2, lw=0.8, color=colors[k], label=name)
    for k, name in enumerate(("dx", "dy", "dz")):
        axes[1].plot(t, translation[:, k] * length_scale, ".-", ms=2, lw=0.8,
                     color=colors[k], label=name)
    if truth is not None:
        ta, tt = (np.asarray(a, float) for a in truth)
        if ta.shape != angles.shape or tt.shape != translation.shape:
            raise InputError("plot_motion: truth arrays must have the shape of the result's")
        for k in range(3):  # a wide grey band under the measured (coloured) curves
            axes[0].plot(t, ta[:, k], "-", color="0.55", lw=3.0, alpha=0.5, zorder=1,
                         label="truth" if k == 0 else None)
            axes[1].plot(t, tt[:, k] * length_scale, "-", color="0.55", lw=3.0, alpha=0.5,
                         zorder=1, label="truth" if k == 0 else None)
    axes[2].plot(t, rms, ".", ms=2, color="tab:purple")
    failed = ~ok
    for ax in axes:
        if failed.any():
            ax.plot(t[failed], np.zeros(failed.sum()), "|", color="red", ms=12,
                    transform=ax.get_xaxis_transform(), label="failed")
        ax.grid(True, lw=0.3)
    axes[0].set_ylabel(f"{who} attitude (deg)")
    axes[1].set_ylabel(f"{who} displacement ({length_unit})")
    axes[2].set_ylabel("RMS (px)")
    axes[2].set_xlabel(xlabel)
    for ax in axes[:2]:  # outside the axes, so that they never hide data
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, borderaxespad=0)
    n_ok = int(ok.sum())
    head = title or f"{who} motion relative to frame {reference}"
    fig.suptitle(f"{head}: {n_ok}/{len(ok)} frames solved, median RMS "
                 f"{np.nanmedian(rms) if n_ok else float('nan'):.3f} px", fontsize=10)
    return fig


def save_figure(fig, path: str | os.PathLike) -> None:
    """Write ``fig`` to ``path`` (format from the suffix; a PNG at zlib level
    :data:`PNG_COMPRESS_LEVEL`) through a temporary file renamed into place."""
    from resection.io.outputs import atomic_path, picture_format

    path = os.fspath(path)
    suffix = picture_format(fig, path)
    kw = {"pil_kwargs": {"compress_level": PNG_COMPRESS_LEVEL}} if suffix == "png" else {}
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=suffix, dpi=fig.dpi, **kw)
