"""The run's memory budget and its progress line.

:func:`plan_blocks` turns a memory budget (``--memory MB``) into the blocks the run holds
at a time: Phase 1 keeps ``frames_per_block`` frames of every node (uint16 codes, with and
without the self-illumination removed, :mod:`selfillum.unsteady.work`) before writing them,
Phase 2 reads ``nodes_per_block`` nodes of every frame (codes) and makes their dCp (float32),
statistics, the change made by the SI removal and Welch spectra; when its blocks are
narrower than a chunk column, HDF5's cache of one chunk column of codes comes on top and is
counted. Both are whole chunk rows / columns of the
``(tc, nc)`` chunks when the budget allows, and smaller (partial chunks: slower, never
wrong) when it does not. The budget bounds the memory that grows with frames x nodes; the
fixed part of a run (the interpreter and libraries, one frame's images and surface maps,
the grid, the form factors) comes on top of it and is reported by :func:`peak_rss_mb`.

:class:`Progress` prints the whole command's progress on one line: frames done, frames/s,
the time left, and the nodes of Phase 2.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

from resection.errors import InputError

__all__ = ["PHASE1_BYTES_PER_CELL", "PHASE2_BYTES_PER_CELL", "BlockPlan", "plan_blocks",
           "chunk_column_bytes",
           "peak_rss_mb", "Progress", "DEFAULT_MEMORY_MB"]

#: Bytes a (frame, node) cell costs in Phase 1's block: two uint16 buffers.
PHASE1_BYTES_PER_CELL = 4
#: Bytes a (frame, node) cell costs at Phase 2's peak (codes with and without SI, dCp with
#: and without SI in float32, Welch's segments and their FFT; the NumPy path of nodes seen
#: in some frames only works a quarter of the block at a time): measured with tracemalloc
#: at 12 to 20 (1,024 frames, blocks of 85 to 2,160 nodes, every node seen), with a
#: margin for the nodes seen in part of the frames (float64 fits).
PHASE2_BYTES_PER_CELL = 48
#: The default budget of the blocks, MiB: with the fixed part of a 1280x800 run on a
#: 600k-node grid with SI and a moving model (about 1.05 GB), the whole run peaks under
#: 1.5 GB (asv's bench_unsteady.py); larger blocks only batch the writes more.
DEFAULT_MEMORY_MB = 256.0


@dataclass(frozen=True)
class BlockPlan:
    """``frames_per_block`` (Phase 1), ``nodes_per_block`` (Phase 2), ``budget`` (bytes,
    None: one chunk row / column)."""

    frames_per_block: int
    nodes_per_block: int
    budget: int | None

    def bytes_phase1(self, n_nodes: int) -> int:
        return self.frames_per_block * n_nodes * PHASE1_BYTES_PER_CELL

    def bytes_phase2(self, n_frames: int) -> int:
        return self.nodes_per_block * n_frames * PHASE2_BYTES_PER_CELL


def _fit(count: int, chunk: int, total: int) -> int:
    count = max(1, min(int(count), total))
    return count if count < chunk else count // chunk * chunk


def plan_blocks(n_frames: int, n_nodes: int, chunks: tuple[int, int],
                memory_mb: float | None = None, node_bytes: int = 0) -> BlockPlan:
    """Blocks for a ``(T, N)`` run chunked ``(tc, nc)`` within ``memory_mb`` (MiB).

    Without a budget: one chunk row of frames, one chunk column of nodes (a Phase 2 block
    of ``T nc`` cells: it grows with the length of the run). With one: the most whole
    chunk rows / columns that fit, or fewer frames / nodes than a chunk (at least one).
    ``node_bytes``: what a node of a Phase 2 block costs beyond its frames (its spectra,
    :attr:`selfillum.unsteady.spectra.Spectra.bytes_per_node`), counted in the budget.
    """
    T, N = int(n_frames), int(n_nodes)
    tc, nc = chunks
    if memory_mb is None:
        return BlockPlan(tc, nc, None)
    if not 0 < memory_mb < float("inf"):
        raise InputError(f"--memory must be a positive number of MiB, got {memory_mb}")
    b = int(memory_mb * 2**20)
    per_node = T * PHASE2_BYTES_PER_CELL + int(node_bytes)
    fpb = _fit(b // (N * PHASE1_BYTES_PER_CELL), tc, T)
    npb = _fit(b // per_node, nc, N)
    if npb < nc:  # HDF5 then caches a chunk column of codes (each chunk read once)
        npb = _fit(max(b - chunk_column_bytes(T, (tc, nc)), 0) // per_node, nc, N)
    return BlockPlan(fpb, npb, b)


def chunk_column_bytes(n_frames: int, chunks: tuple[int, int]) -> int:
    """Bytes of one chunk column of the work file's codes (uint16) over ``n_frames``."""
    tc, nc = (int(c) for c in chunks)
    return (int(n_frames) // tc + 1) * tc * nc * 2


def peak_rss_mb() -> float:
    """The process's peak resident memory so far, MiB: Linux's ``VmHWM`` (this program's
    own high-water mark; ``getrusage``'s ``ru_maxrss`` also holds the peak of the process
    it was started from, which a spawned child inherits through ``exec``), else
    ``getrusage``."""
    import resource

    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kb / (2**20 if sys.platform == "darwin" else 1024)


class Progress:
    """One line of progress for the whole run (to ``stream``, at most every ``every_s``).

    ``frame(done)`` after Phase 1's frames ``0 .. done - 1``: frames done, frames/s of
    this run (a resumed run counts from ``start``), the time left for Phase 1 at that rate;
    ``nodes(done)`` in Phase 2; ``close()`` ends the line.
    """

    def __init__(self, n_frames: int, n_nodes: int, *, enabled: bool = True,
                 stream=None, every_s: float = 0.5, start: int = 0):
        self.T, self.N = int(n_frames), int(n_nodes)
        self.start = int(start)  # frames done before (a resumed run)
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stdout
        self.every = every_s
        self.t0 = time.perf_counter()
        self.t2 = None
        self.t_first = None
        self._last = -1e9
        self.rate = float("nan")

    def _show(self, text: str, force: bool) -> None:
        now = time.perf_counter()
        if self.enabled and (force or now - self._last >= self.every):
            self._last = now
            print(f"\r{text}", end="", file=self.stream, flush=True)

    def frame(self, done: int) -> None:
        if self.t_first is None:
            self.t_first = time.perf_counter()  # the first frame mapped (its references)
        el = time.perf_counter() - self.t0
        self.rate = (done - self.start) / el if el > 0 else float("nan")
        left = (self.T - done) / self.rate if self.rate > 0 else float("nan")
        self._show(f"phase 1: frame {done}/{self.T}, {self.rate:.1f} frames/s, "
                   f"{left:.0f} s left   ", done == self.T)

    def nodes(self, done: int) -> None:
        now = time.perf_counter()
        if self.t2 is None:
            self.t2 = now
            if self.enabled:
                print(file=self.stream)
        el = now - self.t2
        rate = done / el if el > 0 else float("nan")
        left = (self.N - done) / rate if rate > 0 else float("nan")
        self._show(f"phase 2: node {done}/{self.N}, {rate:.0f} nodes/s, {left:.0f} s left   ",
                   done == self.N)

    def close(self) -> None:
        if self.enabled:
            print(file=self.stream, flush=True)
