"""``resection._threads.run_blocks``: every block once, results in the blocks' order, the
calling thread among the workers, the first error raised in the caller."""

from __future__ import annotations

import threading
import time

import pytest

from resection._threads import run_blocks, split_range


@pytest.mark.parametrize("workers", [1, 2, 5])
def test_run_blocks_runs_each_block_once_in_order(workers):
    blocks = split_range(1000, workers, min_size=7)
    seen, lock = [], threading.Lock()

    def fn(b):
        time.sleep(0.001 * (b[0] % 3))  # blocks end out of order
        with lock:
            seen.append((b, threading.get_ident()))
        return sum(range(*b))

    got = run_blocks(fn, blocks, workers)
    assert got == [sum(range(*b)) for b in blocks]
    assert sorted(b for b, _ in seen) == sorted(blocks)  # each once
    threads = {t for _, t in seen}
    assert len(threads) <= workers
    if workers > 1:  # the caller works too (not only waits)
        assert threading.get_ident() in threads


def test_run_blocks_raises_the_first_error_and_stops_taking_blocks():
    ran = []

    def fn(b):
        ran.append(b)
        if b[0] == 0:
            raise ValueError("block 0")
        time.sleep(0.01)
        return b

    blocks = [(i, i + 1) for i in range(50)]
    with pytest.raises(ValueError, match="block 0"):
        run_blocks(fn, blocks, 2)
    assert len(ran) < len(blocks)
