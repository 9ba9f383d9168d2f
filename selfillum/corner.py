"""The corner case end to end: view factors, self-illumination, correction, profile, plot.

Two painted plates at 90 degrees (:mod:`scenes.corner`). The *measured* radiosity is
simulated with light transport that the correction did not compute itself, so that the
residual left after correction is the error of the working (ray-cast) view factors:

- ``reference="exact"`` (default): converged form factors from the closed-form
  point-to-triangle kernel (:func:`scenes.corner.exact_radiosity`), another estimator
  altogether (no rays), within about 3e-5 of the exact radiosity;
- ``reference="rays"``: ray-cast factors with another seed and ``reference_factor`` times
  more rays (their own noise then adds to the residual).

The working factors are ray-cast by :func:`selfillum.view_factors` (RQMC rays). With
``symmetry=True`` (default) they are then averaged over the corner's exact symmetries
(translation along the fold, reciprocity, the mirror ``x <-> z``;
:func:`scenes.corner.symmetric_factors`): an unbiased estimate with the noise of about
4 times the rays at 1024 rays a face. A general model has no such symmetry; ``symmetry=False``
shows what the rays alone leave (measured in ``docs/benchmark_history.md``).
"""

from __future__ import annotations

import csv
import json
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from threadpoolctl import threadpool_limits

from resection.errors import InputError
from scenes.corner import (
    DEFAULT_REFLECTANCE,
    CornerScene,
    corner,
    corner_profile_line,
    exact_radiosity,
    symmetric_factors,
)
from selfillum.solve.radiosity import correct, forward
from selfillum.transport.viewfactors import view_factors

__all__ = ["CornerNumbers", "CornerResult", "run_corner", "plot_corner", "write_corner",
           "DEFAULT_RAYS"]

#: Rays per face of the main job's working view factors: with the RQMC rays averaged over
#: the corner's symmetries the largest residual after correction is then about 0.2 %
#: (measured in docs/benchmark_history.md; without the symmetry 4096 rays are needed for that).
DEFAULT_RAYS = 1024


@dataclass(frozen=True)
class CornerNumbers:
    """Headline numbers of the corner case (fractions, not percent).

    Attributes
    ----------
    faces : int
        Faces of the mesh.
    rays_per_face : int
        Rays of the working view factors.
    reference : str
        How the measurement was simulated: ``"exact"`` (closed-form kernel) or
        ``"rays"``.
    reference_rays_per_face : int
        Rays of the reference view factors (0 for the closed-form reference).
    symmetry : bool
        Whether the working factors were averaged over the corner's symmetries.
    reflectance : float
        Paint reflectance.
    max_si_fraction : float
        Largest ``(B - E) / B`` over faces: share of self-illumination in what is seen.
    max_si_fraction_profile : float
        The same along the profile line.
    max_residual_fraction : float
        Largest ``|E_corrected - E_true| / E_true`` over faces after correction.
    rms_residual_fraction : float
        Root mean square of the same.
    max_residual_fraction_profile : float
        Largest ``|E_corrected - E_true| / E_true`` along the profile line.
    seconds : dict
        Wall time of each step (s).
    """

    faces: int
    rays_per_face: int
    reference: str
    reference_rays_per_face: int
    symmetry: bool
    reflectance: float
    max_si_fraction: float
    max_si_fraction_profile: float
    max_residual_fraction: float
    rms_residual_fraction: float
    max_residual_fraction_profile: float
    seconds: dict = field(default_factory=dict)


@dataclass(frozen=True)
class CornerResult:
    """Everything the corner run computed.

    Attributes
    ----------
    scene : CornerScene
        Mesh, true emission and reflectance.
    F : scipy.sparse.csr_matrix or scipy.sparse.linalg.LinearOperator
        Working form factors (used for the correction), ``(N, N)``: the ray-cast matrix,
        or with ``symmetry=True`` an operator on its symmetric average (floor-to-wall
        block and its transpose; ``F @ x`` works for both).
    radiosity : (N,) ndarray
        Simulated measurement: emission plus self-illumination (reference form factors).
    corrected : (N,) ndarray
        Emission recovered from ``radiosity`` with ``F``.
    profile : dict of str -> ndarray
        Along the line across the corner: ``s`` (signed distance from the corner, model
        units, negative on the floor), ``x``, ``y``, ``z``, ``face``, ``true``,
        ``with_si``, ``corrected``.
    numbers : CornerNumbers
    """

    scene: CornerScene
    F: sp.csr_matrix | spla.LinearOperator
    radiosity: np.ndarray
    corrected: np.ndarray
    profile: dict
    numbers: CornerNumbers


def run_corner(
    resolution: int = 40,
    rays_per_face: int = DEFAULT_RAYS,
    *,
    size: float = 1.0,
    reflectance: float = DEFAULT_REFLECTANCE,
    pattern: str = "smooth",
    seed: int = 0,
    reference: str = "exact",
    reference_factor: int = 4,
    symmetry: bool = True,
    profile_points: int = 801,
    progress: bool = False,
) -> CornerResult:
    """Run the corner case.

    Parameters
    ----------
    resolution : int
        Squares along each plate side (``4 * resolution**2`` triangles).
    rays_per_face : int
        Rays per face of the working view factors.
    size : float
        Plate side (model units).
    reflectance : float
        Paint reflectance in ``[0, 1)``; the default gives about 30% SI at the corner.
    pattern : {"smooth", "uniform"}
        True emission field (see :func:`scenes.corner.corner`).
    seed : int
        Seed of the working view factors; a ray-cast reference uses ``seed + 1``.
    reference : {"exact", "rays"}
        How the measurement is simulated (see the module's docstring).
    reference_factor : int
        A ray-cast reference uses this many times more rays (>= 1).
    symmetry : bool
        Average the working factors over the corner's symmetries
        (:func:`scenes.corner.symmetric_factors`) before the correction.
    profile_points : int
        Samples along the profile line.
    progress : bool
        Show progress bars on the ray casting.

    Returns
    -------
    CornerResult
    """
    if reference not in ("exact", "rays"):
        raise InputError(f"reference must be 'exact' or 'rays', got {reference!r}")
    if int(reference_factor) < 1:
        raise InputError(f"reference_factor must be >= 1, got {reference_factor}")
    seconds = {}
    t0 = time.perf_counter()
    scene = corner(size=size, resolution=resolution, reflectance=reflectance, pattern=pattern)
    E = scene.emission
    t = time.perf_counter()
    if reference == "exact":
        B = exact_radiosity(scene)
        ref_rays = 0
    else:
        ref_rays = int(rays_per_face) * int(reference_factor)
        with _bar(progress, "reference view factors", len(E)) as bar:
            F_ref = view_factors(scene.mesh, ref_rays, seed + 1, progress=bar)
        B = forward(F_ref, E, scene.reflectance)
    seconds["simulate_measurement"] = time.perf_counter() - t
    t = time.perf_counter()
    with _bar(progress, "working view factors", len(E)) as bar:
        F = view_factors(scene.mesh, rays_per_face, seed, progress=bar)
    if symmetry:
        F = _block_operator(symmetric_factors(scene, F, dtype=np.float32))
    seconds["view_factors"] = time.perf_counter() - t
    t = time.perf_counter()
    # every face is seen: correct() is E = B - rho F B, written out for the operator
    E_corr = B - scene.reflectance * (F @ B) if symmetry else correct(F, B, scene.reflectance)
    seconds["correction"] = time.perf_counter() - t

    s, pts = corner_profile_line(scene, n=profile_points)
    _, _, face = scene.mesh.nearest.on_surface(pts)
    face = np.asarray(face, dtype=np.int64)
    profile = {
        "s": s,
        "x": pts[:, 0],
        "y": pts[:, 1],
        "z": pts[:, 2],
        "face": face,
        "true": E[face],
        "with_si": B[face],
        "corrected": E_corr[face],
    }
    si = (B - E) / B
    res = np.abs(E_corr - E) / E
    seconds["total"] = time.perf_counter() - t0
    numbers = CornerNumbers(
        faces=len(E),
        rays_per_face=int(rays_per_face),
        reference=reference,
        reference_rays_per_face=ref_rays,
        symmetry=bool(symmetry),
        reflectance=scene.reflectance,
        max_si_fraction=float(si.max()),
        max_si_fraction_profile=float(si[face].max()),
        max_residual_fraction=float(res.max()),
        rms_residual_fraction=float(np.sqrt(np.mean(res**2))),
        max_residual_fraction_profile=float(res[face].max()),
        seconds={k: round(v, 3) for k, v in seconds.items()},
    )
    return CornerResult(scene, F, B, E_corr, profile, numbers)


def _block_operator(G: np.ndarray) -> spla.LinearOperator:
    """``(N, N)`` operator of form factors with floor-to-wall block ``G`` (``(M, M)``,
    ``N = 2 M``), wall-to-floor block ``G.T`` and nothing within a plate. The products
    run in ``G``'s precision (float32: about 1e-7 relative) and return float64."""
    m = G.shape[0]

    def mv(x):
        x = np.asarray(x).ravel().astype(G.dtype)
        with threadpool_limits(limits=1, user_api="blas"):  # see exact_radiosity
            return np.concatenate([G @ x[m:], G.T @ x[:m]]).astype(np.float64)

    return spla.LinearOperator((2 * m, 2 * m), matvec=mv, rmatvec=mv, dtype=np.float64)


@contextmanager
def _bar(show: bool, desc: str, total: int):
    """A ``progress`` callable for :func:`view_factors` driving a ``tqdm`` bar named
    ``desc`` over ``total`` faces (``None`` when ``show`` is false)."""
    if not show:
        yield None
        return
    from tqdm.auto import tqdm

    with tqdm(desc=desc, total=total, unit="face", leave=False) as bar:

        def update(done: int, _total: int) -> None:
            bar.update(done - bar.n)

        yield update


def plot_corner(result: CornerResult, path) -> Path:
    """Save the profile across the corner (true, with SI, corrected) as an image file.

    Parameters
    ----------
    result : CornerResult
    path : str or Path
        Output file; the format follows the suffix (PNG, PDF, SVG).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    p = result.profile
    num = result.numbers
    fig, (ax, ax2) = plt.subplots(
        2, 1, figsize=(7.5, 6.0), sharex=True, gridspec_kw={"height_ratios": [3, 1.3]}
    )
    ax.plot(
        p["s"], p["with_si"], color="tab:red", lw=1.6, label="measured (with self-illumination)"
    )
    ax.plot(p["s"], p["true"], color="black", lw=2.4, label="true emission")
    ax.plot(p["s"], p["corrected"], color="tab:blue", lw=1.2, ls="--", label="corrected")
    ax.axvline(0.0, color="0.6", lw=0.8)
    ax.set_ylabel("exitance (arbitrary units)")
    ax.set_title(
        f"Self-illumination across a 90-degree corner (reflectance {num.reflectance:g}, "
        f"{num.faces} faces)",
        fontsize=10,
    )
    ax.legend(loc="upper left", fontsize=9, frameon=False)
    ymax = float(np.max(p["with_si"]))
    ax.text(
        -0.02 * result.scene.size,
        0.02 + ax.get_ylim()[0],
        "corner",
        ha="right",
        va="bottom",
        fontsize=8,
        color="0.4",
    )
    ax.set_ylim(top=ymax * 1.12)
    si = (p["with_si"] - p["true"]) / p["with_si"]
    err = (p["corrected"] - p["true"]) / p["true"]
    ax2.plot(
        p["s"],
        100 * si,
        color="tab:red",
        lw=1.4,
        label="self-illumination, % of the measured signal",
    )
    ax2.plot(
        p["s"],
        100 * err,
        color="tab:blue",
        lw=1.2,
        label="error after correction, % of the true emission",
    )
    ax2.axhline(0.0, color="0.6", lw=0.8)
    ax2.axvline(0.0, color="0.6", lw=0.8)
    ax2.set_ylabel("% of signal")
    ax2.set_xlabel("distance from the corner along the surface (floor < 0 < wall)")
    ax2.legend(loc="upper left", fontsize=8, frameon=False)
    # fixed margins: tight_layout measured every tick label again (half the plot's time)
    fig.subplots_adjust(left=0.085, right=0.985, top=0.945, bottom=0.085, hspace=0.07)
    path = Path(path)
    # PNG: light compression (a third less time to write, a tenth more bytes)
    png = {"pil_kwargs": {"compress_level": 1}} if path.suffix.lower() == ".png" else {}
    fig.savefig(path, dpi=130, **png)
    plt.close(fig)
    return path


def write_corner(result: CornerResult, out_dir) -> dict:
    """Write ``corner_profile.png``, ``corner_profile.csv`` and ``corner_numbers.json``
    to ``out_dir`` (created if needed); return their paths by kind."""
    from resection.io.outputs import output_folder

    # a folder made here is removed again when a file cannot be written (a full disk)
    with output_folder(out_dir) as out:
        return _write_corner_files(result, out)


def _write_corner_files(result: CornerResult, out: Path) -> dict:
    from resection.io.outputs import atomic_path  # each file via a temporary name

    png = out / "corner_profile.png"
    # one BLAS thread: OpenBLAS's idle threads would spin on the cores meanwhile
    with atomic_path(png) as tmp, threadpool_limits(limits=1, user_api="blas"):
        plot_corner(result, tmp)
    csv_path = out / "corner_profile.csv"
    p = result.profile
    cols = ["s", "x", "y", "z", "face", "true", "with_si", "corrected"]
    with atomic_path(csv_path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for row in zip(*(p[c] for c in cols), strict=True):
            w.writerow(
                [int(v) if c == "face" else f"{v:.9g}" for c, v in zip(cols, row, strict=True)]
            )
    json_path = out / "corner_numbers.json"
    with atomic_path(json_path) as tmp:
        tmp.write_text(json.dumps({"written_by": "selfillum corner",
                                   **asdict(result.numbers)}, indent=2) + "\n")
    return {"png": png, "csv": csv_path, "json": json_path}
