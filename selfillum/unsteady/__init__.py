"""The unsteady PSP run (NASA uPSP's ``psp_process``, and beyond it): from the videos of
several cameras to dCp time histories at every grid node, self-illumination removed.

Takes a uPSP input deck (or the same by flags), the ``.wtd`` conditions, the paint gain
file and the steady Cp; gives one HDF5 file (frames x nodes, chunked for frames and for
node histories) with an XDMF sidecar (``docs/unsteady.md``).

Modules, by concept:

- :mod:`~selfillum.unsteady.conditions`: tunnel conditions, the Phase 2 formulas (gain,
  recovery temperature, steady pressure);
- :mod:`~selfillum.unsteady.grid`: grid nodes in the grid file's order, the steady Cp;
- :mod:`~selfillum.unsteady.spots`: targets, taps and Kulites masked or patched;
- :mod:`~selfillum.unsteady.config`: the run's settings (flags or a deck) and its result;
- :mod:`~selfillum.unsteady.inputs`: the videos opened and checked, poses from tracking;
- :mod:`~selfillum.unsteady.registration`: uPSP's affine pixel registration;
- :mod:`~selfillum.unsteady.phase1`: frames onto nodes (registration, spots, cameras
  combined, self-illumination removed);
- :mod:`~selfillum.unsteady.phase2`: node intensities to dCp;
- :mod:`~selfillum.unsteady.insitu`: the gain from the taps without a paint calibration;
- :mod:`~selfillum.unsteady.output`: the HDF5 layout, XDMF, uPSP's flat files;
- :mod:`~selfillum.unsteady.results`: the output file's content, Phase 2 written into it;
- :mod:`~selfillum.unsteady.uncertainty_out`: ``--uncertainty``'s per-node fields;
- :mod:`~selfillum.unsteady.run`: :func:`run_unsteady`, the whole job.
"""

from __future__ import annotations

from resection._lazy import attach

#: Public name -> submodule (loaded on first use, so the command line builds light).
_EXPORTS: dict[str, str] = {
    "Conditions": ".conditions",
    "CameraInput": ".config",
    "UnsteadyConfig": ".config",
    "UnsteadyResult": ".config",
    "config_from_deck": ".config",
    "run_unsteady": ".run",
}

__all__ = ["Conditions", "CameraInput", "UnsteadyConfig", "UnsteadyResult",
           "config_from_deck", "run_unsteady"]

__getattr__, __dir__ = attach(__name__, _EXPORTS)
