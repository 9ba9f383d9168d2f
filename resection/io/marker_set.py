"""The 3-D markers of a model as one small dataclass: ids, positions, diameters, normals,
and which of them are pressure taps (known dark spots, never matched as targets).

Read and written by :mod:`resection.io.markers` (CSV) and :mod:`resection.io.tgts` (uPSP).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from resection.errors import InputError

__all__ = ["MarkerSet"]


@dataclass(frozen=True)
class MarkerSet:
    """Markers of a model.

    Attributes
    ----------
    ids : tuple of str
        Unique marker names.
    xyz : (N, 3) ndarray
        Model coordinates, model units.
    diameter : (N,) ndarray
        Diameters, model units (NaN where not given).
    normals : (N, 3) ndarray
        Outward unit surface normals at the markers (rows of NaN where not given). A marker
        whose normal faces away from a camera is not expected in its image
        (:meth:`facing`).
    taps : (N,) bool ndarray
        True for pressure taps and transducers (``*Taps``, ``*Virtuals``/``*Kulites`` of a
        ``.tgts`` file): known dark spots that are *not* targets. Matching and pose must
        not take them for targets (use :attr:`targets`); ``selfillum psp`` may use their
        positions for the in-situ fit.
    """

    ids: tuple[str, ...]
    xyz: np.ndarray
    diameter: np.ndarray
    normals: np.ndarray | None = None
    taps: np.ndarray | None = None

    def __post_init__(self):
        n = len(self.ids)
        normals = np.full((n, 3), np.nan) if self.normals is None else \
            np.array(self.normals, dtype=np.float64).reshape(-1, 3)
        taps = np.zeros(n, bool) if self.taps is None else np.array(self.taps, dtype=bool)
        if normals.shape != (n, 3) or taps.shape != (n,):
            raise InputError(f"MarkerSet: {n} ids but normals {normals.shape}, taps "
                             f"{taps.shape}")
        with np.errstate(invalid="ignore"):
            norm = np.linalg.norm(normals, axis=1)
        given = np.isfinite(norm)
        if np.any(given & ~(norm > 0)):
            raise InputError("MarkerSet: zero-length normal")
        normals[given] /= norm[given, None]
        normals.setflags(write=False)
        taps.setflags(write=False)
        object.__setattr__(self, "normals", normals)
        object.__setattr__(self, "taps", taps)

    def __len__(self) -> int:
        return len(self.ids)

    def subset(self, mask) -> MarkerSet:
        """The markers where ``mask`` (bool array or index array) selects them."""
        idx = np.arange(len(self))[mask]
        return MarkerSet(tuple(self.ids[i] for i in idx), self.xyz[idx], self.diameter[idx],
                         self.normals[idx], self.taps[idx])

    @property
    def targets(self) -> MarkerSet:
        """The markers without the pressure taps (what matching and pose use)."""
        return self if not self.taps.any() else self.subset(~self.taps)

    @property
    def tap_set(self) -> MarkerSet:
        """Only the pressure taps."""
        return self.subset(self.taps)

    def facing(self, center) -> np.ndarray:
        """``(N,)`` bool: True where the marker's normal faces the point ``center`` (a
        camera's perspective centre, model units), or where no normal is given."""
        c = np.asarray(center, dtype=np.float64).reshape(3)
        with np.errstate(invalid="ignore"):
            dots = np.einsum("ij,ij->i", self.normals, c - self.xyz)
        return ~(dots <= 0)

    def select(self, ids) -> np.ndarray:
        """Coordinates ``(M, 3)`` of the given ids, in that order (unknown id: InputError)."""
        pos = {k: i for i, k in enumerate(self.ids)}
        missing = [k for k in ids if k not in pos]
        if missing:
            raise InputError(f"unknown marker id(s): {', '.join(map(str, missing[:10]))}")
        return self.xyz[[pos[k] for k in ids]]
