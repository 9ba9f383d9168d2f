"""Ctrl-C during a command's start-up still stops it (exit status 130).

Some libraries guard their own optional imports with ``except BaseException`` (trimesh does,
around SciPy, networkx, ...): a Ctrl-C that arrives while such an import runs is swallowed
with the import's failure, and the command would run on to the end and exit 0.
:func:`install` (called by the console scripts first thing) puts in place:

* a SIGINT handler that raises :class:`KeyboardInterrupt` as Python's own does, and records
  that the user asked to stop (:func:`interrupted`);
* an import hook for the packages in :data:`DEFERRED` (trimesh): while one of their modules
  runs its import, a Ctrl-C is held, not raised into it, and raised as soon as the import
  is over, where nothing swallows it.

The common runner (:func:`resection.cli.util.run`) also checks :func:`interrupted` after a
command returned: an interrupt swallowed elsewhere still ends in status 130. Once the
status is decided, :func:`done` ignores Ctrl-C while the interpreter ends.
Standard library only: it is imported before anything else of the command.
"""

from __future__ import annotations

import importlib.abc
import signal
import sys

__all__ = ["install", "interrupted", "done", "DEFERRED"]

#: Top-level packages whose imports catch ``BaseException``: Ctrl-C is held during them.
DEFERRED = frozenset({"trimesh"})


class _State:
    def __init__(self):
        self.asked = False  # the user pressed Ctrl-C (since install)
        self.pending = False  # ... while interrupts were held
        self.depth = 0  # imports of DEFERRED packages running

    def handler(self, signum, frame):
        self.asked = True
        # an object the interrupt tore in its construction may fail in its finalizer when
        # it is collected (llvmlite's, when numba was compiling at that moment: "Exception
        # ignored in ... __del__", 9 lines of traceback after the command's one line): the
        # command is stopping, such failures are not the user's concern
        sys.unraisablehook = _ignore_unraisable
        if self.depth:
            self.pending = True
            return
        raise KeyboardInterrupt

    def enter(self) -> None:
        self.depth += 1

    def leave(self) -> None:
        self.depth -= 1
        if self.depth == 0 and self.pending:
            self.pending = False
            raise KeyboardInterrupt


_STATE: _State | None = None


def _ignore_unraisable(unraisable) -> None:
    """``sys.unraisablehook`` once Ctrl-C was pressed: finalizers' failures are dropped."""


class _HoldingLoader(importlib.abc.Loader):
    """A loader that runs another's ``exec_module`` with Ctrl-C held."""

    def __init__(self, inner, state: _State):
        self._inner = inner
        self._state = state

    def create_module(self, spec):
        return self._inner.create_module(spec)

    def exec_module(self, module):
        module.__loader__ = self._inner  # the module sees its own loader (resources)
        self._state.enter()
        try:
            self._inner.exec_module(module)
        finally:
            self._state.leave()

    def __getattr__(self, name):
        return getattr(self._inner, name)


class _HoldingFinder(importlib.abc.MetaPathFinder):
    """Finds the modules of :data:`DEFERRED` through the other finders and wraps their
    loader in :class:`_HoldingLoader`."""

    def __init__(self, state: _State):
        self._state = state

    def find_spec(self, name, path, target=None):
        if name.partition(".")[0] not in DEFERRED:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(name, path, target)
            if spec is not None:
                if spec.loader is not None and hasattr(spec.loader, "exec_module"):
                    spec.loader = _HoldingLoader(spec.loader, self._state)
                return spec
        return None


def install() -> None:
    """Install the SIGINT handler and the import hook (see the module docstring); a second
    call does nothing. Only from the main thread (where Python delivers signals)."""
    global _STATE
    if _STATE is not None:
        return
    state = _State()
    signal.signal(signal.SIGINT, state.handler)
    sys.meta_path.insert(0, _HoldingFinder(state))
    _STATE = state


def done() -> None:
    """The command's status is decided (its outputs complete or removed): a Ctrl-C from
    now on, while the interpreter ends, changes nothing and is ignored (else it would
    interrupt the exit with a traceback)."""
    if _STATE is not None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def interrupted() -> bool:
    """Whether Ctrl-C was pressed since :func:`install` (False without it)."""
    return _STATE is not None and _STATE.asked
