"""The pressure stage as users run it: ``selfillum unsteady`` with uPSP's deck (its whole
command in a fresh process) against the same run mapped the full way (a ray cast every
frame: the path before the sparse products), each deck option against the deck, and what
``--uncertainty`` adds to ``selfillum psp`` and ``selfillum unsteady``.

Folded from ``bench/bench_unsteady_options.py`` and ``bench/bench_uncertainty.py``. The
whole run at the issue's size (609,000 faces, 256 frames of 1280 x 800), and beside a
checkout of another revision, is in ``bench_unsteady``.
"""

from __future__ import annotations

import sys

from ._peers import bench_size, best_times, run_command
from .bench_io import cache_dir

#: The options scene: 20,000 faces, one 320 x 240 12-bit camera, 96 frames at 2 kHz, a
#: 0.3-degree vibration, uPSP's deck (``polynomial``, ``pixel``, ``average_view``).
OPTIONS_SCENE = dict(frames=96, faces=20_000, width=320, height=240, vibration_deg=0.3,
                     bits=12, fps=2000.0, freqs={"tone": 200.0, "wave": 140.0,
                                                 "block": 500.0, "vibration": 36.0})

#: Deck options against the deck (one camera): the flags the command is given.
OPTION_CASES = {
    "deck": [],
    "registration none": ["--registration", "none"],
    "track": ["--registration", "track"],
    "patcher none": ["--target-patcher", "none"],
    "pixel, gaussian 5": ["--filter", "gaussian", "--filter-size", "5"],
    "track, gaussian 5": ["--registration", "track", "--filter", "gaussian",
                          "--filter-size", "5"],
    "best_view": ["--overlap", "best_view"],
    "merge": ["--overlap", "merge"],
    "first-frame": ["--registration", "first-frame"],
    "2 cameras": [],
    "4 cameras": [],
}

#: The cameras of each case's scene (the options scene made with that many cameras).
OPTION_CAMERAS = {"2 cameras": 2, "4 cameras": 4}

#: The option set every case is measured against, on the case's own scene (the same
#: cameras): no registration, the least work a frame.
FASTEST = "registration none"


def _options_scene(cameras: int = 1, size: str = "small"):
    """The options scene (``small``) or the issue's 609,000-face run (``issue``,
    :data:`benchmarks.bench_unsteady.DECK`) made with ``cameras`` cameras, written once."""
    from scenes.unsteady_run import make_unsteady_run

    if size == "issue":
        from .bench_unsteady import DECK, deck_scene

        if cameras == 1:
            return deck_scene("issue")
        folder = cache_dir(f"unsteady_deck_issue_{cameras}cams")
        if not (folder / "run.inp").exists():
            make_unsteady_run(folder, cameras=cameras, **DECK["issue"])
        return folder
    folder = cache_dir("unsteady_options" + ("" if cameras == 1 else f"_{cameras}cams"))
    if not (folder / "run.inp").exists():
        make_unsteady_run(folder, truth_rays=256, cameras=cameras, **OPTIONS_SCENE)
    return folder


def _clear_outputs(out) -> None:
    """Remove what an earlier call wrote at ``out``: the file or folder itself and what is
    named after it beside it (``OUT.xdmf``, ``OUT_rms.png``, the ``OUT.h5.work`` folder),
    not a neighbour that merely starts with the same letters (the inputs' folder): the
    commands refuse an existing output."""
    import shutil

    for p in [out, *out.parent.glob(out.stem + ".*"), *out.parent.glob(out.stem + "_*")]:
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()


def _unsteady(folder, out, flags):
    """The command on ``folder``'s deck writing ``out`` (its earlier outputs removed)."""
    _clear_outputs(out)
    return [sys.executable, "-m", "selfillum.cli", "unsteady", str(folder / "run.inp"),
            "--paint-calibration", str(folder / "paint.txt"), "--steady",
            str(folder / "steady.f"), "--fps", str(OPTIONS_SCENE["fps"]), "--out", str(out),
            "--no-plots", "--quiet", *flags]


class UnsteadyDeckAgainstFullMaps:
    """``selfillum unsteady run.inp`` on the options scene (see ``OPTIONS_SCENE``) with
    uPSP's deck, whole command in a fresh process, against the same command with
    ``--full-maps`` (every frame cast and merged: the path before the sparse products).
    Tracked beside: the peak memory."""

    timeout = 1800
    number = 1
    repeat = (1, 2, 600.0)

    def setup(self):
        self.folder = _options_scene()
        self.out = cache_dir("unsteady_deck_out")

    def _deck(self):
        return run_command(_unsteady(self.folder, self.out / "deck.h5", []))

    def _full(self):
        return run_command(_unsteady(self.folder, self.out / "full.h5", ["--full-maps"]))

    def time_deck(self):
        self._deck()

    def time_full_maps(self):
        self._full()

    def track_ratio_to_full_maps(self):
        a, b = best_times(self._deck, self._full, repeat=2)
        return a / b

    track_ratio_to_full_maps.unit = "deck / full maps"

    def track_peak_memory(self):
        return self._deck()[1]

    track_peak_memory.unit = "MiB"


class UnsteadyDeckOptions:
    """Each deck option (``OPTION_CASES``), the whole command in a fresh process, against
    the fastest option set (:data:`FASTEST`, no registration) on the same scene, in turn
    (target: every option set at least 0.8 of the fastest). The scene is the options scene
    (``WTO_BENCH_SIZE`` unset or ``small``) or the issue's 609,000-face run of 256 frames
    (``issue``); the camera cases run the deck on the scene made with 2 or 4 cameras
    (``OPTION_CAMERAS``), measured against no registration on those cameras (2 or 4 times
    the pixels of the one-camera scene: ``track_ratio_to_deck`` gives their cost over the
    one-camera deck)."""

    timeout = 3600
    number = 1
    repeat = (1, 2, 600.0)
    params = ([bench_size()], list(OPTION_CASES))
    param_names = ["size", "option"]

    def setup(self, size, option):
        self.size = size
        self.folder = _options_scene(1, size)
        self.own = _options_scene(OPTION_CAMERAS.get(option, 1), size)
        self.out = cache_dir(f"unsteady_options_out_{size}")

    def _run(self, folder, flags):
        out = self.out / "case.h5"
        if self.size == "issue":
            from .bench_unsteady import deck_command

            _clear_outputs(out)
            return run_command(deck_command(folder, out, "--no-plots", "--quiet", *flags))
        return run_command(_unsteady(folder, out, flags))

    def _case(self, option):
        return self._run(self.own, OPTION_CASES[option])

    def _fastest(self):
        return self._run(self.own, OPTION_CASES[FASTEST])

    def time_command(self, size, option):
        self._case(option)

    def time_fastest(self, size, option):
        self._fastest()

    def track_of_fastest(self, size, option):
        a, b = best_times(self._fastest, lambda: self._case(option), repeat=3,
                          alternate=True)
        return a / b

    track_of_fastest.unit = "fastest / option (target >= 0.8)"

    def track_ratio_to_deck(self, size, option):
        a, b = best_times(lambda: self._case(option),
                          lambda: self._run(self.folder, OPTION_CASES["deck"]), repeat=2,
                          alternate=True)
        return a / b

    track_ratio_to_deck.unit = "option / one-camera deck"


class UncertaintyCost:
    """What ``--uncertainty`` (linear) adds, the whole command with it against the same
    command without it, in turn in fresh processes: ``psp`` on the painted corner of
    ``scenes/psp_uncertainty.py`` (3,600 faces, a 640 x 480 camera, 5 frames a
    condition, the taps in a ``.wtd``, ``--u marker=0.05px``), with and without its
    pictures; ``unsteady`` on ``scenes/unsteady_run.py`` (2,500 faces, 200 frames). Targets
    (issue 36): at most 1.3 for ``psp`` and 1.2 for ``unsteady``."""

    timeout = 1800
    number = 1
    repeat = (1, 2, 600.0)
    params = ["psp", "psp --no-plots", "unsteady"]
    param_names = ["command"]

    def setup(self, command):
        folder = cache_dir("uncertainty")
        if command.startswith("psp"):
            from scenes.psp_uncertainty import psp_uncertainty_case, write_psp_files

            pdir = folder / "psp30"
            pdir.mkdir(exist_ok=True)
            c = psp_uncertainty_case(resolution=30, width=640, height=480, exact_rays=1024)
            self.base = write_psp_files(c, pdir, 5, rays=1024, seed=0)
            self.extra = ["--uncertainty", "--markers", str(pdir / "model.tgts"), "--u",
                          "marker=0.05px"]
            if command.endswith("--no-plots"):
                self.base = [*self.base, "--no-plots"]
            self.out = pdir / "out"
        else:
            from scenes.unsteady_run import make_unsteady_run

            udir = folder / "unsteady"
            fps = 1000.0  # the scene's rate, given: its frames are an NPY stack
            if not (udir / "run.inp").exists():
                make_unsteady_run(udir, frames=200, fps=fps)
            self.base = ["unsteady", str(udir / "run.inp"), "--paint-calibration",
                         str(udir / "paint.txt"), "--steady", str(udir / "steady.f"),
                         "--quiet", "--no-plots", "--fps", str(fps)]
            self.extra = ["--uncertainty", "--u", "gain_a=0.01", "--u", "t0=1K", "--u",
                          "q=2psf"]
            self.out = folder / "u.h5"

    def _run(self, extra):
        _clear_outputs(self.out)
        return run_command([sys.executable, "-m", "selfillum.cli", *self.base, *extra,
                            "--out", str(self.out)])

    def time_with_uncertainty(self, command):
        self._run(self.extra)

    def time_without(self, command):
        self._run([])

    def track_ratio_to_without(self, command):
        a, b = best_times(lambda: self._run(self.extra), lambda: self._run([]), repeat=2)
        return a / b

    track_ratio_to_without.unit = "with / without --uncertainty"
