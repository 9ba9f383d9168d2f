"""Heat flux into the model from its surface temperature history, per node, batched over
nodes (a block of node histories is one ``(frames, nodes)`` array).

Methods (``method``):

- ``"cook-felderman"``: the 1-D semi-infinite substrate's closed-form discrete inverse
  (Cook and Felderman 1966; the surface temperature taken linear between samples)::

      q_n = 2 e / sqrt(pi) sum_{i=1..n} (T_i - T_{i-1}) / (sqrt(t_n - t_i) + sqrt(t_n - t_{i-1}))

  with the thermal effusivity ``e = sqrt(rho c k)``; for equal time steps a convolution
  (FFT along time, every node of the block at once).
- ``"impulse"``: the impulse-response method (Oldfield 2008): the substrate's temperature
  response to a unit heat-flux ramp ``R(t)`` (closed form ``4 t^1.5 / (3 sqrt(pi) e)`` for
  a semi-infinite body; for layers on a base, the exact 1-D transfer function of the
  layers inverted numerically, :func:`step_response`) gives the response of a heat flux
  linear between frames (a sum of hats, ``q(t_0) = 0``), ``T_n - T_0 = sum_i q_i w_{n-i}``
  (:func:`hat_response`); the inverse of that lower-triangular Toeplitz system, solved once
  for the run, is the impulse response ``h`` and ``q = h * (T - T_0)`` (FFT along time, a
  block of nodes at once). A heat flux linear in time is recovered exactly; a step at
  ``t_0`` (not linear over the first interval) rings for a few samples (module tests:
  within 1 % from the 6th sample). This is the method for a TSP or insulating layer on a
  substrate.

Limits, stated: conduction is 1-D, normal to the surface (lateral conduction along the
model is neglected; it matters where the heat flux changes over lengths comparable to the
heat's penetration depth ``sqrt(alpha t)``); the model is at one uniform temperature at the
first frame (``T_0``), and the heat flux is zero before it; a base without ``thickness`` is
semi-infinite (valid while ``sqrt(alpha t)`` stays well under the real wall's thickness),
a base with ``thickness`` has an insulated back face.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from resection.errors import InputError
from selfillum.thermal.jsonfile import number, read_object

__all__ = ["Layer", "Substrate", "read_substrate", "step_response", "cook_felderman",
           "impulse_heat_flux", "heat_flux", "surface_temperature", "METHODS"]

METHODS = ("cook-felderman", "impulse")


@dataclass(frozen=True)
class Layer:
    """A material: density ``rho`` (kg/m^3), specific heat ``c`` (J/kg/K), conductivity
    ``k`` (W/m/K), ``thickness`` (m; None: semi-infinite)."""

    rho: float
    c: float
    k: float
    thickness: float | None = None

    @property
    def effusivity(self) -> float:
        """``e = sqrt(rho c k)`` (W s^0.5 / m^2 / K)."""
        return float(np.sqrt(self.rho * self.c * self.k))

    @property
    def diffusivity(self) -> float:
        """``alpha = k / (rho c)`` (m^2/s)."""
        return self.k / (self.rho * self.c)


@dataclass(frozen=True)
class Substrate:
    """``layers`` (top first, each with a thickness) on a ``base``."""

    base: Layer
    layers: tuple = ()

    @property
    def semi_infinite(self) -> bool:
        """One semi-infinite material, no layer: Cook-Felderman applies."""
        return not self.layers and self.base.thickness is None


def _layer(d, where: str, *, need_thickness: bool) -> Layer:
    if not isinstance(d, dict):
        raise InputError(f"{where}: expected an object with rho, c, k")
    vals = {key: number(d, key, where, positive=True) for key in ("rho", "c", "k")}
    th = number(d, "thickness", where, positive=True) if d.get("thickness") is not None \
        else None
    if th is None and need_thickness:
        raise InputError(f"{where}: a layer needs its thickness (m)")
    unknown = set(d) - {"rho", "c", "k", "thickness", "name"}
    if unknown:
        raise InputError(f"{where}: unknown key {sorted(unknown)[0]!r}")
    return Layer(vals["rho"], vals["c"], vals["k"], th)


def read_substrate(path) -> Substrate:
    """A substrate file (JSON): ``{"rho": ..., "c": ..., "k": ...}`` (SI; a semi-infinite
    body, or with ``thickness`` a slab with an insulated back), or ``{"layers": [{"rho",
    "c", "k", "thickness"}, ...], "substrate": {"rho", "c", "k"[, "thickness"]}}`` (layers
    top first)."""
    d = read_object(path, "substrate file")
    p = Path(path)
    if "layers" in d:
        if not isinstance(d["layers"], list) or not d["layers"]:
            raise InputError(f"{p}: layers must be a non-empty list")
        if "substrate" not in d:
            raise InputError(f"{p}: layers need the substrate they lie on")
        layers = tuple(_layer(x, f"{p}: layer {i + 1}", need_thickness=True)
                       for i, x in enumerate(d["layers"]))
        return Substrate(_layer(d["substrate"], f"{p}: substrate", need_thickness=False),
                         layers)
    return Substrate(_layer(d, str(p), need_thickness=False))


# ------------------------------------------------------------------ the step response
def _impedance(sub: Substrate, s: np.ndarray) -> np.ndarray:
    """Surface temperature over surface heat flux in Laplace space, ``Z(s)`` (K m^2/W s):
    the base's impedance carried up through each layer's exact transfer matrix."""
    b = sub.base
    g = np.sqrt(s / b.diffusivity)
    if b.thickness is None:
        Z = 1.0 / (b.k * g)
    else:
        Z = 1.0 / (b.k * g * _tanh(g * b.thickness))
    for L in reversed(sub.layers):  # from the base up
        g = np.sqrt(s / L.diffusivity)
        th = _tanh(g * L.thickness)
        kg = L.k * g
        Z = (Z + th / kg) / (kg * th * Z + 1.0)
    return Z


def _tanh(z: np.ndarray) -> np.ndarray:
    """Complex tanh without overflow (1 where the real part is large)."""
    big = z.real > 20.0
    return np.where(big, 1.0 + 0j, np.tanh(np.where(big, 0.0, z)))


#: Terms of the fixed-Talbot Laplace inversion (Abate and Valko 2004): about 1e-10
#: relative in double precision for these smooth responses.
TALBOT_M = 32


def step_response(sub: Substrate, t, ramp: bool = False) -> np.ndarray:
    """Surface temperature rise (K) at times ``t`` (s) for a unit heat-flux step (1 W/m^2)
    from ``t = 0`` (``ramp``: for a heat flux rising at 1 W/m^2/s): ``2 sqrt(t) / (sqrt(pi)
    e)`` (ramp ``4 t^1.5 / (3 sqrt(pi) e)``) for a semi-infinite body, else the inverse
    Laplace transform of ``Z(s) / s`` (``Z(s) / s^2``) by the fixed Talbot contour."""
    t = np.asarray(t, dtype=np.float64)
    out = np.zeros(t.shape)
    pos = t > 0
    if sub.semi_infinite:
        c = np.sqrt(np.pi) * sub.base.effusivity
        out[pos] = 4.0 * t[pos] ** 1.5 / (3.0 * c) if ramp else 2.0 * np.sqrt(t[pos]) / c
        return out
    tp = t[pos][:, None]
    M = TALBOT_M
    th = np.arange(1, M) * np.pi / M
    cot = 1.0 / np.tan(th)
    r = 2.0 * M / (5.0 * tp)  # (n, 1)
    s = r * th * (cot + 1j)  # (n, M-1)
    sig = th + (th * cot - 1.0) * cot
    p = 2 if ramp else 1
    F0 = (_impedance(sub, r.astype(complex)) / r**p).real
    Fk = _impedance(sub, s) / s**p
    val = 0.5 * F0 * np.exp(r * tp) + np.sum(
        (np.exp(tp * s) * Fk * (1.0 + 1j * sig)).real, axis=1, keepdims=True)
    out[pos] = (r / M * val)[:, 0]
    return out


def hat_response(sub: Substrate, n: int, dt: float) -> np.ndarray:
    """``w`` (``(n - 1,)``, K m^2/W): the surface temperature ``m`` steps after the peak of
    a unit hat of heat flux (1 W/m^2 at one frame, linear to 0 at the frames on either
    side): ``(R(t + dt) - 2 R(t) + R(t - dt)) / dt`` with ``R`` the ramp response."""
    m = np.arange(n, dtype=np.float64)
    R = step_response(sub, m * dt, ramp=True)  # R[0] = 0 and R(-dt) = 0
    Rm1 = np.concatenate([[0.0], R[:-1]])
    return (R[1:] - 2.0 * R[:-1] + Rm1[:-1]) / dt


def surface_temperature(sub: Substrate, q, dt: float) -> np.ndarray:
    """The forward problem: surface temperature rise (K) at ``t_n = n dt`` for a heat flux
    (W/m^2, ``(n,)`` or ``(n, m)``) linear between the frames' values ``q`` (``q[0]``
    taken as 0)."""
    q = np.asarray(q, dtype=np.float64)
    n = q.shape[0]
    dT = _convolve_time(q[1:], hat_response(sub, n, dt))
    return np.concatenate([np.zeros((1,) + q.shape[1:]), dT])


# ------------------------------------------------------------------ the inverses
def _convolve_time(x, kernel) -> np.ndarray:
    """The first ``len(x)`` samples of the linear convolution of ``x`` (``(n,)`` or
    ``(n, m)``, along time) with ``kernel`` (``(n,)``): one real FFT along time for the
    whole block of nodes (the kernel's once)."""
    from scipy import fft

    n = x.shape[0]
    L = fft.next_fast_len(2 * n - 1, real=True)
    K = fft.rfft(kernel, L)
    X = fft.rfft(x, L, axis=0)
    X *= K.reshape((-1,) + (1,) * (x.ndim - 1))
    return fft.irfft(X, L, axis=0)[:n]


def _check_T(T, dt):
    T = np.asarray(T, dtype=np.float64)
    if T.ndim not in (1, 2) or T.shape[0] < 2:
        raise InputError(f"temperature history: need (frames, nodes) with 2 frames or "
                         f"more, got {T.shape}")
    if not (np.isfinite(dt) and dt > 0):
        raise InputError(f"time step {dt} s must be positive")
    return T


def cook_felderman(T, dt: float, effusivity: float) -> np.ndarray:
    """Heat flux (W/m^2) at every sample by Cook-Felderman (module notes): ``T`` (K),
    ``(frames,)`` or ``(frames, nodes)`` at equal steps ``dt`` (s); ``q[0] = 0``."""
    T = _check_T(T, dt)
    n = T.shape[0]
    m = np.arange(n - 1, dtype=np.float64)
    q = _convolve_time(np.diff(T, axis=0), 1.0 / (np.sqrt(m) + np.sqrt(m + 1.0)))
    q *= 2.0 * effusivity / np.sqrt(np.pi * dt)
    return np.concatenate([np.zeros((1,) + T.shape[1:]), q])


def impulse_response(sub: Substrate, n: int, dt: float) -> np.ndarray:
    """``h`` (``(n - 1,)``, W/m^2/K): the inverse of the discrete response ``w`` (module
    notes), the first column of the inverse of its lower-triangular Toeplitz matrix."""
    a = hat_response(sub, n, dt)
    h = np.zeros(n - 1)
    if n < 2:
        return h
    h[0] = 1.0 / a[0]
    for m in range(1, n - 1):  # one dot product a sample of the kernel (not of the data)
        h[m] = -np.dot(a[m:0:-1], h[:m]) / a[0]
    return h


def impulse_heat_flux(T, dt: float, sub: Substrate, h=None) -> np.ndarray:
    """Heat flux (W/m^2) at every sample by the impulse-response method (module notes);
    ``h`` from :func:`impulse_response` when already built for this length and step."""
    T = _check_T(T, dt)
    n = T.shape[0]
    h = impulse_response(sub, n, dt) if h is None else h
    q = _convolve_time(T[1:] - T[:1], h)
    return np.concatenate([np.zeros((1,) + T.shape[1:]), q])


def heat_flux(T, dt: float, sub: Substrate, method: str | None = None, h=None) -> np.ndarray:
    """Heat flux (W/m^2) from surface temperature histories ``T`` (K, ``(frames, nodes)``)
    at equal steps ``dt`` (s). ``method``: ``"cook-felderman"`` (a semi-infinite body
    only) or ``"impulse"``; default Cook-Felderman for a semi-infinite body, the impulse
    response otherwise. NaN samples (unseen) make the node's flux NaN from there on."""
    method = method or ("cook-felderman" if sub.semi_infinite else "impulse")
    if method not in METHODS:
        raise InputError(f"heat-flux method {method!r} unknown (one of {', '.join(METHODS)})")
    if method == "cook-felderman":
        if not sub.semi_infinite:
            raise InputError("Cook-Felderman needs one semi-infinite material; layers or a "
                             "finite base take method 'impulse'")
        return cook_felderman(T, dt, sub.base.effusivity)
    return impulse_heat_flux(T, dt, sub, h=h)


def fill_gaps(T) -> tuple[np.ndarray, np.ndarray]:
    """``(T filled, usable)``: gaps of unseen samples (NaN) inside each node's history
    filled linearly in time between the seen samples around them, trailing ones held at the
    last seen value; ``usable`` (nodes,) is False for a node unseen at the first frame (no
    initial temperature) or never seen. Vectorized over nodes (indices by running maxima)."""
    T = np.asarray(T, dtype=np.float64)
    fin = np.isfinite(T)
    if T.ndim == 2 and T.shape[0]:  # only the nodes with a gap (most are seen throughout)
        gap = ~fin.all(axis=0)
        if not gap.any():
            return T, np.ones(T.shape[1], bool)
        if not gap.all():
            out, usable = T.copy(), np.ones(T.shape[1], bool)
            out[:, gap], usable[gap] = fill_gaps(T[:, gap])
            return out, usable
    n = T.shape[0]
    idx = np.arange(n)[:, None] * np.ones((1, T.shape[1]), dtype=np.int64)
    prev = np.maximum.accumulate(np.where(fin, idx, -1), axis=0)
    nxt = np.minimum.accumulate(np.where(fin, idx, n)[::-1], axis=0)[::-1]
    usable = fin[0] if n else np.zeros(T.shape[1], bool)
    p = np.clip(prev, 0, n - 1)
    q = np.where(nxt < n, nxt, p)
    Tp = np.take_along_axis(np.where(fin, T, 0.0), p, axis=0)
    Tq = np.take_along_axis(np.where(fin, T, 0.0), q, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(q > p, (idx - p) / np.maximum(q - p, 1), 0.0)
    out = np.where(fin, T, Tp + w * (Tq - Tp))
    out[:, ~usable] = np.nan
    return out, usable
