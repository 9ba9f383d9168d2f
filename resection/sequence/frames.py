"""Reading the frames of a sequence, and telling whether a frame's file has changed.

A frame is a path to an image file (TIFF/PNG/NPY, :func:`resection.io.images.read_image`),
an in-memory ``(H, W)`` array, or a :class:`VideoFrame`: frame ``i`` of a file holding many
(Phantom ``.cine``, Photron ``.mraw``, multi-page TIFF, 3-D NPY), read through
:func:`resection.io.video.open_frames`. A sequence given as one such file is expanded by
:func:`expand_frames` into its frames, which are read one at a time where they are
processed (a worker opens the file once per chunk of frames).

The *fingerprint* of a file frame is what a resumed run compares with the fingerprint
recorded when the frame was computed: size, modification time, inode and status-change
time (``st_ctime``, which no user can set back: a file copied over another one with
``cp -p``, or restored with ``touch -r``, still changes it), and a digest (BLAKE2b) of a
sample of the content: the first and last 4 KiB and 16 blocks of 256 bytes at fixed
fractions of the size, 12 KiB in all whatever the file's size, so that no change of the
metadata alone can hide a new content. A different fingerprint recomputes the frame. Not
the whole content: hashing a 1 Mpx frame costs as much as reading it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from resection.errors import InputError

#: suffixes of files that may hold many frames
_MULTI_SUFFIXES = (".cine", ".mraw", ".cih", ".cihx", ".tif", ".tiff", ".npy")


@dataclass(frozen=True)
class VideoFrame:
    """Frame ``index`` (0-based) of the multi-frame file ``path``; ``label`` names it
    (``"run.cine#12"``) in messages and result files."""

    path: str
    index: int
    label: str


def expand_frames(frames: list) -> list:
    """``frames`` as given, or, when it is a single multi-frame file (``.cine``, ``.mraw``/
    ``.cih``, multi-page TIFF, 3-D NPY), the :class:`VideoFrame` of each of its frames
    (none is read here: only the file's header)."""
    if len(frames) != 1 or not isinstance(frames[0], (str, os.PathLike)):
        return frames
    p = Path(frames[0])
    if p.suffix.lower() not in _MULTI_SUFFIXES or not p.is_file():
        return frames
    from resection.io.video import VIDEO_SUFFIXES, open_frames

    with open_frames(p) as src:
        if src.n == 1 and p.suffix.lower() not in VIDEO_SUFFIXES:
            return frames  # one image
        return [VideoFrame(str(p), i, src.label(i)) for i in range(src.n)]


def load_image(frame, sources: dict | None = None) -> np.ndarray:
    """The frame's image (saturated pixels of integer files masked as NaN). ``sources``:
    the multi-frame files already open (path -> FrameSource), kept open for the next
    frames; without it a multi-frame file is opened and closed for this frame."""
    if isinstance(frame, np.ndarray):
        img = frame
    elif isinstance(frame, VideoFrame):
        from resection.io.video import open_frames

        if sources is None:
            with open_frames(frame.path, mask_saturated=True) as src:
                img = src[frame.index]
        else:
            if frame.path not in sources:
                sources[frame.path] = open_frames(frame.path, mask_saturated=True)
            img = sources[frame.path][frame.index]
    else:
        from resection.io.images import read_image

        img = read_image(frame, mask_saturated=True)  # saturated pixels -> NaN, masked
    if img.ndim != 2:
        raise InputError(f"expected a 2-D image, got shape {img.shape}")
    return img


def frame_name(frame) -> str:
    if isinstance(frame, VideoFrame):
        return frame.label
    return "" if isinstance(frame, np.ndarray) else os.fspath(frame)


_HEAD = 4096  # bytes sampled at the start and at the end of a file
_BLOCKS, _BLOCK = 16, 256  # and blocks at fixed fractions of its size


def content_digest(path: str | os.PathLike, size: int | None = None) -> str:
    """BLAKE2b digest (hex, 16 bytes) of the size of ``path`` and a fixed sample of its
    bytes (first and last 4 KiB, 16 blocks of 256 bytes spread evenly): 12 KiB read
    whatever the size."""
    import hashlib

    if size is None:
        size = os.path.getsize(path)
    h = hashlib.blake2b(str(size).encode(), digest_size=16)
    offsets = [0, max(0, size - _HEAD)]
    lengths = [_HEAD, _HEAD]
    for k in range(_BLOCKS):
        offsets.append(int((size - _BLOCK) * (k + 0.5) / _BLOCKS) if size > _BLOCK else 0)
        lengths.append(_BLOCK)
    with open(path, "rb") as fh:
        for off, n in zip(offsets, lengths, strict=True):
            fh.seek(off)
            h.update(fh.read(n))
    return h.hexdigest()


def fingerprint(frame, digests: dict | None = None) -> list | None:
    """``[size, mtime_ns, ctime_ns, inode, digest]`` of a file frame (of the whole file
    for a :class:`VideoFrame`; ``digest``: :func:`content_digest`), taken before it is
    read; ``[-1, -1, -1, -1, ""]`` for a path that cannot be examined (missing) or is not
    a regular file; None for an in-memory frame. ``digests``: the digests already taken
    (a caller's dict, filled here), reused for a file whose path and metadata are
    unchanged: the frames of one video share their file's."""
    import stat

    if isinstance(frame, np.ndarray):
        return None
    path = frame.path if isinstance(frame, VideoFrame) else frame
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            return [-1, -1, -1, -1, ""]
        key = (str(path), st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)
        digest = None if digests is None else digests.get(key)
        if digest is None:
            digest = content_digest(path, st.st_size)
            if digests is not None:
                digests[key] = digest
    except (OSError, ValueError):
        return [-1, -1, -1, -1, ""]
    return [int(st.st_size), int(st.st_mtime_ns), int(st.st_ctime_ns), int(st.st_ino), digest]


def changed(frame, recorded, digests: dict | None = None) -> bool:
    """Whether ``frame`` differs from the frame whose fingerprint was ``recorded`` (a
    record without one, from an older run, counts as changed); ``digests`` as for
    :func:`fingerprint`."""
    if isinstance(frame, np.ndarray):
        return False  # an in-memory frame has no identity beyond its index
    return recorded is None or list(recorded) != fingerprint(frame, digests)


def failure_reason(exc: BaseException, name: str) -> str:
    """One line: the exception's type and first line, naming the frame's file."""
    msg = str(exc).splitlines()[0] if str(exc) else ""
    if name and name not in msg:
        msg = f"{name}: {msg}" if msg else name
    return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__
