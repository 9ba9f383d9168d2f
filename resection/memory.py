"""Memory budget of per-pixel work: refuse an image size that cannot be allocated,
before allocating it (a one-line error instead of a ``MemoryError`` traceback or a
machine swapping itself to a halt)."""

from __future__ import annotations

import os

from resection.errors import InputError

__all__ = ["available_memory", "check_memory", "check_pixel_memory", "release_freed_memory",
           "keep_freed_memory"]

#: Bytes a pixel at least costs in :class:`resection.surface.surface_map.SurfaceMap` (pixel grid,
#: ray directions, hit face, depth and barycentric coordinates: 80 bytes in float64/int64,
#: with the temporaries of the ray set-up and the hit test about twice that).
SURFACE_MAP_BYTES_PER_PIXEL = 160
#: Bytes a pixel at least costs in a picture (RGBA canvas, colour-mapped float image).
PICTURE_BYTES_PER_PIXEL = 40


def available_memory() -> int | None:
    """Memory the process can still allocate, bytes: ``MemAvailable`` of
    ``/proc/meminfo`` (Linux), else the physical memory (``sysconf``), else None."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):
        return None


def check_pixel_memory(width: int, height: int, bytes_per_pixel: float, what: str, *,
                       available: int | None = None) -> None:
    """Raise :class:`InputError` when ``width x height`` pixels at ``bytes_per_pixel``
    exceed the memory available.

    Parameters
    ----------
    width, height : int
        Image size, pixels.
    bytes_per_pixel : float
        What one pixel costs at least (a lower bound, so that nothing that would fit is
        refused).
    what : str
        What is being allocated, for the message (e.g. ``"the surface map"``).
    available : int, optional
        Bytes available; default :func:`available_memory` (no check when unknown).
    """
    w, h = int(width), int(height)
    if w <= 0 or h <= 0:
        raise InputError(f"{what}: image size must be positive, got {w}x{h}")
    avail = available_memory() if available is None else int(available)
    need = float(w) * float(h) * float(bytes_per_pixel)
    if avail is not None and need > avail:
        raise InputError(
            f"{what}: a {w}x{h} image ({w * h / 1e6:.4g} Mpixel) needs at least "
            f"{need / 2**30:.3g} GiB, only {avail / 2**30:.3g} GiB available: use a smaller "
            "image size")


def check_memory(need: float, what: str, *, available: int | None = None) -> None:
    """Raise :class:`InputError` when ``need`` bytes (a lower bound of what ``what``
    allocates) exceed the memory available; no check when that is unknown."""
    avail = available_memory() if available is None else int(available)
    if avail is not None and float(need) > avail:
        raise InputError(f"{what} needs at least {float(need) / 2**30:.3g} GiB, only "
                         f"{avail / 2**30:.3g} GiB available")


def release_freed_memory() -> bool:
    """Give the pages of the C heap that are free back to the system (glibc's
    ``malloc_trim(0)``); False where there is no such call (not glibc).

    Arrays freed by NumPy and SciPy stay in the process's resident memory when glibc keeps
    them for later allocations (below its mmap threshold, which grows after large frees):
    after a one-off peak (a frame's ray cast and merge, a solve's work arrays) the resident
    memory stays at the peak for the rest of a long run. Measured on the unsteady bench's
    first frame (1.1 M faces, 1 Mpx): 1,029 MB resident before, 816 MB after.
    """
    import ctypes

    trim = _libc_call("malloc_trim", [ctypes.c_size_t])
    if trim is None:
        return False
    trim(0)
    return True


def _libc_call(name: str, argtypes: list):
    """The C library's function ``name`` with its argument types, or None where there is
    no such call (not glibc)."""
    import ctypes
    import ctypes.util

    try:
        fn = getattr(ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6"), name)
    except (OSError, AttributeError):
        return None
    fn.argtypes = argtypes
    return fn


#: glibc's ``mallopt`` parameters (``malloc.h``).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


def keep_freed_memory(mmap_threshold: int = 32 * 2**20,
                      trim_threshold: int = 64 * 2**20) -> bool:
    """Let glibc keep freed arrays for the next allocations (its ``mallopt``): arrays
    under ``mmap_threshold`` bytes come from the heap, and the heap's top is given back
    only beyond ``trim_threshold`` free bytes (:func:`release_freed_memory` still gives
    it back when asked). False where there is no such call (not glibc).

    Dask's nanny starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also
    fixes glibc's mmap threshold at 128 KiB: every array of a frame (a few MB) was then
    mapped and unmapped, its pages faulted in anew each time. Measured on the unsteady run
    of 48 frames on 609k faces with that variable: 1.77 M minor page faults and 6.5 s of
    system time, against 125,000 and 1.5 s without it; the entry's Dask worker made 58 M
    faults on the issue's size. A worker's task calls this first; the settings are glibc's
    own defaults' ceiling (its mmap threshold grows to 32 MiB on its own in a process
    started without the variable).
    """
    import ctypes

    mallopt = _libc_call("mallopt", [ctypes.c_int, ctypes.c_int])
    if mallopt is None:
        return False
    ok = mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold)) == 1
    ok &= mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)) == 1
    return bool(ok)

