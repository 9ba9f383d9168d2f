"""Is the orchestration of ``selfillum entry`` free? A whole entry against the sum of its
datapoints run alone (each its own process, its own view factors), whole commands in fresh
processes after an untimed warm-up (numba's cached kernels, the page cache): issue 35's
target is a ratio of at most 1.2.

Folded from ``bench/bench_entry.py`` (the synthetic entry of ``scenes.entry``) and
``bench/bench_entry_big.py`` (the issue's size, built by ``scenes.entry_big`` from the
run of ``bench_unsteady.DECK``). The issue's size (4 datapoints x 2 cameras x 500 frames of
1280 x 800 on the 609,000-face grid: about half an hour a round on 2 cores; the ratio
takes two rounds and each ``time_`` one more)::

    WTO_BENCH_SIZE=issue .venv/bin/asv run --python=same --quick -b EntryVsUnsteadyAlone
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

from ._peers import bench_size, best_times, run_command
from .bench_io import cache_dir
from .bench_unsteady import deck_scene

#: ``bench_entry.py``'s entry: ``make_entry`` with 4 datapoints (ALPHA -5 to 15 degrees),
#: 2,500 faces, 64 frames of 200 x 150, no wind-off, nothing corrupt; ``--rays 64``.
SMALL_ENTRY = dict(datapoints=4, faces=2500, frames=64, width=200, height=150, rays=64)

#: ``make_big_entry``'s size at each ``WTO_BENCH_SIZE`` (its source: ``DECK[size]``);
#: ``--rays 64``, the entry on the default Dask local cluster (``--workers 1``).
BIG_ENTRY = {"small": dict(datapoints=2, cameras=2, frames=32, rays=64, workers=1),
             "issue": dict(datapoints=4, cameras=2, frames=500, rays=64, workers=1)}


def _selfillum(*args: str) -> list[str]:
    return [sys.executable, "-m", "selfillum.cli", *args]


def _fresh(path: Path) -> Path:
    if path.is_dir():
        shutil.rmtree(path)
    elif path.exists():
        path.unlink()
    return path


class EntryVsDatapointsAlone:
    """``selfillum entry INDEX --processing P --rays 64 --workers W`` on the synthetic
    entry of ``scenes.entry`` (``SMALL_ENTRY``: uPSP's index and processing file, 12-bit
    ``.mraw``, the plate and block at 2,500 faces, 4 datapoints of 64 frames of 200 x 150),
    the whole entry in a fresh process against the sum of its datapoints each run alone
    (``entry --only ID``: its own process, cluster and view factors), for the Dask local
    cluster (``W`` = 1) and in-process (``W`` = 0); target: at most 1.2."""

    timeout = 3600
    number = 1
    repeat = (1, 2, 600.0)
    params = [1, 0]
    param_names = ["workers"]

    def setup_cache(self):
        from scenes.entry import make_entry

        s = SMALL_ENTRY
        folder = cache_dir("entry_small")
        n = s["datapoints"]
        alphas = tuple(-5.0 + 20.0 * k / max(1, n - 1) for k in range(n))
        e = make_entry(_fresh(folder / "entry"), alphas=alphas, wind_off=False,
                       corrupt=False, faces=s["faces"], frames=s["frames"], width=s["width"],
                       height=s["height"])
        info = {"index": str(e.index), "processing": str(e.processing), "ids": list(e.ids)}
        for workers in self.params:  # untimed: compiled kernels cached, the page cache
            run_command(_selfillum(*self._base(info, workers), "--only", e.ids[0], "--out",
                                   str(_fresh(folder / "warm"))))
        return info

    @staticmethod
    def _base(info, workers):
        return ["entry", info["index"], "--processing", info["processing"], "--rays",
                str(SMALL_ENTRY["rays"]), "--quiet", "--workers", str(workers)]

    def _entry(self, info, workers):
        out = _fresh(cache_dir("entry_small") / "all")
        run_command(_selfillum(*self._base(info, workers), "--out", str(out)))

    def _alone(self, info, workers):
        for dp in info["ids"]:
            out = _fresh(cache_dir("entry_small") / dp)
            run_command(_selfillum(*self._base(info, workers), "--only", dp, "--out",
                                   str(out)))

    def time_entry(self, info, workers):
        self._entry(info, workers)

    def time_datapoints_alone(self, info, workers):
        self._alone(info, workers)

    def track_ratio_to_datapoints_alone(self, info, workers):
        a, b = best_times(lambda: self._entry(info, workers),
                          lambda: self._alone(info, workers), repeat=2, alternate=True)
        return a / b

    track_ratio_to_datapoints_alone.unit = "entry / sum(alone)"


class EntryVsUnsteadyAlone:
    """``selfillum entry index.json --processing processing.json --rays 64`` on the
    entry ``scenes.entry_big`` builds from the run of ``bench_unsteady.DECK`` (uPSP's
    index, processing file with uPSP's options, camera-to-tunnel calibrations; each
    datapoint's ALPHA 0.1-0.2 degree off the video's; ``BIG_ENTRY``: 2 datapoints x 2
    cameras x 32 frames of 320 x 200 on 20,000 faces at ``small``, the issue's 4 x 2 x 500
    frames of 1280 x 800 on 609,000 faces at ``issue``) on the default Dask local cluster,
    against the sum of its datapoints run alone by ``selfillum unsteady`` (uPSP's deck
    with the calibrated first frames of an untimed 8-frame warm-up entry,
    ``--reflectance 0.6``, the same rays), every command whole in a fresh process, the two
    sides in turn with the order alternating (A B, B A), best of 2; target: at most 1.2."""

    timeout = 14400
    number = 1
    repeat = (1, 1, 600.0)
    params = [bench_size()]
    param_names = ["size"]

    def setup_cache(self):
        from scenes.entry_big import datapoint_deck, make_big_entry

        size = bench_size()
        s = BIG_ENTRY[size]
        source = deck_scene(size)
        out = cache_dir(f"entry_big_{size}")
        if not (out / "processing-warmup.json").exists():  # the last file it writes
            make_big_entry(out, source, datapoints=s["datapoints"], cameras=s["cameras"],
                           frames=s["frames"])
        ids = list(json.loads((out / "index.json").read_text())["datapoints"])
        cal = out / "calibrated"
        # untimed: numba's cached kernels, the page cache; its calibrated first frames
        run_command(_selfillum(*self._base(out, s), "--processing",
                               str(out / "processing-warmup.json"), "--out",
                               str(_fresh(cal))))
        decks = [str(datapoint_deck(out, dp, s["cameras"], cal)) for dp in ids]
        return {"folder": str(out), "decks": decks, "ids": ids}

    @staticmethod
    def _base(out: Path, s: dict) -> list[str]:
        return ["entry", str(out / "index.json"), "--rays", str(s["rays"]), "--quiet",
                "--workers", str(s["workers"])]

    def setup(self, info, size):
        self.s = BIG_ENTRY[size]
        self.folder = Path(info["folder"])

    def _entry(self, info):
        run_command(_selfillum(*self._base(self.folder, self.s), "--processing",
                               str(self.folder / "processing.json"), "--out",
                               str(_fresh(self.folder / "A"))))

    def _alone(self, info):
        dst = self.folder / "B"
        _fresh(dst).mkdir()
        for dp, deck in zip(info["ids"], info["decks"], strict=True):
            run_command(_selfillum(
                "unsteady", deck, "--paint-calibration",
                str(self.folder / "inputs" / "paint.txt"), "--steady",
                str(self.folder / "inputs" / "steady.f"), "--reflectance", "0.6", "--rays",
                str(self.s["rays"]), "--out", str(dst / f"{dp}.h5")))

    def time_entry(self, info, size):
        self._entry(info)

    def time_unsteady_alone(self, info, size):
        self._alone(info)

    def track_ratio_to_unsteady_alone(self, info, size):
        a, b = best_times(lambda: self._entry(info), lambda: self._alone(info), repeat=2,
                          alternate=True)
        return a / b

    track_ratio_to_unsteady_alone.unit = "entry / sum(alone)"
