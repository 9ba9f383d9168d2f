"""Pictures: surface data seen from any Point of View, and the resection check.

* :func:`plot_surface` (the paper's Figure 22): per-face data rendered through a (real or
  virtual) camera, with a colour map and a colour bar. ``method="raster"`` backprojects the
  faces with :class:`~resection.surface.surface_map.SurfaceMap` (one Embree ray per pixel, hidden
  surfaces removed exactly); ``method="polygons"`` draws the visible faces as a matplotlib
  PolyCollection sorted by depth (painter's algorithm, vector output).
* :func:`virtual_camera`: a camera looking at the model from an azimuth / elevation.
* :func:`plot_resection` (Figure 20): the image, the model grid outline projected with the
  solved camera, detected and reprojected markers, residual vectors (magnified, the factor
  written on the picture) and the RMS in the title.

Functions return :class:`matplotlib.figure.Figure` objects built without pyplot (no global
state) and save a PNG when ``path`` is given.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import trimesh
from matplotlib import colormaps, patheffects
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from resection._checks import as_points
from resection.camera.model import Camera
from resection.errors import InputError
from resection.io.outputs import picture_format
from resection.memory import PICTURE_BYTES_PER_PIXEL, check_pixel_memory
from resection.surface.outline import outline_edges, visible_segments
from resection.surface.surface_map import SurfaceMap
from resection.surface.visibility import visible_faces

__all__ = ["plot_surface", "virtual_camera", "frame_camera", "plot_resection",
           "outline_edges", "SurfaceView", "prepare_view"]


def virtual_camera(mesh: trimesh.Trimesh, azimuth_deg: float = 30.0,
                   elevation_deg: float = 30.0, *, width: int = 640, height: int = 480,
                   hfov_deg: float = 40.0, up=(0.0, 0.0, 1.0), margin: float = 1.1,
                   target=None) -> Camera:
    """A pinhole camera looking at ``mesh`` from a direction given in degrees.

    The viewing direction is ``(cos el cos az, cos el sin az, sin el)`` from the target
    (default: the bounding-box centre) in model axes; the distance makes the bounding
    sphere (times ``margin``) fit the smaller field of view.
    """
    if width < 2 or height < 2:
        raise InputError(f"virtual_camera: image size {width}x{height} too small")
    lo, hi = np.asarray(mesh.bounds, dtype=float)
    centre = (lo + hi) / 2 if target is None else np.asarray(target, dtype=float)
    radius = 0.5 * float(np.linalg.norm(hi - lo)) * margin
    f = (width / 2) / np.tan(np.radians(hfov_deg) / 2)
    half = np.arctan(min(width, height) / 2 / f)
    dist = radius / np.sin(half)
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    direction = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    up = np.asarray(up, dtype=float)
    if abs(np.dot(up / np.linalg.norm(up), direction)) > 0.999:
        up = np.array([0.0, 1.0, 0.0]) if abs(direction[1]) < 0.9 else np.array([1.0, 0, 0])
    K = [[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]]
    return Camera.look_at(centre + dist * direction, centre, up, K=K, width=width,
                          height=height)


def frame_camera(camera: Camera, *, target=None, zoom: float = 1.0, box=None,
                 margin: float = 1.1) -> Camera:
    """The same Point of View magnified onto a region: a target point and a zoom, or a box.

    Only ``K`` changes (focal lengths times the magnification, principal point moved), so
    the picture is exactly a magnified crop of ``camera``'s image, distortion included, of
    the same size: pixel ``u`` of ``camera`` goes to ``cx' + m (u - u_c)``.

    Parameters
    ----------
    camera : Camera
    target : (3,) array_like, optional
        Model point put at the picture's centre (default: the image centre stays).
    zoom : float
        Magnification (> 0) when framing a target.
    box : (2, 3) array_like, optional
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` (model units): the picture is centred
        on the projection of its corners and magnified so they fit, times ``margin``.
    margin : float
        Room left around the box (1: the box's projection touches the picture's edges).

    Raises
    ------
    InputError
        A target or box corner behind the camera, a zoom or margin not positive, both a
        target and a box.
    """
    if not isinstance(camera, Camera):
        raise InputError(f"camera: expected a resection.Camera, got {type(camera).__name__}")
    if target is not None and box is not None:
        raise InputError("frame: give a target (and zoom) or a box, not both")
    try:
        zoom, margin = float(zoom), float(margin)
    except (TypeError, ValueError):
        raise InputError(f"frame: zoom and margin must be numbers, got {zoom!r}, {margin!r}") \
            from None
    if not (np.isfinite(zoom) and zoom > 0):
        raise InputError(f"frame: zoom must be a positive number, got {zoom}")
    if not (np.isfinite(margin) and margin > 0):
        raise InputError(f"frame: margin must be a positive number, got {margin}")
    W, H = camera.width, camera.height
    centre = np.array([(W - 1) / 2, (H - 1) / 2])
    if box is not None:
        b = as_points(box, 3, "box")
        if b.shape != (2, 3) or not np.all(b[1] >= b[0]):
            raise InputError(f"box: expected [[xmin, ymin, zmin], [xmax, ymax, zmax]] with "
                             f"max >= min, got {np.asarray(box).tolist()}")
        corners = np.array([[b[i, 0], b[j, 1], b[k, 2]] for i in (0, 1) for j in (0, 1)
                            for k in (0, 1)])
        if np.any(camera.to_camera_frame(corners)[:, 2] <= 0):
            raise InputError("box: partly behind the camera")
        uv = camera.project(corners)
        if not np.all(np.isfinite(uv)):
            raise InputError("box: outside the camera's field of view")
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        if np.max(hi - lo) < 1.0:
            raise InputError(f"box: {np.asarray(box).tolist()} is under a pixel across in "
                             "this view (a box without extent?)")
        centre_uv = (lo + hi) / 2
        size = np.maximum(hi - lo, 1e-9) * margin
        m = float(min((W - 1) / size[0], (H - 1) / size[1]))
    elif target is not None:
        X = as_points(target, 3, "target")
        if len(X) != 1:
            raise InputError(f"target: expected one point (x, y, z), got {len(X)}")
        if camera.to_camera_frame(X)[0, 2] <= 0:
            raise InputError("target: behind the camera")
        centre_uv = camera.project(X)[0]
        if not np.all(np.isfinite(centre_uv)):
            raise InputError("target: outside the camera's field of view")
        m = zoom
    else:
        centre_uv, m = centre, zoom
    K = np.array(camera.K, dtype=np.float64)
    # u' = m (u - u_c) + c  with  u = fx x + cx  =>  fx' = m fx, cx' = m (cx - u_c) + c
    K[0, 0] *= m
    K[1, 1] *= m
    K[0, 1] *= m
    K[0, 2] = m * (K[0, 2] - centre_uv[0]) + centre[0]
    K[1, 2] = m * (K[1, 2] - centre_uv[1]) + centre[1]
    return camera.replace(K=K)


def _outline_uv(mesh, camera, crease_deg) -> np.ndarray:
    """(S, 2, 2) pixel segments of the silhouettes and creases of ``mesh`` seen by
    ``camera``, hidden parts removed."""
    seg = outline_edges(mesh, crease_deg, camera=camera)
    if not len(seg):
        return np.zeros((0, 2, 2))
    # split long edges so that partly hidden ones are drawn in part
    n = 4
    s = np.linspace(0.0, 1.0, n + 1)
    pts = seg[:, None, 0, :] + s[None, :, None] * (seg[:, None, 1, :] - seg[:, None, 0, :])
    sub = np.stack([pts[:, :-1], pts[:, 1:]], axis=2).reshape(-1, 2, 3)
    sub = sub[visible_segments(mesh, camera, sub)]
    uv = camera.project(sub.reshape(-1, 3)).reshape(-1, 2, 2)
    return uv[np.all(np.isfinite(uv), axis=(1, 2))]


def _draw_outline(ax, mesh, camera, crease_deg, color, width, label, uv=None) -> None:
    """Silhouettes and creases of ``mesh`` seen by ``camera``, hidden parts removed
    (``uv``: their segments when made already)."""
    uv = _outline_uv(mesh, camera, crease_deg) if uv is None else uv
    if len(uv):
        ax.add_collection(LineCollection(uv, colors=color, linewidths=width, label=label))


@dataclass(frozen=True)
class SurfaceView:
    """What a raster picture of a mesh from a camera needs besides the values: the face
    each pixel sees and, optionally, the outline's segments (pixels). Made once by
    :func:`prepare_view` (for instance while a run computes the values), then given to
    :func:`plot_surface` as ``view``.

    Attributes
    ----------
    camera : Camera
    surface_map : SurfaceMap
    outline_uv : (S, 2, 2) ndarray or None
        Pixel segments of the outline (None: not prepared).
    crease_deg : float
        The crease angle the outline was made with, degrees.
    """

    camera: Camera
    surface_map: SurfaceMap
    outline_uv: np.ndarray | None
    crease_deg: float = 30.0


def prepare_view(mesh: trimesh.Trimesh, camera: Camera | None = None, *,
                 outline: bool = False, crease_deg: float = 30.0) -> SurfaceView:
    """The :class:`SurfaceView` of ``mesh`` from ``camera`` (default
    :func:`virtual_camera`): one Embree ray a pixel, and the outline when asked. Builds
    its own ray-tracing scene, so it may run in another thread than the one that uses
    ``mesh`` (trimesh's caches are not shared: it works on a copy of the faces)."""
    local = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False)
    camera = virtual_camera(local) if camera is None else camera
    if not isinstance(camera, Camera):
        raise InputError(f"camera: expected a resection.Camera, got {type(camera).__name__}")
    smap = SurfaceMap(local, camera)
    uv = _outline_uv(local, camera, crease_deg) if outline else None
    return SurfaceView(camera, smap, uv, float(crease_deg))


def finish_figure(fig: Figure, path, dpi: float | None = None) -> Figure:
    """Save ``fig`` to ``path`` (format from the suffix) when given; return it."""
    if path is not None:
        path = os.fspath(path)
        picture_format(fig, path)
        fig.savefig(path, dpi=fig.dpi if dpi is None else dpi)
    return fig


def _colormap(cmap):
    if not isinstance(cmap, str):
        return cmap
    try:
        return colormaps[cmap]
    except KeyError:
        raise InputError(f"cmap: unknown colour map {cmap!r} (e.g. viridis, jet, coolwarm, "
                         "gray)") from None


def plot_surface(
    mesh: trimesh.Trimesh,
    face_values,
    camera: Camera | None = None,
    *,
    method: str = "raster",
    cmap: str = "viridis",
    vmin: float | None = None,
    vmax: float | None = None,
    label: str = "",
    title: str | None = None,
    background=None,
    interpolation: str = "linear",
    edges: bool = False,
    outline: bool = False,
    crease_deg: float = 30.0,
    path: str | os.PathLike | None = None,
    dpi: int = 100,
    view: SurfaceView | None = None,
) -> Figure:
    """Per-face data seen from ``camera`` with a colour map and a colour bar.

    Parameters
    ----------
    mesh : trimesh.Trimesh
    face_values : (F,) array_like
        One value per face (NaN: not drawn).
    camera : Camera, optional
        Point of View; default :func:`virtual_camera` of the mesh.
    method : {"raster", "polygons"}
        See the module docstring.
    cmap, vmin, vmax, label, title
        Colour map, its limits (default: data range) and the colour bar label.
    background : None or (H, W) image
        Raster only: a grey image drawn under the data (e.g. the camera image).
    interpolation : {"linear", "mean", "nearest"}
        Raster only: see :meth:`SurfaceMap.to_image`.
    edges : bool
        Polygons only: draw the face edges.
    outline : bool
        Draw the model's outline: silhouettes and creases sharper than ``crease_deg``
        degrees (:func:`resection.surface.outline.outline_edges`; grid-block interfaces never),
        hidden parts removed.
    path : path-like, optional
        Save a PNG there.
    view : SurfaceView, optional
        Raster only: the pixels' faces (and the outline) made already by
        :func:`prepare_view`; its camera is used (``camera`` must then be None or it).
    """
    fv = np.asarray(face_values, dtype=np.float64)
    if fv.shape != (len(mesh.faces),):
        raise InputError(
            f"face_values: shape {fv.shape} does not match the mesh's {len(mesh.faces)} faces"
        )
    if method not in ("raster", "polygons"):
        raise InputError(f"method must be 'raster' or 'polygons', got {method!r}")
    if view is not None:
        if method != "raster" or (camera is not None and camera is not view.camera):
            raise InputError("view: only for method='raster', with its own camera")
        if view.surface_map.n_faces != len(mesh.faces):
            raise InputError(f"view: made for {view.surface_map.n_faces} faces, the mesh has "
                             f"{len(mesh.faces)}")
        camera = view.camera
    camera = virtual_camera(mesh) if camera is None else camera
    if not isinstance(camera, Camera):
        raise InputError(f"camera: expected a resection.Camera, got {type(camera).__name__}")
    for name, val in (("vmin", vmin), ("vmax", vmax)):
        if val is not None and not np.isfinite(val):
            raise InputError(f"{name} must be a finite number, got {val}")
    if vmin is not None and vmax is not None and not vmax > vmin:
        raise InputError(f"vmax ({vmax}) must be larger than vmin ({vmin})")
    cm = _colormap(cmap)
    finite = fv[np.isfinite(fv)]
    lo = float(vmin) if vmin is not None else (float(finite.min()) if finite.size else 0.0)
    hi = float(vmax) if vmax is not None else (float(finite.max()) if finite.size else 1.0)
    if hi <= lo:  # constant data, or one limit given beyond the data
        hi, lo = (lo + 1.0, lo) if vmax is None else (hi, hi - 1.0)
    norm = Normalize(lo, hi)
    W, H = camera.width, camera.height
    check_pixel_memory(W, H, PICTURE_BYTES_PER_PIXEL, "plot_surface")
    fig_w = max(W / dpi, 5.0)
    fig = Figure(figsize=(fig_w + 1.4, fig_w * H / W + 0.6), dpi=dpi, layout="constrained")
    ax = fig.add_subplot()
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    if method == "raster":
        if background is not None:
            bg = np.asarray(background, dtype=float)
            if bg.shape != (H, W):
                raise InputError(f"background: shape {bg.shape} does not match the camera "
                                 f"image (H, W) = ({H}, {W})")
            ax.imshow(bg, cmap="gray", interpolation="nearest")
        smap = SurfaceMap(mesh, camera) if view is None else view.surface_map
        img = smap.to_image(fv, interpolation=interpolation)
        mappable = ax.imshow(np.ma.masked_invalid(img), cmap=cm, norm=norm,
                             interpolation="nearest")
    else:
        vis = visible_faces(mesh, camera, max_obliqueness_deg=90.0, samples_per_face=7,
                            require="any", in_image=False) & np.isfinite(fv)
        idx = np.flatnonzero(vis)
        tri = np.asarray(mesh.vertices, dtype=float)[np.asarray(mesh.faces)[idx]]
        uv = camera.project(tri.reshape(-1, 3)).reshape(-1, 3, 2)
        depth = camera.to_camera_frame(tri.mean(axis=1))[:, 2]
        ok = np.all(np.isfinite(uv), axis=(1, 2))
        order = np.argsort(-depth[ok])  # far first
        polys = PolyCollection(uv[ok][order], array=fv[idx][ok][order], cmap=cm, norm=norm,
                               edgecolors="k" if edges else "face",
                               linewidths=0.2 if edges else 0.3)
        mappable = ax.add_collection(polys)
    if outline:
        ready = view is not None and view.outline_uv is not None and \
            view.crease_deg == float(crease_deg)
        _draw_outline(ax, mesh, camera, crease_deg, "black", 0.9, None,
                      uv=view.outline_uv if ready else None)
    cb = fig.colorbar(mappable, ax=ax, shrink=0.85)
    if label:
        cb.set_label(label)
    if title is not None:
        ax.set_title(title)
    return finish_figure(fig, path)


def plot_resection(
    image,
    camera: Camera,
    markers_xyz,
    detected_uv,
    *,
    mesh: trimesh.Trimesh | None = None,
    crease_deg: float = 30.0,
    ids=None,
    residual_scale: float | None = None,
    title: str | None = None,
    path: str | os.PathLike | None = None,
    dpi: int = 100,
) -> Figure:
    """The resection check picture (the paper's Figure 20).

    Parameters
    ----------
    image : (H, W) array_like
        The camera image (grey).
    camera : Camera
        The solved camera.
    markers_xyz : (N, 3) array_like
        Model coordinates of the matched markers.
    detected_uv : (N, 2) array_like
        Their detected image positions (pixels; NaN rows: not detected, drawn as
        reprojection only).
    mesh : trimesh.Trimesh, optional
        Model grid; its outline (silhouettes and creases sharper than ``crease_deg``
        degrees, :func:`resection.surface.outline.outline_edges`; never grid-block interfaces),
        hidden parts removed, is projected with ``camera``.
    ids : sequence of str, optional
        Marker labels written next to the markers.
    residual_scale : float, optional
        Magnification of the residual vectors (default: the largest residual is drawn 5 %
        of the image width long). Written on the picture.
    title : str, optional
        Prefix of the title; the RMS residual (pixels) and marker count are always shown.
    """
    img = np.asarray(image, dtype=float)
    H, W = camera.height, camera.width
    if img.shape != (H, W):
        raise InputError(f"image: shape {img.shape} does not match the camera image "
                         f"(H, W) = ({H}, {W})")
    X = as_points(markers_xyz, 3, "markers_xyz")
    uv_det = as_points(detected_uv, 2, "detected_uv", allow_nan=True)
    if len(X) != len(uv_det):
        raise InputError(f"markers_xyz has {len(X)} rows but detected_uv has {len(uv_det)}")
    if ids is not None:
        ids = [str(i) for i in (ids.tolist() if isinstance(ids, np.ndarray) else ids)]
        if len(ids) != len(X):
            raise InputError(f"ids has {len(ids)} labels but markers_xyz has {len(X)} rows")
    uv_rep = camera.project(X)
    res = uv_det - uv_rep
    ok = np.all(np.isfinite(res), axis=1)
    rms = float(np.sqrt(np.mean(np.sum(res[ok] ** 2, axis=1)))) if ok.any() else np.nan
    fig_w = max(W / dpi, 8.0)
    fig = Figure(figsize=(fig_w, fig_w * H / W + 0.6), dpi=dpi, layout="constrained")
    ax = fig.add_subplot()
    finite = img[np.isfinite(img)]
    lo, hi = (np.percentile(finite, [1, 99.5]) if finite.size else (0.0, 1.0))
    ax.imshow(img, cmap="gray", vmin=lo, vmax=hi if hi > lo else lo + 1,
              interpolation="nearest")
    if mesh is not None:
        _draw_outline(ax, mesh, camera, crease_deg, "deepskyblue", 1.3, "model outline")
    ax.plot(uv_det[ok, 0], uv_det[ok, 1], "o", mfc="none", mec="lime", ms=8,
            label="detected")
    ax.plot(uv_rep[:, 0], uv_rep[:, 1], "+", color="red", ms=9, mew=1.2, label="reprojected")
    if ok.any():
        mags = np.linalg.norm(res[ok], axis=1)
        if residual_scale is None:
            residual_scale = 0.05 * W / max(float(mags.max()), 1e-12)
        ax.quiver(uv_rep[ok, 0], uv_rep[ok, 1], res[ok, 0] * residual_scale,
                  res[ok, 1] * residual_scale, angles="xy", scale_units="xy", scale=1,
                  color="yellow", edgecolor="black", linewidth=0.4, width=0.004,
                  label="residual")
        ax.text(0.01, 0.01, f"residual vectors x {residual_scale:.3g}",
                transform=ax.transAxes, color="yellow", fontsize=9, va="bottom",
                bbox={"facecolor": "black", "alpha": 0.5, "pad": 2})
    if ids is not None:
        halo = [patheffects.withStroke(linewidth=2.0, foreground="black")]
        for k, name in enumerate(ids):  # labels of a few tens of markers
            if np.all(np.isfinite(uv_rep[k])):  # white on a black halo: readable anywhere
                ax.annotate(name, uv_rep[k], xytext=(6, 6), textcoords="offset points",
                            color="white", fontsize=8, path_effects=halo)
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)
    ax.set_xticks([])
    ax.set_yticks([])
    head = f"{title}: " if title else ""
    ax.set_title(f"{head}RMS residual {rms:.3f} px ({int(ok.sum())} markers)")
    ax.legend(loc="upper right", fontsize=8, framealpha=0.6)
    return finish_figure(fig, path)
