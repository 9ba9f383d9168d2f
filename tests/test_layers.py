"""The layers contract: imports run one way by stage (pyproject.toml, [tool.importlinter]).

import-linter builds the import graph of both packages, lazy imports inside functions
included, and fails if any module imports a stage above its own."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_import_linter_contracts_are_kept():
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    assert exe is not None, "import-linter is a test dependency (pyproject.toml [test])"
    out = subprocess.run([exe, "--no-cache"], cwd=ROOT, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
    assert "0 broken" in out.stdout


def test_contract_catches_an_import_against_the_flow(tmp_path):
    """A copy of the tree with one import against the flow (camera -> io) breaks it."""
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    copy = tmp_path / "tree"
    for name in ("resection", "selfillum"):
        shutil.copytree(ROOT / name, copy / name,
                        ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", copy / "pyproject.toml")
    model = copy / "resection" / "camera" / "model.py"
    model.write_text(model.read_text() + "\nfrom resection.io import cameras  # noqa\n")
    out = subprocess.run([exe, "--no-cache"], cwd=copy, capture_output=True, text=True,
                         timeout=300, env={"PYTHONPATH": str(copy), "PATH": "/usr/bin:/bin"})
    assert out.returncode != 0
    assert "resection.camera is not allowed to import resection.io" in out.stdout


@pytest.mark.parametrize("package", ["resection", "selfillum"])
def test_no_source_file_much_over_600_lines(package):
    sizes = {p: len(p.read_text().splitlines()) for p in (ROOT / package).rglob("*.py")}
    big = {str(p.relative_to(ROOT)): n for p, n in sizes.items() if n > 650}
    assert not big, big
