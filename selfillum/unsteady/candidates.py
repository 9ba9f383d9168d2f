"""The faces a run's cameras may see: the rows of the view factors a run needs.

The self-illumination of the run corrects the faces seen in some frame, and needs the
radiosity of every face they see (:func:`selfillum.transport.coupling.
coupled_view_factors` casts rays from those only, round by round, and the rows it leaves
empty are exactly those no seen face depends on). The faces seen are known only once the
frames are mapped, so the rows are cast from a superset known before: the faces that
**face a camera** of frame 0 (within ``cos_min`` of grazing, for a vibrating model) and
**project into its image** (within ``margin`` of the image's size around it). Faces that
face away from every camera (the underside of a plate, the inside of a body) and are not
lit by a candidate get no row: on a plate-and-block model, about half the faces.
"""

from __future__ import annotations

import numpy as np

__all__ = ["faces_in_view"]


def faces_in_view(mesh, cameras, *, margin: float = 0.1, cos_min: float = -0.1) -> np.ndarray:
    """(F,) bool: faces facing one of ``cameras`` and projecting into its image.

    Parameters
    ----------
    mesh : trimesh.Trimesh
    cameras : sequence of resection.Camera
        Frame 0's cameras.
    margin : float
        Share of the image's width and height added on every side.
    cos_min : float
        Cosine between a face's normal and the direction to the camera above which the
        face counts as facing it (slightly negative: grazing faces that a vibration may
        turn towards the camera).
    """
    c = np.asarray(mesh.triangles_center, dtype=np.float64)
    nrm = np.asarray(mesh.face_normals, dtype=np.float64)
    out = np.zeros(len(c), bool)
    for cam in cameras:  # a few cameras
        d = np.asarray(cam.center, dtype=np.float64)[None, :] - c
        d /= np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None]
        facing = np.einsum("ij,ij->i", nrm, d) > cos_min
        Xc = cam.to_camera_frame(c[facing])
        front = Xc[:, 2] > 0
        idx = np.flatnonzero(facing)[front]
        uv = cam.project(c[idx])
        mu, mv = margin * cam.width, margin * cam.height
        ok = np.isfinite(uv).all(axis=1) & (uv[:, 0] >= -mu) & (uv[:, 0] <= cam.width + mu) \
            & (uv[:, 1] >= -mv) & (uv[:, 1] <= cam.height + mv)
        out[idx[ok]] = True
    return out
