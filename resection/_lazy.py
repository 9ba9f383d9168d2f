"""Public names of a package loaded on first use (PEP 562), as scikit-image's
``lazy_loader.attach``: a command pays only for the submodules it calls."""

from __future__ import annotations

import importlib
from collections.abc import Callable


def attach(package: str, exports: dict[str, str]) -> tuple[Callable, Callable]:
    """``(__getattr__, __dir__)`` for the package ``package`` whose public name ``k`` is
    defined in its submodule ``exports[k]`` (relative, e.g. ``".camera"``)."""

    def __getattr__(name: str):
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module, package), name)
        # later lookups find the name in the package and do not come back here
        setattr(importlib.import_module(package), name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(importlib.import_module(package))) | set(exports))

    return __getattr__, __dir__
