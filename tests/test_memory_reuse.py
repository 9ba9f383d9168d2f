"""``resection.memory.keep_freed_memory`` undoes what Dask's nanny sets in its workers'
environment (``MALLOC_TRIM_THRESHOLD_=65536``, which also fixes glibc's mmap threshold at
128 KiB): arrays of a few MB allocated and freed in a loop, as a run does a frame, then
come from the heap again instead of being mapped and their pages faulted in each time."""

from __future__ import annotations

import os
import subprocess
import sys

_LOOP = """
import resource, sys
import numpy as np
if sys.argv[1] == "keep":
    from resection.memory import keep_freed_memory
    assert keep_freed_memory()
a = np.ones(10)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(200):  # a 4 MB array a step, written, then freed
    a = np.full(500_000, 1.0) + a[:1]
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> int:
    env = dict(os.environ, MALLOC_TRIM_THRESHOLD_="65536")
    r = subprocess.run([sys.executable, "-c", _LOOP, mode], env=env, capture_output=True,
                       text=True, check=True)
    return int(r.stdout.split()[-1])


def test_freed_arrays_are_reused_under_the_dask_nannys_environment():
    plain, kept = _faults("plain"), _faults("keep")
    # 200 arrays of 977 pages: mapped anew each time without the setting
    assert plain > 200 * 900
    assert kept < plain / 20
