"""Every compiled kernel a command uses is found again in numba's on-disk cache by the next
process: a second run of the same command compiles nothing. (A kernel made in a factory
that closed over another compiled function was keyed by that function's pickle, new in
every process: each ``unsteady`` run with uPSP's ``registration = pixel`` compiled its
affine fit anew, 1-2.5 s of every run.)"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.unsteady_cases import copy_run, small_run  # noqa: F401 (fixture)

ROOT = Path(__file__).resolve().parents[1]


def _saved(case: Path, out: str, extra: list[str]) -> list[str]:
    """The cache files numba wrote during one run of the command (NUMBA_DEBUG_CACHE)."""
    cmd = [sys.executable, "-m", "selfillum.cli", "unsteady", str(case / "run.inp"),
           "--paint-calibration", str(case / "paint.txt"), "--steady",
           str(case / "steady.f"), "--fps", "1000", "--out", str(case / out), "--quiet",
           "--no-plots", "--rays", "16", *extra]
    env = {**os.environ, "NUMBA_DEBUG_CACHE": "1", "PYTHONPATH": str(ROOT)}
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=str(case))
    assert p.returncode == 0, p.stderr[-2000:]
    return [ln for ln in (p.stdout + p.stderr).splitlines() if "data saved" in ln]


@pytest.mark.parametrize("extra", [[], ["--registration", "track"]],
                         ids=["upsp-deck", "track"])
def test_second_run_compiles_nothing(small_run, tmp_path, extra):  # noqa: F811
    case = copy_run(small_run, tmp_path / "case")
    _saved(case, "first.h5", extra)  # compiles what the cache does not hold yet
    assert _saved(case, "second.h5", extra) == []
