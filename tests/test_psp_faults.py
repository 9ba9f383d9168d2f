"""``selfillum psp`` checks what the Stern-Volmer fit needs before its heavy step (issue 34
item 3): ``--p-ref 0`` and taps all at one pressure were refused only after 60-80 s of
view factors, with an internal function's name as the message's prefix."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def psp_files(tmp_path):
    import trimesh

    from resection.camera import Camera
    from resection.io.cameras import write_camera
    from resection.io.images import write_image

    trimesh.creation.box(extents=(1.0, 1.0, 0.2)).export(tmp_path / "model.ply")
    K = np.array([[400.0, 0, 80], [0, 400.0, 60], [0, 0, 1]])
    write_camera(tmp_path / "cam.json", Camera.look_at([0, 0, 5.0], [0, 0, 0], [0, 1, 0],
                                                       K=K, width=160, height=120))
    img = np.full((120, 160), 1000.0, np.float32)
    write_image(tmp_path / "off.tif", img)
    write_image(tmp_path / "on.tif", img)
    return tmp_path


def _psp(d, taps_text, p_ref, capsys, monkeypatch):
    import selfillum.corner  # noqa: F401 - binds view_factors when imported: first
    import selfillum.images.image_correction  # noqa: F401
    import selfillum.transport.viewfactors as vf
    from selfillum.cli import main

    def boom(*a, **k):
        raise AssertionError("the view factors were computed before the input check")

    monkeypatch.setattr(vf, "view_factors", boom)
    (d / "taps.csv").write_text(taps_text)
    rc = main(["psp", "--mesh", str(d / "model.ply"), "--camera", str(d / "cam.json"),
               "--wind-off", str(d / "off.tif"), "--wind-on", str(d / "on.tif"),
               "--taps", str(d / "taps.csv"), "--p-ref", p_ref, "--out", str(d / "out"),
               "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert "fit_stern_volmer" not in err and not (d / "out").exists()
    return err


TAPS = "id,x,y,z,p\nA,0.1,0.1,0.1,95\nB,-0.1,0.2,0.1,105\nC,0.2,-0.2,0.1,110\n"


def test_p_ref_zero_refused_before_the_view_factors(psp_files, capsys, monkeypatch):
    err = _psp(psp_files, TAPS, "0", capsys, monkeypatch)
    assert "p_ref 0: the wind-off pressure must be a finite number > 0" in err


def test_taps_at_one_pressure_refused_before_the_view_factors(psp_files, capsys,
                                                              monkeypatch):
    same = "id,x,y,z,p\nA,0.1,0.1,0.1,100\nB,-0.1,0.2,0.1,100\nC,0.2,-0.2,0.1,100\n"
    err = _psp(psp_files, same, "100", capsys, monkeypatch)
    assert "taps.csv: all 3 taps at the same pressure (100)" in err
