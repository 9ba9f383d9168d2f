"""The choices of the run's options (no numerical imports: the command line uses them)."""

from __future__ import annotations

__all__ = ["REGISTRATIONS", "OVERLAPS", "FILTERS", "PATCHERS"]

#: ``track``: each frame's own pose; ``first-frame``: uPSP's affine registration; ``none``.
REGISTRATIONS = ("track", "first-frame", "none")
#: How cameras are combined per face.
OVERLAPS = ("average_view", "best_view", "merge")
#: Image filters.
FILTERS = ("none", "gaussian")
#: Dark spots masked (``none``) or patched (``polynomial``).
PATCHERS = ("none", "polynomial")
