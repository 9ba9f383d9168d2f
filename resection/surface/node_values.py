"""Node values: the one definition of an image's value at a grid node.

A node's value is :meth:`resection.surface.surface_map.SurfaceMap.to_nodes` of the image:
the mean of the finite pixels that see a face around the node, each weighted by the barycentric
coordinate of its hit point on that node. ``map`` writes it to a Plot3D function file
(``.f``) and to a time history (``.h5``, ``--per node``) alike, so that the two files agree
for the same frame.

Merged over cameras (``map`` with several ``--camera``), a node's value is the weighted mean
of the cameras' node values, each divided by its camera's gain (the gains of
:func:`resection.surface.merge.merge_views`, reference camera's units), with the camera's weight at
the node the mean of its face weights around the node (the feathered weights of the merge).
With one camera this is that camera's node value.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["image_node_fields", "merged_node_fields"]


def image_node_fields(smap, image, name: str) -> dict[str, np.ndarray]:
    """``{name, name_count, name_seen}`` per node of one image (``SurfaceMap.to_nodes``)."""
    res = smap.to_nodes(image)
    return {name: res.values, f"{name}_count": res.counts, f"{name}_seen": ~res.unseen}


def merged_node_fields(maps, images, merged, names) -> dict[str, np.ndarray]:
    """Per-node fields of a merge: ``merged``, ``merged_weight``, ``merged_cameras`` and, per
    camera, ``NAME`` (its node value before gain matching) and ``NAME_weight``.

    Parameters
    ----------
    maps : sequence of SurfaceMap
        One per camera, of the same mesh.
    images : sequence of (H, W) arrays
    merged : resection.surface.merge.MergedViews
        The face merge of the same maps and images (its gains and face weights).
    names : sequence of str
        Field name of each camera's image.
    """
    mesh = maps[0].mesh
    nv, nf = len(mesh.vertices), len(mesh.faces)
    faces = np.asarray(mesh.faces)
    inc = sp.csr_matrix((np.ones(faces.size), (faces.ravel(), np.repeat(np.arange(nf), 3))),
                        shape=(nv, nf))
    deg = np.asarray(inc.sum(axis=1)).ravel()
    fields: dict[str, np.ndarray] = {}
    num, den = np.zeros(nv), np.zeros(nv)
    ncam = np.zeros(nv, np.int64)
    for c, (smap, img, name) in enumerate(zip(maps, images, names, strict=True)):
        v = smap.to_nodes(img).values
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where(deg > 0, inc @ merged.camera_weights[c] / deg, 0.0)
        w = np.where(np.isfinite(v), w, 0.0)
        fields[name] = v
        fields[f"{name}_weight"] = w
        num += w * np.where(w > 0, v, 0.0) / merged.gains[c]
        den += w
        ncam += w > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        value = np.where(den > 0, num / den, np.nan)
    return {"merged": value, "merged_weight": den, "merged_cameras": ncam,
            "merged_seen": den > 0, **fields}
