"""What a self-illumination correction did, in numbers a user can trust.

The headline is the self-illumination share of the signal, ``(B - E) / B``, over the
*well-seen* faces: painted faces with pixels, seen within the obliqueness cut-off (faces
seen edge-on are unseen, :func:`selfillum.images.image_correction.correct_image`). It is given as
percentiles (median, 95th, 99th), not as a maximum: a maximum is set by the one worst
face, usually one at the edge of the view. The summary also states what unseen and
unpainted faces were taken to emit and how much of the correction rests on that.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["CorrectionSummary", "summarize", "write_summary"]

PERCENTILES = (50.0, 95.0, 99.0)


@dataclass(frozen=True)
class CorrectionSummary:
    """Numbers of a correction (all frames of a stack pooled).

    Attributes
    ----------
    faces : int
        Faces of the mesh.
    seen_min, seen_max : int
        Well-seen (painted, seen) faces per frame (least and most).
    grazing : int
        Faces seen beyond the obliqueness cut-off (counted as unseen).
    coupled : int
        Unseen faces coupled to the seen ones through ``F`` (most over frames): the
        unknowns of the unseen-face solve.
    si_percentiles : dict
        ``{"50": .., "95": .., "99": ..}``: self-illumination share ``(B - E) / B`` of the
        signal over the well-seen faces (fractions, not percent).
    si_mean : float
        Its mean.
    unseen_part_percentiles : dict
        Same percentiles of the part of the signal attributed to unseen faces
        (``unseen_share * si``).
    assumption : str
        What unseen and unpainted faces emit, in words.
    warnings : list of str
        Warnings on the result.
    method : str
        Solver(s) of the inverse.
    iterations : int
        Most iterations over frames.
    """

    faces: int
    seen_min: int
    seen_max: int
    grazing: int
    coupled: int
    si_percentiles: dict
    si_mean: float
    unseen_part_percentiles: dict
    assumption: str
    warnings: list
    method: str
    iterations: int


def summarize(result) -> CorrectionSummary:
    """Summary of an :class:`selfillum.images.image_correction.ImageCorrection`."""
    seen = np.atleast_2d(result.seen)
    if result.unpainted is not None:  # no emission to recover on unpainted faces
        seen = seen & ~np.asarray(result.unpainted, bool)[None]
    B, E = np.atleast_2d(result.radiosity), np.atleast_2d(result.emission)
    share = np.atleast_2d(result.unseen_share) if result.unseen_share is not None \
        else np.where(seen, 0.0, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        si = np.where(seen & (B != 0), (B - E) / B, np.nan)[seen]
        part = (share * np.where(seen & (B != 0), (B - E) / B, np.nan))[seen]
    si, part = si[np.isfinite(si)], part[np.isfinite(part)]

    def pct(v):
        if v.size == 0:
            return {f"{p:g}": float("nan") for p in PERCENTILES}
        return {f"{p:g}": float(q) for p, q in zip(PERCENTILES, np.percentile(v, PERCENTILES),
                                                  strict=True)}

    infos = result.info if isinstance(result.info, tuple) else (result.info,)
    per_frame = seen.sum(axis=1)
    grazing = int(np.sum(result.grazing)) if result.grazing is not None else 0
    return CorrectionSummary(
        faces=int(seen.shape[1]),
        seen_min=int(per_frame.min()),
        seen_max=int(per_frame.max()),
        grazing=grazing,
        coupled=int(max(i.n_coupled for i in infos)),
        si_percentiles=pct(si),
        si_mean=float(np.mean(si)) if si.size else float("nan"),
        unseen_part_percentiles=pct(part),
        assumption=result.assumption,
        warnings=list(result.warnings),
        method=", ".join(sorted({i.method for i in infos})),
        iterations=int(max(i.iterations for i in infos)),
    )


def write_summary(path: str | os.PathLike, summary: CorrectionSummary, **extra) -> None:
    """Write the summary (and ``extra`` entries) as JSON, through a temporary file in the
    same folder renamed into place. The side-file mark (``written_by``, ``side_file_of``,
    :mod:`resection.io.marks`), when among ``extra``, comes first."""
    from resection.io._write import atomic_text
    from resection.io.marks import MARK_KEY, PRODUCER_KEY

    first = {k: extra.pop(k) for k in (PRODUCER_KEY, MARK_KEY) if k in extra}
    data = {**first, **asdict(summary), **extra}
    atomic_text(path, json.dumps(data, indent=2, allow_nan=True) + "\n")
