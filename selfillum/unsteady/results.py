"""The output file's content (layout: :mod:`selfillum.unsteady.output`): the grid, the
frames, the cameras, the steady Cp and gain, dCp by Phase 2 (here or on Dask, written by
this process only), the statistics and spectra, and the conditions, options, provenance
and memory plan as attributes: :func:`write_results`."""

from __future__ import annotations

import os

import numpy as np

from selfillum.unsteady.output import FORMAT, VERSION, json_attr, provenance
from selfillum.unsteady.phase2 import DETREND_ORDER, run_phase2, seen_ranges

__all__ = ["write_results"]


def write_results(f, cfg, grid, cond, cp, gain, s1, times, frames, runs, R, t, tc, nc, *,
                  plan=None, spectra=None, progress=None, client=None, work=None) -> dict:
    """Write the run into the open HDF5 file ``f``; returns ``seen``, ``si_median``,
    ``si_p95`` and the per-node ``rms``."""
    vals = s1["values"]
    T, N = vals.shape
    with_si = "raw" in s1  # the work keeps the intensities without SI only in a SI run
    f.attrs["format"] = FORMAT
    f.attrs["version"] = VERSION
    g = f.create_group("grid")
    g.create_dataset("points", data=grid.points)
    g.create_dataset("triangles", data=grid.triangles)
    g.create_dataset("block_dims", data=np.asarray(grid.dims, np.int64))
    fr = f.create_group("frames")
    fr.create_dataset("time", data=times)
    fr.create_dataset("index", data=frames.astype(np.int64))
    cg = f.create_group("cameras")
    for ci, r in enumerate(runs):
        c = cg.create_group(f"cam{r.number:02d}")
        c.attrs.update(width=r.camera.width, height=r.camera.height, number=r.number,
                       video=str(cfg.cameras[ci].video))
        c.create_dataset("K", data=r.camera.K)
        c.create_dataset("dist", data=r.camera.dist)
        c.create_dataset("R", data=R[ci])
        c.create_dataset("t", data=t[ci])
    st = f.create_group("steady")
    st.create_dataset("cp", data=cp)
    st.create_dataset("gain", data=gain)
    dcp = f.create_dataset("dcp", (T, N), "f4", chunks=(tc, nc), fillvalue=np.nan)
    if spectra is not None and spectra.n_bands:
        spectra.band = f.create_dataset("psd/band_psd", (N, spectra.n_bands), "f4",
                                        fillvalue=np.nan)
    if client is None:
        p2 = run_phase2(vals, dcp, frames, gain, cond.q, raw=s1["raw"] if with_si else None,
                        scale=s1["values_scale"][()],
                        raw_scale=s1["raw_scale"][()] if with_si else None,
                        block=plan.nodes_per_block if plan is not None else None,
                        spectra=spectra, progress=progress)
    else:  # on Dask: blocks of nodes on the workers, written here
        from selfillum.unsteady.cluster import phase2_blocks

        p2 = {k: np.full(N, np.nan, np.float32) for k in ("mean", "rms", "si_change")}
        n_done = 0
        for a, d, mean, rms, change, psd in phase2_blocks(
                client, str(work), N, plan.nodes_per_block, frames, np.asarray(gain), cond.q,
                with_si, spectra):
            b = a + d.shape[1]
            for c, e in seen_ranges(np.isfinite(d).any(axis=0), dcp.chunks, a):
                dcp[:, a + c:a + e] = d[:, c:e]  # chunks without a dCp stay unwritten
            p2["mean"][a:b], p2["rms"][a:b] = mean, rms
            if change is not None:
                p2["si_change"][a:b] = change
            if spectra is not None:
                spectra.add(a, None, psd=psd)
            n_done += b - a
            if progress is not None:
                progress(n_done)
    if spectra is not None:
        spectra.write(f.require_group("psd"))
    mean, rms, change = p2["mean"], p2["rms"], p2["si_change"]
    s = f.create_group("stats")
    s.create_dataset("dcp_mean", data=mean)
    s.create_dataset("dcp_rms", data=rms)
    if with_si:
        s.create_dataset("si_change_rms", data=change)
    fin = change[np.isfinite(change)]
    si_med = float(np.median(fin)) if fin.size else float("nan")
    si_p95 = float(np.percentile(fin, 95)) if fin.size else float("nan")
    f.attrs["si_change_median"] = si_med
    f.attrs["si_change_p95"] = si_p95
    f.attrs["conditions"] = json_attr(cond.to_dict())
    f.attrs["options"] = json_attr({
        "registration": cfg.registration, "target_patcher": cfg.target_patcher,
        "overlap": cfg.overlap, "filter": cfg.filter, "filter_size": cfg.filter_size,
        "oblique_angle": cfg.oblique_angle, "number_frames": T,
        "cutoff_x_max": cfg.cutoff_x_max, "si": cfg.si,
        "reflectance": str(cfg.reflectance), "unpainted": str(cfg.unpainted),
        "rays": cfg.rays, "seed": cfg.seed, "detrend_order": DETREND_ORDER,
        "general": cfg.general, "source": cfg.source, "chunks": [tc, nc],
        "psd_probes": [int(n) for n in cfg.psd_probes], "psd_bands": cfg.psd_bands,
        "psd_nperseg": spectra.nperseg if spectra is not None else None})
    f.attrs["provenance"] = json_attr(provenance({
        "grid": cfg.grid, "sds": cfg.sds, "steady": cfg.steady,
        "paint_calibration": cfg.paint_calibration, "targets": cfg.targets,
        "taps": cfg.taps, "tap_positions": cfg.tap_positions, "wind_off": cfg.wind_off,
        "videos": [c.video for c in cfg.cameras],
        "calibrations": [c.calibration for c in cfg.cameras],
        "form_factors": cfg.form_factors,
        "deck": cfg.source if os.path.isfile(cfg.source) else None}))
    f.attrs["memory"] = json_attr({
        "budget_mb": cfg.memory_mb,
        "frames_per_block": plan.frames_per_block if plan is not None else tc,
        "nodes_per_block": plan.nodes_per_block if plan is not None else nc})
    return {"seen": float(np.isfinite(rms).mean()), "si_median": si_med, "si_p95": si_p95,
            "rms": rms}

