"""The run's settings and its result: :class:`UnsteadyConfig` (the command's flags or a
uPSP deck, :func:`config_from_deck`; checked by :func:`check_options`), :class:`CameraInput`
and :class:`UnsteadyResult`."""

from __future__ import annotations

import numbers
import re
from dataclasses import dataclass, field
from pathlib import Path

from resection.defaults import FRAME_RATE_RANGE
from resection.errors import InputError
from selfillum.unsteady.budget import DEFAULT_MEMORY_MB
from selfillum.unsteady.options import FILTERS, OVERLAPS, REGISTRATIONS

__all__ = ["CameraInput", "UnsteadyConfig", "UnsteadyResult", "config_from_deck",
           "check_options", "check_numbers", "cap_workers", "check_scheduler_address"]


@dataclass(frozen=True)
class CameraInput:
    """A camera: ``number``, ``video`` (a ``.cine``, ``.mraw``, TIFF/NPY stack) and
    ``calibration`` (its camera file, pose of the first frame relative to the model)."""

    number: int
    video: Path
    calibration: Path


@dataclass
class UnsteadyConfig:
    """Everything a run needs (the command's flags or a uPSP deck, :func:`config_from_deck`).

    ``registration``: ``track`` (each frame's own pose from the project's tracking, or
    ``track_dirs``), ``first-frame`` (uPSP: affine pixel registration onto frame 0, its
    map), ``none`` (a fixed model: frame 0's map). ``number_frames``: -1 for all.
    ``reflectance``: a number or a per-face file. ``si``: remove the self-illumination.
    Without ``paint_calibration``, the gain comes from the in-situ Stern-Volmer fit on the
    ``taps`` (a ``.wtd`` or a tap file, placed by ``tap_positions`` or the targets file)
    with one ``wind_off`` image per camera at pressure ``p_ref`` (psf)
    (:mod:`selfillum.unsteady.insitu`).
    ``psd_probes`` (node numbers), ``psd_bands`` (None: 8 or fewer,
    :func:`selfillum.unsteady.spectra.default_bands`), ``psd_nperseg``: Welch spectra
    (:mod:`selfillum.unsteady.spectra`). ``memory_mb``: the budget of the blocks
    (:func:`selfillum.unsteady.budget.plan_blocks`). ``plots``: write the dCp RMS on the
    model and the probes' PSD as PNG next to the output. ``fast``: Phase 1 by sparse
    products after the first frame (:mod:`selfillum.unsteady.fastmap`); False maps every
    frame the full way (a ray cast a frame). ``workers`` / ``scheduler``: Phase 1 and
    Phase 2 on Dask (:mod:`selfillum.unsteady.cluster`). ``form_factors``: the view
    factors of this grid already computed (a SciPy sparse ``.npz``, faces x faces, e.g.
    once for a whole entry), read instead of computed.
    """

    grid: Path
    sds: Path
    cameras: list
    out: Path
    paint_calibration: Path | None = None
    steady: Path | None = None
    targets: Path | None = None
    registration: str = "track"
    target_patcher: str = "none"
    overlap: str = "merge"
    filter: str = "none"
    filter_size: int = 3
    oblique_angle: float = 70.0
    number_frames: int = -1
    si: bool = True
    reflectance: object = 0.6
    unpainted: object = None
    rays: int = 64
    seed: int = 0
    fps: float | None = None
    tinf: float | None = None
    upsp_flat: bool = False
    track_dirs: list | None = None
    taps: Path | None = None
    tap_positions: Path | None = None
    wind_off: list | None = None
    p_ref: float | None = None
    progress: bool = False
    psd_probes: list = field(default_factory=list)
    psd_bands: int | None = None
    psd_nperseg: int | None = None
    memory_mb: float | None = DEFAULT_MEMORY_MB
    plots: bool = True
    resume: bool = False
    fast: bool = True
    workers: int | None = None
    scheduler: str | None = None
    form_factors: Path | None = None
    general: dict = field(default_factory=dict)
    source: str = "flags"
    uncertainty: str | None = None  # None, "linear" or "mc" (docs/uncertainty.md)
    samples: int = 200
    stated: object = None  # selfillum.uncertainty.stated.Stated
    surface: list = field(default_factory=list)  # --surface: per-node fields files


@dataclass(frozen=True)
class UnsteadyResult:
    """What a run did: ``out`` (the HDF5 file), ``n_frames``, ``n_nodes``, ``chunks``,
    ``seen`` (share of nodes with a dCp), ``si_change_median`` / ``si_change_p95`` (over
    the seen nodes, of the RMS over time of the change of dCp by the SI removal; NaN
    without SI), ``tracked_failed`` (frames whose pose was taken from the nearest good
    frame), ``files`` (everything written), ``peak_rss_mb`` (the process's peak resident
    memory, MiB), ``frames_per_s`` (frames over the whole run's time), ``blocks``
    (frames per Phase 1 block, nodes per Phase 2 block), ``timings`` (seconds: ``setup``
    = inputs, tracking, form factors; ``phase1``, of which ``first_frame`` (its maps and
    the self-illumination's frame-0 solve); ``phase2`` = Phase 2 and the outputs), ``si``
    (whether the run removed the self-illumination)."""

    out: Path
    n_frames: int
    n_nodes: int
    chunks: tuple
    seen: float
    si_change_median: float
    si_change_p95: float
    tracked_failed: int
    files: tuple
    peak_rss_mb: float = float("nan")
    frames_per_s: float = float("nan")
    blocks: tuple = ()
    timings: dict = field(default_factory=dict)
    uncertainty: dict = field(default_factory=dict)
    si: bool = True


_DECK_REGISTRATION = {"pixel": "first-frame", "none": "none", "track": "track",
                      "first-frame": "first-frame"}


def config_from_deck(deck, **overrides) -> UnsteadyConfig:
    """An :class:`UnsteadyConfig` from a :class:`resection.io.upsp_inputs.Deck`; the
    ``@options`` are honoured or refused by name; ``overrides`` (not None) win."""
    where = f"{deck.path}: @options"
    opts = dict(deck.options)
    kw: dict = {}
    if "target_patcher" in opts:
        kw["target_patcher"] = opts["target_patcher"]
    if "registration" in opts:
        r = opts["registration"]
        if r not in _DECK_REGISTRATION:
            raise InputError(f"{where} registration = {r}: unknown (pixel, none, track)")
        kw["registration"] = _DECK_REGISTRATION[r]
    if opts.get("pixel_interpolation", "linear") != "linear":
        raise InputError(f"{where} pixel_interpolation = {opts['pixel_interpolation']}: "
                         "only linear is supported")
    if "overlap" in opts:
        kw["overlap"] = opts["overlap"]
    if "filter" in opts:
        kw["filter"] = opts["filter"]
    for key, conv in (("filter_size", int), ("oblique_angle", float), ("number_frames", int)):
        if key in opts:
            try:
                kw[key] = conv(opts[key])
            except ValueError:
                raise InputError(f"{where} {key} = {opts[key]}: not a number") from None
    kw.update({k: v for k, v in overrides.items() if v is not None})
    cams = [CameraInput(c.number, c.video, c.calibration) for c in deck.cameras]
    tg = {c.targets for c in deck.cameras if c.targets is not None}
    if len(tg) > 1:
        raise InputError(f"{deck.path}: cameras name different targets files; one .tgts "
                         "for the model")
    targets = tg.pop() if tg else deck.targets
    out = kw.pop("out", None)
    if out is None:
        raise InputError(f"{deck.path}: give --out OUT.h5")
    return UnsteadyConfig(grid=deck.grid, sds=deck.sds, cameras=cams, targets=targets,
                          out=Path(out), general=dict(deck.general), source=str(deck.path),
                          **kw)


def check_options(cfg: UnsteadyConfig) -> None:
    """Each option honoured or refused by name (:class:`InputError`)."""
    where = cfg.source
    if cfg.registration not in REGISTRATIONS:
        raise InputError(f"{where}: registration {cfg.registration!r} unknown (one of "
                         f"{', '.join(REGISTRATIONS)})")
    if cfg.target_patcher not in ("none", "polynomial"):
        raise InputError(f"{where}: target_patcher {cfg.target_patcher!r} unknown (none, "
                         "polynomial)")
    if cfg.overlap not in OVERLAPS:
        raise InputError(f"{where}: overlap {cfg.overlap!r} unknown (one of "
                         f"{', '.join(OVERLAPS)})")
    if cfg.filter not in FILTERS:
        raise InputError(f"{where}: filter {cfg.filter!r} unknown (none, gaussian)")
    if cfg.filter == "gaussian" and (cfg.filter_size < 3 or cfg.filter_size % 2 == 0):
        raise InputError(f"{where}: filter_size {cfg.filter_size} must be odd and >= 3")
    if cfg.filter == "gaussian" and cfg.filter_size > MAX_FILTER_SIZE:
        raise InputError(f"{where}: filter_size {cfg.filter_size} is too large (at most "
                         f"{MAX_FILTER_SIZE} pixels, and within the frame)")
    if not 0 < cfg.oblique_angle <= 90:
        raise InputError(f"{where}: oblique_angle {cfg.oblique_angle} must be in (0, 90]")
    if cfg.number_frames == 0 or cfg.number_frames < -1:
        raise InputError(f"{where}: number_frames {cfg.number_frames} must be -1 (all) or > 0")
    if not cfg.cameras:
        raise InputError(f"{where}: no camera")
    if cfg.out.suffix.lower() not in (".h5", ".hdf5"):
        raise InputError(f"{cfg.out}: the output is an HDF5 file (.h5)")
    check_numbers(cfg)


#: The largest Gaussian filter, pixels a side (uPSP's decks use 3 to 7).
MAX_FILTER_SIZE = 101
#: The largest memory budget accepted, MiB (1 PiB).
MAX_MEMORY_MB = 2.0**30


def _finite(value, name: str, lo: float, hi: float, unit: str = "") -> float:
    """``value`` as a float within ``[lo, hi]``, or InputError naming the option."""
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{name} {value!r}: not a number") from None
    if not lo <= v <= hi:  # NaN fails too
        raise InputError(f"{name} {value}: out of range (expected {lo:g} to {hi:g}"
                         f"{' ' + unit if unit else ''})")
    return v


def check_numbers(cfg: UnsteadyConfig) -> None:
    """The numeric options finite and within their ranges (:class:`InputError` naming the
    option): ``--fps``, ``--tinf`` (above absolute zero), ``--memory``, ``--seed`` (a
    64-bit unsigned integer), ``--rays``, ``--workers``, ``--psd-bands``,
    ``--psd-nperseg``, ``--p-ref``, and the camera numbers."""
    if cfg.fps is not None:
        _finite(cfg.fps, "--fps", *FRAME_RATE_RANGE, "frames/s")
    if cfg.tinf is not None:
        from selfillum.unsteady.conditions import MAX_TEMPERATURE_F, RANKINE

        t = _finite(cfg.tinf, "--tinf", -RANKINE, MAX_TEMPERATURE_F, "deg F")
        if t == -RANKINE:
            raise InputError(f"--tinf {cfg.tinf}: at absolute zero ({-RANKINE} deg F)")
    if cfg.memory_mb is not None:
        if not _finite(cfg.memory_mb, "--memory", 0.0, MAX_MEMORY_MB, "MiB") > 0:
            raise InputError(f"--memory {cfg.memory_mb}: must be > 0 MiB")
    for name, v, lo, hi in (("--seed", cfg.seed, 0, 2**64 - 1), ("--rays", cfg.rays, 1, 2**20),
                            ("--psd-bands", cfg.psd_bands, 0, 2**20),
                            ("--psd-nperseg", cfg.psd_nperseg, 8, 2**31)):
        if v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise InputError(f"{name} {v!r}: not an integer")
        if not lo <= int(v) <= hi:
            raise InputError(f"{name} {v}: out of range (expected {lo} to {hi})")
    if cfg.workers is not None and (isinstance(cfg.workers, bool) or cfg.workers < 1):
        raise InputError(f"--workers {cfg.workers}: expected at least 1 process")
    if cfg.scheduler is not None:
        check_scheduler_address(cfg.scheduler)
    if cfg.p_ref is not None:
        p = _finite(cfg.p_ref, "--p-ref", 0.0, 1e9, "psf")
        if p <= 0:
            raise InputError(f"--p-ref {cfg.p_ref}: the wind-off pressure must be > 0 psf")
    for c in cfg.cameras:
        if not 0 <= int(c.number) <= MAX_CAMERA_NUMBER:
            raise InputError(f"{cfg.source}: camera number {c.number} out of range (0 to "
                             f"{MAX_CAMERA_NUMBER})")


#: The largest camera number (uPSP numbers its cameras from 1; a 16-bit range).
MAX_CAMERA_NUMBER = 65535


def cap_workers(workers: int | None) -> tuple[int | None, str | None]:
    """``--workers`` capped at the cores this process may use: ``(workers, note)``, the
    note (None when nothing changed) saying so."""
    import os

    if workers is None:
        return None, None
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        cores = os.cpu_count() or 1
    if workers <= cores:
        return workers, None
    return cores, (f"--workers {workers}: capped at the {cores} core"
                   f"{'s' if cores != 1 else ''} this machine gives the run")


def check_scheduler_address(address: str) -> None:
    """A Dask scheduler address ``[protocol://]host:port`` (``tcp``, ``tls``, ``ucx``,
    ``ws``, ``wss``, ``inproc``), checked before anything connects to it."""
    m = re.fullmatch(r"(?:(tcp|tls|ucx|ws|wss)://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)"
                     r":(\d{1,5})", address.strip()) if address else None
    if address and address.startswith("inproc://"):
        return
    if m is None or not 0 < int(m.group(3)) < 65536:
        raise InputError(f"--scheduler {address!r}: not a scheduler address (expected "
                         "tcp://host:port)")

