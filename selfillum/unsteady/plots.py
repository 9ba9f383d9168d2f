"""Pictures of an unsteady run that a user opens without code (PNG).

* :func:`plot_rms`: the RMS of dCp over time on the model, through the project's
  :func:`resection.surface.plots.plot_surface` (a face's value: the mean of its three
  nodes; the model seen from :func:`resection.surface.plots.virtual_camera`, or a camera);
* :func:`plot_psd`: the Welch PSD at the probe nodes (log-log), with the mean over all
  the nodes seen.
"""

from __future__ import annotations

import numpy as np

__all__ = ["node_to_faces", "plot_rms", "plot_psd", "write_pictures", "prepare_rms_view"]


def node_to_faces(triangles, node_values) -> np.ndarray:
    """Per-face mean of its three nodes' values, (F,) (NaN if any is NaN)."""
    v = np.asarray(node_values, dtype=np.float64)
    return v[np.asarray(triangles, dtype=np.int64)].mean(axis=1)


def prepare_rms_view(grid):
    """The RMS picture's view of the model (:func:`resection.surface.plots.prepare_view`
    from the default virtual camera, with the outline): what :func:`plot_rms` draws the
    values into, made apart from them (a run makes it in another thread while it maps
    the frames)."""
    from resection.surface.plots import prepare_view

    return prepare_view(grid.mesh, outline=True)


def plot_rms(grid, rms, path, camera=None, *, title: str | None = None, view=None):
    """dCp RMS (per node, ``(N,)``) on the model of ``grid`` (a
    :class:`~selfillum.unsteady.grid.RunGrid`), saved as a picture at ``path``; ``view``
    from :func:`prepare_rms_view` when made already (then ``camera`` is its own)."""
    from resection.surface.plots import plot_surface, virtual_camera

    # grid.triangles are the mesh's faces written in node numbers: face k of the mesh
    fv = node_to_faces(grid.triangles, rms)
    cam = view.camera if view is not None else (
        camera if camera is not None else virtual_camera(grid.mesh))
    fin = fv[np.isfinite(fv)]
    vmax = float(np.percentile(fin, 99)) if fin.size else None
    return plot_surface(grid.mesh, fv, cam, cmap="viridis", vmin=0.0,
                        vmax=vmax if vmax and vmax > 0 else None, label="dCp RMS",
                        title=title or "dCp RMS over the run", outline=True, path=path,
                        view=view)


def plot_psd(freq, probe_psd, probe_nodes, path, *, mean_psd=None, points=None):
    """Welch PSD (``dCp^2/Hz``) at each probe node against frequency (Hz), log-log, with
    the mean over the nodes (``mean_psd``) dashed; ``points`` (N, 3) label the probes
    with their coordinates. Saved at ``path``."""
    from matplotlib.figure import Figure

    from resection.surface.plots import finish_figure

    f = np.asarray(freq, dtype=np.float64)
    fig = Figure(figsize=(7.5, 4.8), dpi=100, layout="constrained")
    ax = fig.add_subplot()
    sel = f > 0
    for row, n in zip(np.atleast_2d(probe_psd), probe_nodes, strict=True):
        lab = f"node {int(n)}"
        if points is not None:
            x, y, z = points[int(n)]
            lab += f" ({x:.3g}, {y:.3g}, {z:.3g})"
        if np.isfinite(row[sel]).any():
            ax.loglog(f[sel], row[sel], lw=1.0, label=lab)
        else:
            ax.plot([], [], label=lab + ": unseen")
    if mean_psd is not None and np.isfinite(mean_psd[sel]).any():
        ax.loglog(f[sel], np.asarray(mean_psd)[sel], "k--", lw=1.0, label="mean of the nodes")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("PSD of dCp (1/Hz)")
    ax.set_title("Welch power spectral density of dCp")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return finish_figure(fig, path)


def write_pictures(grid, rms, spectra, paths, view=None) -> None:
    """The dCp RMS on the model and, with probes, their PSD (PNG); ``view``: the RMS
    picture's, made already (:func:`prepare_rms_view`)."""
    plot_rms(grid, rms, paths[0], view=view)
    if len(paths) > 1:
        plot_psd(spectra.freq, spectra.probe_psd, spectra.probes, paths[1],
                 mean_psd=spectra.mean_psd, points=grid.points)
