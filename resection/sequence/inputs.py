"""Checks of the inputs of :func:`resection.sequence.track` and the settings a resumed run
must share."""

from __future__ import annotations

import inspect
import json
import os

import numpy as np

from resection._checks import as_points
from resection.errors import InputError
from resection.sequence.frames import VideoFrame, expand_frames
from resection.sequence.process import Setup
from resection.sequence.results import FORMAT_VERSION
from resection.trisurface import TriSurface


def _as_markers(markers3d) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``(ids, points, normals)`` from a marker file path, an ``(ids, points)`` pair, or an
    object with ``ids`` and ``points``/``xyz`` (and optionally ``normals``) attributes;
    ``normals`` (N, 3), NaN rows where unknown, or None when no marker has one."""
    normals = None
    if isinstance(markers3d, (str, os.PathLike)):
        from resection.io.markers import read_markers

        markers3d = read_markers(markers3d)
    if isinstance(markers3d, tuple) and len(markers3d) == 2:
        ids, pts = markers3d
    else:
        ids = getattr(markers3d, "ids", None)
        pts = getattr(markers3d, "points", getattr(markers3d, "xyz", None))
        normals = getattr(markers3d, "normals", None)
        if ids is None or pts is None:
            raise InputError("markers3d: expected a marker file, (ids, points) or an object "
                             "with ids and points")
    pts = as_points(pts, 3, "markers3d points")
    ids = np.asarray(ids).astype(str).ravel()
    if len(ids) != len(pts):
        raise InputError(f"markers3d: {len(ids)} ids for {len(pts)} points")
    u, c = np.unique(ids, return_counts=True)
    if np.any(c > 1):
        raise InputError(f"markers3d: duplicate marker id {str(u[c > 1][0])!r}")
    if normals is not None:
        normals = np.array(normals, dtype=float).reshape(len(pts), 3)
        if not np.isfinite(normals).all(axis=1).any():
            normals = None
    return ids, pts, normals


def _mesh_normals(mesh, points: np.ndarray, normals: np.ndarray | None) -> np.ndarray:
    """Normals at the markers from the mesh (a path, a trimesh or a TriSurface): the normal
    of the face nearest each marker, where the marker file gives none."""
    import trimesh

    if isinstance(mesh, (str, os.PathLike)):
        from resection.io.meshes import load_mesh

        mesh = load_mesh(mesh)
    if isinstance(mesh, TriSurface):  # trimesh's nearest-point query needs its mesh
        mesh = mesh.to_trimesh()
    if not isinstance(mesh, trimesh.Trimesh):
        raise InputError(f"mesh: expected a mesh file or a trimesh.Trimesh, got "
                         f"{type(mesh).__name__}")
    _, _, face = trimesh.proximity.closest_point(mesh, points)
    out = np.asarray(mesh.face_normals, float)[face]
    if normals is not None:
        given = np.isfinite(normals).all(axis=1)
        out[given] = normals[given]
    return out


def _check_options(kw, func, name: str, reserved: tuple) -> dict:
    """Checked copy of extra keyword arguments for ``func``: a bad name would otherwise
    make every frame fail, one by one."""
    if kw is None:
        return {}
    if not isinstance(kw, dict):
        raise InputError(f"{name}: expected a dict of {func.__name__} options, got "
                         f"{type(kw).__name__}")
    params = inspect.signature(func).parameters
    allowed = {k for k, p in params.items()
               if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and k not in reserved}
    unknown = sorted(str(k) for k in kw if k not in allowed)
    if unknown:
        why = [k for k in unknown if k in reserved]
        note = (f" ({', '.join(why)}: set by track itself; the intrinsics stay those of "
                "the camera)" if why else "")
        raise InputError(f"{name}: unknown or reserved {func.__name__} option(s) {unknown}"
                         f"{note}; expected some of {sorted(allowed)}")
    # options given at their default value are left out: a run with them resumes one
    # without them (the CLI passes its acceptance options always)
    return {k: v for k, v in kw.items() if not _is_default(v, params[k].default)}


def _is_default(value, default) -> bool:
    if default is inspect.Parameter.empty or isinstance(value, np.ndarray):
        return False
    try:
        return type(value) in (int, float, str, bool, type(None)) and bool(value == default)
    except (TypeError, ValueError):
        return False


def _as_link(link) -> dict | None:
    """``{"path": str or None, "pairs": {id: candidate} or None, "text": file content}``."""
    if link is None:
        return None
    if isinstance(link, (str, os.PathLike)):
        path = os.fspath(link)
        try:
            with open(path, encoding="utf-8") as fh:
                text = fh.read()
        except FileNotFoundError:
            raise InputError(f"{path}: no such linking file") from None
        except OSError as exc:
            raise InputError(f"{path}: cannot read the linking file ({exc})") from None
        return {"path": path, "pairs": None, "text": text}
    if not isinstance(link, dict) or not link:
        raise InputError("link: expected a linking CSV (id,candidate) or a non-empty "
                         "{id: candidate number} dict")
    try:
        pairs = {str(k): int(v) for k, v in link.items()}
    except (TypeError, ValueError):
        raise InputError("link: candidate numbers must be integers") from None
    return {"path": None, "pairs": pairs, "text": None}


def run_settings(setup: Setup, link: dict | None, fixed_camera: bool, chunk_size: int) -> dict:
    """The settings a resumed run must share with the interrupted one (JSON-able)."""
    def plain(d):
        return json.loads(json.dumps(d, default=lambda o: np.asarray(o).tolist()))

    return plain({
        "version": FORMAT_VERSION,
        "camera": setup.camera.to_dict(),
        "markers": {"ids": setup.ids.tolist(), "points": setup.points3d.tolist()},
        "diameter": setup.diameter, "polarity": setup.polarity,
        "detect_kw": setup.detect_kw, "match_kw": setup.match_kw, "pose_kw": setup.pose_kw,
        "min_markers": setup.min_markers, "roi_margin": setup.roi_margin,
        "link": None if link is None else (link["text"] if link["path"] is not None
                                           else {k: link["pairs"][k]
                                                 for k in sorted(link["pairs"])}),
        "fixed_camera": bool(fixed_camera), "chunk_size": int(chunk_size),
        **({} if setup.normals is None else {"normals": setup.normals.tolist()}),
    })


def checked(frames, camera, markers3d, *, link, diameter, polarity, workers, chunk_size,
             min_markers, roi_margin, detect_kw, match_kw, pose_kw, mesh=None):
    """Checked inputs of :func:`track`: ``(frames list, Setup, link dict or None,
    workers, chunk_size)``; InputError for the first bad one, before any file is made."""
    from resection.camera.model import Camera
    from resection.markers.detect import detect_markers
    from resection.markers.match import match_markers
    from resection.pose.solve import solve_pose
    from resection.sequence.execute import default_workers

    if not isinstance(camera, Camera):
        raise InputError(f"camera: expected a resection.Camera, got {type(camera).__name__}")
    if isinstance(frames, (str, os.PathLike)):
        frames = [frames]  # one file: a multi-frame file, or a sequence of one image
    elif isinstance(frames, np.ndarray) and frames.ndim != 3:
        raise InputError("frames: expected a sequence of frames (paths or 2-D arrays)")
    frames = expand_frames(list(frames))
    if not frames:
        raise InputError("frames: the sequence is empty")
    try:
        d = float(diameter)
    except (TypeError, ValueError):
        raise InputError(f"diameter: must be a number of pixels, got {diameter!r}") from None
    if not (np.isfinite(d) and d > 0):
        raise InputError(f"diameter: must be positive, got {diameter!r}")
    if polarity not in ("dark", "bright"):
        raise InputError(f"polarity: expected 'dark' or 'bright', got {polarity!r}")
    if workers is None:
        workers = default_workers()
    try:
        workers = int(workers)
    except (TypeError, ValueError):
        raise InputError(f"workers: must be a whole number, got {workers!r}") from None
    if workers < 1:
        raise InputError(f"workers: must be >= 1, got {workers}")
    if int(chunk_size) < 1:
        raise InputError(f"chunk_size: must be >= 1, got {chunk_size}")
    if int(min_markers) < 3:
        raise InputError(f"min_markers: must be >= 3, got {min_markers}")
    if roi_margin is not None and not (np.isfinite(roi_margin) and roi_margin > 0):
        raise InputError(f"roi_margin: must be positive or None, got {roi_margin!r}")
    for i, f in enumerate(frames):
        if not isinstance(f, (str, os.PathLike, np.ndarray, VideoFrame)):
            raise InputError(f"frames[{i}]: expected a path or a 2-D array, got "
                             f"{type(f).__name__}")
    ids, pts, normals = _as_markers(markers3d)
    if mesh is not None:
        normals = _mesh_normals(mesh, pts, normals)
    link_d = _as_link(link)
    detect_kw = _check_options(detect_kw, detect_markers, "detect_kw",
                               ("image", "diameter", "polarity"))
    match_kw = _check_options(match_kw, match_markers, "match_kw",
                              ("candidates", "markers3d", "reference", "camera", "pose_kw"))
    pose_kw = _check_options(pose_kw, solve_pose, "pose_kw",
                             ("camera", "points3d", "points2d", "refine_intrinsics"))
    _probe_pose_options(camera, pose_kw, solve_pose)
    setup = Setup(camera=camera, ids=ids, points3d=pts, diameter=d, polarity=polarity,
                   detect_kw=detect_kw, match_kw=match_kw,
                   pose_kw=pose_kw, min_markers=int(min_markers),
                   roi_margin=None if roi_margin is None else float(roi_margin),
                   normals=normals)
    return frames, setup, link_d, workers, int(chunk_size)


def _probe_pose_options(camera, pose_kw: dict, solve_pose) -> None:
    """Refuse ``pose_kw`` values that ``solve_pose`` rejects (``{"robust": 5}``), before the
    run: solved once on eight exact synthetic markers in front of the camera, the options
    must give an accepted pose. Otherwise every frame would fail, one by one."""
    if not pose_kw:
        return
    W, H = camera.width, camera.height
    fx, fy = camera.K[0, 0], camera.K[1, 1]
    x = np.array([-1, 1, -1, 1, -0.5, 0.5, 0.3, -0.2]) * 0.2 * W / fx
    y = np.array([-1, -1, 1, 1, 0.4, -0.6, 0.1, -0.3]) * 0.2 * H / fy
    z = np.array([10.0, 11, 12, 9, 10.5, 9.5, 11.5, 10.2])
    cam_pts = np.column_stack([x * z, y * z, z])
    points3d = (cam_pts - camera.t) @ camera.R  # R^T (X_cam - t): model frame
    points2d = camera.project(points3d)
    try:
        solve_pose(camera, points3d, points2d, **pose_kw)
    except Exception as exc:  # noqa: BLE001 - any refusal names the option set
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"pose_kw {pose_kw}: refused by solve_pose ({msg})") from None
