"""The packages' public names load on first use (PEP 562): every exported name resolves
to the object its submodule defines, and importing a package or one light name does not
import the heavy stacks (plotting, Dask, meshes, Mitsuba) that other commands need."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest


@pytest.mark.parametrize("package", ["resection", "selfillum"])
def test_every_exported_name_resolves_to_its_definition(package):
    pkg = importlib.import_module(package)
    assert pkg.__all__, package
    for name in pkg.__all__:
        obj = getattr(pkg, name)
        assert getattr(obj, "__name__", name) == name, (package, name)
        assert obj.__module__.split(".")[0] in ("resection", "selfillum"), (package, name)
    assert set(pkg.__all__) <= set(dir(pkg))
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        pkg.not_a_name  # noqa: B018


def test_correct_image_stays_the_function_after_its_module_is_imported():
    import selfillum
    import selfillum.images
    from selfillum.images.image_correction import read_reflectance  # noqa: F401 - imports the module

    module = sys.modules["selfillum.images.image_correction"]
    assert callable(selfillum.correct_image) and callable(selfillum.images.correct_image)
    assert selfillum.correct_image is module.correct_image
    assert selfillum.images.correct_image is module.correct_image


def _modules_after(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys\n"
                          "print(' '.join(sorted(sys.modules)))"],
                         check=True, capture_output=True, text=True).stdout
    return set(out.split())


def test_light_imports_do_not_load_the_heavy_stacks():
    heavy = {"matplotlib", "dask", "distributed", "trimesh", "mitsuba", "embreex"}
    assert not heavy & _modules_after("import resection")
    assert not heavy & _modules_after("from resection import Camera, InputError")
    # a light name gives a usable object
    assert "resection.camera.model" in _modules_after("from resection import Camera")


def test_resection_command_line_builds_without_the_numerical_stacks():
    """``resection --help`` and argument errors come at once: the parser's defaults
    (:mod:`resection.defaults`) need none of the libraries the commands call."""
    loaded = _modules_after("from resection.cli.main import build_parser\nbuild_parser()")
    assert not {"matplotlib", "dask", "trimesh", "embreex", "numba", "scipy"} & loaded
    loaded = _modules_after("from selfillum.cli.main import build_parser\nbuild_parser()")
    assert not {"matplotlib", "dask", "trimesh", "embreex", "numba", "scipy", "mitsuba"} & loaded
