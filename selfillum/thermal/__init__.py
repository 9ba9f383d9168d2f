"""Infrared thermography and temperature-sensitive paint: surface temperature and heat flux
at every grid node, frame by frame (``docs/thermal.md``).

Modules, by concept:

- :mod:`~selfillum.thermal.radiometry`: FLIR's Planck form, emissivity models;
- :mod:`~selfillum.thermal.balance`: reflected walls and the model's own radiation;
- :mod:`~selfillum.thermal.tsp`: TSP intensity ratio to temperature;
- :mod:`~selfillum.thermal.heatflux`: Cook-Felderman, impulse response, layered substrates;
- :mod:`~selfillum.thermal.stanton`: heat-transfer coefficient and Stanton number;
- :mod:`~selfillum.thermal.inputs`: the frames' signal, tracking with markers that appear;
- :mod:`~selfillum.thermal.early`: that tracking in a child process beside the set-up;
- :mod:`~selfillum.thermal.phase2`, :mod:`~selfillum.thermal.output`,
  :mod:`~selfillum.thermal.run`: the command's run, :func:`run_thermal`.
"""

from __future__ import annotations

from resection._lazy import attach

_EXPORTS: dict[str, str] = {
    "CameraInput": ".config",
    "ThermalConfig": ".config",
    "ThermalResult": ".config",
    "run_thermal": ".run",
}

__all__ = list(_EXPORTS)

__getattr__, __dir__ = attach(__name__, _EXPORTS)
