"""Several cameras: merge what each sees of the surface before the self-illumination inverse.

Each camera maps its image onto the faces it sees (:class:`~resection.surface.SurfaceMap`);
faces hidden from one camera are often seen by another. The merge is
:func:`resection.surface.merge.merge_views` (the one ``resection map`` uses: pixels feathered by
their distance to the image edges and to occlusion boundaries, faces by their view angle up
to the obliqueness cut-off, a gain per camera matched on the overlaps), so that
:func:`selfillum.solve.radiosity.correct` has to guess (by smooth continuation) only the faces no
camera sees. This module keeps the name ``silhouette_margin`` for its ``edge_margin``.
"""

from __future__ import annotations

from collections.abc import Sequence

from resection.errors import InputError
from resection.surface.merge import MergedViews, Overlap
from resection.surface.merge import merge_views as _merge_views

__all__ = ["MergedViews", "Overlap", "merge_views"]


def merge_views(maps: Sequence, images: Sequence, *, method: str = "weighted",
                min_pixels: int = 1, silhouette_margin: int = 1, **options) -> MergedViews:
    """Merge the per-face values that several cameras see of the same surface.

    :func:`resection.surface.merge.merge_views` with ``edge_margin = silhouette_margin`` (pixels
    within this many pixels of the model's outline or of an occlusion boundary are dropped;
    0 keeps them); ``options`` go to it unchanged (``feather_px``,
    ``max_obliqueness``, ``match_gain``, ``gains``, ...).
    """
    try:
        margin = int(silhouette_margin)
    except (TypeError, ValueError):
        margin = -1
    if margin < 0:
        raise InputError(f"merge_views: silhouette_margin must be an integer >= 0, got "
                         f"{silhouette_margin!r}")
    return _merge_views(maps, images, method=method, min_pixels=min_pixels,
                        edge_margin=margin, **options)
