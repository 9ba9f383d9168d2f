"""One datapoint of the entry, from its files to its products, in two Dask tasks:
:func:`calibrate_datapoint` (its inputs, its cameras' first frames) and, when that says
``calibrated``, :func:`run_datapoint` (the unsteady run, the Kulites). Neither raises;
each returns the datapoint's summary row, its final status ``ok``, ``wind-off`` or
``failed: <reason>``.

Products in ``DIR/<datapoint>/`` (fixed names): ``camNN-to-model.json`` and
``camNN-pose.png`` (:mod:`selfillum.entry.calibrate`), ``unsteady.h5`` (with
``unsteady.xdmf``, ``unsteady_rms.png``, as ``selfillum unsteady`` writes them),
``kulites/kulites.csv`` and ``kulites/<name>_psd.png`` (:mod:`selfillum.entry.compare`),
``row.json`` (the summary row) and ``done.json`` (the identity of the inputs and options
the products come from: a resumed entry skips a datapoint whose ``done.json`` matches).
``started.json`` marks a datapoint under way: a resumed one with the same identity keeps
its calibrations and carries its unsteady run on from ``unsteady.h5.work``.
"""

from __future__ import annotations

import json
import math
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

from resection.errors import InputError

__all__ = ["DatapointTask", "calibrate_datapoint", "run_datapoint", "empty_row",
           "run_seq", "PRODUCTS"]

#: the files and folders of a datapoint's folder this module writes (and may remove).
PRODUCTS = ("calibration.json", "unsteady.h5", "unsteady.xdmf", "unsteady_rms.png",
            "unsteady_psd.png", "unsteady.h5.work", "kulites", "row.json", "done.json",
            "started.json")


@dataclass(frozen=True)
class DatapointTask:
    """What one datapoint needs (picklable: it travels to a Dask worker).

    ``dp``: :class:`~selfillum.entry.index.Datapoint`; ``folder``: its products folder;
    ``tunnel``: :class:`~selfillum.entry.tunnel.TunnelConfig`; ``unsteady``: keyword
    arguments of :class:`~selfillum.unsteady.UnsteadyConfig` (deck options, reflectance,
    rays, ...); ``key``: the identity of its inputs and options; ``resume``;
    ``form_factors``: the entry's view factors of this grid (or None);
    ``calibration``: ``marker_accuracy``, ``max_rms``, ``search_radius`` (px)."""

    dp: object
    folder: Path
    tunnel: object
    unsteady: dict
    key: str
    resume: bool = False
    form_factors: Path | None = None
    calibration: dict = field(default_factory=dict)


def empty_row(dp_id: str) -> dict:
    """A summary row with nothing known yet."""
    return {"datapoint": dp_id, "status": "", "mach": math.nan, "alpha": math.nan,
            "beta": math.nan, "phi": math.nan, "q": math.nan, "cameras": "",
            "seen": math.nan, "si_change_median": math.nan, "kulites": "",
            "kulite_rms_ratio": math.nan, "kulite_band_hz": "", "seconds": math.nan,
            "files": {}}


def _clear(folder: Path) -> None:
    for name in PRODUCTS:
        p = folder / name
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()
    for p in folder.glob("cam[0-9][0-9]-*"):
        p.unlink()


def run_seq(wtd, dp_id: str) -> tuple[int, int]:
    """The run and point of a datapoint: the ``.wtd``'s ``RUN n m`` line, else uPSP's id
    ``RRRRSS``."""
    if wtd.run is not None and wtd.sequence is not None:
        return int(wtd.run), int(wtd.sequence)
    if len(dp_id) >= 6 and dp_id[:6].isdigit():  # uPSP's datapoint ids: RRRRSS
        return int(dp_id[:4]), int(dp_id[4:6])
    raise InputError(f"datapoint {dp_id}: {wtd.path} has no 'RUN n m' line and the id is "
                     "not RRRRSS: the Kulites' run and point are unknown")


def _calibrate(task, videos, cals, markers, mesh, att, folder, reuse):
    """Each camera's first frame; returns ([CameraInput], [CameraCalibration])."""
    from resection.io.cameras import read_camera
    from resection.io.video import open_frames
    from selfillum.entry.calibrate import CameraCalibration, calibrate_camera
    from selfillum.entry.tunnel import camera_to_model, read_camera_tunnel
    from selfillum.unsteady.config import CameraInput

    inputs, results = [], []
    stats = folder / "calibration.json"
    kept = json.loads(stats.read_text()) if reuse and stats.is_file() else {}
    for n, video in videos.items():
        js = folder / f"cam{n:02d}-to-model.json"
        try:
            src = open_frames(video)
        except InputError as e:
            raise InputError(f"datapoint {task.dp.id}: {e}") from None
        try:
            if len(src) < 1:
                raise InputError(f"datapoint {task.dp.id}: {video}: no frame")
            H, W = src.shape
            ct = read_camera_tunnel(cals[n], W, H)
            pred = camera_to_model(ct, att, task.tunnel)
            if reuse and js.is_file() and str(n) in kept:
                k = kept[str(n)]
                files = tuple(folder / f for f in k["files"])
                results.append(CameraCalibration(n, read_camera(js), pred, k["used"],
                                                 k["expected"], k["rms"], k["grade"],
                                                 k["shift"], None, files))
            else:
                try:
                    img = src[0]
                except InputError as e:
                    raise InputError(f"datapoint {task.dp.id}: {e}") from None
                results.append(calibrate_camera(n, img, markers, mesh, pred, folder,
                                                **task.calibration))
        finally:
            src.close()
        inputs.append(CameraInput(n, Path(video), js))
    stats.write_text(json.dumps({str(r.number): {
        "used": r.used, "expected": r.expected, "rms": r.rms, "grade": r.grade,
        "shift": r.shift, "reason": r.reason,
        "files": [str(Path(p).relative_to(folder)) for p in r.files]} for r in results},
        indent=1))
    return inputs, results


def _kulites(task, wtd, cond_q, h5, folder, row):
    from resection.io.tgts import read_tgts
    from selfillum.entry.compare import compare_kulites, write_comparison
    from selfillum.entry.kulites import read_kulites

    run, seq = run_seq(wtd, task.dp.id)
    ks = read_kulites(task.dp.kulites, run, seq)
    v = read_tgts(task.dp.targets).virtuals
    pos = {k: x for k, x in zip(v.ids, v.xyz, strict=True)}
    rad = {k: 0.5 * float(d) for k, d in zip(v.ids, v.diameter, strict=True)}
    nor = {k: x for k, x in zip(v.ids, v.normals, strict=True)}
    comps = compare_kulites(h5, ks, pos, rad, cond_q, normals=nor)
    kf = folder / "kulites"
    kf.mkdir(exist_ok=True)
    files = write_comparison(kf, comps)
    left = [k for k in ks.names if k not in {c.name for c in comps}]
    row["kulites"] = f"{len(comps)} compared" + (f"; not placed or not seen: "
                                                 f"{' '.join(left)}" if left else "")
    if comps:
        import numpy as np

        row["kulite_rms_ratio"] = float(np.median([c.rms_ratio for c in comps]))
        row["kulite_band_hz"] = " ".join(f"{c.name}:{c.band[0]:.0f}-{c.band[1]:.0f}"
                                         for c in comps)
        row["files"]["kulite_psd"] = [str(p.relative_to(folder)) for p in files[1:]]
        row["files"]["kulite_table"] = str(files[0].relative_to(folder))
    return comps


def _guarded(task, folder, row, step) -> dict:
    t0 = time.perf_counter()
    try:
        step(task, folder, row)
    except InputError as e:
        msg = str(e).splitlines()[0]
        row["status"] = "failed: " + (msg if msg.startswith("datapoint") else
                                      f"datapoint {task.dp.id}: {msg}")
    except Exception as e:  # noqa: BLE001 -- one datapoint's failure never stops the rest
        row["status"] = f"failed: datapoint {task.dp.id}: {type(e).__name__}: " \
            f"{str(e).splitlines()[0] if str(e) else ''}"
    row["seconds"] = round(row["seconds"] + time.perf_counter() - t0, 2) \
        if row["seconds"] == row["seconds"] else round(time.perf_counter() - t0, 2)
    if row["status"] != "calibrated":
        try:
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "row.json").write_text(json.dumps(row, indent=1, default=float))
            if not row["status"].startswith("failed"):
                (folder / "done.json").write_text(json.dumps({"key": task.key}))
        except OSError as e:
            row["status"] = f"failed: datapoint {task.dp.id}: {folder}: {e}"
    return row


def calibrate_datapoint(task: DatapointTask) -> dict:
    """Stage 1: the datapoint's inputs and its cameras' first frames; the row's status is
    ``calibrated`` (stage 2 to come), ``wind-off`` or ``failed: ...``. Never raises."""
    return _guarded(task, Path(task.folder), empty_row(task.dp.id), _calibrate_stage)


def run_datapoint(task: DatapointTask, row: dict) -> dict:
    """Stage 2, after :func:`calibrate_datapoint` said ``calibrated``: the unsteady run and
    the Kulites; the final row. Never raises."""
    return _guarded(task, Path(task.folder), dict(row), _run_stage)


def _calibrate_stage(task, folder: Path, row: dict) -> None:
    from resection.io.markers import read_markers
    from resection.io.wtd import read_wtd
    from selfillum.entry.index import find_camera_tunnel, find_videos
    from selfillum.entry.tunnel import attitude_from_wtd
    from selfillum.unsteady.grid import load_run_grid

    dp = task.dp
    folder.mkdir(parents=True, exist_ok=True)
    started = folder / "started.json"
    same = started.is_file() and json.loads(started.read_text()).get("key") == task.key
    reuse = task.resume and same
    if not reuse:
        _clear(folder)
    started.write_text(json.dumps({"key": task.key}))
    wtd = read_wtd(dp.wtd)
    att = attitude_from_wtd(wtd)
    row.update(alpha=att.alpha, beta=att.beta, phi=att.phi)
    row["mach"] = wtd.value("MACH") if wtd.has("MACH") else math.nan
    q = wtd.value("Q") if wtd.has("Q") else math.nan
    row["q"] = q
    videos = find_videos(dp)
    cals = find_camera_tunnel(dp, list(videos))
    grid = load_run_grid(dp.grid)
    markers = read_markers(dp.targets)
    inputs, results = _calibrate(task, videos, cals, markers, grid.mesh, att, folder, reuse)
    row["cameras"] = " ".join(
        f"cam{r.number:02d}: {r.used}/{r.expected} targets, RMS {r.rms:.2f} px, "
        f"{r.shift:.1f} px from the tunnel's prediction" if r.camera is not None
        else f"cam{r.number:02d}: failed" for r in results)
    row["files"]["pose"] = [str(p.relative_to(folder)) for r in results for p in r.files
                            if p.suffix == ".png"]
    row["files"]["calibration"] = [str(p.relative_to(folder)) for r in results
                                   for p in r.files if p.suffix == ".json"]
    row["_videos"] = {str(c.number): str(c.video) for c in inputs}
    row["_reuse"] = reuse
    bad = [r for r in results if r.camera is None]
    if bad:
        row["status"] = "failed: " + "; ".join(
            f"datapoint {dp.id}: camera {r.number}: calibration: {r.reason}" for r in bad)
        return
    if not q > 0:  # Q = 0: a wind-off point, calibrated, never processed as wind-on
        row["status"] = "wind-off"
        return
    if dp.steady is None:
        raise InputError(f"datapoint {dp.id}: no steady Cp file")
    row["status"] = "calibrated"


def _run_stage(task, folder: Path, row: dict) -> None:
    from resection.io.wtd import read_wtd
    from selfillum.unsteady.config import CameraInput, UnsteadyConfig
    from selfillum.unsteady.run import run_unsteady

    dp = task.dp
    vids = row.pop("_videos")
    reuse = row.pop("_reuse")
    inputs = [CameraInput(int(n), Path(v), folder / f"cam{int(n):02d}-to-model.json")
              for n, v in vids.items()]
    out = folder / "unsteady.h5"
    work = folder / "unsteady.h5.work"
    cfg = UnsteadyConfig(grid=dp.grid, sds=dp.wtd, cameras=inputs, out=out,
                         paint_calibration=dp.paint_calibration, steady=dp.steady,
                         targets=dp.targets, progress=False,
                         resume=reuse and work.is_dir(), form_factors=task.form_factors,
                         source=f"datapoint {dp.id}", **task.unsteady)
    res = run_unsteady(cfg)
    row["seen"] = res.seen
    row["si_change_median"] = res.si_change_median
    row["files"]["unsteady"] = [str(Path(p).relative_to(folder)) for p in res.files]
    if dp.kulites is not None:
        try:
            _kulites(task, read_wtd(dp.wtd), row["q"], out, folder, row)
        except InputError as e:
            row["kulites"] = f"failed: {str(e).splitlines()[0]}"
    row["status"] = "ok"
