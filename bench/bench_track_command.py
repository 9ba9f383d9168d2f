"""The whole ``resection track`` command, start-up included, against an OpenCV-parts
pipeline on the same frames, in the same run (issue 21).

Scene: ``scenes.revolution`` (cylinder-cone-fin body, 36 targets all around, about half of
them on the far side, no normals and no mesh; 1280 x 800 8-bit frames with speckled paint,
glare and vibration, a roll sweep; 100 fps). ``--frames`` frames are rendered once (to
``--cache``, reused), the 200-frame period listed again for longer runs (the motion is
periodic over 200 frames, so the run stays continuous).

Each round runs, one after the other, in fresh processes (``python -m ...``):

* ``resection track FRAMES --link LINK ...`` (default workers: the run decides whether a
  local cluster pays its start-up), timed from the process start to its end;
* the OpenCV pipeline of ``bench/bench_track.py`` (the 8-bit frame as it is,
  ``SimpleBlobDetector`` with thresholds from 10 to 250 by ``--opencv-step``, nearest
  neighbour within 5 px of the markers projected with the
  previous pose, ``solvePnP`` from the previous pose), seeded with the exact frame-0 pose,
  writing its poses to a CSV; its imports included.

The rounds alternate (``--repeat``), the best of each is kept. Printed: frames/s of each
and their ratio, the peak resident memory (flat: the same for 200 and 2,000 frames), how
many frames went to the statistical matcher, the accuracy of both against the known
motion. ``--profile`` also runs ``track`` in this process under cProfile and prints the
steady cost per frame split by step.

Start-up and steady cost come from two run lengths: ``T(N) = S + N c``.

``--split N1,N2`` also times the command's steps inside its process (best of ``--repeat``,
the rounds alternating): the CLI's imports, the camera and tracker imports, the checks (the
detection, matching and pose modules imported: numba, SciPy), frame 0 (the compiled kernels
loaded from numba's cache, the detection, the linked pose), the frames, the CSVs, the wait
for the plot's process, and what is left of the whole process's wall time (the interpreter's
start and exit); and the plot's process alone (its imports, its warm-up figure, the
figure of N2 frames and its PNG). ``--amdahl N`` runs the command on one core
(``taskset -c 0``) and on the two, alternating: the serial seconds are ``S = 2 T2 - T1``
(Amdahl: ``T1 = S + P``, ``T2 = S + P / 2``), their share of the 2-core time
``S / T2 = 2 - T1 / T2`` (the issue's measure; until 2026-11-27 this printed
``2 T2 / T1 - 1``, their share of the 1-core time, under that name).

Run: ``flock /tmp/bench.lock .venv/bin/python bench/bench_track_command.py --frames 200 2000
[--repeat 2] [--opencv-step 20] [--split 2,200] [--amdahl 200]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PERIOD = 200


def render(cache: Path) -> dict:
    """The 200 frames of one period, the camera, markers and the link of frame 0."""
    from scipy.spatial import cKDTree

    from resection.io.images import read_image
    from resection.markers import detect_markers
    from scenes.revolution import revolution_model, write_sequence

    model = revolution_model(PERIOD)
    done = cache / "done.json"
    if not done.is_file():
        t = time.perf_counter()
        write_sequence(model, cache)
        print(f"rendered {PERIOD} frames in {time.perf_counter() - t:.0f} s")
        done.write_text("{}")
    # the linking of frame 0 (candidate numbers of this version's detection), every run
    cands = detect_markers(read_image(cache / "frame_00000.npy", mask_saturated=True), 5.0)
    vis = model.visible(0)
    d, j = cKDTree(cands.uv).query(model.uv(0)[vis])
    with open(cache / "link.csv", "w", encoding="utf-8") as fh:
        fh.write("id,candidate\n")
        for k, i, e in zip(model.ids[vis], j, d, strict=True):
            if e < 1.0:
                fh.write(f"{k},{i}\n")
    return {"model": model, "frames": [str(cache / f"frame_{k:05d}.npy") for k in range(PERIOD)],
            "camera": str(cache / "camera.json"), "markers": str(cache / "markers.csv"),
            "link": str(cache / "link.csv")}


def timed(cmd: list[str], env: dict) -> tuple[float, float, str]:
    """Wall seconds, peak RSS (MiB) of a command, and its stdout. It runs in the temporary
    folder: ``python -m`` puts the working folder before PYTHONPATH, and the tree it
    imports must be the one PYTHONPATH names (``--baseline``)."""
    import tempfile

    t = time.perf_counter()
    p = subprocess.run(["/usr/bin/time", "-f", "%M", *cmd], env=env, capture_output=True,
                       text=True, check=True, cwd=tempfile.gettempdir())
    wall = time.perf_counter() - t
    rss = float(p.stderr.strip().splitlines()[-1]) / 1024.0
    return wall, rss, p.stdout


OPENCV_RUNNER = """
import sys, json, numpy as np
sys.path.insert(0, {root!r}); sys.path.insert(0, {bench!r})
from bench_track import opencv_pipeline
from resection.io.cameras import read_camera
from resection.io.markers import read_markers
args = json.load(open({args!r}))
cam = read_camera(args["camera"]); ms = read_markers(args["markers"])
rv, tv, uv = opencv_pipeline(args["frames"], cam, ms.ids, ms.xyz, np.array(args["rvec0"]),
                             np.array(args["tvec0"]), 5.0, step=args["step"])
np.save(args["out"], np.hstack([rv, tv]))
"""


SPLIT_RUNNER = """
import time
T0 = time.perf_counter()
import functools, importlib.abc, importlib.machinery, json, sys
sys.path.insert(0, {root!r})
spans = {{}}


def wrap(obj, name, label):
    f = getattr(obj, name)

    @functools.wraps(f)
    def timed(*a, **k):
        t = time.perf_counter()
        try:
            return f(*a, **k)
        finally:
            s = spans.setdefault(label, [t - T0, 0.0])
            s[1] += time.perf_counter() - t
    setattr(obj, name, timed)


WRAP = {{"resection.sequence.run": [("checked", "checks (detection, matching, pose imported)"),
                                    ("track", "track()"),
                                    ("write_csvs", "CSVs")],
        "resection.sequence.execute": [("process_linked", "frame 0 (kernels, detection, link)"),
                                       ("_execute_local", "frames 1..N-1")],
        "resection.cli.track": [("_run", "command")],
        "resection.sequence.plot_worker": [("_draw_there", "plot (waiting for its process)")]}}


class After(importlib.abc.MetaPathFinder):
    # wraps the timed functions as soon as their module is imported by the command
    def find_spec(self, name, path, target=None):
        if name not in WRAP:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        run = spec.loader.exec_module

        def exec_module(module):
            run(module)
            for fn, label in WRAP[name]:
                wrap(module, fn, label)
        spec.loader.exec_module = exec_module
        return spec


sys.meta_path.insert(0, After())
from resection.cli.main import main
args = json.load(open({args!r}))
t = time.perf_counter()
rc = main(args["argv"])
spans["end"] = [time.perf_counter() - T0, 0.0]
print(json.dumps(spans))
from resection.cli.main import end_process
end_process(rc)  # as the command run as the program ends
"""

PLOT_RUNNER = """
import time
T0 = time.perf_counter()
import pickle, sys
sys.path.insert(0, {root!r})
import io
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from resection.sequence.motion_plots import motion_figure, save_figure
t1 = time.perf_counter()
k = np.arange(3)
FigureCanvasAgg(motion_figure(k, np.ones((3, 3)), np.ones((3, 3)), np.ones(3), k > 0,
                              reference=0)).print_png(io.BytesIO(),
                                                      pil_kwargs={{"compress_level": 1}})
t2 = time.perf_counter()
data = pickle.load(open({data!r}, "rb"))
fig = motion_figure(**data)
t3 = time.perf_counter()
save_figure(fig, {png!r})
t4 = time.perf_counter()
print(f"{{t1 - T0:.3f}} {{t2 - t1:.3f}} {{t3 - t2:.3f}} {{t4 - t3:.3f}}")
"""


def split(sc: dict, ns: list[int], repeat: int, env: dict) -> None:
    """The command's steps timed inside its process, and the plot's process alone."""
    import pickle

    from resection.sequence import read_track
    from resection.sequence.motion_plots import motion_data

    cache = Path(sc["frames"][0]).parent
    py = sys.executable
    best: dict = {}
    for _ in range(repeat):
        for n in ns:
            frames = [sc["frames"][k % PERIOD] for k in range(n)]
            out = cache / f"split_{n}"
            argv = ["track", *frames, "--camera", sc["camera"], "--markers", sc["markers"],
                    "--link", sc["link"], "--diameter", "5", "--out", str(out),
                    "--no-progress", "--no-resume"]
            a = cache / f"split_{n}.json"
            a.write_text(json.dumps({"argv": argv}))
            load = os.getloadavg()[0]
            wall, _, stdout = timed([py, "-c", SPLIT_RUNNER.format(root=str(ROOT),
                                                                    args=str(a))], env)
            spans = json.loads(stdout.strip().splitlines()[-1])
            if n not in best or wall < best[n][0]:
                best[n] = (wall, spans, load)
    print("\nsplit of the command (seconds; best of the rounds):")
    for n, (wall, spans, load) in sorted(best.items()):
        cmd0, cmd = spans["command"]
        tr0, tr = spans["track()"]
        ck0, ck = spans["checks (detection, matching, pose imported)"]
        rows = [("interpreter start, CLI imports and parsing", cmd0),
                ("camera and tracker imports", ck0 - cmd0)]
        rows += [(k, v[1]) for k, v in spans.items()
                 if k not in ("command", "track()", "end")]
        rows.append(("track(): the rest (folder, lock, manifest, assembling)",
                     tr - sum(spans[k][1] for k in spans
                              if k in ("checks (detection, matching, pose imported)",
                                       "frame 0 (kernels, detection, link)",
                                       "frames 1..N-1", "CSVs"))))
        rows.append(("command: the rest (read camera, messages)",
                     cmd - tr - (ck0 - cmd0)
                     - spans.get("plot (waiting for its process)", [0, 0])[1]))
        rows.append(("process start and end (whole wall - the rest)",
                     wall - spans["end"][0]))
        print(f"  {n} frames, whole process {wall:.2f} s (load {load:.1f}):")
        for label, v in rows:
            print(f"    {label:55s} {v:6.3f}")
    n2 = max(best)
    data = cache / "plot_data.pkl"
    with open(data, "wb") as fh:
        pickle.dump(motion_data(read_track(cache / f"split_{n2}")), fh)
    runs = []
    for _ in range(repeat):
        _, _, stdout = timed([py, "-c", PLOT_RUNNER.format(root=str(ROOT), data=str(data),
                                                           png=str(cache / "plot.png"))], env)
        runs.append([float(x) for x in stdout.split()])
    imp, warm, fig, png = min(runs, key=sum)
    print(f"  the plot's process alone ({n2} frames): imports {imp:.3f} s, warm-up figure "
          f"{warm:.3f} s (both while the command runs), then the figure {fig:.3f} s and "
          f"its drawing and PNG {png:.3f} s")


def amdahl(sc: dict, n: int, repeat: int, env: dict) -> None:
    """The whole command on one core and on two, alternating: the serial share."""
    frames = [sc["frames"][k % PERIOD] for k in range(n)]
    cmd = [sys.executable, "-m", "resection.cli", "track", *frames, "--camera", sc["camera"],
           "--markers", sc["markers"], "--link", sc["link"], "--diameter", "5", "--out",
           str(Path(sc["frames"][0]).parent / f"amdahl_{n}"), "--no-progress", "--no-resume"]
    best = {1: np.inf, 2: np.inf}
    loads = []
    for _ in range(repeat):
        for cores in (1, 2):
            loads.append(os.getloadavg()[0])
            wall, _, _ = timed((["taskset", "-c", "0"] if cores == 1 else []) + cmd, env)
            best[cores] = min(best[cores], wall)
            print(f"  {n} frames on {cores} core(s): {wall:.2f} s")
    serial = 2.0 * best[2] - best[1]
    print(f"Amdahl, {n} frames: 1 core {best[1]:.2f} s, 2 cores {best[2]:.2f} s, speed-up "
          f"{best[1] / best[2]:.2f}, serial {serial:.2f} s: {100 * serial / best[2]:.0f} % of "
          f"the 2-core time ({100 * serial / best[1]:.0f} % of the 1-core time) (load "
          f"{min(loads):.1f}-{max(loads):.1f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, nargs="+", default=[200, 2000])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--cache", default="/tmp/bench_track_revolution")
    ap.add_argument("--workers", type=int, default=None,
                    help="track's --workers (default: its own choice)")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--split", help="N1,N2: the command's steps timed in its process")
    ap.add_argument("--amdahl", type=int, help="frames of the 1-core / 2-core runs")
    ap.add_argument("--baseline", metavar="DIR",
                    help="also run the command from this source tree (a checkout of "
                    "another commit) in every round: before -> after in the same run")
    ap.add_argument("--skip-ratio", action="store_true",
                    help="only --split / --amdahl / --profile, not the runs against OpenCV")
    ap.add_argument("--opencv-step", type=int, default=10,
                    help="the blob detector's threshold step (bench_track.py: 10; 20 halves "
                    "its time)")
    args = ap.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    sc = render(cache)
    model = sc["model"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    py = sys.executable
    cam0 = model.camera_at(0)
    print(f"load average at start: {os.getloadavg()}")
    results = {}
    for n in ([] if args.skip_ratio else args.frames):
        frames = [sc["frames"][k % PERIOD] for k in range(n)]
        out = cache / f"out_{n}"
        track_cmd = [py, "-m", "resection.cli", "track", *frames, "--camera", sc["camera"],
                     "--markers", sc["markers"], "--link", sc["link"], "--diameter", "5",
                     "--out", str(out), "--no-progress", "--no-resume"]
        if args.workers is not None:
            track_cmd += ["--workers", str(args.workers)]
        cv_args = cache / f"cv_{n}.json"
        cv_args.write_text(json.dumps({"camera": sc["camera"], "markers": sc["markers"],
                                       "frames": frames, "rvec0": cam0.rvec.tolist(),
                                       "tvec0": np.asarray(cam0.t).tolist(),
                                       "out": str(cache / f"cv_{n}.npy"),
                                       "step": args.opencv_step}))
        cv_cmd = [py, "-c", OPENCV_RUNNER.format(root=str(ROOT), bench=str(ROOT / "bench"),
                                                 args=str(cv_args))]
        best = {"track": (np.inf, 0.0), "opencv": (np.inf, 0.0)}
        runs = [("track", track_cmd, env), ("opencv", cv_cmd, env)]
        if args.baseline:
            best["baseline"] = (np.inf, 0.0)
            base_cmd = [*track_cmd]
            base_cmd[base_cmd.index("--out") + 1] = str(out) + "_baseline"
            runs.insert(1, ("baseline", base_cmd, {**env, "PYTHONPATH": args.baseline}))
        loads = []
        for _ in range(args.repeat):
            for key, cmd, cmd_env in runs:
                loads.append(os.getloadavg()[0])
                wall, rss, stdout = timed(cmd, cmd_env)
                if key == "track":
                    summary = stdout.strip().splitlines()
                if wall < best[key][0]:
                    best[key] = (wall, rss)
                print(f"  {n} frames, {key}: {wall:.2f} s ({n / wall:.1f} frames/s), peak "
                      f"RSS {rss:.0f} MiB")
        from resection.sequence import read_track

        res = read_track(out)
        methods = [json.load(open(out / "frames" / f"frame_{k:06d}.json",
                                  encoding="utf-8"))["method"] for k in range(n)]
        ang_truth = np.degrees(model.angles[np.arange(n) % PERIOD])
        from resection.sequence import relative_motion

        e_track = np.abs(res.angles - (ang_truth - ang_truth[0])).max()
        pv = np.load(cache / f"cv_{n}.npy")
        ang_cv, _ = relative_motion(pv[:, :3], pv[:, 3:], 0)
        e_cv = np.nanmax(np.abs(ang_cv - (ang_truth - ang_truth[0])))
        results[n] = best
        t_fps, c_fps = n / best["track"][0], n / best["opencv"][0]
        print(f"{n} frames: track {t_fps:.1f} frames/s (peak {best['track'][1]:.0f} MiB), "
              f"OpenCV parts {c_fps:.1f} frames/s (peak {best['opencv'][1]:.0f} MiB): "
              f"ratio {t_fps / c_fps:.2f}; predicted {methods.count('predicted')}, "
              f"matched {methods.count('matched')}, linked {methods.count('linked')}, "
              f"failed {int((~res.ok).sum())}; largest attitude difference to the truth "
              f"track {e_track:.3f} deg, OpenCV {e_cv:.3f} deg; load during the runs "
              f"{min(loads):.1f}-{max(loads):.1f}")
        if args.baseline:
            b_fps = n / best["baseline"][0]
            print(f"  baseline ({args.baseline}): {b_fps:.1f} frames/s (peak "
                  f"{best['baseline'][1]:.0f} MiB), ratio to OpenCV {b_fps / c_fps:.2f}; "
                  f"this tree / baseline {t_fps / b_fps:.2f}")
        print("  " + " | ".join(summary))
    if len(args.frames) >= 2 and not args.skip_ratio:
        n1, n2 = sorted(args.frames)[:2]
        for key in results[n1]:
            c = (results[n2][key][0] - results[n1][key][0]) / (n2 - n1)
            s = results[n1][key][0] - n1 * c
            print(f"{key}: start-up {s:.2f} s, steady {1e3 * c:.2f} ms a frame "
                  f"({1 / c:.0f} frames/s)")
    if args.split:
        split(sc, [int(x) for x in args.split.split(",")], args.repeat, env)
    if args.amdahl:
        amdahl(sc, args.amdahl, args.repeat, env)
    if args.profile:
        profile(sc, min(args.frames))
    print(f"load average at the end: {os.getloadavg()}")


def profile(sc: dict, n: int) -> None:
    """``track`` in this process (one worker) under cProfile: the steady cost per frame
    split by step (cumulative time of the step's function over the frames)."""
    import cProfile
    import pstats
    import tempfile

    from resection.io.cameras import read_camera
    from resection.sequence import track

    frames = [sc["frames"][k % PERIOD] for k in range(n)]
    cam = read_camera(sc["camera"])
    with tempfile.TemporaryDirectory() as tmp:
        link = sc["link"]
        track(frames[:3], cam, sc["markers"], link=link, diameter=5.0, out_dir=tmp + "/w",
              workers=1, progress=False)  # warm: imports, kernels
        pr = cProfile.Profile()
        t = time.perf_counter()
        pr.enable()
        track(frames, cam, sc["markers"], link=link, diameter=5.0, out_dir=tmp + "/o",
              workers=1, progress=False)
        pr.disable()
        wall = time.perf_counter() - t
    st = pstats.Stats(pr)
    # cProfile sees the main thread only: the frames' files are written by another thread;
    # here, the main thread's queueing of the frame's file
    steps = {"fingerprint": ("frames.py", "fingerprint"),
             "read frame": ("frames.py", "load_image"),
             "predict + gate (whole)": ("predict.py", "track_predicted"),
             "  window fits": ("refine.py", "refine_markers"),
             "  pose (Gauss-Newton)": ("predict.py", "refine_pose"),
             "  acceptance": ("acceptance.py", "judge"),
             "statistical matcher": ("match.py", "match_markers"),
             "detection (frame 0, matcher frames)": ("detect.py", "detect_markers"),
             "frame record + file queued": ("execute.py", "record"),
             "CSVs": ("outputs.py", "write_csvs")}
    cum = {}
    for (file, _, fn), (_, _, _, ct, _) in st.stats.items():
        for label, (where, name) in steps.items():
            if fn == name and file.endswith(where) and "resection" in file:
                cum[label] = cum.get(label, 0.0) + ct
    print(f"\nprofile, {n} frames in this process, main thread (cProfile adds overhead): "
          f"{wall:.2f} s, {1e3 * wall / n:.2f} ms a frame")
    for label in steps:
        if label in cum:
            print(f"  {label:28s} {1e3 * cum[label] / n:7.3f} ms a frame")


if __name__ == "__main__":
    main()
