"""The model's place in the tunnel: the ``.wtd``'s attitude about the centre of rotation,
and each camera's camera-to-tunnel calibration carried to the model (uPSP's
``tunnel_transform`` and ``tf_camera_tgts_thru_tunnel``, written from their documented
conventions).

Frames and signs (NASA Ames UPWT 11-ft, as uPSP's ``camera_tunnel_calibrate``):

* the tunnel frame is the aircraft's right-handed body frame pitched by 180 deg;
* ``ALPHA`` (deg) is a positive pitch, ``BETA`` (deg) a negative yaw, ``PHI`` (deg) a
  positive roll, applied in the order pitch, yaw, roll:
  ``M = (Ry(-ALPHA) Rz(-BETA) Rx(PHI))^T = Rx(-PHI) Rz(BETA) Ry(ALPHA)``, where ``Rk(a)``
  turns by ``a`` about axis ``k`` (right-handed, counter-clockwise seen from +k);
* a point ``X`` of the model (the ``.tgts`` and grid frame) is in the tunnel at
  ``M X + M c + (0, 0, STRUTZ)``, ``c`` = ``tunnel-cor_to_tgts_tvec`` (the centre of
  rotation to the model origin, in model axes; model units) and ``STRUTZ`` the strut's
  height (the ``.wtd``'s ``STRUTZ``, else ``STRUTZ_UNC``);
* a camera-to-tunnel calibration maps ``x_cam = R_ct X_tunnel + t_ct``, so the camera to
  the model is ``R = R_ct M``, ``t = t_ct + R_ct (M c + (0, 0, STRUTZ))``.

As in uPSP, ``tunnel-cor_to_tgts_rmat`` and ``tunnel-cor_to_tunnel-origin_*`` are not used
by the transform; a ``tunnel-cor_to_tgts_rmat`` other than the identity is refused (uPSP
would silently ignore it).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

from resection.camera.model import Camera
from resection.errors import InputError

__all__ = ["TunnelConfig", "Attitude", "read_test_config", "attitude_matrix",
           "model_to_tunnel", "camera_to_model", "attitude_from_wtd", "upsp_principal_point",
           "read_camera_tunnel", "tunnel_config"]

#: test_config keys this module uses; the others are kept in ``TunnelConfig.extra``.
_USED = ("tunnel-cor_to_tgts_tvec", "tunnel-cor_to_tgts_rmat",
         "tunnel-cor_to_tunnel-origin_tvec", "tunnel-cor_to_tunnel-origin_rmat",
         "oblique_angle")


@dataclass(frozen=True)
class TunnelConfig:
    """uPSP's external-calibration configuration (``test_config.json``).

    Attributes
    ----------
    cor_to_model : (3,) float
        ``tunnel-cor_to_tgts_tvec``: centre of rotation to the model origin, model axes and
        units.
    oblique_angle : float
        Degrees; targets seen more obliquely are not used (default 70).
    source : str
    extra : dict
        The other keys (``dot_pad``, ``max_dist``, ...: parameters of uPSP's own detector,
        which the project's detection and acceptance rule replace).
    """

    cor_to_model: np.ndarray
    oblique_angle: float = 70.0
    source: str = "given"
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Attitude:
    """The model's attitude of a datapoint: degrees, and the strut height (model units)."""

    alpha: float
    beta: float
    phi: float
    strutz: float


def _vector(v, what: str) -> np.ndarray:
    a = np.asarray(v, dtype=float) if isinstance(v, list) else None
    if a is None or a.size != 3 or not np.all(np.isfinite(a)):
        raise InputError(f"{what}: expected 3 numbers, got {v!r}")
    return a.reshape(3)


def _matrix(v, what: str) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise InputError(f"{what}: expected a 3x3 matrix, got {v!r}")
    return a


def tunnel_config(d: dict, source: str) -> TunnelConfig:
    """A :class:`TunnelConfig` from the dictionary of a ``test_config.json`` (or of the
    ``external-calibration`` parameters of uPSP's processing file)."""
    if not isinstance(d, dict):
        raise InputError(f"{source}: expected a JSON object")
    key = "tunnel-cor_to_tgts_tvec"
    if key not in d:
        raise InputError(f"{source}: no {key!r} (the tunnel's centre of rotation to the "
                         "model origin; [0, 0, 0] when there is none)")
    cor = _vector(d[key], f"{source}: {key}")
    for k in ("tunnel-cor_to_tgts_rmat",):
        if k in d and not np.allclose(_matrix(d[k], f"{source}: {k}"), np.eye(3),
                                      atol=1e-12):
            raise InputError(f"{source}: {k} is not the identity; uPSP's tunnel_transform "
                             "does not use it and neither does this package")
    for k in ("tunnel-cor_to_tunnel-origin_tvec",):
        if k in d:
            _vector(d[k], f"{source}: {k}")
    for k in ("tunnel-cor_to_tunnel-origin_rmat",):
        if k in d:
            _matrix(d[k], f"{source}: {k}")
    ob = d.get("oblique_angle", 70.0)
    if not isinstance(ob, int | float) or not 0 < ob <= 90:
        raise InputError(f"{source}: oblique_angle must be a number of degrees in (0, 90], "
                         f"got {ob!r}")
    extra = {k: v for k, v in d.items() if k not in _USED}
    return TunnelConfig(cor, float(ob), source, extra)


def read_test_config(path: str | os.PathLike) -> TunnelConfig:
    """Read uPSP's ``test_config.json`` (see :class:`TunnelConfig`)."""
    p = os.fspath(path)
    try:
        with open(p, encoding="utf-8-sig") as fh:
            d = json.load(fh)
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: cannot read ({e})") from None
    except json.JSONDecodeError as e:
        raise InputError(f"{p}: not JSON ({e.msg}, line {e.lineno})") from None
    return tunnel_config(d, p)


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def attitude_matrix(alpha: float, beta: float, phi: float) -> np.ndarray:
    """``M = Rx(-phi) Rz(beta) Ry(alpha)`` (degrees): model axes to tunnel axes."""
    a, b, p = (math.radians(float(x)) for x in (alpha, beta, phi))
    return _rx(-p) @ _rz(b) @ _ry(a)


def model_to_tunnel(att: Attitude, cfg: TunnelConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(M, d)``: a model point ``X`` is at ``M X + d`` in the tunnel."""
    M = attitude_matrix(att.alpha, att.beta, att.phi)
    return M, M @ cfg.cor_to_model + np.array([0.0, 0.0, att.strutz])


def camera_to_model(camera_tunnel: Camera, att: Attitude, cfg: TunnelConfig) -> Camera:
    """The camera posed on the model: its camera-to-tunnel pose carried by the datapoint's
    attitude (module notes)."""
    M, d = model_to_tunnel(att, cfg)
    R = camera_tunnel.R @ M
    t = camera_tunnel.t + camera_tunnel.R @ d
    return camera_tunnel.with_pose(R=R, t=t)


def attitude_from_wtd(wtd) -> Attitude:
    """ALPHA, BETA, PHI and STRUTZ (else STRUTZ_UNC) of a
    :class:`resection.io.wtd.WindTunnelData`, each refused by name when missing."""
    vals = []
    for name in ("ALPHA", "BETA", "PHI"):
        if not wtd.has(name):
            raise InputError(f"{wtd.path}: no {name} column (the model's attitude)")
        vals.append(wtd.value(name))
    if wtd.has("STRUTZ"):
        z = wtd.value("STRUTZ")
    elif wtd.has("STRUTZ_UNC"):
        z = wtd.value("STRUTZ_UNC")
    else:
        raise InputError(f"{wtd.path}: no STRUTZ (nor STRUTZ_UNC) column: the strut's "
                         "height (write 0 for a model without a strut)")
    return Attitude(*vals, z)


def upsp_principal_point(camera: Camera, file_size, width: int, height: int) -> Camera:
    """A uPSP camera-to-tunnel camera taken to an image of ``width`` x ``height``: uPSP
    stores the principal point relative to the image centre and adds the *image's* half
    size (``parsers.convert_uPSP_cm_to_cv2_cm``), so a cropped video keeps that offset.
    ``file_size`` = ``(width, height)`` the camera was read with."""
    if (width, height) == tuple(file_size):
        return camera
    K = np.array(camera.K, float)
    K[0, 2] += (width - file_size[0]) / 2.0
    K[1, 2] += (height - file_size[1]) / 2.0
    return camera.replace(width=int(width), height=int(height), K=K)


def read_camera_tunnel(path: str | os.PathLike, width: int, height: int) -> Camera:
    """A camera-to-tunnel calibration (uPSP's JSON, or any camera file
    :func:`resection.io.cameras.read_camera` reads) for a video of ``width`` x ``height``
    pixels: a uPSP file's principal point follows the video's size as uPSP computes it
    (:func:`upsp_principal_point`)."""
    from resection.io.cameras import read_camera_file

    cf = read_camera_file(path, image_size=(width, height))
    if not cf.has_pose:
        raise InputError(f"{path}: an internal calibration (no rmat/tvec): a camera-to-tunnel "
                         "calibration is needed")
    cam = cf.camera
    if cf.format == "upsp":
        return upsp_principal_point(cam, (cam.width, cam.height), width, height)
    if (cam.width, cam.height) != (width, height):
        raise InputError(f"{path}: a {cam.width}x{cam.height} camera, the video is "
                         f"{width}x{height}")
    return cam
