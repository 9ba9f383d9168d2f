"""The unsteady run's uncertainty per node (``selfillum unsteady --uncertainty``).

``dCp = (I' - fit) Gain 144 / q`` (:mod:`selfillum.unsteady.phase2`). Two parts:

* **random, frame by frame** (``/dcp_u``): what changes from one frame to the next and is
  not signal. Without a stated camera gain it is measured on the run itself: the noise of
  a frame is white, so its level is the Welch PSD of dCp in the highest frequency band
  (``--psd-bands``), ``N0`` (dCp^2/Hz, ``/psd/noise_floor``), and its variance
  ``sigma^2 = N0 fs / 2`` (:func:`noise_from_floor`). This holds the pixels' shot and read
  noise and any other error that is white over the frames (a pose that jitters from frame
  to frame, the uint16 rounding of the work file); a signal that reaches the highest band
  makes it an over-estimate, an error slower than that band (a drift left by the order-6
  detrend, the vibration's own frequency) is not in it. With ``--u camera_gain=``
  (and ``read_noise=``) the pixel noise model is propagated instead
  (:func:`noise_from_camera`: the node's intensity and its number of pixels).
* **systematic, the gain** (``/dcp_u_gain``, relative, the same in every frame): uPSP's gain
  coefficients' stated uncertainties, the surface temperature's (``T0``, ``Tinf``, the
  model) through ``dGain / dT``, ``q`` and ``p_inf`` through ``Pss`` and ``144 / q``
  (:func:`gain_relative_u`); without a gain file, the in-situ Stern-Volmer fit's
  covariance from its residuals at the taps (:func:`insitu_relative_u`).

The RMS of dCp over the frames holds the noise's variance: ``/stats/dcp_rms_signal`` is
``sqrt(max(rms^2 - sigma^2, 0))``, with its standard uncertainty
``/stats/dcp_rms_signal_u`` from the spread of a mean square over ``T`` frames
(``2 rms^4 / T``) and of the floor's estimate (``sigma^2`` over the Welch bins and segments
of the band) (:func:`signal_rms`); the gain's part scales it by ``1 +- dcp_u_gain``.
"""

from __future__ import annotations

import numpy as np

from selfillum.uncertainty import calibration as cal
from selfillum.uncertainty.temperature import surface_u
from selfillum.uncertainty.tunnel import gain_factor_relative_u

__all__ = ["noise_from_floor", "noise_from_camera", "gain_relative_u", "signal_rms",
           "floor_dof", "insitu_covariance", "insitu_relative_u"]


def noise_from_floor(band_psd, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """``(sigma, floor)`` per node from ``band_psd`` (N, B): the highest band's level
    ``floor`` (dCp^2/Hz) and ``sigma = sqrt(floor fps / 2)``."""
    floor = np.asarray(band_psd, np.float64)[:, -1]
    return np.sqrt(floor * fps / 2.0), floor


def floor_dof(freq, edges, n_frames: int, nperseg: int) -> float:
    """Degrees of freedom of the top band's level: 2 per Welch bin and segment (half
    overlap: about ``2 T / nperseg - 1`` segments, taken as independent)."""
    f = np.asarray(freq)
    bins = int(np.sum((f >= edges[-2]) & (f <= edges[-1])))
    segs = max(1, 2 * n_frames // max(nperseg, 1) - 1)
    return 2.0 * max(bins, 1) * segs


def noise_from_camera(mean_intensity, pixels, gain: float, read_noise: float,
                      gain_factor) -> np.ndarray:
    """``sigma`` of a frame's dCp per node from the pixel noise model: a node of mean
    intensity ``I`` (counts) made of ``pixels`` (the effective number, ``(sum w)^2 / sum
    w^2``) has ``var(I) = (I / g + (r / g)^2) / pixels`` and ``dCp = I' G 144 / q`` with
    ``I' ~ 1``: ``sigma = gain_factor sqrt(var(I)) / I``."""
    I = np.asarray(mean_intensity, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        var = (np.maximum(I, 0) / gain + (read_noise / gain) ** 2) / np.asarray(pixels)
        return np.asarray(gain_factor) * np.sqrt(var) / I


def gain_relative_u(coeffs, stated, T: float, cp, q: float,
                    p_inf: float) -> tuple[np.ndarray | None, dict]:
    """Relative standard uncertainty of ``Gain 144 / q`` per node and the status of each
    part (``gain``, ``temperature``, ``tunnel``), None when nothing is stated.

    Parameters
    ----------
    coeffs : (6,) ``a .. f`` of uPSP's gain, or ``("insitu", law, tap_ratio, tap_pressure)``
        for the in-situ Stern-Volmer fit (:func:`insitu_relative_u`).
    T : float
        Surface temperature, deg F.
    """
    cp = np.asarray(cp, np.float64)
    if coeffs is not None and len(coeffs) == 4 and coeffs[0] == "insitu":
        return insitu_relative_u(coeffs[1], coeffs[2], coeffs[3], stated, cp, q, p_inf)
    status = {}
    parts = []
    pss = cp * q + p_inf
    a, b, c, d, e, f_ = (float(v) for v in coeffs)
    G = a + b * T + c * T**2 + (d + e * T + f_ * T**2) * pss
    uc = stated.gain_coefficients()
    if uc is not None:
        parts.append(cal.gain_coefficients_u(uc, T, pss) / G)
        status["gain"] = "stated"
    else:
        status["gain"] = "missing: give --u gain_a= .. gain_f="
    uT = surface_u(stated.t0, stated.tinf, stated.temperature)
    if uT is not None:
        parts.append(np.abs(cal.gain_temperature_slope(coeffs, T, pss)) * uT * 1.8 / G)
        status["temperature"] = "stated"
    else:
        status["temperature"] = "missing: give --u t0=..K (tinf=, temperature=)"
    if stated.q is not None or stated.p_inf is not None:
        parts.append(gain_factor_relative_u(G, cal.gain_pressure_slope(coeffs, T), cp, q,
                                            stated.q, stated.p_inf))
        status["tunnel"] = "stated"
    else:
        status["tunnel"] = "missing: give --u q=..psf p_inf=..psf"
    if not parts:
        return None, status
    return np.sqrt(sum(p * p for p in parts)), status


def insitu_covariance(law, tap_ratio, tap_pressure) -> np.ndarray:
    """(2, 2) covariance of the in-situ fit's ``(A, B)`` from its residuals at the taps
    (``s^2 (M^T M)^-1``, the taps the fit used)."""
    r = np.asarray(tap_ratio, np.float64)
    p = np.asarray(tap_pressure, np.float64)
    ok = np.isfinite(r) & np.isfinite(p)
    M, _ = cal.design(p[ok], law.p_ref)
    return cal.residual_covariance(M, r[ok] - law.ratio(p[ok]))


def insitu_relative_u(law, tap_ratio, tap_pressure, stated, cp, q: float, p_inf: float):
    """The in-situ gain ``G = (A p_ref / B + Pss) / 144``: its relative uncertainty from the
    fit's covariance (``dG = p_ref / 144 (dA / B - A dB / B^2)``), and from ``q`` and
    ``p_inf`` through ``Pss`` and ``144 / q``. A temperature common to the wind-off images and
    the run scales the ratios alike and is absorbed by the fit."""
    C = insitu_covariance(law, tap_ratio, tap_pressure)
    pss = cp * q + p_inf
    G = (law.A * law.p_ref / law.B + pss) / 144.0
    g = np.array([1.0 / law.B, -law.A / law.B**2]) * law.p_ref / 144.0
    parts = [np.sqrt(max(float(g @ C @ g), 0.0)) / G]
    status = {"gain": "estimated: the in-situ fit's residuals at the taps",
              "temperature": "zero: a common temperature is absorbed by the fit on the taps"}
    if stated.q is not None or stated.p_inf is not None:
        parts.append(gain_factor_relative_u(G, np.full_like(G, 1.0 / 144.0), cp, q,
                                            stated.q, stated.p_inf))
        status["tunnel"] = "stated"
    else:
        status["tunnel"] = "missing: give --u q=..psf p_inf=..psf"
    return np.sqrt(sum(p * p for p in parts)), status


def signal_rms(rms, sigma, n_frames: int, dof: float) -> tuple[np.ndarray, np.ndarray]:
    """``(rms_signal, u)``: the RMS of dCp without the noise's variance, and its standard
    uncertainty from the mean square's spread over ``n_frames`` and the noise variance's
    over ``dof`` degrees of freedom."""
    ms = np.asarray(rms, np.float64) ** 2
    s2 = np.asarray(sigma, np.float64) ** 2
    sig2 = np.maximum(ms - s2, 0.0)
    var_ms = 2.0 * ms * ms / max(n_frames, 1)
    var_s2 = 2.0 * s2 * s2 / max(dof, 1.0)
    u2 = np.sqrt(var_ms + var_s2)  # of rms_signal^2
    rs = np.sqrt(sig2)
    with np.errstate(invalid="ignore", divide="ignore"):
        # near zero, the square root's derivative diverges: the uncertainty of rs is at
        # most sqrt(u2) (rs^2 within u2 of 0)
        u = np.minimum(u2 / (2.0 * rs), np.sqrt(u2))
    return rs, u
