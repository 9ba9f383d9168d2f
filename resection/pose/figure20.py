"""The picture of a solved pose (the paper's Figure 20), as ``resection pose --plot`` draws it.

:func:`plot_pose` draws, over the camera image (or a blank frame of its size): the model
outline (silhouettes and creases, :mod:`resection.surface.outline`), the detected and the
reprojected markers with their ids, the residual vectors magnified with their scale written
on the picture, the markers dropped as gross outliers, and the RMS residual with the
acceptance rule's verdict in the title. The drawing itself is
:func:`resection.surface.plots.plot_resection`.
"""

from __future__ import annotations

import os

import numpy as np
import trimesh
from matplotlib.figure import Figure

from resection._checks import as_points
from resection.errors import InputError
from resection.pose.solve import PoseResult
from resection.surface.plots import finish_figure, plot_resection

__all__ = ["plot_pose", "write_pose_plot"]


def plot_pose(
    result: PoseResult,
    points3d,
    points2d,
    *,
    image=None,
    mesh: trimesh.Trimesh | None = None,
    ids=None,
    crease_deg: float = 30.0,
    title: str = "pose",
    path: str | os.PathLike | None = None,
) -> Figure:
    """The resection check picture of a :func:`~resection.pose.solve.solve_pose` result.

    Parameters
    ----------
    result : PoseResult
        The solved pose (its ``used`` markers are drawn with residual vectors; those dropped
        as gross outliers are marked apart and left out of the vector scale).
    points3d : (N, 3) array_like
        Model coordinates of the markers given to the solve, model units.
    points2d : (N, 2) array_like
        Their measured pixel positions (u right, v down, top-left pixel centre at 0, 0).
    image : (H, W) array_like, optional
        The camera image; default a blank frame of the camera's size.
    mesh : trimesh.Trimesh, optional
        Model surface whose outline is drawn.
    ids : sequence of str, optional
        Marker labels.
    crease_deg : float
        Dihedral angle (degrees) above which an edge of ``mesh`` is drawn as a crease.
    title : str
        Title prefix; the RMS residual, marker count and the acceptance verdict follow.
    path : path-like, optional
        Write the picture there (format from the suffix).
    """
    cam = result.camera
    X = as_points(points3d, 3, "points3d")
    uv = as_points(points2d, 2, "points2d")
    if len(X) != len(uv) or len(X) != len(result.errors):
        raise InputError(f"plot_pose: {len(X)} markers, {len(uv)} image points, but the pose "
                         f"was solved from {len(result.errors)}")
    names = [str(k) for k in ids] if ids is not None else [str(i) for i in range(len(X))]
    if len(names) != len(X):
        raise InputError(f"plot_pose: {len(names)} ids for {len(X)} markers")
    used = np.ones(len(X), bool) if result.used is None else np.asarray(result.used, bool)
    img = np.zeros((cam.height, cam.width)) if image is None else np.asarray(image, float)
    acc = result.acceptance
    head = title
    if acc is not None:
        head = f"{title} ({acc.grade}; threshold {acc.threshold:.3g} px)"
    fig = plot_resection(img, cam, X[used], uv[used], mesh=mesh, crease_deg=crease_deg,
                         ids=[k for k, u in zip(names, used, strict=True) if u], title=head)
    if not used.all():
        ax = fig.axes[0]
        out = uv[~used]
        ax.plot(out[:, 0], out[:, 1], "x", color="orange", ms=10, mew=2,
                label="outlier, dropped")
        for k, p in zip(np.array(names)[~used], out, strict=True):  # the few outliers
            ax.annotate(f"{k} (dropped)", p, xytext=(6, -10), textcoords="offset points",
                        color="orange", fontsize=8)
        ax.legend(loc="upper right", fontsize=8, framealpha=0.6)
    return finish_figure(fig, path)


def write_pose_plot(path: str | os.PathLike, result: PoseResult, points3d, points2d,
                    **kwargs) -> None:
    """:func:`plot_pose` written to ``path`` (the writer form for atomic writes)."""
    plot_pose(result, points3d, points2d, path=path, **kwargs)
