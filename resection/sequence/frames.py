"""Reading the frames of a sequence, and telling whether a frame's file has changed.

A frame is a path to an image file (TIFF/PNG/NPY, :func:`resection.io.images.read_image`)
or an in-memory ``(H, W)`` array. The *fingerprint* of a file frame is what a resumed run
compares with the fingerprint recorded when the frame was computed: size, modification
time, inode and status-change time (``st_ctime``, which no user can set back: a file copied
over another one with ``cp -p``, or restored with ``touch -r``, still changes it). A
different fingerprint recomputes the frame. No content hash: hashing a 1 Mpx frame costs
as much as reading it, and every field above changes when a file is written.
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import InputError


def _load_image(frame) -> np.ndarray:
    if isinstance(frame, np.ndarray):
        img = frame
    else:
        from ..io.images import read_image

        img = read_image(frame, mask_saturated=True)  # saturated pixels -> NaN, masked
    if img.ndim != 2:
        raise InputError(f"expected a 2-D image, got shape {img.shape}")
    return img


def _frame_name(frame) -> str:
    return "" if isinstance(frame, np.ndarray) else os.fspath(frame)


def fingerprint(frame) -> list[int] | None:
    """``[size, mtime_ns, ctime_ns, inode]`` of a file frame, taken before it is read;
    ``[-1, -1, -1, -1]`` for a path that cannot be examined (missing); None for an
    in-memory frame."""
    if isinstance(frame, np.ndarray):
        return None
    try:
        st = os.stat(frame)
    except (OSError, ValueError):
        return [-1, -1, -1, -1]
    return [int(st.st_size), int(st.st_mtime_ns), int(st.st_ctime_ns), int(st.st_ino)]


def changed(frame, recorded) -> bool:
    """Whether ``frame`` differs from the frame whose fingerprint was ``recorded`` (a
    record without one, from an older run, counts as changed)."""
    if isinstance(frame, np.ndarray):
        return False  # an in-memory frame has no identity beyond its index
    return recorded is None or list(recorded) != fingerprint(frame)


def failure_reason(exc: BaseException, name: str) -> str:
    """One line: the exception's type and first line, naming the frame's file."""
    msg = str(exc).splitlines()[0] if str(exc) else ""
    if name and name not in msg:
        msg = f"{name}: {msg}" if msg else name
    return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__
