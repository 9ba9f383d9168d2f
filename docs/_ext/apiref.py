"""The API reference, written from the packages' ``__all__`` when the site builds.

Every public module (no part of its name starting with ``_``) of ``resection`` and
``selfillum`` is imported and every name of its ``__all__`` documented once, on the page of
its stage (``resection.camera``, ``selfillum.unsteady``, ...): at the module that defines
it when that module lists it, otherwise at the deepest public module that lists it. The
flat names (``resection.Camera``) get a table linking to where each is documented. A new
module or a new name in an ``__all__`` appears without editing anything here.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from collections import defaultdict
from pathlib import Path

ROOTS = ("resection", "selfillum")


def _public(modname: str) -> bool:
    return not any(part.startswith("_") for part in modname.split("."))


def public_modules(root: str) -> list[str]:
    """Every public module of the package ``root``, imported, in name order."""
    package = importlib.import_module(root)
    names = [root]
    for info in pkgutil.walk_packages(package.__path__, prefix=root + "."):
        if _public(info.name):
            names.append(info.name)
    for name in names:
        importlib.import_module(name)
    return sorted(names)


def homes(root: str) -> tuple[dict[str, list[str]], dict[str, str]]:
    """``(module -> names documented there, flat name -> its documented full name)``."""
    listed: dict[tuple[str, int], list[str]] = defaultdict(list)
    for modname in public_modules(root):
        module = importlib.import_module(modname)
        for name in getattr(module, "__all__", ()):
            listed[(name, id(getattr(module, name)))].append(modname)
    where: dict[str, list[str]] = defaultdict(list)
    full: dict[tuple[str, int], str] = {}
    for (name, key), modules in sorted(listed.items()):
        obj = getattr(importlib.import_module(modules[0]), name)
        defined = getattr(obj, "__module__", None) if (
            inspect.isclass(obj) or inspect.isroutine(obj)) else None
        below_root = [m for m in modules if m != root]
        if defined in modules and defined != root:
            home = defined
        elif below_root:
            home = max(below_root, key=lambda m: (m.count("."), m))
        else:
            home = root
        where[home].append(name)
        full[(name, key)] = f"{home}.{name}"
    package = importlib.import_module(root)
    flat = {n: full[(n, id(getattr(package, n)))] for n in getattr(package, "__all__", ())}
    return where, flat


def _stage(modname: str) -> str:
    parts = modname.split(".")
    return ".".join(parts[:2]) if len(parts) > 1 else parts[0]


def _title(text: str, char: str) -> str:
    return f"{text}\n{char * len(text)}\n"


def _first_line(modname: str) -> str:
    doc = inspect.getdoc(importlib.import_module(modname)) or ""
    return doc.strip().split("\n\n")[0].replace("\n", " ")


def write_pages(out: Path) -> list[Path]:
    """Write ``out/index.rst`` and one page a stage; return the pages written."""
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("*.rst"):
        old.unlink()
    written = []
    index = [
        _title("API reference", "="),
        "Every public name of ``resection`` and ``selfillum``, from the docstrings, written "
        "from the packages' ``__all__`` when the site builds. Each package also gives its "
        "main names flat (``resection.Camera`` is "
        ":class:`resection.camera.model.Camera`), loaded on first use.\n",
    ]
    for root in ROOTS:
        where, flat = homes(root)
        stages: dict[str, list[str]] = defaultdict(list)
        for modname in sorted(where):
            stages[_stage(modname) if modname != root else root].append(modname)
        index.append(_title(f"``{root}``", "-"))
        index.append(f"{_first_line(root)}\n")
        index.append(".. list-table::\n   :header-rows: 1\n\n   * - flat name\n"
                     "     - documented as\n")
        for name in sorted(flat, key=str.lower):
            index.append(f"   * - ``{root}.{name}``\n     - :obj:`{flat[name]}`\n")
        index.append("\nBy stage:\n\n.. toctree::\n   :maxdepth: 1\n")
        index.append("".join(f"\n   {stage}" for stage in sorted(stages)) + "\n")
        for stage, modules in sorted(stages.items()):
            lines = [_title(f"``{stage}``", "=")]
            lines.append(f".. automodule:: {stage}\n   :no-members:\n")
            for modname in modules:
                if modname != stage:
                    lines.append(_title(f"``{modname}``", "-"))
                    lines.append(f".. automodule:: {modname}\n   :no-members:\n")
                lines.append(f".. currentmodule:: {modname}\n")
                lines.append(".. autosummary::\n   :toctree: generated/\n   :nosignatures:\n")
                lines.append("".join(f"\n   {n}" for n in sorted(where[modname])) + "\n")
            page = out / f"{stage}.rst"
            page.write_text("\n".join(lines))
            written.append(page)
    (out / "index.rst").write_text("\n".join(index))
    written.append(out / "index.rst")
    return written


def _config_inited(app, config) -> None:
    # at config-inited, before Sphinx lists the source files: the pages written here are
    # then sources of this build, and autosummary (at builder-inited) writes their stubs
    write_pages(Path(app.srcdir) / "api")


def setup(app):
    app.connect("config-inited", _config_inited)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
