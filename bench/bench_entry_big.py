"""Is the orchestration of ``selfillum entry`` free at the issue's size? An entry of
``--datapoints`` datapoints x ``--cameras`` cameras x ``--frames`` frames of a 1280 x 800
12-bit ``.mraw`` on uPSP's kind of 609,000-face grid, against the sum of the same
datapoints run alone by ``selfillum unsteady`` (one command a datapoint, uPSP's deck, its
own process and its own view factors), on the same files, poses and options.

The entry is built from one single-camera run already on disk (``--source``: a folder with
``model.grid``, ``model.tgts``, ``paint.txt``, ``steady.f``, ``run.wtd``, ``cam01.mraw`` /
``.cih`` and ``cam01.json``, the camera-to-model pose of frame 0, as
:func:`scenes.unsteady_run.make_unsteady_run` writes them), nothing rendered again:

- the video is made ``--frames`` long by playing the source forward and then backward
  (a continuous motion); the even cameras' copy is moved by :data:`SHIFT` pixels (a
  camera with its principal point moved: each camera its own calibration, as the run
  requires); every datapoint's camera is a link to one of these;
- each camera's camera-to-tunnel calibration is the source's camera carried back by the
  source ``.wtd``'s attitude about a centre of rotation (``test_config.json``), so the
  tunnel's prediction is right at the source's ALPHA;
- each datapoint has its own ``.wtd``: ALPHA stepped by ``--alpha-step`` degrees about the
  source's, so each calibration from the tunnel starts off by that much and refines onto
  the video's targets (the video is the same: the refined pose is the same).

Timing: ``--warmup`` runs the entry once on ``--warmup-frames`` frames (untimed: numba's
cached kernels, the page cache) and keeps its ``camNN-to-model.json`` as the alone runs'
calibrations. Then ``--rounds`` rounds, each the entry (A) and the datapoints alone (B),
the order alternating (A B, B A, ...), every command whole under ``/usr/bin/time -v``
and ``nice -n 10``; the ratio A / B per round is printed with the machine's load. The
machine is shared: read the ratios, not the seconds.

    python bench/bench_entry_big.py --make ENTRY_DIR \\
        --source RUN_DIR --datapoints 4 --cameras 2 --frames 500
    python bench/bench_entry_big.py --run ENTRY_DIR --rounds 2
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RUN = "2001"
#: the centre of rotation in model units (the model's nose region; any point will do: the
#: tunnel calibration is made for it).
COR = (0.2, 0.0, 0.0)
#: the even cameras' images moved by this many pixels (dx, dy): a camera of its own (its
#: principal point moved), so no two cameras share a calibration.
SHIFT = (24, -16)


def _frames_of(cih: Path) -> tuple[int, int, int]:
    t = cih.read_text()
    get = {k: int(re.search(rf"{k}\s*:\s*(\d+)", t).group(1))
           for k in ("Total Frame", "Image Width", "Image Height")}
    return get["Total Frame"], get["Image Height"], get["Image Width"]


def _write_video(src: Path, dst: Path, frames: int, shift: tuple = (0, 0)) -> None:
    """``frames`` frames of ``src`` (16-bit ``.mraw``): forward, then backward; each
    image moved by ``shift`` = (dx, dy) pixels (the strip uncovered: zero, no light)."""
    n, h, w = _frames_of(src.with_suffix(".cih"))
    order = list(range(n))
    k = n - 2
    step = -1
    while len(order) < frames:  # ping-pong: a continuous motion
        order.append(k)
        if k in (0, n - 1):
            step = -step
        k += step
    a = np.memmap(src, np.uint16, "r", shape=(n, h, w))
    out = np.memmap(dst, np.uint16, "w+", shape=(frames, h, w))
    dx, dy = shift
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h),
                                                                slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w),
                                                                slice(0, w + dx))
    for i, j in enumerate(order[:frames]):
        if dx or dy:
            out[i] = 0
            out[i, yd, xd] = a[j, ys, xs]
        else:
            out[i] = a[j]
    out.flush()
    del out
    cih = src.with_suffix(".cih").read_text()
    cih = re.sub(r"(Total Frame\s*:\s*)\d+", rf"\g<1>{frames}", cih)
    cih = re.sub(r"(Original Total Frame\s*:\s*)\d+", rf"\g<1>{frames}", cih)
    dst.with_suffix(".cih").write_text(cih)


def make_big_entry(out: Path, source: Path, *, datapoints: int = 4, cameras: int = 2,
                   frames: int = 500, alpha_step: float = 0.1) -> list[str]:
    """Write the entry (module notes) into ``out``; returns the datapoint ids."""
    from resection.io.cameras import read_camera, write_camera
    from resection.io.wtd import read_wtd
    from selfillum.entry.tunnel import Attitude, TunnelConfig, model_to_tunnel

    out.mkdir(parents=True, exist_ok=True)
    for d in ("inputs", "camera-tunnel-calibration", "videos", "wtd", "decks"):
        (out / d).mkdir(exist_ok=True)
    for name in ("model.grid", "model.tgts", "paint.txt", "steady.f"):
        link = out / "inputs" / name
        if not link.exists():
            link.symlink_to(source / name)
    shifts = {n: SHIFT if n % 2 == 0 else (0, 0) for n in range(1, cameras + 1)}
    videos = {}
    for n in range(1, cameras + 1):
        videos[n] = out / "videos" / f"source{frames}_{shifts[n][0]}_{shifts[n][1]}.mraw"
        if not videos[n].exists():
            _write_video(source / "cam01.mraw", videos[n], frames, shifts[n])
    wtd = read_wtd(source / "run.wtd")
    alpha0 = wtd.value("ALPHA")
    cfg = TunnelConfig(np.array(COR))
    M, d = model_to_tunnel(Attitude(alpha0, 0.0, 0.0, 0.0), cfg)
    cam = read_camera(source / "cam01.json")  # camera-to-model: R X + t
    R_ct = cam.R @ M.T  # so that R_ct (M X + d) + t_ct = R X + t
    cam_t = cam.with_pose(R=R_ct, t=cam.t - R_ct @ d)
    for n in range(1, cameras + 1):
        K = np.array(cam_t.K, float)  # a moved image: the principal point moved with it
        K[0, 2] += shifts[n][0]
        K[1, 2] += shifts[n][1]
        write_camera(out / "camera-tunnel-calibration" / f"camera{n:02d}.json",
                     cam_t.replace(K=K), format="upsp")
    rows = [ln for ln in (source / "run.wtd").read_text().splitlines()
            if ln.strip() and not ln.startswith(("RUN", "#"))]
    taps = [ln for ln in rows[1:] if len(ln.split()) == 2]
    head = ["MACH", "ALPHA", "BETA", "PHI", "PTOT", "TTF", "PS", "Q", "STRUTZ"]
    ids = []
    for s in range(1, datapoints + 1):
        dp = f"{RUN}{s:02d}"
        ids.append(dp)
        a = alpha0 + alpha_step * ((s - 1) // 2 + 1) * (1 if s % 2 else -1) \
            if s > 1 else alpha0
        vals = [wtd.value("MACH"), a, 0.0, 0.0, wtd.value("PTOT"), wtd.value("TTF"),
                wtd.value("PS"), wtd.value("Q"), 0.0]
        (out / "wtd" / f"{dp}.wtd").write_text(
            f"RUN {RUN} {s}\n#  " + "\t".join(head) + "\n" +
            "\t".join(f"{v:g}" for v in vals) + "\n# Tap CP\n" + "\n".join(taps) + "\n")
        for n in range(1, cameras + 1):
            for ext in (".mraw", ".cih"):
                link = out / "videos" / f"{dp}{n:02d}{ext}"
                if not link.exists():
                    link.symlink_to(videos[n].with_suffix(ext).name)
    tc = {"oblique_angle": 70, "tunnel-cor_to_tgts_tvec": list(COR),
          "tunnel-cor_to_tgts_rmat": np.eye(3).tolist(),
          "tunnel-cor_to_tunnel-origin_tvec": [0.0, 0.0, 0.0],
          "tunnel-cor_to_tunnel-origin_rmat": np.eye(3).tolist()}
    (out / "inputs" / "test_config.json").write_text(json.dumps(tc, indent=1))
    common = {"camera_tunnel_calibration_dir": "camera-tunnel-calibration",
              "camera_video_dir": "videos", "grid_file": "inputs/model.grid",
              "paint_calibration_file": "inputs/paint.txt",
              "steady_psp_file": "inputs/steady.f", "targets_file": "inputs/model.tgts"}
    (out / "index.json").write_text(json.dumps(
        {"__meta__": {"test_name": "entry-big"},
         "datapoints": {dp: dict(common, wtd_file=f"wtd/{dp}.wtd") for dp in ids}},
        indent=1))
    for nf, name in ((-1, "processing.json"), (8, "processing-warmup.json")):
        (out / name).write_text(json.dumps({"processing": {
            "defaults": {"psp_process": {"target_patcher": "polynomial",
                                         "registration": "pixel",
                                         "overlap": "average_view", "filter": "none",
                                         "filter_size": 3, "oblique_angle": 70,
                                         "number_frames": nf},
                         "external-calibration": tc},
            "__overlays__": [["defaults", {".*": ".*"}]]}}, indent=1))
    return ids


def _deck(out: Path, dp: str, cameras: int, cal_dir: Path) -> Path:
    """uPSP's deck of one datapoint alone, with the entry's calibrated first frames."""
    lines = ["@general", "    test = entry-big", f"    run = {RUN}", f"    sequence = {dp[4:]}",
             "@all", f"    sds = {out / 'wtd' / (dp + '.wtd')}",
             f"    grid = {out / 'inputs' / 'model.grid'}",
             f"    targets = {out / 'inputs' / 'model.tgts'}"]
    for n in range(1, cameras + 1):
        lines += ["@camera", f"    number = {n}",
                  f"    filename = {out / 'videos' / f'{dp}{n:02d}.mraw'}",
                  f"    calibration = {cal_dir / dp / f'cam{n:02d}-to-model.json'}"]
    lines += ["@options", "    target_patcher = polynomial", "    registration = pixel",
              "    overlap = average_view", "    filter = none", "    filter_size = 3",
              "    oblique_angle = 70", "    number_frames = -1",
              "@output", f"    dir = {out / 'decks'}"]
    p = out / "decks" / f"{dp}.inp"
    p.write_text("\n".join(lines) + "\n")
    return p


def _timed(cmd: list, log: Path) -> float:
    """Wall seconds of ``cmd`` under ``/usr/bin/time -v`` and ``nice -n 10``."""
    full = ["nice", "-n", "10", "/usr/bin/time", "-v", *cmd]
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        r = subprocess.run(full, stdout=fh, stderr=subprocess.STDOUT)
    el = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)}: exit {r.returncode}; see {log}")
    m = re.search(r"Elapsed \(wall clock\) time.*: (?:(\d+):)?(\d+):([\d.]+)", log.read_text())
    if m:
        h, mi, s = m.groups()
        el = int(h or 0) * 3600 + int(mi) * 60 + float(s)
    return el


def run_bench(out: Path, rounds: int, cameras: int, rays: int, warmup: bool,
              workers: int = 1, first: int = 0) -> None:
    exe = [str(Path(sys.executable).with_name("selfillum"))]
    ids = list(json.loads((out / "index.json").read_text())["datapoints"])
    logs = out / "logs"
    logs.mkdir(exist_ok=True)
    cal = out / "calibrated"
    base = [str(out / "index.json"), "--rays", str(rays), "--quiet", "--workers", str(workers)]
    if warmup or not cal.is_dir():
        if cal.exists():
            shutil.rmtree(cal)
        el = _timed([*exe, "entry", *base, "--processing", str(out / "processing-warmup.json"),
                     "--out", str(cal)], logs / "warmup.log")
        print(f"warm-up entry (8 frames, untimed for the ratio): {el:.1f} s", flush=True)
    decks = {dp: _deck(out, dp, cameras, cal) for dp in ids}
    for r in range(first, first + rounds):
        order = ("A", "B") if r % 2 == 0 else ("B", "A")
        res = {}
        for side in order:
            load = os.getloadavg()[0]
            if side == "A":
                dst = out / f"A{r}"
                if dst.exists():
                    shutil.rmtree(dst)
                res["A"] = (_timed([*exe, "entry", *base, "--processing",
                                    str(out / "processing.json"), "--out", str(dst)],
                                   logs / f"A{r}.log"), load)
                summ = (dst / "summary.csv").read_text()
                shutil.rmtree(dst)
                print(f"round {r} A: entry (--workers {workers}) {res['A'][0]:.1f} s "
                      f"(load {load:.1f})\n{summ}",
                      flush=True)
            else:
                dst = out / f"B{r}"
                if dst.exists():
                    shutil.rmtree(dst)
                dst.mkdir()
                each = []
                for dp in ids:
                    each.append(_timed([*exe, "unsteady", str(decks[dp]), "--paint-calibration",
                                        str(out / "inputs" / "paint.txt"), "--steady",
                                        str(out / "inputs" / "steady.f"), "--reflectance",
                                        "0.6", "--rays", str(rays), "--out",
                                        str(dst / f"{dp}.h5")], logs / f"B{r}-{dp}.log"))
                shutil.rmtree(dst)
                res["B"] = (sum(each), load)
                print(f"round {r} B: alone {' + '.join(f'{x:.1f}' for x in each)} = "
                      f"{sum(each):.1f} s (load {load:.1f})", flush=True)
        print(f"round {r} ({'-'.join(order)}): ratio entry / sum(alone) = "
              f"{res['A'][0] / res['B'][0]:.3f}; load at the start of each "
              f"{res['A'][1]:.1f} / {res['B'][1]:.1f}", flush=True)


_TIME = re.compile(r"time: set-up ([\d.]+) s, phase 1 ([\d.]+) s \(first frame ([\d.]+) s\), "
                   r"phase 2 and outputs ([\d.]+) s")
_SIZE = re.compile(r"unsteady: (\d+) frames x (\d+) nodes")
_CPU = re.compile(r"(User|System) time \(seconds\): ([\d.]+)")
_WALL = re.compile(r"Elapsed \(wall clock\) time.*: (?:(\d+):)?(\d+):([\d.]+)")


def phase_costs(log: Path, cameras: int) -> dict:
    """A ``selfillum unsteady`` log under ``/usr/bin/time -v``: its phases (wall s), its
    size, its CPU seconds, and the per-cell costs: Phase 1 after frame 0 per frame and
    camera, Phase 2 per node and frame (wall s, and CPU s by the run's CPU/wall)."""
    t = log.read_text()
    setup, p1, first, p2 = (float(x) for x in _TIME.search(t).groups())
    T, N = (int(x) for x in _SIZE.search(t).groups())
    cpu = sum(float(v) for _, v in _CPU.findall(t))
    h, mi, sec = _WALL.search(t).groups()
    wall = int(h or 0) * 3600 + int(mi) * 60 + float(sec)
    util = cpu / wall
    return {"wall": wall, "cpu": cpu, "util": util, "setup": setup, "first": first,
            "phase1": p1, "phase2": p2, "frames": T, "nodes": N,
            "p1_frame_cam": (p1 - first) / ((T - 1) * cameras),
            "p2_cell": p2 / (T * N), "fixed": wall - (p1 - first) - p2}


def run_cores(out: Path, frames: int, repeat: int) -> list:
    """The first datapoint alone (``selfillum unsteady``, its deck, ``--number-frames``)
    on one core and on two (``taskset``), alternating, ``repeat`` times each: Amdahl's
    serial share of the 1-core time, ``s = 2 T2 / T1 - 1``."""
    exe = str(Path(sys.executable).with_name("selfillum"))
    ids = list(json.loads((out / "index.json").read_text())["datapoints"])
    deck = out / "decks" / f"{ids[0]}.inp"
    logs = out / "logs"
    res = {1: [], 2: []}
    for r in range(repeat):
        for c in ((1, 2) if r % 2 == 0 else (2, 1)):
            dst = out / f"cores{c}.h5"
            for q in out.glob(f"cores{c}*"):
                shutil.rmtree(q) if q.is_dir() else q.unlink()
            log = logs / f"cores{c}-{r}.log"
            el = _timed(["taskset", "-c", "0" if c == 1 else "0,1", exe, "unsteady",
                         str(deck), "--paint-calibration", str(out / "inputs" / "paint.txt"),
                         "--steady", str(out / "inputs" / "steady.f"), "--reflectance",
                         "0.6", "--number-frames", str(frames), "--out", str(dst)], log)
            res[c].append(el)
            print(f"cores {c} (round {r}, load {os.getloadavg()[0]:.1f}): {el:.1f} s; "
                  f"{phase_costs(log, 2)}", flush=True)
    for q in out.glob("cores[12]*"):
        shutil.rmtree(q) if q.is_dir() else q.unlink()
    t1, t2 = min(res[1]), min(res[2])
    print(f"best of {repeat}: 1 core {t1:.1f} s, 2 cores {t2:.1f} s: speed-up {t1 / t2:.2f}, "
          f"serial share of the 1-core time {2 * t2 / t1 - 1:.2f}", flush=True)
    return [t1, t2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--make", metavar="DIR", help="write the entry into DIR")
    ap.add_argument("--source", metavar="DIR", help="the single-camera run it is made from")
    ap.add_argument("--run", metavar="DIR", help="time the entry in DIR")
    ap.add_argument("--datapoints", type=int, default=4)
    ap.add_argument("--cameras", type=int, default=2)
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--alpha-step", type=float, default=0.1, metavar="DEG")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--rays", type=int, default=64)
    ap.add_argument("--workers", type=int, default=1,
                    help="the entry's --workers (1: Dask local cluster, the default; 0: in "
                    "this process)")
    ap.add_argument("--first-round", type=int, default=0,
                    help="number of the first round (its parity sets the order A-B / B-A)")
    ap.add_argument("--no-warmup", action="store_true",
                    help="reuse DIR/calibrated from an earlier warm-up")
    ap.add_argument("--cores", metavar="DIR",
                    help="the first datapoint alone on 1 core and on 2 (taskset)")
    ap.add_argument("--cores-frames", type=int, default=128)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--costs", metavar="LOG", nargs="+",
                    help="print the phases and per-cell costs of these alone-run logs")
    a = ap.parse_args()
    if a.make:
        if not a.source:
            raise SystemExit("--make needs --source")
        t0 = time.perf_counter()
        ids = make_big_entry(Path(a.make), Path(a.source), datapoints=a.datapoints,
                             cameras=a.cameras, frames=a.frames, alpha_step=a.alpha_step)
        print(f"entry of {len(ids)} datapoints x {a.cameras} cameras x {a.frames} frames in "
              f"{a.make} ({time.perf_counter() - t0:.1f} s)")
    if a.run:
        run_bench(Path(a.run), a.rounds, a.cameras, a.rays, not a.no_warmup, a.workers,
                  a.first_round)
    if a.cores:
        run_cores(Path(a.cores), a.cores_frames, a.repeat)
    for log in a.costs or []:
        print(log, phase_costs(Path(log), a.cameras))


if __name__ == "__main__":
    main()
