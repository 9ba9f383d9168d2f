"""Camera files: the package's JSON, NASA uPSP's JSON and OpenCV's FileStorage (YAML/XML).

One reader, :func:`read_camera`, recognises the family by content (not by extension) and
returns a :class:`resection.Camera`; every command reads its cameras through it, so
every command that reads a camera reads all three. :func:`write_camera` writes any of them.

Formats
-------
``json`` (native)
    ``{"width", "height", "K", "dist", "R", "t"}`` plus optional ``"oof"``, ``"name"``;
    parsed and validated by :meth:`resection.Camera.from_dict`.
``upsp`` (NASA uPSP camera-to-tunnel file, JSON)
    ``uPSP_cameraMatrix``: ``K`` with the principal point relative to the image centre
    (``cx = K[0][2] + width / 2``, ``cy = K[1][2] + height / 2``, pixels);
    ``distCoeffs``: OpenCV ``[k1, k2, p1, p2, k3]`` (1x5 nested list or flat);
    ``rmat``, ``tvec``: ``x_cam = rmat @ X + tvec``;
    ``sensor_resolution`` (optional, as uPSP documents it): ``[rows, cols, channels]``;
    without it the image size comes from the image the camera is used with
    (``image_size=``), or the error names the key. ``sensor_size``: inches. A file without
    ``rmat``/``tvec`` is an internal calibration (intrinsics only): its camera gets the
    identity pose and ``has_pose`` is False.
``upsp-model`` (NASA uPSP camera-to-model file, ``camNN-to-model.json``)
    Written by ``upsp-external-calibration`` and read by ``psp_process``.
    ``cameraMatrix``: ``K`` with an absolute principal point (pixels); ``distCoeffs``: flat
    ``[k1, k2, p1, p2, k3]``; ``imageSize``: ``[width, height]``; ``rmat``, ``tvec`` as
    above.

In both uPSP families, keys we do not use (``Updated``, or any other a uPSP tool adds) are
kept in :attr:`CameraFile.extra` and written back by :func:`write_camera`, so a file
round-trips; a key one letter or so from a known key (``distCoefs``) is refused as a typing
mistake, naming the key it resembles.

``opencv`` (OpenCV FileStorage, YAML or XML)
    As ``cv2.FileStorage`` and OpenCV's calibration sample write them.
    ``camera_matrix`` or ``cameraMatrix``; ``distortion_coefficients`` or ``distCoeffs``
    (4, 5 or more coefficients, beyond 5 zero); ``image_width`` and ``image_height`` (or
    ``image_size`` / ``imageSize`` = ``[width, height]``); optional ``rvec`` (Rodrigues) or
    ``R`` and ``tvec`` or ``T``. The calibration sample's bookkeeping keys are accepted
    and ignored; any other key is an error.

Unknown keys are errors in the native and OpenCV families, so a typing mistake is never
silently ignored. A UTF-8 byte-order mark is accepted.

A native camera written by ``resection pose`` may hold ``"solved_on"``: the image and the
marker file it was solved on (:mod:`resection.pose.camera_fit`), kept in
:attr:`CameraFile.solved_on` and used by the commands that take the camera to another image.
"""

from __future__ import annotations

import difflib
import json
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

from resection._checks import json_array
from resection.camera.model import Camera
from resection.errors import InputError
from resection.io._write import atomic_text

__all__ = ["CameraFile", "read_camera", "read_camera_file", "write_camera", "camera_format"]

FORMATS = ("json", "upsp", "upsp-model", "opencv-yaml", "opencv-xml")

_UPSP_KEYS = ("uPSP_cameraMatrix", "distCoeffs", "rmat", "tvec", "sensor_resolution",
              "sensor_size")
_UPSP_MODEL_KEYS = ("cameraMatrix", "distCoeffs", "imageSize", "rmat", "tvec")
_CV_K = ("camera_matrix", "cameraMatrix")
_CV_DIST = ("distortion_coefficients", "distCoeffs", "dist_coeffs")
_CV_SIZE = ("image_width", "image_height", "image_size", "imageSize")
_CV_POSE = ("rvec", "R", "tvec", "T")
# written by OpenCV's calibration sample (calibration.cpp); informational only
_CV_IGNORED = ("calibration_time", "nr_of_frames", "nframes", "board_width", "board_height",
               "square_size", "aspectRatio", "fix_aspect_ratio", "flags", "flagValue",
               "fisheye_model", "avg_reprojection_error", "per_view_reprojection_errors",
               "extrinsic_parameters", "image_points", "grid_points")


@dataclass(frozen=True)
class CameraFile:
    """What a camera file holds besides the :class:`~resection.Camera`.

    Attributes
    ----------
    camera : Camera
        The camera (identity pose when ``has_pose`` is False).
    format : str
        One of ``"json"``, ``"upsp"``, ``"opencv-yaml"``, ``"opencv-xml"``.
    has_pose : bool
        False for an intrinsics-only file (uPSP internal calibration, OpenCV file without
        ``rvec``/``tvec``).
    sensor_size : tuple of float or None
        uPSP ``sensor_size`` (inches), kept so that a uPSP file round-trips.
    channels : int or None
        Third entry of uPSP ``sensor_resolution``.
    updated : str or None
        uPSP ``Updated`` text (also in ``extra``).
    extra : dict
        uPSP keys that the camera does not use (``Updated`` and any other), in file order,
        written back by :func:`write_camera` in the uPSP families.
    solved_on : dict or None
        Native JSON: what ``resection pose`` recorded about the image and markers the
        camera was solved on (:mod:`resection.pose.camera_fit`).
    size_from_file : bool
        False when the file gives no image size and it was taken from ``image_size``.
    """

    camera: Camera
    format: str
    has_pose: bool = True
    sensor_size: tuple[float, ...] | None = None
    channels: int | None = None
    updated: str | None = None
    extra: dict = field(default_factory=dict)
    solved_on: dict | None = None
    size_from_file: bool = True


def _int(v, what: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise InputError(f"{what} must be an integer, got {v!r}")
    return v


# --------------------------------------------------------------------------- reading
def camera_format(text: str) -> str:
    """The family of a camera file's text: ``json``, ``upsp``, ``opencv-yaml``, ``opencv-xml``.

    The native and uPSP JSON are told apart by their keys (``uPSP_cameraMatrix``: uPSP
    camera-to-tunnel; ``cameraMatrix`` without ``K``: uPSP camera-to-model).
    """
    head = text.lstrip()[:200]
    if head.startswith("%YAML") or "!!opencv-matrix" in text:
        return "opencv-yaml"
    if head.startswith("<?xml") or head.startswith("<opencv_storage"):
        return "opencv-xml"
    if '"uPSP_cameraMatrix"' in text:
        return "upsp"
    if '"cameraMatrix"' in text and '"K"' not in text:
        return "upsp-model"
    return "json"


def read_camera(path: str | os.PathLike, *, image_size=None) -> Camera:
    """Read a camera file of any supported family (see the module docstring).

    Parameters
    ----------
    image_size : (width, height), optional
        The size of the image the camera is used with: the image size of a uPSP file that
        gives none (``sensor_resolution`` / ``imageSize`` are optional there).

    Raises
    ------
    InputError
        Missing or unreadable file, unknown family, unknown or missing keys, wrong types
        or shapes; the message names the file.
    """
    return read_camera_file(path, image_size=image_size).camera


def read_camera_file(path: str | os.PathLike, *, image_size=None) -> CameraFile:
    """Read a camera file and what it holds besides the camera (:class:`CameraFile`);
    ``image_size`` as in :func:`read_camera`."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
    except FileNotFoundError:
        raise InputError(f"camera file not found: {path}") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, not a camera file") from None
    try:
        text = raw.decode("utf-8-sig")  # a byte-order mark is accepted
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text camera file (not UTF-8)") from None
    if not text.strip():
        raise InputError(f"{path}: empty camera file")
    fmt = camera_format(text)
    try:
        if fmt == "opencv-yaml":
            return _from_opencv(_parse_fs_yaml(text, path), fmt)
        if fmt == "opencv-xml":
            return _from_opencv(_parse_fs_xml(text, path), fmt)
        try:
            d = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"not valid JSON ({exc})") from None
        except RecursionError:
            raise InputError("JSON nested too deeply to be a camera file") from None
        if fmt == "upsp":
            return _from_upsp(d, image_size)
        if fmt == "upsp-model":
            return _from_upsp_model(d, image_size)
        solved_on = None
        if isinstance(d, dict) and "solved_on" in d:
            d = dict(d)
            solved_on = d.pop("solved_on")
            if not isinstance(solved_on, dict):
                raise InputError(f"'solved_on' must be an object, got {solved_on!r}")
        return CameraFile(Camera.from_dict(d, source=path), "json", solved_on=solved_on)
    except InputError as exc:
        msg = str(exc)
        raise InputError(msg if msg.startswith(path) else f"{path}: {msg}") from None


def _upsp_extra(d, known, what: str) -> dict:
    """The keys of a uPSP file that the camera does not use (kept), refusing near-typos of
    the known keys."""
    extra = {}
    for k, v in d.items():
        if k in known:
            continue
        near = difflib.get_close_matches(k, known, n=1, cutoff=0.85)
        if near:
            raise InputError(f"{what}: unknown key {k!r} (did you mean {near[0]!r}?)")
        extra[k] = v
    return extra


def _size_from_image(image_size, key: str, what: str) -> tuple[int, int]:
    if image_size is None:
        raise InputError(f"{what}: no key {key!r} and no image to take the image size from "
                         f"(add {key!r} to the file, or give the image with the camera)")
    w, h = (int(x) for x in image_size)
    return w, h


def _upsp_pose(d, what: str):
    has_r, has_t = "rmat" in d, "tvec" in d
    if has_r != has_t:
        raise InputError(f"{what}: 'rmat' and 'tvec' come together (or neither, for an "
                         "internal calibration)")
    R = json_array(d["rmat"], ((3, 3),), f"{what}: rmat") if has_r else np.eye(3)
    t = json_array(d["tvec"], ((3,), (3, 1), (1, 3)), f"{what}: tvec").ravel() \
        if has_t else np.zeros(3)
    return has_r, R, t


def _from_upsp(d, image_size=None) -> CameraFile:
    what = "uPSP camera"
    if not isinstance(d, dict):
        raise InputError(f"expected a JSON object, got {type(d).__name__}")
    extra = _upsp_extra(d, _UPSP_KEYS, what)
    for k in ("uPSP_cameraMatrix", "distCoeffs"):
        if k not in d:
            raise InputError(f"{what}: missing key {k!r}")
    channels = None
    if "sensor_resolution" in d:
        res = d["sensor_resolution"]
        if not isinstance(res, list) or len(res) not in (2, 3):
            raise InputError(f"{what}: sensor_resolution must be [rows, cols, channels], "
                             f"got {res!r}")
        rows = _int(res[0], f"{what}: sensor_resolution[0] (rows)")
        cols = _int(res[1], f"{what}: sensor_resolution[1] (cols)")
        channels = _int(res[2], f"{what}: sensor_resolution[2] (channels)") \
            if len(res) == 3 else None
    else:  # optional in uPSP's camera-to-tunnel files: the principal point needs the size
        cols, rows = _size_from_image(image_size, "sensor_resolution", what)
    K = json_array(d["uPSP_cameraMatrix"], ((3, 3),), f"{what}: uPSP_cameraMatrix")
    K[0, 2] += cols / 2.0
    K[1, 2] += rows / 2.0
    dist = json_array(d["distCoeffs"], ((1, 5), (5,), (5, 1)), f"{what}: distCoeffs").ravel()
    has_r, R, t = _upsp_pose(d, what)
    size = None
    if "sensor_size" in d:
        size = tuple(json_array(d["sensor_size"], ((2,), (3,)), f"{what}: sensor_size"))
    upd = d.get("Updated")
    if upd is not None and not isinstance(upd, str):
        raise InputError(f"{what}: 'Updated' must be text, got {upd!r}")
    cam = Camera(cols, rows, K, dist, R, t)
    return CameraFile(cam, "upsp", has_r, size, channels, upd, extra,
                      size_from_file="sensor_resolution" in d)


def _from_upsp_model(d, image_size=None) -> CameraFile:
    what = "uPSP camera-to-model"
    if not isinstance(d, dict):
        raise InputError(f"expected a JSON object, got {type(d).__name__}")
    extra = _upsp_extra(d, _UPSP_MODEL_KEYS, what)
    for k in ("cameraMatrix", "distCoeffs"):
        if k not in d:
            raise InputError(f"{what}: missing key {k!r}")
    if "imageSize" in d:
        wh = json_array(d["imageSize"], ((2,), (1, 2), (2, 1)), f"{what}: imageSize").ravel()
        if not all(float(x).is_integer() and x > 0 for x in wh):
            raise InputError(f"{what}: imageSize must be two positive integers [width, "
                             f"height], got {d['imageSize']!r}")
        w, h = int(wh[0]), int(wh[1])
    else:
        w, h = _size_from_image(image_size, "imageSize", what)
    K = json_array(d["cameraMatrix"], ((3, 3),), f"{what}: cameraMatrix")
    dist = json_array(d["distCoeffs"], ((1, 5), (5,), (5, 1)), f"{what}: distCoeffs").ravel()
    has_r, R, t = _upsp_pose(d, what)
    upd = d.get("Updated")
    cam = Camera(w, h, K, dist, R, t)
    return CameraFile(cam, "upsp-model", has_r, updated=upd if isinstance(upd, str) else None,
                      extra=extra, size_from_file="imageSize" in d)


def _from_opencv(d: dict, fmt: str) -> CameraFile:
    known = set(_CV_K + _CV_DIST + _CV_SIZE + _CV_POSE + _CV_IGNORED)
    unknown = sorted(set(d) - known)
    if unknown:
        raise InputError(f"OpenCV camera: unknown key(s) {', '.join(map(repr, unknown))}")

    def pick(names, what):
        found = [n for n in names if n in d]
        if len(found) > 1:
            raise InputError(f"OpenCV camera: both {found[0]!r} and {found[1]!r} given")
        if not found:
            raise InputError(f"OpenCV camera: missing {what} ({' or '.join(names)})")
        return d[found[0]]

    K = _cv_matrix(pick(_CV_K, "camera matrix"), "camera matrix", ((3, 3),))
    dist = _cv_matrix(pick(_CV_DIST, "distortion coefficients"), "distortion coefficients",
                      None).ravel()
    if "image_size" in d or "imageSize" in d:
        wh = _cv_matrix(pick(("image_size", "imageSize"), "image size"), "image size",
                        ((2,), (2, 1), (1, 2))).ravel()
        w, h = wh
    elif "image_width" in d and "image_height" in d:
        w = _cv_matrix(d["image_width"], "image_width", ((),))
        h = _cv_matrix(d["image_height"], "image_height", ((),))
    else:
        raise InputError("OpenCV camera: missing the image size (image_width and "
                         "image_height, or image_size)")
    w, h = float(w), float(h)
    if not (w.is_integer() and h.is_integer()):
        raise InputError(f"OpenCV camera: image size must be integers, got {w}, {h}")
    has_r = any(k in d for k in ("rvec", "R"))
    has_t = any(k in d for k in ("tvec", "T"))
    if has_r != has_t:
        raise InputError("OpenCV camera: a rotation (rvec or R) and a translation (tvec or "
                         "T) come together")
    rvec = np.zeros(3)
    R = None
    tvec = np.zeros(3)
    if has_r:
        if "rvec" in d and "R" in d:
            raise InputError("OpenCV camera: both 'rvec' and 'R' given")
        if "rvec" in d:
            rvec = _cv_matrix(d["rvec"], "rvec", ((3,), (3, 1), (1, 3))).ravel()
        else:
            R = _cv_matrix(d["R"], "R", ((3, 3),))
        tvec = _cv_matrix(pick(("tvec", "T"), "translation"), "tvec",
                          ((3,), (3, 1), (1, 3))).ravel()
    cam = Camera.from_opencv(K, dist, rvec, tvec, int(w), int(h))
    if R is not None:
        cam = Camera(int(w), int(h), cam.K, cam.dist, R, tvec)
    return CameraFile(cam, fmt, has_r)


def _cv_matrix(v, what: str, shapes) -> np.ndarray:
    if isinstance(v, (bool, str)) or v is None:
        raise InputError(f"OpenCV camera: {what} must be numeric, got {v!r}")
    try:
        arr = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"OpenCV camera: {what} must be numeric, got {v!r}") from None
    if shapes is not None and arr.shape not in shapes:
        raise InputError(f"OpenCV camera: {what} has shape {arr.shape}, expected "
                         f"{' or '.join(map(str, shapes))}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"OpenCV camera: {what} contains NaN or infinite values")
    return arr


def _fs_matrix(rows, cols, data, what: str) -> np.ndarray:
    try:
        rows, cols = int(rows), int(cols)
        arr = np.asarray([float(x) for x in data], dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"OpenCV camera: {what} is not a numeric matrix") from None
    if arr.size != rows * cols:
        raise InputError(f"OpenCV camera: {what} has {arr.size} values for {rows}x{cols}")
    return arr.reshape(rows, cols)


def _parse_fs_yaml(text: str, path: str) -> dict:
    """OpenCV FileStorage YAML (``%YAML:1.0`` header, ``!!opencv-matrix`` nodes)."""
    import yaml

    class _Loader(yaml.SafeLoader):
        pass

    def matrix(loader, node):
        m = loader.construct_mapping(node, deep=True)
        missing = {"rows", "cols", "data"} - set(m)
        if missing:
            raise InputError(f"OpenCV camera: matrix node lacks {sorted(missing)}")
        return _fs_matrix(m["rows"], m["cols"], m["data"] or [], "matrix")

    _Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", matrix)
    lines = text.splitlines()
    body = "\n".join(ln for ln in lines if not ln.startswith("%YAML"))
    try:
        d = yaml.load(body, Loader=_Loader)  # noqa: S506 - SafeLoader subclass
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0]
        raise InputError(f"not a valid OpenCV FileStorage YAML file ({first})") from None
    if not isinstance(d, dict):
        raise InputError("OpenCV FileStorage YAML: expected a mapping of named nodes")
    return d


def _parse_fs_xml(text: str, path: str) -> dict:
    """OpenCV FileStorage XML (``<opencv_storage>`` with ``type_id="opencv-matrix"``)."""
    try:
        root = ET.fromstring(text.encode("utf-8"))
    except ET.ParseError as exc:
        raise InputError(f"not a valid OpenCV FileStorage XML file ({exc})") from None
    if root.tag != "opencv_storage":
        raise InputError(f"OpenCV FileStorage XML: root element is <{root.tag}>, expected "
                         "<opencv_storage>")
    d: dict = {}
    for el in root:
        if el.get("type_id") == "opencv-matrix":
            parts = {c.tag: (c.text or "") for c in el}
            if not {"rows", "cols", "data"} <= set(parts):
                raise InputError(f"OpenCV camera: matrix <{el.tag}> lacks rows, cols or data")
            d[el.tag] = _fs_matrix(parts["rows"], parts["cols"], parts["data"].split(), el.tag)
        elif len(el):
            d[el.tag] = None  # a nested structure (sequence, map): only ignored keys have one
        else:
            txt = (el.text or "").strip()
            try:
                vals = [float(x) for x in txt.split()]
                d[el.tag] = vals[0] if len(vals) == 1 else vals
            except ValueError:
                d[el.tag] = txt.strip('"')
    return d


# --------------------------------------------------------------------------- writing
def write_camera(
    path: str | os.PathLike,
    camera: Camera,
    *,
    format: str = "auto",
    sensor_size: tuple[float, ...] | None = None,
    channels: int | None = None,
    intrinsics_only: bool = False,
    extra: dict | None = None,
    solved_on: dict | None = None,
) -> None:
    """Write ``camera`` as one of :data:`FORMATS`.

    Parameters
    ----------
    format : {"auto", "json", "upsp", "upsp-model", "opencv-yaml", "opencv-xml"}
        ``auto``: OpenCV YAML for ``.yml``/``.yaml``, OpenCV XML for ``.xml``, else the
        native JSON.
    sensor_size, channels : optional
        uPSP ``sensor_size`` (inches) and the third entry of ``sensor_resolution``.
    intrinsics_only : bool
        uPSP / OpenCV: leave the pose out (an internal calibration file).
    extra : dict, optional
        uPSP families: keys kept from a uPSP file (:attr:`CameraFile.extra`, ``Updated``
        ...), written after the camera's own. Other families have no room for them.
    solved_on : dict, optional
        Native JSON: the record of the image and markers the camera was solved on
        (:mod:`resection.pose.camera_fit`).

    The file is written to a temporary name in the same folder and renamed into place.
    """
    path = os.fspath(path)
    fmt = format
    if fmt == "auto":
        ext = os.path.splitext(path)[1].lower()
        fmt = {".yml": "opencv-yaml", ".yaml": "opencv-yaml", ".xml": "opencv-xml"}.get(ext,
                                                                                       "json")
    if fmt not in FORMATS:
        raise InputError(f"{path}: unknown camera format {format!r}; one of "
                         f"{', '.join(FORMATS)}")
    if fmt == "json":
        d = camera.to_dict()
        if solved_on:
            d["solved_on"] = solved_on
        text = json.dumps(d, indent=2) + "\n"
    elif fmt in ("upsp", "upsp-model"):
        d = _to_upsp(camera, sensor_size, channels, intrinsics_only) if fmt == "upsp" else \
            _to_upsp_model(camera, intrinsics_only)
        for k, v in (extra or {}).items():
            d.setdefault(k, v)
        text = json.dumps(d, indent=2) + "\n"
    else:
        text = _to_opencv(camera, fmt, intrinsics_only)
    atomic_text(path, text)


def _to_upsp(cam: Camera, sensor_size, channels, intrinsics_only) -> dict:
    K = np.array(cam.K)
    K[0, 2] -= cam.width / 2.0
    K[1, 2] -= cam.height / 2.0
    d: dict = {"uPSP_cameraMatrix": K.tolist(), "distCoeffs": [np.asarray(cam.dist).tolist()]}
    if not intrinsics_only:
        d["rmat"] = np.asarray(cam.R).tolist()
        d["tvec"] = np.asarray(cam.t).tolist()
    d["sensor_resolution"] = [cam.height, cam.width] + ([int(channels)] if channels else [1])
    if sensor_size is not None:
        d["sensor_size"] = [float(x) for x in sensor_size]
    return d


def _to_upsp_model(cam: Camera, intrinsics_only) -> dict:
    d: dict = {"cameraMatrix": np.asarray(cam.K).tolist(),
               "distCoeffs": np.asarray(cam.dist).tolist(),
               "imageSize": [cam.width, cam.height]}
    if not intrinsics_only:
        d["rmat"] = np.asarray(cam.R).tolist()
        d["tvec"] = np.asarray(cam.t).tolist()
    return d


def _to_opencv(cam: Camera, fmt: str, intrinsics_only: bool) -> str:
    mats = {"camera_matrix": np.asarray(cam.K),
            "distortion_coefficients": np.asarray(cam.dist).reshape(1, 5)}
    if not intrinsics_only:
        mats["rvec"] = cam.rvec.reshape(3, 1)
        mats["tvec"] = np.asarray(cam.t).reshape(3, 1)
    if fmt == "opencv-yaml":
        out = ["%YAML:1.0", "---", f"image_width: {cam.width}", f"image_height: {cam.height}"]
        for name, m in mats.items():
            data = ", ".join(repr(float(x)) for x in m.ravel())
            out += [f"{name}: !!opencv-matrix", f"   rows: {m.shape[0]}",
                    f"   cols: {m.shape[1]}", "   dt: d", f"   data: [ {data} ]"]
        return "\n".join(out) + "\n"
    out = ['<?xml version="1.0"?>', "<opencv_storage>",
           f"<image_width>{cam.width}</image_width>",
           f"<image_height>{cam.height}</image_height>"]
    for name, m in mats.items():
        data = " ".join(repr(float(x)) for x in m.ravel())
        out += [f'<{name} type_id="opencv-matrix">', f"  <rows>{m.shape[0]}</rows>",
                f"  <cols>{m.shape[1]}</cols>", "  <dt>d</dt>", f"  <data>{data}</data>",
                f"</{name}>"]
    out.append("</opencv_storage>")
    return "\n".join(out) + "\n"
