"""Camera files: the package's JSON, NASA uPSP's JSON and OpenCV's FileStorage (YAML/XML).

One reader, :func:`read_camera`, recognises the family by content (not by extension) and
returns a :class:`resection.Camera`; every command reads its cameras through it, so
every command that reads a camera reads all three. :func:`write_camera` writes any of them.

Formats
-------
``json`` (native, DESIGN.md)
    ``{"width", "height", "K", "dist", "R", "t"}`` plus optional ``"oof"``, ``"name"``;
    parsed and validated by :meth:`resection.Camera.from_dict`.
``upsp`` (NASA uPSP camera-to-tunnel file, JSON)
    ``uPSP_cameraMatrix``: ``K`` with the principal point relative to the image centre
    (``cx = K[0][2] + width / 2``, ``cy = K[1][2] + height / 2``, pixels);
    ``distCoeffs``: OpenCV ``[k1, k2, p1, p2, k3]`` (1x5 nested list or flat);
    ``rmat``, ``tvec``: ``x_cam = rmat @ X + tvec``;
    ``sensor_resolution``: ``[rows, cols, channels]``; ``sensor_size``: inches;
    ``Updated``: free text. A file without ``rmat``/``tvec`` is an internal calibration
    (intrinsics only): its camera gets the identity pose and ``has_pose`` is False.
``opencv`` (FileStorage YAML or XML, as ``cv2.FileStorage`` and OpenCV's calibration sample
    write them)
    ``camera_matrix`` or ``cameraMatrix``; ``distortion_coefficients`` or ``distCoeffs``
    (4, 5 or more coefficients, beyond 5 zero); ``image_width`` and ``image_height`` (or
    ``image_size`` / ``imageSize`` = ``[width, height]``); optional ``rvec`` (Rodrigues) or
    ``R`` and ``tvec`` or ``T``. The calibration sample's bookkeeping keys are accepted
    and ignored; any other key is an error.

Unknown keys are errors in every family, so a typing mistake is never silently ignored.
A UTF-8 byte-order mark is accepted.
"""

from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from resection._checks import json_array
from resection.camera.model import Camera
from resection.errors import InputError
from resection.io._write import atomic_text

__all__ = ["CameraFile", "read_camera", "read_camera_file", "write_camera", "camera_format"]

FORMATS = ("json", "upsp", "opencv-yaml", "opencv-xml")

_UPSP_KEYS = ("uPSP_cameraMatrix", "distCoeffs", "rmat", "tvec", "sensor_resolution",
              "sensor_size", "Updated")
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
        uPSP ``Updated`` text.
    """

    camera: Camera
    format: str
    has_pose: bool = True
    sensor_size: tuple[float, ...] | None = None
    channels: int | None = None
    updated: str | None = None


def _int(v, what: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise InputError(f"{what} must be an integer, got {v!r}")
    return v


# --------------------------------------------------------------------------- reading
def camera_format(text: str) -> str:
    """The family of a camera file's text: ``json``, ``upsp``, ``opencv-yaml``, ``opencv-xml``.

    The native and uPSP JSON are told apart by their keys (``uPSP_cameraMatrix``).
    """
    head = text.lstrip()[:200]
    if head.startswith("%YAML") or "!!opencv-matrix" in text:
        return "opencv-yaml"
    if head.startswith("<?xml") or head.startswith("<opencv_storage"):
        return "opencv-xml"
    if '"uPSP_cameraMatrix"' in text:
        return "upsp"
    return "json"


def read_camera(path: str | os.PathLike) -> Camera:
    """Read a camera file of any supported family (see the module docstring).

    Raises
    ------
    InputError
        Missing or unreadable file, unknown family, unknown or missing keys, wrong types
        or shapes; the message names the file.
    """
    return read_camera_file(path).camera


def read_camera_file(path: str | os.PathLike) -> CameraFile:
    """Read a camera file and what it holds besides the camera (:class:`CameraFile`)."""
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
        if fmt == "upsp":
            return _from_upsp(d)
        return CameraFile(Camera.from_dict(d, source=path), "json")
    except InputError as exc:
        msg = str(exc)
        raise InputError(msg if msg.startswith(path) else f"{path}: {msg}") from None


def _from_upsp(d) -> CameraFile:
    if not isinstance(d, dict):
        raise InputError(f"expected a JSON object, got {type(d).__name__}")
    unknown = sorted(set(d) - set(_UPSP_KEYS))
    if unknown:
        raise InputError(f"uPSP camera: unknown key(s) {', '.join(map(repr, unknown))}; "
                         f"allowed: {', '.join(_UPSP_KEYS)}")
    for k in ("uPSP_cameraMatrix", "distCoeffs"):
        if k not in d:
            raise InputError(f"uPSP camera: missing key {k!r}")
    if "sensor_resolution" not in d:
        raise InputError("uPSP camera: missing key 'sensor_resolution' (the image size; "
                         "the principal point is relative to the image centre)")
    res = d["sensor_resolution"]
    if not isinstance(res, list) or len(res) not in (2, 3):
        raise InputError(f"uPSP camera: sensor_resolution must be [rows, cols, channels], "
                         f"got {res!r}")
    rows = _int(res[0], "uPSP camera: sensor_resolution[0] (rows)")
    cols = _int(res[1], "uPSP camera: sensor_resolution[1] (cols)")
    channels = _int(res[2], "uPSP camera: sensor_resolution[2] (channels)") \
        if len(res) == 3 else None
    K = json_array(d["uPSP_cameraMatrix"], ((3, 3),), "uPSP camera: uPSP_cameraMatrix")
    K[0, 2] += cols / 2.0
    K[1, 2] += rows / 2.0
    dist = json_array(d["distCoeffs"], ((1, 5), (5,), (5, 1)), "uPSP camera: distCoeffs").ravel()
    has_r, has_t = "rmat" in d, "tvec" in d
    if has_r != has_t:
        raise InputError("uPSP camera: 'rmat' and 'tvec' come together (or neither, for an "
                         "internal calibration)")
    R = json_array(d["rmat"], ((3, 3),), "uPSP camera: rmat") if has_r else np.eye(3)
    t = json_array(d["tvec"], ((3,), (3, 1), (1, 3)), "uPSP camera: tvec").ravel() \
        if has_t else np.zeros(3)
    size = None
    if "sensor_size" in d:
        size = tuple(json_array(d["sensor_size"], ((2,), (3,)), "uPSP camera: sensor_size"))
    upd = d.get("Updated")
    if upd is not None and not isinstance(upd, str):
        raise InputError(f"uPSP camera: 'Updated' must be text, got {upd!r}")
    cam = Camera(cols, rows, K, dist, R, t)
    return CameraFile(cam, "upsp", has_r, size, channels, upd)


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
) -> None:
    """Write ``camera`` as one of :data:`FORMATS`.

    Parameters
    ----------
    format : {"auto", "json", "upsp", "opencv-yaml", "opencv-xml"}
        ``auto``: OpenCV YAML for ``.yml``/``.yaml``, OpenCV XML for ``.xml``, else the
        native JSON.
    sensor_size, channels : optional
        uPSP ``sensor_size`` (inches) and the third entry of ``sensor_resolution``.
    intrinsics_only : bool
        uPSP / OpenCV: leave the pose out (an internal calibration file).

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
        text = json.dumps(camera.to_dict(), indent=2) + "\n"
    elif fmt == "upsp":
        text = json.dumps(_to_upsp(camera, sensor_size, channels, intrinsics_only),
                          indent=2) + "\n"
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
