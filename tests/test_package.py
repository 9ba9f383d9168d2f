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


def test_correct_command_does_not_import_trimesh(tmp_path):
    """``selfillum correct`` on a PLY reads it without trimesh (0.3-0.4 s of imports:
    scipy.spatial, networkx, ...): at the end of the command trimesh is not loaded. And
    SciPy's sparse matrices and solvers (0.2 s of imports) are not loaded before the rays:
    a thread imports them while the rays run."""
    import numpy as np

    from resection import Camera
    from resection.io.cameras import write_camera
    from scenes.corner import corner

    sc = corner(resolution=4)
    sc.mesh.export(tmp_path / "corner.ply")
    write_camera(tmp_path / "cam.json", Camera.look_at(
        [1.6, 0.5, 1.3], [0.3, 0.5, 0.3], [0.0, 1.0, 0.0],
        K=[[40.0, 0.0, 23.5], [0.0, 40.0, 17.5], [0.0, 0.0, 1.0]], width=48, height=36))
    np.save(tmp_path / "img.npy", np.ones((36, 48), np.float32))
    args = ["correct", "--mesh", "corner.ply", "--camera", "cam.json", "--image", "img.npy",
            "--reflectance", "0.5", "--rays", "16", "--out", "out.npy", "--quiet"]
    # the modules of SciPy's sparse code and of the solve loaded when the rays start,
    # written to a file by a spy on the step that starts them
    spy = ("import sys\nimport selfillum.images.image_correction as ic\n"
           "rays = ic._view_factors_and_fit\n"
           "def spied(*a, **kw):\n"
           "    early = [m for m in sys.modules\n"
           "             if m.startswith('scipy.sparse') or m == 'selfillum.solve.radiosity']\n"
           "    open('before_rays.txt', 'w').write(' '.join(early))\n"
           "    return rays(*a, **kw)\n"
           "ic._view_factors_and_fit = spied\n")
    code = (f"import os\nos.chdir({str(tmp_path)!r})\n{spy}from selfillum.cli.main import main\n"
            f"assert main({args!r}) == 0\nassert os.path.exists('out.npy')")
    loaded = _modules_after(code)
    assert "selfillum.images.image_correction" in loaded  # the command ran
    assert "trimesh" not in loaded
    assert (tmp_path / "before_rays.txt").read_text() == ""
    assert {"scipy.sparse.linalg", "selfillum.solve.radiosity"} <= loaded  # then, the solve
