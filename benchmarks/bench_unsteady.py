"""``selfillum unsteady`` end to end as a user runs it, whole commands in fresh processes:
its speed against the bare read of its frames (the I/O floor no run can beat), at a small
size by default and at the issue's size on request; the same run beside another checkout;
and its accuracy next to a painted block against a uPSP-like pipeline.

Folded from ``bench/bench_unsteady.py`` (its cases and its ``--deck`` and ``--baseline``
modes) and ``bench/bench_unsteady_accuracy.py``. The size is the environment variable
``WTO_BENCH_SIZE`` (``small``, the default, or ``issue``), the benchmarks' one parameter,
so that asv keeps the two sizes' histories apart::

    WTO_BENCH_SIZE=issue .venv/bin/asv run --python=same --quick -b UnsteadyDeckVsRead

The issue-size inputs are written once under ``<tmp>/wto-asv/`` (the 609,000-face run took
47 minutes to render on the 2-core development machine) and reused by later runs.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ._peers import ROOT, baseline_root, bench_size, best_times, run_command
from .bench_io import cache_dir

#: ``make_large_run``'s sizes (``bench_unsteady.py``'s defaults at ``issue``).
LARGE = {"small": dict(nodes=20_000, frames=64, width=320, height=200),
         "issue": dict(nodes=600_000, frames=2000, width=1280, height=800)}

#: uPSP's kind of run (issue 33): ``make_unsteady_run``'s arguments at each size; the
#: ``issue`` one is the 609,000-face run of the history (286,338 nodes, a 12-bit 1280 x 800
#: ``.mraw`` of 256 frames at 10 kHz, uPSP's deck).
_DECK_COMMON = dict(fps=10000.0, vibration_deg=0.15, heave_m=0.0005, drift_deg=0.05,
                    bits=12, video_format="mraw",
                    freqs={"tone": 1000.0, "wave": 700.0, "block": 2500.0,
                           "vibration": 180.0})
DECK = {"small": dict(_DECK_COMMON, faces=20_000, frames=64, width=320, height=200,
                      truth_rays=256),
        "issue": dict(_DECK_COMMON, faces=609_000, frames=256, width=1280, height=800)}

#: The flags of ``bench_unsteady.py``'s cases, on the ``make_large_run`` scene.
CASES = {"fixed": ["--registration", "none", "--no-si"],
         "fixed+si": ["--registration", "none"],
         "moving+si": ["--registration", "track", "--track", "{folder}/track1"]}


def deck_scene(size: str) -> Path:
    """The folder of uPSP's kind of run at ``size`` (``DECK``), written once."""
    from scenes.unsteady_run import make_unsteady_run

    folder = cache_dir(f"unsteady_deck_{size}")
    if not (folder / "run.inp").exists():
        make_unsteady_run(folder, **DECK[size])
    return folder


def read_frames_command(video: Path) -> list[str]:
    """A fresh process reading every frame of ``video`` through ``open_frames`` (the
    package's reader: the same decoding the run pays), each frame summed."""
    code = ("import sys; from resection.io.video import open_frames; "
            "s = open_frames(sys.argv[1]); [s.native(k).sum() for k in range(len(s))]")
    return [sys.executable, "-c", code, str(video)]


def deck_command(folder: Path, out: Path, *extra: str) -> list[str]:
    """The user's command on the scene's deck, nothing else."""
    return [sys.executable, "-m", "selfillum.cli", "unsteady", str(folder / "run.inp"),
            "--paint-calibration", str(folder / "paint.txt"), "--steady",
            str(folder / "steady.f"), "--reflectance", "0.6", "--out", str(out), *extra]


def _clear(out: Path) -> None:
    for p in out.parent.glob(out.stem + "*"):
        if p.is_file():
            p.unlink()


class UnsteadyCasesVsRead:
    """``selfillum unsteady`` on ``scenes.unsteady_large`` (the slab and block as a Plot3D
    grid, one 12-bit camera as an NPY stack, a 120 Hz tone, a 0.1-degree vibration at 30 Hz;
    ``LARGE``: 20,000 nodes, 64 frames of 320 x 200 at ``small``, 600,000 nodes, 2,000
    frames of 1280 x 800 at ``issue``), for each case (``CASES``: fixed model without SI,
    fixed with SI, moving with SI from a ``track`` folder of the true poses), the whole
    command in a fresh process with its defaults and ``--overlap average_view``, against
    a fresh process reading every frame of the same video. Tracked beside: frames/s of
    the whole process and its peak memory."""

    timeout = 7200
    number = 1
    repeat = (1, 2, 600.0)
    params = ([bench_size()], list(CASES))
    param_names = ["size", "case"]

    def setup(self, size, case):
        from scenes.unsteady_large import make_large_run

        self.folder = cache_dir(f"unsteady_large_{size}")
        made = self.folder / "inputs.npy"
        if not made.exists():
            info = make_large_run(self.folder, **LARGE[size])
            np.save(made, [info["fps"]])
        self.fps = float(np.load(made)[0])
        self.frames = LARGE[size]["frames"]
        self.out = cache_dir("unsteady_large_out") / f"{case}.h5"
        f = self.folder
        self.cmd = [sys.executable, "-m", "selfillum.cli", "unsteady", "--grid",
                    str(f / "model.grid"), "--sds", str(f / "run.wtd"), "--video",
                    str(f / "cam01.npy"), "--calibration", str(f / "cam01.json"),
                    "--paint-calibration", str(f / "paint.txt"), "--steady",
                    str(f / "steady.f"), "--fps", str(self.fps), "--out", str(self.out),
                    "--quiet", "--overlap", "average_view",
                    *(a.format(folder=f) for a in CASES[case])]

    def _ours(self):
        _clear(self.out)
        return run_command(self.cmd)

    def _read(self):
        return run_command(read_frames_command(self.folder / "cam01.npy"))

    def time_command(self, size, case):
        self._ours()

    def time_read_frames(self, size, case):
        self._read()

    def track_ratio_to_read(self, size, case):
        a, b = best_times(self._ours, self._read, repeat=2)
        return a / b

    track_ratio_to_read.unit = "command / bare read"

    def track_frames_per_s(self, size, case):
        return self.frames / self._ours()[0]

    track_frames_per_s.unit = "frames/s"

    def track_peak_memory(self, size, case):
        return self._ours()[1]

    track_peak_memory.unit = "MiB"


class UnsteadyDeckVsRead:
    """The user's whole command on uPSP's kind of run (``DECK``: ``scenes.unsteady_run``,
    a 12-bit ``.mraw``, the deck's ``target_patcher = polynomial``, ``registration =
    pixel``, ``overlap = average_view``, SI, pictures; 20,000 faces and 64 frames of 320 x
    200 at ``small``, the issue's 609,000 faces and 256 frames of 1280 x 800 at ``issue``,
    target 10 frames/s and under 1,500 MB), ``selfillum unsteady run.inp
    --paint-calibration paint.txt --steady steady.f --reflectance 0.6 --out OUT.h5`` in a
    fresh process, against a fresh process reading every frame of its video. Tracked
    beside: frames/s of the whole process and its peak memory."""

    timeout = 7200
    number = 1
    repeat = (1, 2, 600.0)
    params = [bench_size()]
    param_names = ["size"]

    def setup(self, size):
        self.folder = deck_scene(size)
        self.frames = DECK[size]["frames"]
        self.out = cache_dir("unsteady_deck_out") / "deck.h5"

    def _ours(self):
        _clear(self.out)
        return run_command(deck_command(self.folder, self.out))

    def _read(self):
        return run_command(read_frames_command(self.folder / "cam01.mraw"))

    def time_command(self, size):
        self._ours()

    def time_read_frames(self, size):
        self._read()

    def track_ratio_to_read(self, size):
        a, b = best_times(self._ours, self._read, repeat=2)
        return a / b

    track_ratio_to_read.unit = "command / bare read"

    def track_frames_per_s(self, size):
        return self.frames / self._ours()[0]

    track_frames_per_s.unit = "frames/s"

    def track_peak_memory(self, size):
        return self._ours()[1]

    track_peak_memory.unit = "MiB"


class UnsteadyDeckVsBaseline:
    """The command of ``UnsteadyDeckVsRead`` on the same run, beside the same command run
    from another checkout (``WTO_BENCH_BASELINE``: the absolute path of a folder with that
    revision's ``resection/`` and ``selfillum/``, e.g. made by ``git archive REV | tar -x
    -C DIR``; it runs with this environment's libraries), the two in
    turn, the order alternating, best of 3 each: the ratio is this checkout's time over
    the baseline's (below 1: faster). Skipped when ``WTO_BENCH_BASELINE`` is unset."""

    timeout = 7200
    number = 1
    repeat = (1, 1, 600.0)
    params = [bench_size()]
    param_names = ["size"]

    def setup(self, size):
        import os
        import subprocess

        self.base = baseline_root()
        if self.base is None:
            raise NotImplementedError("WTO_BENCH_BASELINE is not set")
        # the baseline's package is the one imported under its PYTHONPATH
        where = subprocess.run([sys.executable, "-c", "import selfillum; "
                                "print(selfillum.__file__)"], capture_output=True, text=True,
                               env={**os.environ, "PYTHONPATH": str(self.base)},
                               cwd=str(self.base.parent), check=True).stdout.strip()
        if not Path(where).resolve().is_relative_to(self.base):
            raise RuntimeError(f"the baseline imports {where}, not {self.base}'s package")
        self.folder = deck_scene(size)
        self.out = cache_dir("unsteady_deck_out") / "base.h5"

    def _run(self, root):
        _clear(self.out)
        return run_command(deck_command(self.folder, self.out), root=root)

    def time_command(self, size):
        self._run(ROOT)

    def time_baseline(self, size):
        self._run(self.base)

    def track_ratio_to_baseline(self, size):
        a, b = best_times(lambda: self._run(ROOT), lambda: self._run(self.base), repeat=3,
                          alternate=True)
        return a / b

    track_ratio_to_baseline.unit = "this checkout / baseline"


def _amplitude(d, t, f):
    A = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)])
    c, *_ = np.linalg.lstsq(A, d, rcond=None)
    return np.hypot(c[0], c[1])


def score(run, d, t, pts) -> dict:
    """The run's dCp ``d`` (T, N) at times ``t`` against the scene's truth after uPSP's
    own 6th-order detrend (what Phase 2 can see): p95 over the nodes of the RMS error away
    from the block (> 0.12) and within 0.038 (1.5 in) of it; the plate tone's amplitude
    over the truth's (median, nodes away); the block's tone on the plate nodes within
    0.025 of it on every side (the truth has none there): median amplitude, its excess."""
    truth = np.nan_to_num(run.truth)
    c = np.polynomial.polynomial.polyfit(t, truth, 6)
    seen_truth = truth - np.polynomial.polynomial.polyval(t, c).T
    seen = np.isfinite(d).all(axis=0)
    x, y = pts[:, 0], pts[:, 1]
    gap = np.maximum(np.abs(x) - 0.04, np.abs(y) - 0.03)
    far = run.plate & seen & (gap > 0.12)
    near = run.plate & seen & (gap < 0.038)
    around = run.around & seen
    err = np.sqrt(np.mean((d - seen_truth) ** 2, axis=0))
    tone = np.median(_amplitude(d[:, far], t, run.freqs["tone"])) / run.amps["tone"]
    b = np.median(_amplitude(d[:, around], t, run.freqs["block"]))
    b_truth = np.median(_amplitude(seen_truth[:, around], t, run.freqs["block"]))
    return {"p95_far": float(np.percentile(err[far], 95)),
            "p95_near": float(np.percentile(err[near], 95)), "tone_ratio": float(tone),
            "block_tone": float(b), "block_excess": float(b - b_truth)}


class UnsteadyAccuracyVsUpspLike:
    """Accuracy next to a painted block whose tone is on all its faces (issue 33's table):
    ``scenes.unsteady_run`` (2,500 faces, 200 frames of 200 x 150, a vibrating model,
    painted targets, noise, uPSP's deck), ``selfillum unsteady`` with the project's
    defaults (``--registration track``, SI) against a uPSP-like run of the same deck
    (``--registration first-frame``: uPSP's affine registration of the first frame's map,
    ``--no-si``), both in this process, scored against the truth after uPSP's 6th-order
    detrend (``score``). The ratio is of their times; tracked beside: the 95th percentile
    over the nodes of the RMS dCp error near the block (within 1.5 in) and away from it,
    the plate tone's amplitude over the truth's, and the block tone's excess on the plate
    around it (ours over the uPSP-like run's)."""

    timeout = 1800
    number = 1
    repeat = (1, 2, 600.0)
    FRAMES, FACES, FPS = 200, 2500, 1000.0

    def setup_cache(self):
        from scenes.unsteady_run import make_unsteady_run

        run = make_unsteady_run(cache_dir("unsteady_accuracy") / "scene", frames=self.FRAMES,
                                faces=self.FACES, fps=self.FPS)
        return {k: score(run, *self._run(k)) for k in ("ours", "upsp")}

    def _run(self, side):
        import h5py

        from selfillum.cli import main

        scene = cache_dir("unsteady_accuracy") / "scene"
        out = cache_dir("unsteady_accuracy") / f"{side}.h5"
        _clear(out)
        extra = ["--registration", "first-frame", "--no-si"] if side == "upsp" else []
        rc = main(["unsteady", str(scene / "run.inp"), "--paint-calibration",
                   str(scene / "paint.txt"), "--steady", str(scene / "steady.f"), "--fps",
                   str(self.FPS), "--out", str(out), "--quiet", "--no-plots", *extra])
        if rc != 0:
            raise RuntimeError(f"{out.name}: exit {rc}")
        with h5py.File(out) as f:
            return f["dcp"][()], f["frames/time"][()], f["grid/points"][()]

    def time_ours(self, scores):
        self._run("ours")

    def time_upsp_like(self, scores):
        self._run("upsp")

    def track_ratio_to_upsp_like(self, scores):
        a, b = best_times(lambda: self._run("ours"),
                          lambda: self._run("upsp"), repeat=2)
        return a / b

    track_ratio_to_upsp_like.unit = "ours / uPSP-like"

    def track_p95_error_near_block(self, scores):
        return scores["ours"]["p95_near"]

    track_p95_error_near_block.unit = "dCp"

    def track_p95_error_near_block_upsp_like(self, scores):
        return scores["upsp"]["p95_near"]

    track_p95_error_near_block_upsp_like.unit = "dCp"

    def track_p95_error_away(self, scores):
        return scores["ours"]["p95_far"]

    track_p95_error_away.unit = "dCp"

    def track_tone_over_truth(self, scores):
        return scores["ours"]["tone_ratio"]

    track_tone_over_truth.unit = "amplitude / truth"

    def track_block_tone_excess_over_upsp_like(self, scores):
        return scores["ours"]["block_excess"] / scores["upsp"]["block_excess"]

    track_block_tone_excess_over_upsp_like.unit = "ours / uPSP-like"
