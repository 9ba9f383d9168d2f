"""Which chunk of a run can start again, and from which frames.

The chunks of a run go to the workers together, each seeded from the reference frame
(frame 0). A chunk whose first frame fails from frame 0 (the model moved too far since)
computes nothing more and comes back *deferred* (:func:`resection.sequence.process.run_chunk`).
Here such a chunk is started again, on a worker, as soon as the chunk before it has come
back with good frames: seeded from its last two good frames, as the chunks of a run in one
process are. A roll sweep then still runs in parallel: the chunks near frame 0's attitude
run first, and each deferred chunk follows its neighbour, rather than all of them waiting
for the sequential pass at the end (:func:`resection.sequence.process.repair`), which now
only sees the frames that failed twice.

A chunk is started again once at most; one that is deferred again is left to that pass.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from resection.sequence.results import DEFERRED, FrameResult

__all__ = ["ChunkChain", "is_deferred", "tail_of"]

#: the frames before a chunk are not known yet (that chunk is running, or deferred)
_UNKNOWN = object()


def is_deferred(dicts: list[dict]) -> bool:
    """Whether a chunk came back without computing its frames (see module notes)."""
    return any(d.get("matched_from") == DEFERRED for d in dicts)


def tail_of(dicts: list[dict]) -> tuple[FrameResult, FrameResult | None] | None:
    """``(last, the one before it)`` of the good frames of a chunk's results, or ``None``
    when it has none."""
    good = [d for d in dicts if d.get("status") == "ok"]
    if not good:
        return None
    tail = [FrameResult.from_dict(d) for d in good[-2:]]
    return tail[-1], (tail[0] if len(tail) == 2 else None)


@dataclass
class ChunkChain:
    """The chunks of a run, in frame order, as they come back.

    Parameters
    ----------
    seeds : list of int
        Frame index each chunk was first seeded from (frame 0, the reference).
    before : (FrameResult, FrameResult or None) or None
        The last two good frames before the first chunk (``None``: none).
    known : bool
        Whether ``before`` is known now; if not, :meth:`set_before` gives it later.
    """

    seeds: list[int]
    before: tuple | None
    known: bool = True
    _tails: list = field(init=False)
    _waiting: set = field(init=False, default_factory=set)
    _retried: set = field(init=False, default_factory=set)

    def __post_init__(self) -> None:
        self._tails = [_UNKNOWN] * len(self.seeds)
        if not self.known:
            self.before = _UNKNOWN

    def set_before(self, before: tuple | None) -> list[tuple[int, tuple]]:
        """The last two good frames before the first chunk are now known (``known``
        false: the chunk before it ran beside the others). Returns the chunks to start
        now, as :meth:`came_back`."""
        self.before = before
        return self._release()

    def _before(self, k: int):
        return self.before if k == 0 else self._tails[k - 1]

    def came_back(self, k: int, dicts: list[dict]) -> list[tuple[int, tuple]]:
        """Chunk ``k`` came back with the frame dictionaries ``dicts``. Returns the chunks
        to start now, ``[(k, (reference, previous)), ...]``."""
        if is_deferred(dicts) and k not in self._retried:
            self._retried.add(k)
            self._waiting.add(k)
        else:
            tail = tail_of(dicts)
            # no good frame in it: the frames before it are those before the chunk
            self._tails[k] = tail if tail is not None else self._before(k)
        return self._release()

    def _release(self) -> list[tuple[int, tuple]]:
        ready = []
        for k in sorted(self._waiting):
            seed = self._before(k)
            if seed is _UNKNOWN:
                continue
            self._waiting.discard(k)
            if seed is None or seed[0].frame <= self.seeds[k]:
                continue  # no closer frame than the first seed: left to the repair pass
            ready.append((k, seed))
        return ready

    @property
    def waiting(self) -> list[int]:
        """Deferred chunks still waiting for the chunk before them."""
        return sorted(self._waiting)
