"""Linking candidates to markers by hand, once per camera set-up.

:func:`draw_links` draws the image with the numbered candidates and, when an approximate
camera is given, the 3-D markers projected through it with their ids (a PNG for a person
to read). The person writes a linking CSV ``id,candidate`` (marker id, candidate number);
:func:`read_links` reads it and returns the linked markers, throwing away the candidates
left unlinked. :func:`suggest_links` pre-fills such a file with the nearest projected
marker of every candidate, to be checked and edited.

Candidate numbers are the row indices (from 0) of the candidate list, i.e. of the
candidate CSV written by ``resection detect``.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from resection.camera.model import Camera
from resection.errors import InputError
from resection.markers.detect import Candidates

__all__ = ["draw_links", "read_links", "write_links", "suggest_links"]


def _uv_of(candidates) -> np.ndarray:
    uv = candidates.uv if isinstance(candidates, Candidates) else candidates
    uv = np.asarray(uv, dtype=float)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise InputError(f"candidates: expected (N, 2) positions, got shape {uv.shape}")
    return uv


def draw_links(
    path: str | os.PathLike,
    image,
    candidates,
    *,
    camera: Camera | None = None,
    markers=None,
    diameter: float | None = None,
    dpi: int = 100,
) -> None:
    """Write a PNG of the image with numbered candidates and projected markers.

    Parameters
    ----------
    path : path-like
        Output PNG.
    image : (H, W) array
        The image (displayed with a 1-99 percentile stretch).
    candidates : Candidates or (N, 2) array
        Drawn as red circles labelled with their number.
    camera : Camera, optional
        Approximate camera; with ``markers``, each marker is projected and drawn as a
        cyan cross labelled with its id.
    markers : MarkerSet or (ids, xyz), optional
    diameter : float, optional
        Circle diameter, px (default: the candidates' diameters, else 8).
    dpi : int
        The figure is one image pixel per screen pixel at this dpi (larger images are
        drawn at their size, up to 4000 px).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.patheffects as pe
    import matplotlib.pyplot as plt
    from matplotlib.collections import EllipseCollection

    img = np.asarray(image, dtype=float)
    if img.ndim != 2:
        raise InputError(f"image: expected a 2-D array, got shape {img.shape}")
    uv = _uv_of(candidates)
    if camera is not None and img.shape != (camera.height, camera.width):
        raise InputError(f"image: {img.shape[1]}x{img.shape[0]} pixels, but the camera is "
                         f"{camera.width}x{camera.height} (wrong image or camera file?)")
    path = Path(path)
    if not path.parent.exists():
        raise FileNotFoundError(f"{path.parent}: output directory does not exist")
    H, W = img.shape
    # small images are enlarged (to 1600 px) so that the labels, whose size is fixed in
    # points, do not cover each other; large ones are drawn at most 4000 px wide
    scale = min(1.0, 4000.0 / max(H, W)) if max(H, W) > 4000 else max(1.0, 1600.0 / max(H, W))
    fig = plt.figure(figsize=(W * scale / dpi, H * scale / dpi), dpi=dpi)
    ax = fig.add_axes((0, 0, 1, 1))
    fin = img[np.isfinite(img)]
    lo, hi = np.percentile(fin, [1, 99]) if fin.size else (0, 1)
    ax.imshow(img, cmap="gray", vmin=lo, vmax=hi if hi > lo else lo + 1,
              extent=(-0.5, W - 0.5, H - 0.5, -0.5), interpolation="nearest")
    if isinstance(candidates, Candidates) and np.isfinite(candidates.diameter).any():
        dia = np.where(np.isfinite(candidates.diameter), candidates.diameter, 8.0)
    else:
        dia = np.full(len(uv), 8.0)
    if diameter is not None:
        dia = np.full(len(uv), float(diameter))
    fs = 9.0
    outline = [pe.withStroke(linewidth=2.5, foreground="black")]
    ring = 2.0 * (dia / 2 + 2.0)  # circle diameter, image pixels
    ax.add_collection(EllipseCollection(ring, ring, 0.0, units="xy", offsets=uv,
                                        offset_transform=ax.transData, facecolors="none",
                                        edgecolors="orangered", linewidths=1.2))
    for k, ((u, v), d) in enumerate(zip(uv, dia, strict=True)):  # one label per candidate
        ax.text(u + d / 2 + 2, v - d / 2 - 2, str(k), color="orangered", fontsize=fs,
                fontweight="bold", path_effects=outline)
    if camera is not None and markers is not None:
        from resection.markers.match import marker_table

        ids, xyz = marker_table(markers)
        proj = camera.project(xyz)
        ok = np.isfinite(proj).all(axis=1) & camera.in_image(proj)
        ax.plot(proj[ok, 0], proj[ok, 1], "+", color="cyan", ms=10, mew=1.5,
                path_effects=outline)
        for k in np.flatnonzero(ok):
            ax.text(proj[k, 0] - 3, proj[k, 1] + 3, ids[k], color="cyan", fontsize=fs,
                    ha="right", va="top", path_effects=outline)
    key = "orange-red circle + number: candidate"
    if camera is not None and markers is not None:
        key += "     cyan cross + id: marker projected by the approximate camera"
    ax.text(0.01, 0.01, key, transform=ax.transAxes, color="white", fontsize=fs,
            va="bottom", ha="left", path_effects=outline,
            bbox={"facecolor": "black", "alpha": 0.6, "edgecolor": "none"})
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)
    ax.axis("off")
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def read_links(path: str | os.PathLike, candidates, markers=None):
    """Read a linking CSV ``id,candidate``.

    Parameters
    ----------
    path : path-like
        CSV with header ``id,candidate``; ``candidate`` is a candidate number (row index
        from 0). Empty lines and lines starting with ``#`` are skipped.
    candidates : Candidates or (N, 2) array
        The numbered candidates.
    markers : MarkerSet or (ids, xyz), optional
        When given, every linked id must be one of its markers.

    Returns
    -------
    ids : tuple of str
        Linked marker ids, in the file's order.
    uv : (M, 2) array
        Their candidates' positions (unlinked candidates are thrown away).
    index : (M,) int array
        Their candidate numbers.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such linking file")
    uv_all = _uv_of(candidates)
    with open(path, newline="", encoding="utf-8") as fh:
        rows = [(n, r) for n, r in enumerate(csv.reader(fh), start=1)
                if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if not rows:
        raise InputError(f"{path}: empty linking file, expected a header id,candidate")
    header = [h.strip() for h in rows[0][1]]
    if sorted(header) != ["candidate", "id"]:
        raise InputError(f"{path}: expected the columns id,candidate, got {','.join(header)}")
    ci, ii = header.index("candidate"), header.index("id")
    ids, index = [], []
    for n, r in rows[1:]:
        if len(r) != 2:
            raise InputError(f"{path}:{n}: expected 2 fields, got {len(r)}")
        k = r[ii].strip()
        if not k:
            raise InputError(f"{path}:{n}: empty marker id")
        try:
            c = int(r[ci])
        except ValueError:
            raise InputError(f"{path}:{n}: candidate {r[ci]!r} is not an integer") from None
        if not 0 <= c < len(uv_all):
            raise InputError(f"{path}:{n}: candidate {c} does not exist "
                             f"({len(uv_all)} candidates, numbered from 0)")
        ids.append(k)
        index.append(c)
    if len(set(ids)) != len(ids):
        dup = sorted({k for k in ids if ids.count(k) > 1})
        raise InputError(f"{path}: marker id(s) linked twice: {', '.join(dup[:10])}")
    if len(set(index)) != len(index):
        dup = sorted({c for c in index if index.count(c) > 1})
        raise InputError(f"{path}: candidate(s) linked twice: {dup[:10]}")
    if markers is not None:
        from resection.markers.match import marker_table

        known = set(marker_table(markers)[0])
        unknown = [k for k in ids if k not in known]
        if unknown:
            raise InputError(f"{path}: id(s) not in the marker file: {', '.join(unknown[:10])}")
    index = np.asarray(index, dtype=int)
    return tuple(ids), uv_all[index], index


def write_links(path: str | os.PathLike, ids, index) -> None:
    """Write a linking CSV ``id,candidate``."""
    ids = [str(k) for k in ids]
    index = [int(i) for i in index]
    if len(ids) != len(index):
        raise InputError(f"write_links: {len(ids)} ids for {len(index)} candidates")
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["id", "candidate"])
        w.writerows(zip(ids, index, strict=True))


def suggest_links(candidates, camera: Camera, markers, *, max_distance: float = 20.0):
    """Nearest projected marker of each candidate within ``max_distance`` px, one-to-one
    (a starting point for the person, who checks it on the :func:`draw_links` PNG).

    Returns ``(ids, index)`` as :func:`write_links` takes them.
    """
    from resection.markers.match import assign_nearest, marker_table

    uv = _uv_of(candidates)
    ids, xyz = marker_table(markers)
    proj = camera.project(xyz)
    ok = np.isfinite(proj).all(axis=1)
    if len(uv) == 0 or not ok.any():
        return (), np.zeros(0, int)
    j = np.full(len(ids), -1)
    j[ok], _ = assign_nearest(proj[ok], cKDTree(uv), max_distance)
    sel = np.flatnonzero(j >= 0)
    return tuple(ids[i] for i in sel), j[sel]
