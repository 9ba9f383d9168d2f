"""The moving model of :mod:`scenes.moving_model` as a painted surface: a wing slab and a
fuselage box, a known paint field, and frames rendered by closed-form ray casting.

Used to check per-frame mapping of a moving model (:mod:`resection.sequence.mapping`)
against the truth: every pixel of frame ``k`` takes the paint field at the point of the
model its line of sight hits first (ray/box intersection in closed form, the slab method:
no Embree, no :class:`resection.SurfaceMap`), or the background where it misses. The field
is attached to the model (model coordinates), so a mapping that puts a pixel on the wrong
point of the model, or keeps a background pixel, shows as an error against
:func:`paint_field` at the grid's nodes.

Pixels are point samples at their centres (no integration over the pixel area).
"""

from __future__ import annotations

import numpy as np
import trimesh

from scenes.moving_model import MovingModel

__all__ = ["BOXES", "model_surface", "paint_field", "render_surface", "edge_nodes"]

#: The model's parts as axis-aligned boxes in model coordinates (metres): (low, high).
BOXES = (
    (np.array([-0.12, -0.20, -0.012]), np.array([0.12, 0.20, 0.0])),     # wing slab
    (np.array([-0.22, -0.025, 0.0]), np.array([0.24, 0.025, 0.035])),    # fuselage
)


def model_surface(face_size: float = 0.01) -> trimesh.Trimesh:
    """Triangle grid of the two boxes (faces about ``face_size`` metres, normals out).

    The boxes' surfaces are kept as two closed shells (the fuselage's bottom lies on the
    wing's top: those faces are hidden from the camera, as in a real grid's junction).
    """
    parts = []
    for lo, hi in BOXES:
        box = trimesh.creation.box(bounds=np.stack([lo, hi]))
        v, f = box.vertices, box.faces
        while True:
            edges = np.linalg.norm(v[f[:, 1]] - v[f[:, 0]], axis=1)
            if edges.max() <= face_size * 1.5:
                break
            v, f = trimesh.remesh.subdivide(v, f)
        parts.append(trimesh.Trimesh(v, f, process=False))
    mesh = trimesh.util.concatenate(parts)
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)


def paint_field(points) -> np.ndarray:
    """The paint's brightness at model points ``(N, 3)`` (metres): smooth, between about
    600 and 1400 counts, varying on the scale of a few faces."""
    X = np.asarray(points, dtype=np.float64)
    return (1000.0 + 250.0 * np.sin(12.0 * X[:, 0] + 1.0) * np.cos(9.0 * X[:, 1])
            + 3000.0 * X[:, 2] + 400.0 * X[:, 0])


def render_surface(model: MovingModel, k: int, *, background: float = 50.0) -> np.ndarray:
    """Frame ``k``: the paint field seen through ``model.camera_at(k)``, float32 ``(H, W)``.

    Rays through every pixel centre (lens distortion included) are intersected with each
    box in closed form (slab method); the nearest hit gives the pixel its field value.
    """
    cam = model.camera_at(k)  # shares the fixed camera's undistortion map
    H, W = cam.height, cam.width
    _, d = cam.rays()  # every pixel centre, lens distortion included
    o = cam.center
    best = np.full(len(d), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        for lo, hi in BOXES:  # two boxes: a loop over parts, the rays are batched
            t1, t2 = (lo - o) * inv, (hi - o) * inv
            tn = np.nanmax(np.minimum(t1, t2), axis=1)
            tf = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (tn <= tf + 1e-7) & (tf > 0) & (tn > 0)  # grazing within 0.1 um: a hit
            best = np.where(hit & (tn < best), tn, best)
    img = np.full(len(d), background)
    on = np.isfinite(best)
    img[on] = paint_field(o + best[on, None] * d[on])
    return img.reshape(H, W).astype(np.float32)


def edge_nodes(mesh: trimesh.Trimesh, width: float = 0.012) -> np.ndarray:
    """(V,) bool: nodes within ``width`` metres of an edge of either box (the model's
    outline and the fuselage-wing junction, where a map of another frame goes wrong)."""
    V = np.asarray(mesh.vertices, dtype=np.float64)
    near = np.zeros(len(V), dtype=bool)
    for lo, hi in BOXES:
        inside = np.all((V >= lo - 1e-9) & (V <= hi + 1e-9), axis=1)
        dist = np.minimum(np.abs(V - lo), np.abs(V - hi))  # to each face plane pair
        # a box edge is where two of the three coordinates sit on planes
        close = np.sort(dist, axis=1)[:, 1] <= width
        near |= inside & close
    return near
