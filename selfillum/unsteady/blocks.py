"""Phase 1 of a run, committed block by block of frames to the work file
(:class:`selfillum.unsteady.work.Phase1Store`): in this process (:func:`local_phase1`) or
on Dask (:func:`cluster_phase1`, blocks finishing in any order, written here)."""

from __future__ import annotations

from selfillum.unsteady.phase1 import map_run
from selfillum.unsteady.work import BlockBuffer

__all__ = ["local_phase1", "cluster_phase1"]


def local_phase1(cfg, grid, runs, todo, spots, si, unpainted, store, R, t, done, fb, T, N,
                  prog, caster=None, counts=None, nondata=None):
    """Phase 1 in this process, committing blocks of ``fb`` frames; returns frame 0's
    gains. ``caster``: the grid's Embree scene when built already (the view factors');
    ``counts``: the frames mapped each way (:func:`~selfillum.unsteady.phase1.map_run`);
    ``nondata``: nodes stored unseen (``cutoff_x_max``)."""
    buf = BlockBuffer(fb, N, with_raw=si is not None, nondata=nondata)
    a = done
    gains0 = None
    for fn in map_run(grid, runs, todo, spots=spots, registration=cfg.registration,
                      patcher=cfg.target_patcher, overlap=cfg.overlap, filter=cfg.filter,
                      filter_size=cfg.filter_size, max_obliqueness=cfg.oblique_angle, si=si,
                      unpainted=unpainted, fast=cfg.fast, plan_frames=range(T),
                      caster=caster, counts=counts):
        k = fn.index  # (a moving model's references planned over the whole run, also on
        # a resume: as on Dask)
        gains0 = fn.gains if gains0 is None else gains0
        if k < done:
            continue  # frame 0 again, already stored
        buf.put(k - a, fn.values, fn.raw)
        for ci, cm in enumerate(fn.cameras):
            R[ci, k], t[ci, k] = cm.R, cm.t
        if k - a + 1 == fb or k == T - 1:  # a block of frames (whole chunk rows when the
            # budget allows), committed
            store.write_block(a, buf.rows(k + 1 - a), R[:, a:k + 1], t[:, a:k + 1])
            a = k + 1
        prog.frame(k + 1)
    return gains0


def cluster_phase1(client, cfg, grid, runs, spots, unpainted, rho, F, store, R, t, done, fb,
                    T, prog, nondata=None):
    """Phase 1 on Dask: blocks of frames on the workers, written here as they finish;
    returns frame 0's gains (mapped here, for the in-situ fit). ``nondata``: nodes stored
    unseen (``cutoff_x_max``)."""
    from selfillum.unsteady.cluster import Phase1Job, phase1_blocks

    job = Phase1Job(str(cfg.grid), tuple(str(c.video) for c in cfg.cameras),
                    tuple(r.camera for r in runs), tuple(r.number for r in runs),
                    spots, cfg.registration, cfg.target_patcher, cfg.overlap, cfg.filter,
                    cfg.filter_size, cfg.oblique_angle, unpainted, rho, None, cfg.fast,
                    nondata)
    poses = None if runs[0].poses is None else [r.poses for r in runs]
    blocks = [(a, min(a + fb, T)) for a in range(done, T, fb)]
    finished, prefix, count = set(), done, done
    for a, rows, Rb, tb in phase1_blocks(client, job, F, blocks, poses):
        b = a + len(rows["values"][0])
        finished.add(a)
        while prefix in finished:  # frames_done: the blocks done from frame 0 on
            prefix = min(prefix + fb, T)
        R[:, a:b], t[:, a:b] = Rb, tb
        store.write_block(a, rows, Rb, tb, frames_done=prefix)
        count += b - a
        prog.frame(count)
    fn = next(map_run(grid, runs, [0], spots=spots, registration="none",
                      patcher=cfg.target_patcher, overlap=cfg.overlap, filter=cfg.filter,
                      filter_size=cfg.filter_size, max_obliqueness=cfg.oblique_angle,
                      unpainted=unpainted, fast=False))
    return fn.gains
