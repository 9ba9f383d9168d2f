"""Pressure-sensitive paint: wind-off / wind-on ratio, Stern-Volmer calibration on pressure
taps, pressure, with the self-illumination removed from both images first.

The luminescence ``I`` of PSP falls with the oxygen partial pressure, hence with the air
pressure ``p``. Against a *wind-off* image ``I_ref`` taken at a uniform reference pressure
``p_ref`` (same camera, same excitation), the Stern-Volmer law reads

``I_ref / I = A + B p / p_ref``,

which cancels the excitation non-uniformity and the paint thickness. ``A`` and ``B`` are
fitted by linear least squares to the ratio read at pressure taps (model positions with
known pressures), then every face gets ``p = p_ref (I_ref / I - A) / B``.

Self-illumination breaks the cancellation: a face also shows light emitted elsewhere, at
another pressure. Both images are therefore corrected to the faces' emission
(:func:`selfillum.solve.radiosity.correct`) before the ratio; ``correct_si=False`` gives the
uncorrected result for comparison.

Tap file (CSV with header): ``id,x,y,z,p`` (model units, pressure in any unit, the same as
``p_ref``).
"""

from __future__ import annotations

import csv
import os
import warnings
from dataclasses import dataclass

import numpy as np
import trimesh

from resection.errors import InputError
from selfillum.mesh import check_mesh
from selfillum.solve.radiosity import check_reflectance, correct

__all__ = ["SternVolmer", "Taps", "fit_stern_volmer", "check_fit_inputs", "read_taps",
           "tap_faces", "PSPResult",
           "psp_pressure", "psp_images"]


@dataclass(frozen=True)
class SternVolmer:
    """``I_ref / I = A + B p / p_ref``."""

    A: float
    B: float
    p_ref: float

    def pressure(self, ratio) -> np.ndarray:
        """Pressure from the intensity ratio ``I_ref / I``."""
        return self.p_ref * (np.asarray(ratio, dtype=np.float64) - self.A) / self.B

    def ratio(self, pressure) -> np.ndarray:
        """Intensity ratio ``I_ref / I`` at a pressure."""
        return self.A + self.B * np.asarray(pressure, dtype=np.float64) / self.p_ref


@dataclass(frozen=True)
class Taps:
    """Pressure taps: ``ids`` (str), ``points`` (M, 3) model coordinates, ``pressure`` (M,)."""

    ids: list
    points: np.ndarray
    pressure: np.ndarray


def read_taps(path: str | os.PathLike, positions=None) -> Taps:
    """Read a tap CSV file with the header ``id,x,y,z,p``, or ``id,p`` with the positions
    taken from ``positions``.

    Parameters
    ----------
    positions : path-like or resection.io.markers.MarkerSet, optional
        Where the taps are: a uPSP ``.tgts`` file (its ``*Taps`` or ``*Virtuals``/``*Kulites``
        sections, or any of its markers) or a marker CSV; needed when the tap file holds
        only ``id,p``, and for a ``.wtd``.

    A uPSP wind-tunnel data file (``.wtd``, :mod:`resection.io.wtd`) is read too: its
    ``# Tap CP`` table gives each tap's pressure ``p = PS + Cp Q`` (the file's units, psf
    at NASA Ames: ``p_ref`` must be in the same unit), and tap number ``n`` is the
    ``.tgts`` point named ``CPnn`` (1 -> ``CP01``; then ``CPn``, then ``n``:
    :func:`resection.io.wtd.tap_name`).
    """
    from resection.io.wtd import is_wtd

    path = os.fspath(path)
    if is_wtd(path):
        return _wtd_taps(path, positions)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.DictReader(fh))
            header = rows[0].keys() if rows else []
    except FileNotFoundError:
        raise InputError(f"tap file not found: {path}") from None
    if not rows:
        raise InputError(f"{path}: no taps")
    need = ("id", "x", "y", "z", "p") if set(header) != {"id", "p"} else ("id", "p")
    missing = [k for k in need if k not in header]
    unknown = [k for k in header if k not in need]
    if missing or unknown:
        raise InputError(f"{path}: expected the columns id,x,y,z,p (or id,p with tap "
                         "positions from a .tgts file)"
                         + (f"; missing {missing}" if missing else "")
                         + (f"; unknown {unknown}" if unknown else ""))
    ids = [r["id"] for r in rows]
    if len(set(ids)) != len(ids):
        raise InputError(f"{path}: duplicate tap ids")
    try:
        p = np.array([float(r["p"]) for r in rows])
        if need != ("id", "p"):
            pts = np.array([[float(r["x"]), float(r["y"]), float(r["z"])] for r in rows])
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: not a number ({exc})") from None
    if need == ("id", "p"):  # outside the try: a bad positions file names itself
        pts = _tap_positions(path, ids, positions)
    bad = np.flatnonzero(~np.isfinite(pts).all(axis=1))
    if bad.size:
        raise InputError(f"{path}: tap {ids[bad[0]]}: NaN or infinite coordinates")
    _check_pressures(path, ids, p)
    return Taps(ids, pts, p)


#: Largest steady Cp a tap may hold: uPSP's psp_process takes a steady Cp above 3 for no
#: data (NaN); a stagnation point reaches 1 at low speed, 1.84 at most (gamma 1.4).
MAX_TAP_CP = 3.0
#: A tap pressure this many times the median of the taps' is no reading (a unit slip, a
#: sentinel): the largest real ratio, a stagnation point against a suction peak at
#: Mach 3, is about 12.
MAX_TAP_SPREAD = 1000.0


def _check_pressures(path: str, ids: list, p: np.ndarray) -> None:
    """Each tap pressure a finite absolute pressure > 0 and within
    :data:`MAX_TAP_SPREAD` of the taps' median, else InputError naming the tap (before
    the fit, which would otherwise take the blame)."""
    bad = np.flatnonzero(~(np.isfinite(p) & (p > 0)))
    if bad.size:
        raise InputError(f"{path}: tap {ids[bad[0]]}: pressure {p[bad[0]]:g} is not a finite "
                         "absolute pressure > 0" + (f" ({bad.size} such taps)"
                                                    if bad.size > 1 else ""))
    med = float(np.median(p))
    far = np.flatnonzero((p > MAX_TAP_SPREAD * med) | (p < med / MAX_TAP_SPREAD))
    if far.size:
        k = far[np.argmax(np.abs(np.log(p[far] / med)))]
        raise InputError(f"{path}: tap {ids[k]}: pressure {p[k]:.4g} is {p[k] / med:.3g} "
                         f"times the taps' median {med:.4g}: not a reading (a unit or a "
                         "no-data value?)")


def _wtd_taps(path: str, positions) -> Taps:
    """Taps of a ``.wtd``'s ``# Tap CP`` table, named and placed through ``positions``."""
    from resection.io.markers import MarkerSet, read_markers
    from resection.io.wtd import NO_DATA_CP, read_wtd, tap_candidates, tap_name

    wtd = read_wtd(path)
    if not wtd.taps:
        if wtd.no_data_taps:
            raise InputError(f"{path}: all {len(wtd.no_data_taps)} taps hold the no-data Cp "
                             f"{NO_DATA_CP} (no tap was read for this point)")
        raise InputError(f"{path}: no '# Tap CP' table (no taps)")
    if wtd.wind_off:
        raise InputError(f"{path}: PS = Q = 0, a wind-off point ({wtd.label}); the taps' "
                         "Cp needs the wind-on point's PS and Q")
    q, ps = wtd.value("Q"), wtd.value("PS")
    if not q > 0:
        raise InputError(f"{path}: Q = {q:g}; the taps' Cp needs a dynamic pressure > 0")
    if wtd.no_data_taps:
        warnings.warn(f"{path}: {len(wtd.no_data_taps)} tap(s) hold the no-data Cp "
                      f"{NO_DATA_CP} and are left out (taps "
                      f"{', '.join(str(n) for n in wtd.no_data_taps[:10])}"
                      f"{', ...' if len(wtd.no_data_taps) > 10 else ''})",
                      UserWarning, stacklevel=2)
    if positions is None:
        raise InputError(f"{path}: a .wtd numbers its taps; give their positions "
                         "(--tap-positions MODEL.tgts)")
    ms = positions if isinstance(positions, MarkerSet) else \
        read_markers(positions, include_taps=True)
    ids, missing = [], []
    for n in wtd.taps:
        name = tap_name(n, ms.ids)
        (ids if name is not None else missing).append(name if name is not None else n)
    if missing:
        src = getattr(positions, "path", positions)
        raise InputError(f"{path}: tap(s) {', '.join(str(n) for n in missing[:10])} have no "
                         f"position in {src} (looked for "
                         f"{' / '.join(tap_candidates(missing[0]))})")
    cp = np.array(list(wtd.taps.values()), dtype=np.float64)
    high = np.flatnonzero(cp > MAX_TAP_CP)
    if high.size:
        n = list(wtd.taps)[high[0]]
        raise InputError(f"{path}: tap {n}: Cp {cp[high[0]]:g} is above {MAX_TAP_CP:g}, no "
                         "steady Cp (uPSP takes it for no data); fix or remove the row")
    with np.errstate(over="ignore"):
        p = ps + cp * q
    low = np.flatnonzero(~(p > 0))
    if low.size:
        n = list(wtd.taps)[low[0]]
        raise InputError(f"{path}: tap {n}: Cp {cp[low[0]]:g} gives PS + Cp Q = "
                         f"{p[low[0]]:g}, not an absolute pressure > 0")
    _check_pressures(path, ids, p)
    pos = {k: i for i, k in enumerate(ms.ids)}
    return Taps(ids, ms.xyz[[pos[k] for k in ids]], p)


def _tap_positions(path: str, ids: list, positions) -> np.ndarray:
    from resection.io.markers import MarkerSet, read_markers

    if positions is None:
        raise InputError(f"{path}: holds id,p only; give the tap positions (a .tgts file "
                         "with a *Taps section, or a marker file)")
    ms = positions if isinstance(positions, MarkerSet) else \
        read_markers(positions, include_taps=True)
    pos = {k: i for i, k in enumerate(ms.ids)}
    missing = [k for k in ids if k not in pos]
    if missing:
        raise InputError(f"{path}: tap id(s) not in the tap positions: "
                         f"{', '.join(missing[:10])}")
    return ms.xyz[[pos[k] for k in ids]]


def tap_faces(mesh: trimesh.Trimesh, points, max_distance: float | None = None) -> np.ndarray:
    """Face under each tap: the face of the closest point of the surface.

    Raises
    ------
    InputError
        A tap farther than ``max_distance`` (default 1 % of the mesh's size) from the
        surface.
    """
    check_mesh(mesh)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    closest, dist, faces = trimesh.proximity.closest_point(mesh, pts)
    limit = 0.01 * float(np.ptp(mesh.vertices, axis=0).max()) if max_distance is None \
        else float(max_distance)
    far = np.flatnonzero(dist > limit)
    if far.size:
        from resection.camera.units import spread_hint

        hint = spread_hint(pts, mesh.vertices, "the taps", "the mesh") if len(pts) > 1 else None
        raise InputError(f"tap {int(far[0])} is {dist[far[0]]:.3g} from the surface "
                         f"(more than {limit:.3g})" + (f": {hint}" if hint else ""))
    return np.asarray(faces, dtype=np.int64)


_ROUNDING_TOL = 1e-9  # a slope below this share of the ratios is rounding, not signal
def check_fit_inputs(taps: Taps, p_ref: float, source: str = "taps") -> None:
    """What the Stern-Volmer fit needs, checked before any heavy step: ``p_ref`` a finite
    pressure > 0 and the taps at 2 pressures at least (else ``B`` is undetermined; each
    tap's pressure is checked by :func:`read_taps`). ``source`` names the tap file in the
    messages.

    Raises
    ------
    InputError
    """
    try:
        pr = float(p_ref)
    except (TypeError, ValueError):
        raise InputError(f"p_ref {p_ref!r}: not a number") from None
    if not (np.isfinite(pr) and pr > 0):
        raise InputError(f"p_ref {p_ref:g}: the wind-off pressure must be a finite number > 0")
    p = np.asarray(taps.pressure, dtype=np.float64)
    if p.size < 2:
        raise InputError(f"{source}: {p.size} tap; the Stern-Volmer fit needs 2 at least")
    if np.ptp(p / pr) <= 1e-9 * max(1.0, float(np.abs(p / pr).max())):
        raise InputError(f"{source}: all {p.size} taps at the same pressure ({p[0]:g}): the "
                         "Stern-Volmer slope B is undetermined")


def fit_stern_volmer(ratio, pressure, p_ref: float) -> SternVolmer:
    """Least-squares ``A, B`` of ``ratio = A + B p / p_ref`` at the taps.

    Raises
    ------
    InputError
        Fewer than 2 taps with a finite ratio, all at the same pressure, ``p_ref <= 0``,
        a fitted ``B`` that is not significantly positive (``B <= 3`` standard errors with
        3 taps or more, or a ratio that does not vary).
    """
    r = np.asarray(ratio, dtype=np.float64).ravel()
    p = np.asarray(pressure, dtype=np.float64).ravel()
    if r.shape != p.shape:
        raise InputError(f"Stern-Volmer fit: {r.size} ratios for {p.size} pressures")
    if not (np.isfinite(p_ref) and p_ref > 0):
        raise InputError(f"p_ref {p_ref:g}: the wind-off pressure must be a finite number > 0")
    ok = np.isfinite(r) & np.isfinite(p)
    if ok.sum() < 2:
        raise InputError(f"Stern-Volmer fit: need at least 2 taps with a ratio (seen in "
                         f"both images), got {ok.sum()}")
    x = p[ok] / p_ref
    if np.ptp(x) <= 1e-9 * max(1.0, np.abs(x).max()):
        raise InputError("Stern-Volmer fit: all taps at the same pressure, B is undetermined")
    M = np.column_stack([np.ones_like(x), x])
    (A, B), *_ = np.linalg.lstsq(M, r[ok], rcond=None)
    # B must stand out of the scatter of the taps (3 standard errors, >= 3 taps) and of
    # the rounding of the fit itself: a ratio that does not vary at all (wind-on =
    # wind-off) gives B = +-1e-16, which is zero, not a sign. Tolerance stated here:
    # ROUNDING_TOL relative to the size of the ratios.
    se = 0.0
    if x.size > 2:
        res = r[ok] - (A + B * x)
        s2 = float(res @ res) / (x.size - 2)
        se = float(np.sqrt(s2 / np.sum((x - x.mean()) ** 2)))
    noise = max(3.0 * se, _ROUNDING_TOL * max(1.0, float(np.abs(r[ok]).max())))
    if B < -noise:
        raise InputError(f"Stern-Volmer fit: fitted B = {B:.3g} < 0 (standard error "
                         f"{se:.2g}): the ratio must grow with p (images swapped?)")
    if B <= noise:
        raise InputError(
            f"Stern-Volmer fit: fitted B = {B:.3g} (standard error {se:.2g}) is not "
            "significantly > 0: the intensity ratio at the taps does not follow their "
            "pressures (wrong images, taps or p_ref?)"
        )
    return SternVolmer(float(A), float(B), float(p_ref))


@dataclass(frozen=True)
class PSPResult:
    """Pressure on the faces and what it came from.

    Attributes
    ----------
    pressure : (F,) ndarray
        Pressure per face (NaN where unknown).
    ratio : (F,) ndarray
        ``I_ref / I`` per face (SI-corrected when ``corrected``).
    stern_volmer : SternVolmer
        The fitted law.
    tap_faces : (M,) ndarray
        Face of each tap.
    tap_residuals : (M,) ndarray
        Fitted minus tap pressure at the taps.
    corrected : bool
        Whether the self-illumination was removed.
    """

    pressure: np.ndarray
    ratio: np.ndarray
    stern_volmer: SternVolmer
    tap_faces: np.ndarray
    tap_residuals: np.ndarray
    corrected: bool


def psp_pressure(
    mesh: trimesh.Trimesh,
    wind_off,
    wind_on,
    taps: Taps,
    p_ref: float,
    *,
    F=None,
    reflectance=None,
    seen=None,
    correct_si: bool = True,
) -> PSPResult:
    """Pressure on the faces from wind-off and wind-on per-face intensities.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The model.
    wind_off, wind_on : (F,) array_like
        Per-face intensity (e.g. :meth:`resection.surface.surface_map.SurfaceMap.to_surface` of the
        images, or :func:`resection.surface.merge.merge_views`), proportional to radiance.
        NaN on faces not seen.
    taps : Taps
        Tap positions and pressures.
    p_ref : float
        Pressure of the wind-off image.
    F : sparse (F, F), optional
        Form factors; required with ``correct_si``.
    reflectance : float or (F,) array_like, optional
        Paint reflectance; required with ``correct_si``.
    seen : (F,) bool, optional
        Faces with a measurement in both images (default: finite in both).
    correct_si : bool
        Remove the self-illumination from both images before the ratio.

    Returns
    -------
    PSPResult
    """
    check_mesh(mesh)
    n = len(mesh.faces)
    off = np.asarray(wind_off, dtype=np.float64)
    on = np.asarray(wind_on, dtype=np.float64)
    if off.shape != (n,) or on.shape != (n,):
        raise InputError(f"psp_pressure: wind_off and wind_on must have one value per face "
                         f"({n}), got {off.shape} and {on.shape}")
    if not isinstance(taps, Taps):
        raise InputError(f"psp_pressure: taps must be a Taps, got {type(taps).__name__}")
    mask = np.isfinite(off) & np.isfinite(on) if seen is None else np.asarray(seen, bool)
    if mask.shape != (n,):
        raise InputError(f"psp_pressure: seen must have shape ({n},)")
    if not mask.any():
        raise InputError("no face of the model is seen in both the wind-off and the wind-on "
                         "images")
    if correct_si:
        if F is None or reflectance is None:
            raise InputError("psp_pressure: correct_si needs the form factors F and the "
                             "reflectance")
        rho = check_reflectance(reflectance, n)
        kw = {} if mask.all() else {"mesh": mesh}
        e_off = correct(F, np.where(mask, off, np.nan), rho, mask, **kw)
        e_on = correct(F, np.where(mask, on, np.nan), rho, mask, **kw)
    else:
        e_off, e_on = off, on
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(mask & (e_on > 0), e_off / e_on, np.nan)
    tf = tap_faces(mesh, taps.points)
    law = fit_stern_volmer(ratio[tf], taps.pressure, p_ref)
    pressure = law.pressure(ratio)
    return PSPResult(pressure, ratio, law, tf, pressure[tf] - taps.pressure, bool(correct_si))


def psp_images(
    maps,
    wind_off_images,
    wind_on_images,
    taps: Taps,
    p_ref: float,
    *,
    F=None,
    reflectance=None,
    correct_si: bool = True,
) -> tuple[PSPResult, list]:
    """The PSP workflow from camera images: one or several cameras, wind-off and wind-on.

    Each camera's images are mapped onto the faces and merged over the cameras
    (:func:`resection.surface.merge.merge_views`: feathered weights, obliqueness cut-off, camera
    gains matched on the wind-off overlaps and reused wind-on), the pressure is
    computed on the faces seen in both merged images (:func:`psp_pressure`) and
    backprojected into every camera (interpolated over the surface).

    Parameters
    ----------
    maps : sequence of resection.surface.surface_map.SurfaceMap
        One per camera, all of the same mesh. The model is assumed not to move between
        wind-off and wind-on (align the images first otherwise).
    wind_off_images, wind_on_images : sequence of (H_c, W_c) arrays
        One image per camera each, dark level removed.
    taps, p_ref, F, reflectance, correct_si
        As in :func:`psp_pressure`.

    Returns
    -------
    result : PSPResult
        Per-face pressure and the fitted law.
    images : list of (H_c, W_c) float64 arrays
        Pressure seen by each camera (NaN off the model and on faces without pressure).
    """
    from resection.surface.merge import merge_views

    maps = list(maps)
    if not maps:
        raise InputError("psp_images: no camera given")
    off = merge_views(maps, wind_off_images)
    on = merge_views(maps, wind_on_images, gains=off.gains)
    mesh = maps[0].mesh
    res = psp_pressure(mesh, off.values, on.values, taps, p_ref, F=F, reflectance=reflectance,
                       seen=off.seen & on.seen, correct_si=correct_si)
    images = [m.to_image(res.pressure) for m in maps]
    return res, images
