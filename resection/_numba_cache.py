"""A writable place for numba's cache of the package's compiled kernels.

The kernels are compiled with ``cache=True``: the first run of a fresh install compiles
them (10-30 s) and saves the machine code; later runs load it (0.3 s). numba saves it next
to the sources (``__pycache__``) or, where that is read-only, in its user-wide cache folder
(``~/.cache/numba``). When neither can be written (an installation owned by another user,
with a read-only home: a container, a cluster node) numba refuses to build the kernels at
all: ``RuntimeError: cannot cache function ...: no locator available`` when the package's
modules are imported. :func:`ensure_numba_cache` falls back to a folder of the user's own
in the temporary directory (kept between runs on that machine), through numba's
``NUMBA_CACHE_DIR`` setting, and to a one-line error where even that cannot be written.
"""

from __future__ import annotations

import os
import tempfile

from resection.errors import InputError

__all__ = ["ensure_numba_cache"]

#: the folders that hold compiled kernels, relative to the folder of the packages
KERNEL_FOLDERS = ("resection", "resection/markers", "resection/camera", "resection/surface",
                  "selfillum/solve", "selfillum/transport", "selfillum/unsteady")


def _writable(folder: str) -> bool:
    """numba's own test: the folder can be made and a file written in it."""
    try:
        os.makedirs(folder, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
    except OSError:
        return False
    return True


def _user_wide() -> str | None:
    try:
        from numba.misc.appdirs import AppDirs

        return AppDirs(appname="numba", appauthor=False).user_cache_dir
    except Exception:  # noqa: BLE001 - numba's private layout changed: not usable
        return None


def ensure_numba_cache(in_tree: list[str] | None = None, user_wide: str | None = None,
                       fallback: str | None = None) -> str | None:
    """Make sure numba can cache the package's kernels; call before they are imported.

    Parameters
    ----------
    in_tree : list of str, optional
        The ``__pycache__`` folders next to the kernels' sources (default: those of
        :data:`KERNEL_FOLDERS`).
    user_wide : str, optional
        numba's user-wide cache folder (default: numba's).
    fallback : str, optional
        Where to cache otherwise (default: ``<temporary directory>/numba-cache-<uid>``).

    Returns
    -------
    str or None
        The folder given to numba (``numba.config.CACHE_DIR``), or None when numba's own
        choice works (``NUMBA_CACHE_DIR`` set, the sources' folders or the user-wide
        folder writable).

    Raises
    ------
    InputError
        No folder can be written: set ``NUMBA_CACHE_DIR`` to a writable one.
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    if in_tree is None:
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        in_tree = [os.path.join(root, sub, "__pycache__") for sub in KERNEL_FOLDERS
                   if os.path.isdir(os.path.join(root, sub))]
    if all(_writable(f) for f in in_tree):
        return None
    user_wide = _user_wide() if user_wide is None else user_wide
    if user_wide is not None and _writable(user_wide):
        return None
    if fallback is None:
        uid = os.getuid() if hasattr(os, "getuid") else "user"
        fallback = os.path.join(tempfile.gettempdir(), f"numba-cache-{uid}")
    if not _writable(fallback):
        raise InputError(f"numba cannot cache the compiled kernels: none of {in_tree[0]}, "
                         f"{user_wide}, {fallback} can be written (set NUMBA_CACHE_DIR to "
                         "a writable folder)")
    from numba.core import config

    config.CACHE_DIR = fallback
    return fallback
