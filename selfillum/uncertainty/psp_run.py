"""``selfillum psp --uncertainty``: the nominal chain and its budget by either method,
:func:`psp_uncertainty`."""

from __future__ import annotations

from resection.errors import InputError
from selfillum.uncertainty.noise import PixelNoise, estimate_noise
from selfillum.uncertainty.psp_chain import PSPInputs, run_chain

__all__ = ["psp_uncertainty", "noise_models", "METHODS"]

METHODS = ("linear", "mc")


def noise_models(stated, n_cameras: int, off_var=None, on_var=None, off=None, on=None):
    """Per camera ``(wind-off, wind-on)`` :class:`PixelNoise`: the stated gain and read
    noise, else estimated from the stacks' temporal variance (both conditions of a camera
    on one photon transfer curve), else None (missing)."""
    if stated.camera_gain is not None:
        pn = PixelNoise(stated.camera_gain, float(stated.read_noise or 0.0),
                        "stated" if stated.read_noise is not None
                        else "stated (camera gain; read noise not stated, taken as 0)")
        return [(pn, pn)] * n_cameras
    if off_var is None or on_var is None:
        return None
    out = []
    for c in range(n_cameras):
        vs = [v for v in (off_var[c], on_var[c]) if v is not None]
        ms = [m for m, v in ((off[c], off_var[c]), (on[c], on_var[c])) if v is not None]
        if not vs:
            return None
        pn = estimate_noise(ms, vs, f"camera {c + 1}'s frames")
        out.append((pn, pn))
    return out


def psp_uncertainty(inp: PSPInputs, stated, *, method: str = "linear", samples: int = 200,
                    noise=None, seed: int = 0, progress=None):
    """The nominal run and its budgets.

    Returns
    -------
    state : ChainState
        The nominal chain (its ``result`` is the :class:`selfillum.images.psp.PSPResult`).
    budgets : dict
        ``"p"`` and, with a ``.wtd``, ``"cp"``: :class:`selfillum.uncertainty.budget.Budget`.
    """
    from selfillum.uncertainty.psp_linear import linear_budget, model_sources

    if method not in METHODS:
        raise InputError(f"--uncertainty {method}: expected 'linear' or 'mc'")
    if method == "mc" and not samples >= 2:
        raise InputError(f"--samples {samples}: the Monte Carlo needs at least 2 samples")
    state = run_chain(inp)
    S = model_sources(inp, state, stated, noise)
    if method == "linear":
        return state, linear_budget(inp, state, S, stated)
    from selfillum.uncertainty.psp_mc import mc_budget

    return state, mc_budget(inp, state, S, stated, samples, seed, progress)
