"""A wing-body junction with markers: a closer-to-real self-illumination case.

Geometry (model units, metres by default; x downstream, y spanwise to starboard, z up):

* the *fuselage*: a cylinder of radius ``radius`` about the x axis, ``0 <= x <= length``,
  normals pointing outwards (open tube: the inside is never lit nor seen);
* the *wing*: a thin rectangular-planform wing of chord ``chord`` starting at
  ``x = wing_x``, span ``span`` from the fuselage side, thickness ``thickness``: an upper
  surface (normal +z) at ``z = +thickness/2``, a lower surface (normal -z) at
  ``z = -thickness/2``, and the tip, leading and trailing edges closing it. The root of
  each surface lies on the cylinder, so that wing and fuselage meet at a concave, nearly
  90-degree junction, where each sees the other over a large solid angle (strong
  self-illumination).

Per-face fields: ``emission`` is a pressure-like luminescence (a suction peak behind the
leading edge of the upper surface, decaying downstream; uniform fuselage), ``part`` says
which surface a face belongs to (0 fuselage, 1 wing upper, 2 wing lower, 3 wing edges).
``markers`` are small painted dots at known positions on the upper wing and the fuselage
(ids ``W..`` and ``F..``), written by :func:`write_markers` in the DESIGN marker format.
:func:`default_camera` looks at the junction from above and ahead, as a PSP camera in a
tunnel's top window would.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import trimesh

from resection.camera.model import Camera
from resection.errors import InputError

__all__ = ["WingBody", "wing_body", "default_camera", "write_markers", "PART_NAMES"]

PART_NAMES = ("fuselage", "wing upper", "wing lower", "wing edges")


@dataclass(frozen=True)
class WingBody:
    """The wing-body scene.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        All surfaces, faces in the order fuselage, wing upper, wing lower, wing edges.
    emission : (N,) ndarray
        True emitted exitance per face (arbitrary units).
    reflectance : float
        Diffuse reflectance of the paint.
    part : (N,) ndarray of int
        0 fuselage, 1 wing upper, 2 wing lower, 3 wing edges (see ``PART_NAMES``).
    marker_ids : tuple of str
        Marker ids.
    markers : (M, 3) ndarray
        Marker centres on the surface.
    marker_diameter : float
        Diameter of the painted dots (model units).
    radius, length, wing_x, chord, span, thickness : float
        The geometry parameters.
    """

    mesh: trimesh.Trimesh
    emission: np.ndarray
    reflectance: float
    part: np.ndarray
    marker_ids: tuple
    markers: np.ndarray
    marker_diameter: float
    radius: float
    length: float
    wing_x: float
    chord: float
    span: float
    thickness: float


def _grid_faces(nu: int, nv: int, offset: int, flip: bool) -> np.ndarray:
    """Two triangles per cell of a ``(nu+1) x (nv+1)`` vertex grid (row-major in u)."""
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1) + offset
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return f[:, ::-1] if flip else f


def _orient(vertices, faces, outward) -> np.ndarray:
    """Flip the faces whose normal points against ``outward`` (one vector per face)."""
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    bad = np.einsum("ij,ij->i", n, outward) < 0
    faces = faces.copy()
    faces[bad] = faces[bad][:, ::-1]
    return faces


def wing_body(
    *,
    radius: float = 0.1,
    length: float = 1.0,
    wing_x: float = 0.3,
    chord: float = 0.4,
    span: float = 0.5,
    thickness: float = 0.02,
    resolution: int = 4,
    reflectance: float = 0.6,
    n_markers: int = 16,
    seed: int = 0,
) -> WingBody:
    """Build the wing-body junction.

    Parameters
    ----------
    radius, length : float
        Fuselage cylinder (model units).
    wing_x, chord, span, thickness : float
        Wing leading-edge station, chord, span from the fuselage side, thickness.
    resolution : int
        Faces per 0.1 model units along the surfaces, about (>= 2).
    reflectance : float
        Paint reflectance in ``[0, 1)``.
    n_markers : int
        Markers, half on the upper wing, half on the upper fuselage.
    seed : int
        Seed of the marker positions.
    """
    vals = dict(radius=radius, length=length, chord=chord, span=span, thickness=thickness)
    for k, v in vals.items():
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"wing_body: {k} must be a positive number, got {v}")
    if not (0 <= wing_x and wing_x + chord <= length):
        raise InputError("wing_body: the wing (wing_x .. wing_x + chord) must lie on the "
                         "fuselage (0 .. length)")
    if thickness >= radius:
        raise InputError("wing_body: thickness must be smaller than the fuselage radius")
    if int(resolution) != resolution or resolution < 2:
        raise InputError(f"wing_body: resolution must be an integer >= 2, got {resolution!r}")
    if not (0.0 <= reflectance < 1.0):
        raise InputError(f"wing_body: reflectance must be in [0, 1), got {reflectance}")
    res = int(resolution) / 0.1  # faces per model unit

    def n_of(extent):
        return max(2, int(round(extent * res)))

    verts, faces, parts = [], [], []
    # fuselage: the cylinder, x along the axis, theta around it
    nx, nt = n_of(length), max(16, n_of(2 * np.pi * radius))
    x = np.linspace(0.0, length, nx + 1)
    t = np.linspace(0.0, 2 * np.pi, nt + 1)
    X, Tt = np.meshgrid(x, t, indexing="ij")
    fv = np.column_stack([X.ravel(), radius * np.cos(Tt).ravel(), radius * np.sin(Tt).ravel()])
    ff = _grid_faces(nx, nt, 0, False)
    c = fv[ff].mean(axis=1)
    ff = _orient(fv, ff, np.column_stack([np.zeros(len(c)), c[:, 1], c[:, 2]]))
    verts.append(fv)
    faces.append(ff)
    parts.append(np.zeros(len(ff), int))
    off = len(fv)
    # wing upper / lower surfaces: root on the cylinder at z = +-thickness/2
    h = thickness / 2.0
    y_root = np.sqrt(radius**2 - h**2)
    nc, ns = n_of(chord), n_of(span)
    xs = np.linspace(wing_x, wing_x + chord, nc + 1)
    ys = np.linspace(y_root, radius + span, ns + 1)
    XW, YW = np.meshgrid(xs, ys, indexing="ij")
    for z, part in ((h, 1), (-h, 2)):
        wv = np.column_stack([XW.ravel(), YW.ravel(), np.full(XW.size, z)])
        wf = _grid_faces(nc, ns, off, False)
        wf = _orient(np.vstack(verts + [wv]), wf, np.tile([0.0, 0.0, np.sign(z)], (len(wf), 1)))
        verts.append(wv)
        faces.append(wf)
        parts.append(np.full(len(wf), part))
        off += len(wv)
    # wing edges: tip (y = radius + span, normal +y), leading and trailing edges (-x, +x)
    XT, ZT = np.meshgrid(xs, np.array([-h, h]), indexing="ij")
    YE, ZE = np.meshgrid(ys, np.array([-h, h]), indexing="ij")
    strips = (
        (np.column_stack([XT.ravel(), np.full(XT.size, radius + span), ZT.ravel()]), nc,
         [0.0, 1.0, 0.0]),
        (np.column_stack([np.full(YE.size, wing_x), YE.ravel(), ZE.ravel()]), ns,
         [-1.0, 0.0, 0.0]),
        (np.column_stack([np.full(YE.size, wing_x + chord), YE.ravel(), ZE.ravel()]), ns,
         [1.0, 0.0, 0.0]),
    )
    for sv, nseg, outward in strips:
        sf = _grid_faces(nseg, 1, off, False)
        sf = _orient(np.vstack(verts + [sv]), sf, np.tile(outward, (len(sf), 1)))
        verts.append(sv)
        faces.append(sf)
        parts.append(np.full(len(sf), 3))
        off += len(sv)
    V = np.vstack(verts)
    Fc = np.vstack(faces)
    part = np.concatenate(parts)
    mesh = trimesh.Trimesh(V, Fc, process=False)

    # emission: suction peak behind the upper leading edge, uniform elsewhere
    c = np.asarray(mesh.triangles_center)
    xi = (c[:, 0] - wing_x) / chord
    peak = 0.5 * np.exp(-((xi - 0.15) / 0.12) ** 2) * (1.0 - 0.3 * (c[:, 1] - radius) / span)
    emission = np.where(part == 1, 1.0 + peak, 1.0)

    # markers: on the upper wing and the upper fuselage, away from edges and junction
    rng = np.random.default_rng(seed)
    n_w = n_markers // 2
    n_f = n_markers - n_w
    wx = wing_x + chord * rng.uniform(0.1, 0.9, n_w)
    wy = radius + span * rng.uniform(0.2, 0.9, n_w)
    wing_pts = np.column_stack([wx, wy, np.full(n_w, h)])
    fx = rng.uniform(max(0.0, wing_x - 0.5 * chord), min(length, wing_x + 1.5 * chord), n_f)
    ft = rng.uniform(np.radians(30), np.radians(80), n_f)  # upper starboard side
    fus_pts = np.column_stack([fx, radius * np.cos(ft), radius * np.sin(ft)])
    # onto the faceted surface (the cylinder's chords lie slightly inside the circle)
    fus_pts = trimesh.proximity.closest_point(mesh, fus_pts)[0]
    ids = tuple([f"W{i + 1:02d}" for i in range(n_w)] + [f"F{i + 1:02d}" for i in range(n_f)])
    return WingBody(mesh, emission, float(reflectance), part, ids,
                    np.vstack([wing_pts, fus_pts]), 0.01, float(radius), float(length),
                    float(wing_x), float(chord), float(span), float(thickness))


def default_camera(scene: WingBody, width: int = 320, height: int = 240) -> Camera:
    """A camera above and ahead of the junction looking at it (no distortion); its
    horizontal field of view is 60 degrees."""
    target = np.array([scene.wing_x + 0.5 * scene.chord, scene.radius + 0.3 * scene.span,
                       0.0])
    eye = target + np.array([-0.45, 0.55, 0.9]) * (scene.chord + scene.span)
    f = (width / 2.0) / np.tan(np.radians(30.0))
    K = [[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]]
    return Camera.look_at(eye, target, [1.0, 0.0, 0.0], K=K, width=width, height=height)


def write_markers(scene: WingBody, path: str | os.PathLike) -> None:
    """Write the markers as a DESIGN marker CSV (``id,x,y,z,diameter``)."""
    from resection.io.markers import write_markers as _write

    _write(path, scene.marker_ids, scene.markers,
           np.full(len(scene.marker_ids), scene.marker_diameter))
