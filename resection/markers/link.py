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

__all__ = ["draw_links", "read_links", "write_links", "suggest_links", "numbered",
           "LIKELY_SNR", "MAX_LABELS"]

#: Below this contrast-to-noise ratio the detector's own fit ranks a candidate unlikely (the
#: detector keeps down to ``min_snr = 3``); such candidates get no number without a camera.
LIKELY_SNR = 5.0
#: Most numbers drawn without a camera (the strongest candidates by merit).
MAX_LABELS = 150


def _uv_of(candidates) -> np.ndarray:
    uv = candidates.uv if isinstance(candidates, Candidates) else candidates
    uv = np.asarray(uv, dtype=float)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise InputError(f"candidates: expected (N, 2) positions, got shape {uv.shape}")
    return uv


def numbered(candidates, *, camera: Camera | None = None, markers=None,
             near: float | None = None, max_labels: int = MAX_LABELS) -> np.ndarray:
    """The candidates :func:`draw_links` numbers (sorted indices), so that the numbers
    stay legible.

    With ``camera`` and ``markers``: only those within ``near`` px (default ``max(3 d,
    10)``, ``d`` the median candidate diameter) of a marker projected into the image. Without:
    those the detector ranks as likely (``snr >= LIKELY_SNR`` when the candidates carry
    their SNR), at most ``max_labels`` of them, the strongest by merit.
    """
    uv = _uv_of(candidates)
    n = len(uv)
    if n == 0:
        return np.zeros(0, int)
    is_cand = isinstance(candidates, Candidates)
    if camera is not None and markers is not None:
        from resection.markers.match import marker_table

        _, xyz = marker_table(markers)
        proj, valid = camera.project(xyz, return_valid=True)
        proj = proj[valid & camera.in_image(np.where(valid[:, None], proj, 0.0))]
        if near is None:
            dia = candidates.diameter if is_cand else np.full(n, np.nan)
            dm = float(np.nanmedian(dia)) if np.isfinite(dia).any() else 8.0
            near = max(3.0 * dm, 10.0)
        if not len(proj):
            return np.zeros(0, int)
        d, _ = cKDTree(proj).query(uv)
        return np.flatnonzero(d <= near)
    keep = np.ones(n, bool)
    if is_cand and np.isfinite(candidates.snr).any():
        keep &= ~(candidates.snr < LIKELY_SNR)
    idx = np.flatnonzero(keep)
    if is_cand and len(idx) > max_labels:
        merit = np.nan_to_num(candidates.merit[idx], nan=-np.inf)
        idx = np.sort(idx[np.argsort(-merit, kind="stable")[:max_labels]])
    return idx[:max_labels]


def draw_links(
    path: str | os.PathLike,
    image,
    candidates,
    *,
    camera: Camera | None = None,
    markers=None,
    diameter: float | None = None,
    dpi: int = 100,
) -> np.ndarray:
    """Write a PNG of the image with numbered candidates and projected markers.

    Only some candidates are numbered, so that the numbers can be read (:func:`numbered`):
    with a camera, those near a projected marker (every candidate keeps its ring); without,
    those the detector ranks as likely, the strongest first (the others are left out). The
    numbers stay the candidates' row numbers. The image is enlarged until the drawn
    candidates lie about two labels apart.

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

    Returns
    -------
    (K,) int array
        The candidate numbers drawn (numbered).
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
    show = numbered(candidates, camera=camera, markers=markers)
    fs = 11.0
    # enlarged (to 1600 px at least) until the drawn candidates lie two labels apart (a
    # label is about 2.2 fs px wide at 100 dpi), at most 4000 px
    gap = 2.0 * 2.2 * fs * dpi / 72.0
    if len(show) > 1:
        nn = cKDTree(uv[show]).query(uv[show], k=2)[0][:, 1]
        want = gap / max(float(np.median(nn)), 1e-6)
    else:
        want = 1.0
    scale = min(max(1.0, 1600.0 / max(H, W), want), 4000.0 / max(H, W))
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
    outline = [pe.withStroke(linewidth=2.5, foreground="black")]
    # with a camera every candidate keeps its ring (only the numbers are thinned out)
    ringed = np.arange(len(uv)) if camera is not None and markers is not None else show
    ring = 2.0 * (dia[ringed] / 2 + 2.0)  # circle diameter, image pixels
    ax.add_collection(EllipseCollection(ring, ring, 0.0, units="xy", offsets=uv[ringed],
                                        offset_transform=ax.transData, facecolors="none",
                                        edgecolors="orangered", linewidths=1.2))
    for k in show.tolist():  # one label per drawn candidate
        u, v, d = uv[k, 0], uv[k, 1], dia[k]
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
    key = f"orange-red circle + number: candidate ({len(show)} of {len(uv)} numbered: "
    if camera is not None and markers is not None:
        key += "those near a projected marker)     cyan cross + id: marker projected by " \
            "the approximate camera"
    else:
        key += f"SNR >= {LIKELY_SNR:g}, the strongest)     or link by clicking: " \
            "resection link --serve"
    ax.text(0.01, 0.01, key, transform=ax.transAxes, color="white", fontsize=fs,
            va="bottom", ha="left", path_effects=outline,
            bbox={"facecolor": "black", "alpha": 0.6, "edgecolor": "none"})
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)
    ax.axis("off")
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return show


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
