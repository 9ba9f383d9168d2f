"""The thermal run's settings and result: :class:`ThermalConfig` (the command's flags),
:class:`ThermalResult`, and the Phase 1 settings it shares with the unsteady run
(:meth:`ThermalConfig.phase1_config`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from resection.errors import InputError
from selfillum.unsteady.budget import DEFAULT_MEMORY_MB
from selfillum.unsteady.config import CameraInput, UnsteadyConfig

__all__ = ["ThermalConfig", "ThermalResult", "CameraInput"]


@dataclass
class ThermalConfig:
    """Everything a thermal run needs.

    IR: ``radiometry`` (:func:`selfillum.thermal.radiometry.read_radiometry`). TSP:
    ``tsp_calibration`` (:func:`selfillum.thermal.tsp.read_tsp_calibration`) and one
    ``wind_off`` image per camera (taken with the calibration's pose), the paint's
    ``reflectance`` for its self-illumination. ``substrate``
    (:func:`selfillum.thermal.heatflux.read_substrate`); ``method`` of the heat flux
    (default: Cook-Felderman on a semi-infinite body, else the impulse response).
    ``sds``: the ``.wtd`` for the Stanton number and heat-transfer coefficient, with
    ``recovery_factor``. ``target_patcher``: ``polynomial`` (default, uPSP's
    patch: the markers filled from a ring of the model around them) or ``none`` (left out:
    nodes wholly under a marker unseen). ``marker_polarity``: the markers on the
    images (IR: plaster holes heat faster, ``bright``). ``probes``: node numbers whose T
    and q histories are drawn; ``picture_times``: times (s) of the pictures of q on the
    model. ``si``: reflected light of the model's own parts (view factors of ``rays`` a
    face) removed, the faces no camera sees solved again when the seen signal drifts by
    ``si_refresh`` (:mod:`selfillum.thermal.reflections`).
    """

    grid: Path
    cameras: list
    out: Path
    substrate: Path
    targets: Path | None = None
    radiometry: Path | None = None
    tsp_calibration: Path | None = None
    wind_off: list | None = None
    reflectance: object = 0.6
    sds: Path | None = None
    recovery_factor: float | None = None
    tinf: float | None = None
    method: str | None = None
    fps: float | None = None
    number_frames: int = -1
    registration: str = "track"
    target_patcher: str = "polynomial"
    overlap: str = "average_view"
    oblique_angle: float = 70.0
    marker_polarity: str | None = None
    track_dirs: list | None = None
    si: bool = True
    si_refresh: float = 0.01
    rays: int = 256
    seed: int = 0
    probes: list = field(default_factory=list)
    picture_times: list = field(default_factory=list)
    memory_mb: float | None = DEFAULT_MEMORY_MB
    resume: bool = False
    progress: bool = False
    plots: bool = True

    @property
    def mode(self) -> str:
        return "ir" if self.radiometry is not None else "tsp"

    def check(self) -> None:
        """Each option honoured or refused by name (:class:`InputError`)."""
        if (self.radiometry is None) == (self.tsp_calibration is None):
            raise InputError("give either --radiometry R.json (IR) or --tsp-calibration C "
                             "with --wind-off W (TSP)")
        if self.tsp_calibration is not None:
            if not self.wind_off or len(self.wind_off) != len(self.cameras):
                raise InputError("TSP needs one --wind-off image per camera "
                                 f"({len(self.cameras)} cameras, "
                                 f"{len(self.wind_off or [])} wind-off images)")
        if not self.cameras:
            raise InputError("no camera: give --video V --calibration CAM")
        if Path(self.out).suffix.lower() not in (".h5", ".hdf5"):
            raise InputError(f"{self.out}: the output is an HDF5 file (.h5)")
        if self.marker_polarity not in (None, "dark", "bright"):
            raise InputError(f"marker polarity {self.marker_polarity!r}: dark or bright")
        if self.recovery_factor is not None and not 0 < self.recovery_factor <= 1:
            raise InputError(f"--recovery-factor {self.recovery_factor} must be in (0, 1]")
        if not self.si_refresh > 0:
            raise InputError(f"--si-refresh {self.si_refresh} must be positive")
        if self.rays < 1:
            raise InputError(f"--rays {self.rays} must be >= 1")

    @property
    def polarity(self) -> str:
        return self.marker_polarity or ("bright" if self.mode == "ir" else "dark")

    def phase1_config(self) -> UnsteadyConfig:
        """The unsteady run's settings for the same Phase 1 (videos, tracking, maps, the
        work file), no filter, the fast way."""
        return UnsteadyConfig(grid=Path(self.grid), sds=Path(self.sds or self.grid),
                              cameras=list(self.cameras), out=Path(self.out),
                              targets=self.targets, registration=self.registration,
                              target_patcher=self.target_patcher, overlap=self.overlap,
                              oblique_angle=self.oblique_angle,
                              number_frames=self.number_frames, si=self.si,
                              reflectance=self.reflectance, rays=self.rays, seed=self.seed,
                              fps=self.fps, track_dirs=self.track_dirs,
                              progress=self.progress, memory_mb=self.memory_mb,
                              resume=self.resume, plots=False, source="selfillum thermal")


@dataclass(frozen=True)
class ThermalResult:
    """What a run did: ``out``, ``n_frames``, ``n_nodes``, ``seen`` (share of nodes with
    a heat flux), ``tracked_failed`` (frames without their own pose: the nearest tracked
    frame's taken), ``saturated_pixels`` (masked, in the frames this run mapped),
    ``out_of_range`` (node samples outside the calibration's range, NaN), ``files``,
    ``frames_per_s`` (frames over the whole run's time), ``method``."""

    out: Path
    n_frames: int
    n_nodes: int
    seen: float
    tracked_failed: int
    saturated_pixels: int
    out_of_range: int
    files: tuple
    frames_per_s: float
    method: str
    timings: dict = field(default_factory=dict)
