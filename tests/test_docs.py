"""The documentation site builds with warnings as errors, and its gallery and tutorial run.

``sphinx-build -W`` on ``docs/`` (the command the site's conf.py and README give): the API
reference is written from the packages' ``__all__`` (every public name must get its page),
the command-line reference from the parsers (every command must be there), and every
gallery script and the tutorial are executed (each must leave its pictures). The slow
gallery scripts (``examples/*_slow.py``) run only in the slow test.
"""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: the build command of the README and docs/conf.py; run here with this interpreter, the
#: output in a temporary folder, and every warning shown (--keep-going)
SITE_COMMAND = ".venv/bin/python -m sphinx -W -b html docs docs/_build/html"


def _build(tmp_path: Path, slow: bool) -> Path:
    out = tmp_path / "html"
    env = dict(os.environ, WTO_DOCS_RERUN="1", WTO_DOCS_SLOW="1" if slow else "0",
               MPLBACKEND="Agg")
    args = SITE_COMMAND.split()
    assert args[0] == ".venv/bin/python" and args[-2:] == ["docs", "docs/_build/html"]
    done = subprocess.run(
        [sys.executable, *args[1:-2], "--keep-going", "-q", "-d", str(tmp_path / "doctrees"),
         str(DOCS), str(out)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=1800,
    )
    assert done.returncode == 0, (done.stdout + done.stderr)[-6000:]
    return out


def _scripts(slow: bool) -> list[Path]:
    found = sorted((ROOT / "examples").glob("plot_*.py"))
    return [p for p in found if slow or not p.stem.endswith("_slow")]


def _check_site(out: Path, slow: bool) -> None:
    # every public name of both packages has its API page
    for root in ("resection", "selfillum"):
        package = importlib.import_module(root)
        flat = (out / "api" / "index.html").read_text()
        for name in package.__all__:
            assert f"{root}.{name}<" in flat or f"{root}.{name}</span>" in flat, name
    generated = {p.stem for p in (out / "api" / "generated").glob("*.html")}
    sys.path.insert(0, str(DOCS / "_ext"))
    try:
        import apiref
    finally:
        sys.path.remove(str(DOCS / "_ext"))
    for root in apiref.ROOTS:
        where, _ = apiref.homes(root)
        for module, names in where.items():
            for name in names:
                assert f"{module}.{name}" in generated, f"{module}.{name}"
    # every command of both programs is in the CLI reference
    cli = (out / "cli.html").read_text()
    for module in ("resection.cli.main", "selfillum.cli.main"):
        parser = importlib.import_module(module).build_parser()
        commands = next(a for a in parser._actions if a.choices and a.dest == "command")
        for command in commands.choices:
            assert f'id="{parser.prog}-{command}"' in cli, command
    # each executed gallery script and the tutorial left pictures on their pages
    for script in _scripts(slow):
        page = (out / "gallery" / f"{script.stem}.html").read_text()
        assert page.count(f"sphx_glr_{script.stem}_") >= 1, script.name
    tutorial = (out / "tutorial_built" / "tutorial_unsteady.html").read_text()
    assert len(set(re.findall(r"sphx_glr_tutorial_unsteady_\d+\.png", tutorial))) >= 7
    assert "Traceback" not in tutorial
    # the ParaView step: VTK's vtkXdmfReader (ParaView's "Xdmf Reader") read run.xdmf and
    # found the same dCp as h5py in run.h5
    assert "dCp as in run.h5: True" in tutorial


def test_site_builds_warning_free_and_runs_the_gallery(tmp_path):
    _check_site(_build(tmp_path, slow=False), slow=False)


@pytest.mark.slow
def test_site_builds_with_the_slow_gallery(tmp_path):
    _check_site(_build(tmp_path, slow=True), slow=True)
