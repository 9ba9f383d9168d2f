"""A wind-tunnel entry processed: :func:`run_entry`.

1. Everything is read and checked before any heavy step (one line naming the datapoint,
   the file and the problem; :class:`InputError`): the index, the processing parameters
   and their overlays, each datapoint's ``.wtd`` (its attitude), grid, targets, steady Cp
   (each distinct file once), paint calibration and the tunnel's configuration. Videos
   are a datapoint's own: a missing or corrupt one fails that datapoint only.
2. Each datapoint's calibration is a Dask task
   (:func:`selfillum.entry.datapoint.calibrate_datapoint`): a local cluster by default, a
   running scheduler, or a PBS/Slurm batch cluster (:mod:`selfillum.entry.jobqueue`).
   Each writes only its own folder ``DIR/<id>/``.
3. What depends only on the model is computed once for the entry, when a calibrated
   datapoint needs it: the view factors of each grid (``DIR/_entry/F-<key>.npz``, a Dask
   task), given to every datapoint's run.
4. Each calibrated wind-on datapoint's unsteady run and Kulites, a Dask task
   (:func:`selfillum.entry.datapoint.run_datapoint`).
5. ``DIR/summary.csv`` and ``DIR/index.html`` (:mod:`selfillum.entry.summary`);
   ``DIR/entry.json`` marks the folder as this command's.

With ``resume``, a datapoint whose ``done.json`` holds the identity of its current inputs
and options is skipped; one under way carries on (its calibrations kept, its unsteady run
from its work folder); any other is done again from nothing. Without ``resume``, an
existing datapoint folder is refused (no product is overwritten unasked).
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from resection.errors import InputError

__all__ = ["EntryConfig", "EntryResult", "run_entry", "prepare_entry", "DEFAULT_OPTIONS",
           "MANIFEST", "OUT_NAMES"]

#: the file marking ``DIR`` as this command's output, and what it writes there itself.
MANIFEST = "entry.json"
OUT_NAMES = ("summary.csv", "index.html", MANIFEST, "_entry")

#: the deck options of an entry unless the index or the processing file say otherwise:
#: what uPSP users set (target_patcher polynomial, registration pixel, overlap
#: average_view).
DEFAULT_OPTIONS = {"target_patcher": "polynomial", "registration": "first-frame",
                   "overlap": "average_view"}


@dataclass
class EntryConfig:
    """``index``: the datapoint index; ``out``: the products folder; ``processing``: uPSP's
    processing parameters file; ``test_config``: the tunnel's configuration for a uPSP
    index without ``external-calibration`` parameters; ``only``: datapoint ids;
    ``resume``; ``workers`` (local Dask processes; 0: in this process, no Dask),
    ``scheduler`` (address),
    ``jobqueue`` (batch cluster file); ``rays``, ``seed``: view factors;
    ``unsteady``: further :class:`~selfillum.unsteady.UnsteadyConfig` keywords (e.g.
    ``memory_mb``, ``fps``, ``si``); ``calibration``: ``marker_accuracy``, ``max_rms``,
    ``search_radius`` (px); ``progress``: a line per datapoint on stderr."""

    index: Path
    out: Path
    processing: Path | None = None
    test_config: Path | None = None
    only: list | None = None
    resume: bool = False
    workers: int = 1
    scheduler: str | None = None
    jobqueue: Path | None = None
    rays: int = 1024
    seed: int = 0
    unsteady: dict = field(default_factory=dict)
    calibration: dict = field(default_factory=dict)
    progress: bool = True


@dataclass(frozen=True)
class EntryResult:
    """``rows``: the summary rows in index order; ``summary``, ``html``: their files;
    ``skipped``: datapoints resumed as done; ``seconds``."""

    rows: list
    summary: Path
    html: Path
    skipped: tuple
    seconds: float

    @property
    def failed(self) -> list:
        return [r for r in self.rows if r["status"].startswith("failed")]


def _stat(p) -> list:
    if p is None:
        return None
    p = Path(p)
    if p.is_dir():
        return sorted([str(q), q.stat().st_size, q.stat().st_mtime_ns]
                      for q in p.iterdir() if q.is_file())
    st = p.stat()
    return [str(p.resolve()), st.st_size, st.st_mtime_ns]


def _key(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def _own_files(d, wtd) -> list:
    """The datapoint's own videos, calibrations and Kulite files (not the whole shared
    folders: another datapoint's new video leaves this one's identity as it was)."""
    from selfillum.entry.datapoint import run_seq
    from selfillum.entry.index import find_camera_tunnel, find_videos
    from selfillum.entry.kulites import upsp_info_files

    try:
        vids = find_videos(d)
        files = list(vids.values()) + [p.with_suffix(".cih") for p in vids.values()
                                       if p.suffix.lower() == ".mraw"]
        files += list(find_camera_tunnel(d, list(vids)).values())
    except InputError as e:  # the datapoint will fail with it; its identity says so
        return [str(e)]
    if d.kulites is not None:
        k = Path(d.kulites)
        if k.is_dir():
            try:
                infos = upsp_info_files(k, *run_seq(wtd, d.id))
            except InputError as e:
                return [str(e)]
            files += infos + [q for p in infos for q in (p.with_suffix(".fast"),
                                                         p.with_suffix(".slow"),
                                                         p.with_suffix(".zPXImat"))]
        else:
            files.append(k)
    return [_stat(p) for p in files if Path(p).exists()]


def _check_file(dp_id, p, what):
    if p is not None and not Path(p).is_file():
        raise InputError(f"datapoint {dp_id}: {what} {p}: file not found")


def prepare_entry(cfg: EntryConfig):
    """The datapoints' tasks and the entry's view-factor jobs, every input checked
    (module notes). Returns ``(index, tasks, ff_jobs)``."""
    from resection.io.markers import read_markers
    from resection.io.upsp_inputs import read_paint_calibration
    from resection.io.wtd import read_wtd
    from selfillum.entry.datapoint import DatapointTask
    from selfillum.entry.index import read_index
    from selfillum.entry.processing import psp_options, read_processing, resolve_overlays
    from selfillum.entry.tunnel import attitude_from_wtd, read_test_config, tunnel_config
    from selfillum.unsteady.config import CameraInput, UnsteadyConfig, check_options
    from selfillum.unsteady.grid import load_run_grid, nondata_nodes, read_steady_cp

    idx = read_index(cfg.index)
    dps = list(idx.datapoints)
    if cfg.only:
        known = {d.id for d in dps}
        bad = [k for k in cfg.only if k not in known]
        if bad:
            raise InputError(f"--only {bad[0]}: no such datapoint in {idx.source}")
        dps = [d for d in dps if d.id in set(cfg.only)]
    proc = read_processing(cfg.processing) if cfg.processing else None
    params = resolve_overlays(proc, {d.id: d.entries for d in idx.datapoints}) if proc \
        else {}
    base_tunnel = None
    tc = cfg.test_config or idx.test_config
    if tc is not None:
        base_tunnel = read_test_config(tc)
    out = Path(cfg.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: not a folder")
    folders = {(out / d.id).resolve() for d in dps}
    for d in dps:
        for p in (d.wtd, d.grid, d.targets, d.steady, d.paint_calibration, d.video_dir,
                  *(d.videos or {}).values()):
            if p is not None and (Path(p).resolve().parent in folders
                                  or Path(p).resolve() in folders):
                raise InputError(f"datapoint {d.id}: {p} lies in a products folder of "
                                 f"--out {out}: choose another --out")
    tasks, ff_jobs = [], {}
    checked = {}
    for d in dps:
        w = f"datapoint {d.id}"
        for p, what in ((d.wtd, "wtd"), (d.grid, "grid"), (d.targets, "targets"),
                        (d.steady, "steady Cp"), (d.paint_calibration, "paint calibration")):
            _check_file(d.id, p, what)
        if d.kulites is not None and not Path(d.kulites).exists():
            raise InputError(f"{w}: Kulites {d.kulites}: not found")
        try:
            wtd = read_wtd(d.wtd)
            attitude_from_wtd(wtd)
            if d.paint_calibration is not None and d.paint_calibration not in checked:
                checked[d.paint_calibration] = read_paint_calibration(d.paint_calibration)
            if d.targets not in checked:
                checked[d.targets] = read_markers(d.targets)
            if d.grid not in checked:
                checked[d.grid] = load_run_grid(d.grid)
            if d.steady is not None and (d.grid, d.steady) not in checked:
                checked[(d.grid, d.steady)] = read_steady_cp(d.steady, checked[d.grid]) \
                    is not None
        except InputError as e:
            raise InputError(f"{w}: {str(e).splitlines()[0]}") from None
        p = params.get(d.id, {})
        tunnel = base_tunnel
        if "external-calibration" in p:
            tunnel = tunnel_config(p["external-calibration"],
                                   f"{cfg.processing}: external-calibration of {d.id}")
        if tunnel is None:
            raise InputError(f"{w}: no tunnel configuration: give --processing with "
                             "'external-calibration' (tunnel-cor_to_tgts_tvec) or "
                             "--test-config test_config.json")
        opts = dict(DEFAULT_OPTIONS)
        opts.update(psp_options(idx.options, f"{idx.source}: entry: options"))
        opts.update(psp_options(p.get("psp_process", {}),
                                f"{cfg.processing}: psp_process of {d.id}"))
        uns = {"reflectance": idx.reflectance, "rays": cfg.rays, "seed": cfg.seed,
               **opts, **cfg.unsteady}
        probe = UnsteadyConfig(grid=d.grid, sds=d.wtd, cameras=[CameraInput(1, d.wtd,
                                                                            d.wtd)],
                               out=Path("x.h5"), source=w, **uns)
        check_options(probe)
        try:
            nondata_nodes(checked[d.grid], uns.get("cutoff_x_max"), "cutoff_x_max")
        except InputError as e:
            raise InputError(f"{w}: {cfg.processing or idx.source}: {e}") from None
        ff = None
        if uns.get("si", True):
            fk = _key({"grid": _stat(d.grid), "rays": cfg.rays, "seed": cfg.seed})[:16]
            ff = out / "_entry" / f"F-{fk}.npz"
            ff_jobs[ff] = d.grid
        key = _key({"files": [_stat(x) for x in (d.wtd, d.grid, d.targets, d.steady,
                                                 d.paint_calibration)],
                    "own": _own_files(d, wtd),
                    "tunnel": [tunnel.cor_to_model.tolist(), tunnel.oblique_angle],
                    "unsteady": uns, "calibration": cfg.calibration})
        tasks.append(DatapointTask(d, out / d.id, tunnel, uns, key, cfg.resume, ff,
                                   dict(cfg.calibration)))
    if not cfg.resume:
        for t in tasks:
            if t.folder.exists() and any(t.folder.iterdir()):
                raise InputError(f"{t.folder}: exists (products of an earlier run); give "
                                 "--resume or another --out")
    return idx, tasks, ff_jobs


def _form_factors(path: Path, grid: Path, rays: int, seed: int) -> str:
    """The view factors of ``grid``, saved to ``path`` (skipped when it is there)."""
    import scipy.sparse as sp

    from selfillum.transport.viewfactors import view_factors
    from selfillum.unsteady.grid import load_run_grid

    if path.is_file():
        return str(path)
    F = view_factors(load_run_grid(grid).mesh, rays_per_face=rays, seed=seed, progress=False)
    tmp = path.with_name(path.stem + f".{os.getpid()}.tmp.npz")
    sp.save_npz(tmp, sp.csr_matrix(F))
    tmp.replace(path)
    return str(path)


def _say(cfg, text):
    if cfg.progress:
        print(text, file=sys.stderr, flush=True)


def _stages(cfg, todo, ff_jobs, rows, out, submit, gather) -> None:
    """Stage 1 (calibrations) for every datapoint, then the view factors the calibrated
    ones need, then stage 2 (their unsteady runs); ``submit(fn, *args)`` -> handle,
    ``gather(handles)`` yields ``(position in handles, result or exception)`` as they
    finish."""
    from selfillum.entry.datapoint import calibrate_datapoint, empty_row, run_datapoint

    def collect(handles, owner, stage):
        done = {}
        for n, (i, r) in enumerate(gather(handles), start=1):
            t = owner[i]
            if isinstance(r, BaseException):  # a worker lost: that datapoint fails
                r = dict(empty_row(t.dp.id), status=f"failed: datapoint {t.dp.id}: "
                         f"{type(r).__name__}: {r}")
            done[t.dp.id] = r
            if r["status"] != "calibrated":
                rows[t.dp.id] = r
            _say(cfg, f"entry: {stage} [{n}/{len(handles)}] {t.dp.id}: {r['status']} "
                 f"({r['seconds']} s)")
        return done

    hs = [submit(calibrate_datapoint, t) for t in todo]
    first = collect(hs, todo, "calibration")
    go = [t for t in todo if first[t.dp.id]["status"] == "calibrated"]
    need = {t.form_factors: ff_jobs[t.form_factors] for t in go if t.form_factors}
    if need:
        (out / "_entry").mkdir(exist_ok=True)
        _say(cfg, f"entry: view factors of {len(need)} grid(s), {cfg.rays} rays a face, "
             "once for the entry")
        for _, r in gather([submit(_form_factors, p, g, cfg.rays, cfg.seed)
                            for p, g in need.items()]):
            if isinstance(r, BaseException):
                raise r
    hs = [submit(run_datapoint, t, first[t.dp.id]) for t in go]
    collect(hs, go, "run")


def _on_worker(fn, *a):
    """``fn(*a)`` on a Dask worker, glibc told first to keep freed arrays for reuse
    (:func:`resection.memory.keep_freed_memory`: the nanny's ``MALLOC_TRIM_THRESHOLD_``
    made the worker fault every array's pages in anew)."""
    from resection.memory import keep_freed_memory

    keep_freed_memory()
    return fn(*a)


def _local():
    def submit(fn, *a):
        try:
            return (fn(*a),)
        except Exception as e:  # noqa: BLE001 -- handed to the caller as on Dask
            return (e,)

    def gather(handles):
        for i, h in enumerate(handles):
            yield i, h[0]

    return submit, gather


def _dask(client):
    from dask.distributed import as_completed

    def submit(fn, *a):
        return client.submit(_on_worker, fn, *a, pure=False)

    def gather(futs):
        where = {f.key: i for i, f in enumerate(futs)}
        for f in as_completed(futs):
            try:
                yield where[f.key], f.result()
            except Exception as e:  # noqa: BLE001 -- a worker lost
                yield where[f.key], e

    return submit, gather


def run_entry(cfg: EntryConfig) -> EntryResult:
    """Process the entry (module notes)."""
    from resection.io.marks import PRODUCER_KEY
    from selfillum.entry.summary import write_summary

    t0 = time.perf_counter()
    idx, tasks, ff_jobs = prepare_entry(cfg)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / MANIFEST).write_text(json.dumps({PRODUCER_KEY: "selfillum entry",
                                            "index": str(Path(cfg.index).resolve()),
                                            "datapoints": [t.dp.id for t in tasks]},
                                           indent=1))
    rows, skipped, todo = {}, [], []
    for t in tasks:
        done = t.folder / "done.json"
        row = t.folder / "row.json"
        if cfg.resume and done.is_file() and row.is_file() and \
                json.loads(done.read_text()).get("key") == t.key:
            rows[t.dp.id] = json.loads(row.read_text())
            skipped.append(t.dp.id)
            _say(cfg, f"entry: {t.dp.id}: done before ({rows[t.dp.id]['status']}), skipped")
        else:
            todo.append(t)
    if todo:
        if cfg.workers == 0 and not (cfg.scheduler or cfg.jobqueue):  # in this process
            _stages(cfg, todo, ff_jobs, rows, out, *_local())
        else:
            from selfillum.entry.jobqueue import open_client

            client, closers = open_client(workers=cfg.workers, scheduler=cfg.scheduler,
                                          jobqueue=cfg.jobqueue)
            try:
                _stages(cfg, todo, ff_jobs, rows, out, *_dask(client))
            finally:
                for c in closers:
                    c.close()
    ordered = [rows[t.dp.id] for t in tasks]
    el = time.perf_counter() - t0
    csv_path, html = write_summary(out, ordered, idx, el)
    return EntryResult(ordered, csv_path, html, tuple(skipped), el)
