"""A binary file object over a real file ``_f`` whose writes after a failure are kept in
memory (``_shadow``: ``(offset, bytes)`` records) and read back over the file: the common
part of :class:`resection.io.journal.JournaledFile` and :class:`resection.io.guarded.
GuardedFile`, which decide when a write is shadowed."""

from __future__ import annotations

import io
import os

__all__ = ["ShadowedFile"]


class ShadowedFile(io.RawIOBase):
    """Position, size and reads of a file ``_f`` with in-memory records ``_shadow`` laid
    over it (subclasses set ``_f``, ``_pos = 0`` and ``_shadow = []``)."""

    def readable(self):
        return True

    def writable(self):
        return True

    def seekable(self):
        return True

    def seek(self, pos, whence=0):
        if whence == 2:
            pos += self._size()
        elif whence == 1:
            pos += self._pos
        self._pos = pos
        return pos

    def tell(self):
        return self._pos

    def _size(self) -> int:
        size = os.fstat(self._f.fileno()).st_size
        for off, data in self._shadow:
            size = max(size, off + len(data))
        return size

    def readinto(self, b):
        n = len(b)
        self._f.seek(self._pos)
        got = self._f.readinto(b) or 0
        if self._shadow:
            end = self._pos + n
            for off, data in self._shadow:
                a, z = max(self._pos, off), min(end, off + len(data))
                if a < z:
                    b[a - self._pos: z - self._pos] = data[a - off: z - off]
                    got = max(got, z - self._pos)
        self._pos += got
        return got
