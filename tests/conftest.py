"""Fixtures shared by several test files."""

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
