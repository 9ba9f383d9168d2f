"""Fixtures shared by several test files."""

import shutil
from pathlib import Path

import pytest


@pytest.fixture
def embree_scenes(monkeypatch) -> list:
    """The Embree scenes built (RayCaster's and RayScene's, all of them
    :class:`resection.surface.embree.Scene`) while the test runs: a list that grows by one
    a scene."""
    from resection.surface.embree import Scene

    built = []
    init = Scene.__init__

    def counted(self, *a, **kw):
        built.append(1)
        init(self, *a, **kw)

    monkeypatch.setattr(Scene, "__init__", counted)
    return built


UPSP_SAMPLES = Path(__file__).parent / "data" / "upsp"


@pytest.fixture
def upsp_samples(tmp_path) -> Path:
    """A writable copy of NASA uPSP's test data as shipped (``tests/data/upsp``: the
    ``.wtd``, the grid, the ``.tgts``, the calibrations; NOSA 1.3, see its README)."""
    dst = tmp_path / "upsp-samples"
    shutil.copytree(UPSP_SAMPLES, dst)
    return dst
