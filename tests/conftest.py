"""Fixtures shared by several test files."""

import pytest


@pytest.fixture
def embree_scenes(monkeypatch) -> list:
    """The Embree scenes built (RayCaster's and RayScene's) while the test runs: a list
    that grows by one a scene."""
    from embreex import rtcore_scene

    from resection.surface import visibility
    from selfillum.transport import viewfactors

    built = []

    class Counted:
        @staticmethod
        def EmbreeScene(*a, **kw):  # noqa: N802 - embreex's name
            built.append(1)
            return rtcore_scene.EmbreeScene(*a, **kw)

    monkeypatch.setattr(visibility, "rtcore_scene", Counted)
    monkeypatch.setattr(viewfactors, "rtcore_scene", Counted)
    return built
