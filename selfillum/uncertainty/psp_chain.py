"""The ``selfillum psp`` chain as the uncertainty methods see it: its inputs in one place
(:class:`PSPInputs`) and one run of the chain, with any input replaced by a drawn value
(:func:`run_chain`).

The chain is the one of :func:`selfillum.images.psp.psp_images`: the images merged onto the
faces (wind-on with the wind-off gains), the self-illumination removed from both
(:func:`selfillum.solve.radiosity.correct`), the ratio, the Stern-Volmer fit on the taps,
the pressure; with a ``.wtd``, ``Cp = (p - PS) / Q``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from resection.errors import InputError

__all__ = ["PSPInputs", "ChainState", "run_chain"]


@dataclass
class PSPInputs:
    """Everything the chain is computed from.

    Attributes
    ----------
    mesh : trimesh.Trimesh
    maps : list of SurfaceMap
        One per camera (the cameras' estimated poses).
    off, on : list of (H, W) float64
        Per camera, the mean wind-off / wind-on image (counts).
    off_frames, on_frames : list of int
        Frames averaged in each.
    taps : selfillum.images.psp.Taps
    p_ref : float
    F : sparse or None
        Form factors (None: no self-illumination removal).
    reflectance : (F,) float64 or None
    rays, seed : int
        Rays per face and seed of ``F`` (the Monte Carlo draws other seeds).
    tunnel : tuple or None
        ``(PS, Q, tap_cp)`` when the taps come from a ``.wtd``.
    markers : (M, 3) or None
        Marker positions for the poses' covariance.
    caster : RayCaster or None
        The mesh's Embree scene (reused by the Monte Carlo's maps and form factors).
    """

    mesh: object
    maps: list
    off: list
    on: list
    off_frames: list
    on_frames: list
    taps: object
    p_ref: float
    F: object = None
    reflectance: np.ndarray | None = None
    rays: int = 1024
    seed: int = 0
    tunnel: tuple | None = None
    markers: np.ndarray | None = None
    caster: object = None

    @property
    def correct_si(self) -> bool:
        return self.F is not None


@dataclass
class ChainState:
    """One run of the chain: what the uncertainty methods need of it."""

    result: object  # PSPResult
    merged_off: object
    merged_on: object
    seen: np.ndarray
    b_off: np.ndarray
    b_on: np.ndarray
    e_off: np.ndarray
    e_on: np.ndarray
    hidden_emission: tuple | None = None  # continuation of (off, on) on coupled hidden faces
    cp: np.ndarray | None = None
    extra: dict = field(default_factory=dict)


def _correct(F, b, rho, seen, mesh, unseen="continue"):
    from selfillum.solve.radiosity import correct

    kw = {} if seen.all() else {"mesh": mesh}
    return correct(F, np.where(seen, b, np.nan), rho, seen, unseen=unseen, **kw)


def run_chain(inp: PSPInputs, *, maps=None, off=None, on=None, F=None, reflectance=None,
              unseen_scale: float = 0.0, on_factor=None, tap_pressure=None,
              tunnel=None) -> ChainState:
    """The chain with the given inputs replaced (None: the nominal one).

    Parameters
    ----------
    unseen_scale : float
        The unseen faces emit ``1 + unseen_scale`` times the continuation.
    on_factor : (F,) array_like, optional
        Multiplies the wind-on emission (the paint's temperature response).
    tap_pressure : (M,) array_like, optional
        The taps' pressures (else from ``tunnel`` or the nominal taps).
    tunnel : tuple, optional
        ``(PS, Q)`` drawn (with a ``.wtd``): the taps' pressures are ``PS + Cp Q``.
    """
    from dataclasses import replace

    from resection.surface.merge import pixel_weights
    from selfillum.images.multiview import merge_views
    from selfillum.images.psp import psp_pressure

    maps = inp.maps if maps is None else maps
    off = inp.off if off is None else off
    on = inp.on if on is None else on
    pw = [pixel_weights(m, edge_margin=1) for m in maps]  # both merges' (the defaults)
    mo = merge_views(maps, off, pixel_weights_=pw)
    mn = merge_views(maps, on, gains=mo.gains, pixel_weights_=pw)
    seen = mo.seen & mn.seen
    if not seen.any():
        raise InputError("psp: no face is seen in both images")
    hidden = None
    if inp.correct_si:
        F = inp.F if F is None else F
        rho = inp.reflectance if reflectance is None else reflectance
        e_off = _correct(F, mo.values, rho, seen, inp.mesh)
        e_on = _correct(F, mn.values, rho, seen, inp.mesh)
        if not seen.all():
            hidden = (np.where(seen, np.nan, e_off), np.where(seen, np.nan, e_on))
            if unseen_scale:
                e_off = _correct(F, mo.values, rho, seen, inp.mesh,
                                 np.nan_to_num(hidden[0]) * (1.0 + unseen_scale))
                e_on = _correct(F, mn.values, rho, seen, inp.mesh,
                                np.nan_to_num(hidden[1]) * (1.0 + unseen_scale))
    else:
        e_off, e_on = np.where(seen, mo.values, np.nan), np.where(seen, mn.values, np.nan)
    if on_factor is not None:
        e_on = e_on * np.asarray(on_factor, np.float64)
    taps = inp.taps
    cp = None
    if tunnel is not None:
        ps, q = tunnel
        taps = replace(taps, pressure=ps + np.asarray(inp.tunnel[2]) * q)
    if tap_pressure is not None:
        taps = replace(taps, pressure=np.asarray(tap_pressure, np.float64))
    res = psp_pressure(inp.mesh, np.where(seen, e_off, np.nan), np.where(seen, e_on, np.nan),
                       taps, inp.p_ref, seen=seen, correct_si=False)
    res = replace(res, corrected=inp.correct_si)
    if inp.tunnel is not None:
        ps, q = (inp.tunnel[0], inp.tunnel[1]) if tunnel is None else tunnel
        cp = (res.pressure - ps) / q
    return ChainState(res, mo, mn, seen, np.where(seen, mo.values, np.nan),
                      np.where(seen, mn.values, np.nan), e_off, e_on, hidden, cp,
                      extra={"pixel_weights": pw})
