"""One acceptance rule for poses, matches, tracked frames and calibrations.

Every fit of the package that turns marker positions into a camera (``solve_pose``,
``match_markers``, ``pose --image``, ``track``, ``calibrate``) ends with the same decision,
made here:

1. **Stated accuracy.** ``marker_accuracy`` (px, default 1) is the RMS length of the error of
   one marker's position as the fit sees it: the survey error of its model coordinates,
   projected into the image, combined with the detection noise. It is taken as isotropic
   Gaussian noise of standard deviation ``marker_accuracy / sqrt(2)`` on each of ``u`` and
   ``v``.
2. **Gross outliers** are markers whose error exceeds what ``n`` such markers reach with a
   probability of 1e-3 (:func:`outlier_gate`: ``sigma sqrt(2 ln(n / 1e-3))``, about 3.1 px
   for 15 markers at 1 px). They are named and dropped, the worst first and the fit
   repeated, within limits (:func:`outlier_limit`: at most a fifth of the markers, and
   never below five used markers). More than that is a refusal.
3. **Residual test.** With ``dof = 2 n - p`` degrees of freedom (``p`` fitted parameters),
   ``sum(e**2) / sigma**2`` follows a chi-square law; the fit is accepted when the RMS
   residual of the used markers is at most its 99.9 % bound
   ``marker_accuracy sqrt(chi2_0.999(dof) / (2 n))`` and at most ``max_rms`` (default 2 px:
   the paper's guide, "over 2 px something is wrong"). With ``dof = 0`` nothing can be
   judged and the fit is accepted as exact.
4. **Ambiguity** (two poses or two matchings that fit alike) is refused by the solver or
   matcher itself, before this rule.

The result states the tested statistic (the RMS of the used markers), its threshold and
the paper's grade: about 0.2 px is good PSP, 0.4 px good IRT, over 2 px something is wrong.
The rule is written down for users in ``docs/acceptance.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc, chdtri

from resection.defaults import DEFAULT_MARKER_ACCURACY, DEFAULT_MAX_RMS
from resection.errors import InputError, SolveError

__all__ = ["Acceptance", "DEFAULT_MARKER_ACCURACY", "DEFAULT_MAX_RMS", "CONFIDENCE",
           "OUTLIER_RISK", "check_accuracy", "rms_threshold", "outlier_gate",
           "outlier_limit", "grade", "judge", "require", "drop_outliers"]

#: Confidence of the residual test (probability that a correct fit passes).
CONFIDENCE = 0.999
#: Probability that one of the ``n`` correct markers is taken for a gross outlier.
OUTLIER_RISK = 1e-3
#: The paper's guide: RMS residual (px) and what it means.
GUIDE = ((0.2, "good PSP"), (0.4, "good IRT"), (2.0, "usable"))


def check_accuracy(marker_accuracy, who: str = "marker_accuracy") -> float:
    """``marker_accuracy`` as a positive float, or an :class:`InputError` naming ``who``."""
    try:
        a = float(marker_accuracy)
    except (TypeError, ValueError):
        raise InputError(f"{who}: marker_accuracy must be a number of pixels, got "
                         f"{marker_accuracy!r}") from None
    if not (math.isfinite(a) and a > 0):
        raise InputError(f"{who}: marker_accuracy must be positive, got {marker_accuracy}")
    return a


def grade(rms: float) -> str:
    """The paper's reading of an RMS residual (px): good PSP (<= 0.2), good IRT (<= 0.4),
    usable (<= 2) or 'something is wrong' (> 2)."""
    for limit, text in GUIDE:
        if rms <= limit:
            return text
    return "something is wrong"


def rms_threshold(n_used: int, n_params: int, marker_accuracy: float = DEFAULT_MARKER_ACCURACY,
                  max_rms: float | None = DEFAULT_MAX_RMS,
                  confidence: float = CONFIDENCE) -> float:
    """Largest accepted RMS residual (px) of ``n_used`` markers after fitting ``n_params``
    parameters: ``min(marker_accuracy sqrt(chi2_q(dof) / (2 n)), max_rms)``; ``inf`` (or
    ``max_rms``) when ``dof = 2 n - p <= 0``."""
    dof = 2 * n_used - n_params
    bound = math.inf
    if dof > 0:
        bound = marker_accuracy * math.sqrt(chdtri(dof, 1.0 - confidence) / (2.0 * n_used))
    return min(bound, max_rms) if max_rms is not None else bound


def outlier_gate(n: int, marker_accuracy: float = DEFAULT_MARKER_ACCURACY) -> float:
    """Error (px) above which a marker is a gross outlier: the length that ``n`` markers of
    accuracy ``marker_accuracy`` exceed with probability ``OUTLIER_RISK`` (Rayleigh law:
    ``sigma sqrt(2 ln(n / risk))``, ``sigma = marker_accuracy / sqrt(2)``)."""
    sigma = marker_accuracy / math.sqrt(2.0)
    return sigma * math.sqrt(2.0 * math.log(max(n, 1) / OUTLIER_RISK))


def outlier_limit(n: int, n_params: int = 6) -> int:
    """Most markers that may be dropped as outliers from ``n``: a fifth of them, keeping at
    least five and at least two more residuals than parameters (``2 n_used - p >= 2``)."""
    keep = max(5, n_params // 2 + 1)
    return max(0, min(n // 5, n - keep))


@dataclass(frozen=True)
class Acceptance:
    """What the acceptance rule decided, and on what.

    Attributes
    ----------
    accepted : bool
    statistic : float
        The tested statistic: RMS residual of the used markers, px.
    threshold : float
        Its largest accepted value, px (``inf`` when ``dof <= 0``).
    marker_accuracy : float
        Stated accuracy of a marker position (RMS length, px).
    max_rms : float or None
        Upper limit applied whatever the accuracy, px.
    n_used, n_params, dof : int
        Markers used, fitted parameters, ``2 n_used - n_params``.
    chi2 : float
        ``sum(e**2) / (marker_accuracy**2 / 2)`` over the used markers.
    p_value : float
        Probability that markers of the stated accuracy give a chi2 at least this large
        (1 when ``dof <= 0``).
    outliers : tuple of str
        Names (ids or indices) of the markers dropped as gross outliers.
    outlier_errors : tuple of float
        Their errors, px, when they were dropped.
    gate : float
        Outlier gate used, px.
    what : str
        Which fit was judged (``"pose"``, ``"match"``, ``"calibration"``, ...).
    """

    accepted: bool
    statistic: float
    threshold: float
    marker_accuracy: float
    max_rms: float | None
    n_used: int
    n_params: int
    dof: int
    chi2: float
    p_value: float
    outliers: tuple = ()
    outlier_errors: tuple = ()
    gate: float = math.inf
    what: str = "pose"

    @property
    def grade(self) -> str:
        """The paper's reading of :attr:`statistic`."""
        return grade(self.statistic)

    def describe(self) -> str:
        """One line: statistic, threshold, grade and dropped outliers."""
        if self.dof <= 0:
            test = f"rms {self.statistic:.3g} px with {self.dof} degrees of freedom: not testable"
        else:
            rel = "<=" if self.accepted else ">"
            test = (f"rms {self.statistic:.3g} px {rel} threshold {self.threshold:.3g} px "
                    f"({self.n_used} markers, {self.dof} dof, marker accuracy "
                    f"{self.marker_accuracy:g} px"
                    + (f", max_rms {self.max_rms:g} px" if self.max_rms is not None else "")
                    + f"; p = {self.p_value:.2g})")
        out = ""
        if self.outliers:
            out = "; outliers dropped: " + ", ".join(
                f"{k} ({e:.3g} px)" for k, e in zip(self.outliers, self.outlier_errors,
                                                    strict=True))
        return f"{test}, {self.grade}{out}"


def judge(errors, n_params: int, marker_accuracy: float = DEFAULT_MARKER_ACCURACY,
          max_rms: float | None = DEFAULT_MAX_RMS, *, outliers=(), outlier_errors=(),
          n_total: int | None = None, what: str = "pose") -> Acceptance:
    """Apply the residual test to the errors (px) of the used markers (no exception).

    Parameters
    ----------
    errors : (n,) array_like
        Reprojection error lengths of the markers used in the fit, px.
    n_params : int
        Parameters fitted to them (6 for a pose, 6 + intrinsics, 6 for an affine map).
    marker_accuracy : float
        Stated accuracy of a marker position (RMS length, px).
    max_rms : float or None
        Upper limit of the RMS whatever the accuracy, px (None: none).
    outliers, outlier_errors : sequences
        Markers already dropped as gross outliers, reported with the result.
    n_total : int, optional
        Markers before the outliers were dropped (for the outlier gate reported).
    what : str
        Name of the fit, for messages.
    """
    a = check_accuracy(marker_accuracy, what)
    e = np.asarray(errors, float).ravel()
    n = int(e.size)
    if n == 0 or not np.all(np.isfinite(e)):
        return Acceptance(False, math.inf, 0.0, a, max_rms, n, n_params, 2 * n - n_params,
                          math.inf, 0.0, tuple(outliers), tuple(outlier_errors), what=what)
    rms = float(np.sqrt(np.mean(e**2)))
    dof = 2 * n - n_params
    x2 = float(np.sum(e**2) / (a * a / 2.0))
    p = float(chdtrc(dof, x2)) if dof > 0 else 1.0
    thr = rms_threshold(n, n_params, a, max_rms)
    ok = rms <= thr
    return Acceptance(bool(ok), rms, thr, a, max_rms, n, n_params, dof, x2, p,
                      tuple(outliers), tuple(float(x) for x in outlier_errors),
                      outlier_gate(n_total if n_total is not None else n, a), what)


def require(acc: Acceptance, who: str, hint: str = "wrong pairing or wrong camera?") -> None:
    """Raise :class:`SolveError` (``who: ...``) with the tested statistic and threshold
    when ``acc`` is not accepted."""
    if not acc.accepted:
        raise SolveError(f"{who}: refused by the acceptance rule: {acc.describe()}; {hint}")


def drop_outliers(fit, n: int, n_params: int,
                  marker_accuracy: float = DEFAULT_MARKER_ACCURACY, names=None,
                  what: str = "pose"):
    """Fit, drop the worst gross outlier, fit again, ... within :func:`outlier_limit`.

    Parameters
    ----------
    fit : callable
        ``fit(used)`` with a ``(n,)`` bool mask of the markers to use; returns ``(result,
        errors)`` where ``errors (n,)`` are the error lengths (px) of *every* marker under
        that fit (NaN or inf for a marker it cannot place, e.g. behind the camera).
    n, n_params : int
        Markers, and parameters of one fit.
    marker_accuracy : float
        Stated accuracy of a marker position, px.
    names : sequence of str, optional
        Marker names for the messages (default: their indices).
    what : str
        Name of the fit, for messages.

    Returns
    -------
    result, used (n,) bool, dropped (tuple of names), dropped_errors (tuple of px)

    Raises
    ------
    SolveError
        More gross outliers than :func:`outlier_limit` allows (they are named); refused at
        once when more markers exceed the gate than ``max(2 r, r + 3)``, ``r`` the number
        that may still be dropped.
    """
    a = check_accuracy(marker_accuracy, what)
    names = [str(i) for i in range(n)] if names is None else [str(k) for k in names]
    gate, limit = outlier_gate(n, a), outlier_limit(n, n_params)
    used = np.ones(n, bool)
    dropped, derr = [], []
    result, err = fit(used)
    while True:
        e = np.where(np.isfinite(err), err, np.inf)
        e = np.where(used, e, -np.inf)
        k = int(np.argmax(e))
        if e[k] <= gate:
            return result, used, tuple(dropped), tuple(derr)
        above = int(np.sum(e > gate))
        left = limit - len(dropped)
        # one gross outlier can pull a few others over the gate; far more than may still
        # be dropped cannot all be cleared: refused at once rather than fit after fit
        if left <= 0 or above > max(2 * left, left + 3):
            worst = np.flatnonzero(used & (e > gate))
            worst = worst[np.argsort(-e[worst])][:10]
            listed = ", ".join(f"{names[i]} ({e[i]:.3g} px)" for i in worst)
            prev = (f" after dropping {', '.join(dropped)}" if dropped else "")
            raise SolveError(
                f"{what}: refused by the acceptance rule: gross outlier(s) {listed} above "
                f"the gate {gate:.3g} px (marker accuracy {a:g} px){prev}; at most {limit} "
                f"of {n} markers may be dropped: wrong pairing or wrong camera?")
        used[k] = False
        dropped.append(names[k])
        derr.append(float(e[k]))
        result, err = fit(used)
