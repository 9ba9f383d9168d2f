"""The corner case (two plates at 90 degrees) end to end, and the ``selfillum`` CLI."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import scipy.sparse as sp
from test_viewfactors import howell_perpendicular

from resection.errors import InputError
from scenes.corner import corner, corner_form_factors, corner_profile_line, symmetric_factors
from selfillum import forward, view_factors
from selfillum.cli.main import main
from selfillum.corner import run_corner
from selfillum.mesh import face_areas, face_normals
from selfillum.transport.kernel import pair_factors


def test_corner_scene_geometry():
    sc = corner(size=2.0, resolution=5)
    assert len(sc.mesh.faces) == 4 * 25
    np.testing.assert_allclose(face_areas(sc.mesh).sum(), 2 * 2.0**2)
    n = face_normals(sc.mesh)
    np.testing.assert_allclose(n[sc.plate == 0], [[0, 0, 1]] * 50)
    np.testing.assert_allclose(n[sc.plate == 1], [[1, 0, 0]] * 50)
    # one connected surface: the plates share the corner edge
    assert len(sc.mesh.face_adjacency) == 2 * (3 * 25 - 10) + 5
    s, pts = corner_profile_line(sc)
    assert s.min() < -1.99 and s.max() > 1.99
    np.testing.assert_allclose(np.where(s < 0, pts[:, 0], pts[:, 2]), np.abs(s))
    with pytest.raises(InputError, match="reflectance"):
        corner(reflectance=1.0)
    with pytest.raises(InputError, match="resolution"):
        corner(resolution=0)
    with pytest.raises(InputError, match="pattern"):
        corner(pattern="checker")


def test_first_bounce_at_the_corner_matches_howell():
    """Uniform emission: the light a floor strip along the corner receives directly from
    the wall is rho * E * F(strip -> wall), with F from Howell's C-14 (w = strip width)."""
    res = 20
    sc = corner(resolution=res, pattern="uniform")
    F = view_factors(sc.mesh, rays_per_face=1024, seed=3)
    c = sc.mesh.triangles_center
    strip = (sc.plate == 0) & (c[:, 0] < 1.0 / res)
    a = face_areas(sc.mesh)
    got = a[strip] @ (F[strip] @ (sc.plate == 1).astype(float)) / a[strip].sum()
    assert got == pytest.approx(howell_perpendicular(1.0 / res, 1.0, 1.0), rel=0.01)


def test_corner_self_illumination_about_30_percent():
    sc = corner(resolution=20, pattern="uniform")
    F = view_factors(sc.mesh, rays_per_face=256, seed=0)
    B = forward(F, sc.emission, sc.reflectance)
    si = (B - sc.emission) / B
    assert 0.25 < si.max() < 0.35
    c = sc.mesh.triangles_center
    far = (c[:, 0] > 0.9) | (c[:, 2] > 0.9)  # far edges: much less
    assert si[far].max() < 0.5 * si.max()
    assert np.argmax(si) in np.flatnonzero((c[:, 0] < 0.05) & (c[:, 2] < 0.05))


def test_run_corner_correction_residual_small():
    r = run_corner(resolution=20, rays_per_face=256, reference="rays")
    n = r.numbers
    assert 0.25 < n.max_si_fraction < 0.35
    # the measurement was simulated with independent, 4x finer view factors: what is left
    # after correction is the view-factor noise, an order of magnitude below the SI
    assert n.max_residual_fraction < 0.15 * n.max_si_fraction
    assert n.rms_residual_fraction < 0.02
    p = r.profile
    assert np.abs(p["corrected"] - p["true"]).max() < 0.2 * np.abs(p["with_si"] - p["true"]).max()
    assert p["s"].shape == p["face"].shape == p["true"].shape


def test_cli_corner_writes_outputs(tmp_path, capsys):
    out = tmp_path / "corner"
    rc = main(["corner", "--out", str(out), "--resolution", "8", "--rays", "64", "--quiet"])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "largest self-illumination" in printed and "largest residual" in printed
    numbers = json.loads((out / "corner_numbers.json").read_text())
    assert numbers["faces"] == 256 and numbers["rays_per_face"] == 64
    assert 0.1 < numbers["max_si_fraction"] < 0.4
    with open(out / "corner_profile.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) > 100
    assert set(rows[0]) == {"s", "x", "y", "z", "face", "true", "with_si", "corrected"}
    with_si = np.array([float(r["with_si"]) for r in rows])
    true = np.array([float(r["true"]) for r in rows])
    assert np.all(with_si > true)  # self-illumination only adds light
    import matplotlib.image

    img = matplotlib.image.imread(out / "corner_profile.png")
    assert img.ndim == 3 and img.shape[0] > 400 and img.shape[1] > 600


@pytest.mark.parametrize(
    "args, match",
    [
        (["--reflectance", "1.0"], "reflectance"),
        (["--resolution", "0"], "must be > 0"),
        (["--out", "FILE"], "is not a folder"),
    ],
)
def test_cli_bad_input_one_line_exit_2(tmp_path, capsys, args, match):
    (tmp_path / "FILE").write_text("not a folder")
    args = [str(tmp_path / a) if a == "FILE" else a for a in args]
    argv = ["corner", "--out", str(tmp_path / "o"), "--quiet", *args]
    if match == "must be > 0":  # argparse refuses it before the library runs
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
    else:
        assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert match in err[-1] and err[-1].startswith("selfillum corner: error:")


def test_progress_bars_name_each_ray_casting(capsys):
    run_corner(resolution=4, rays_per_face=8, progress=True, reference="rays")
    err = capsys.readouterr().err
    for step in ("reference view factors", "working view factors"):
        assert f"{step}:" in err and "/64 " in err  # 64 faces
    run_corner(resolution=4, rays_per_face=8, progress=False)
    assert capsys.readouterr().err == ""


def test_general_rays_without_symmetry_reach_the_target_small():
    """Without the corner's symmetries (a general model has none), 4096 RQMC rays a face
    leave at most 0.3 % after correction and 256 several times more; a coarse corner
    keeps it fast."""
    n = run_corner(resolution=10, rays_per_face=4096, symmetry=False).numbers
    assert n.reference == "exact" and not n.symmetry
    assert 0.2 < n.max_si_fraction < 0.35
    assert n.max_residual_fraction <= 0.003
    n256 = run_corner(resolution=10, rays_per_face=256, symmetry=False).numbers
    assert n256.max_residual_fraction > 2 * n.max_residual_fraction


def test_main_job_residual_within_target():
    """The README's main job itself (6400 faces, 1024 RQMC rays a face averaged over the
    corner's symmetries, measurement from the closed-form reference): largest residual
    after correction <= 0.3 %, and the symmetric average's largest residual at least 1.5 times
    below that of the same rays used as they are."""
    n = run_corner().numbers
    assert n.faces == 6400 and n.rays_per_face == 1024 and n.symmetry
    assert n.reference == "exact"
    assert n.max_residual_fraction <= 0.003
    assert 0.25 < n.max_si_fraction < 0.35
    raw = run_corner(symmetry=False).numbers
    assert raw.max_residual_fraction > 1.5 * n.max_residual_fraction


def test_symmetry_classes_hold_for_exact_factors():
    """Every floor-to-wall pair integrated directly (no symmetry used): the reference's
    classes (translation along the fold, mirror x <-> z with reciprocity) reproduce it,
    and averaging it over the classes leaves it as it is."""
    sc = corner(resolution=3)
    m = 18
    i, j = np.meshgrid(np.arange(m), m + np.arange(m), indexing="ij")
    G = pair_factors(sc.mesh.vertices, sc.mesh.faces, face_normals(sc.mesh), i.ravel(),
                     j.ravel(), order=10).reshape(m, m)
    # what is left is the quadrature's own error (about 1e-6 at 100 points a face)
    np.testing.assert_allclose(corner_form_factors(sc, 10, far_order=10), G, atol=1e-5)
    F = sp.bmat([[None, sp.csr_matrix(G)], [sp.csr_matrix(G.T), None]]).tocsr()
    np.testing.assert_allclose(symmetric_factors(sc, F), G, atol=1e-5)
    # a matrix without the symmetry is not left as it is (the test can fail)
    G2 = G.copy()
    G2[0, 0] += 0.01
    F2 = sp.bmat([[None, sp.csr_matrix(G2)], [sp.csr_matrix(G2.T), None]]).tocsr()
    assert np.abs(symmetric_factors(sc, F2) - G2).max() > 1e-3
    with pytest.raises(InputError, match="faces"):
        symmetric_factors(sc, F[:10, :10])


def test_symmetric_factors_unbiased_and_less_noisy():
    """The average keeps the total exchanged between the plates (the mean of the two
    directions' totals, exactly: it only averages) and has several times less noise per
    pair than the ray-cast entries, against the converged kernel."""
    sc = corner(resolution=6)
    G = corner_form_factors(sc, order=6)
    m = G.shape[0]
    for seed in range(3):
        F = view_factors(sc.mesh, 256, seed=seed)
        Gs = symmetric_factors(sc, F)
        raw = F[:m][:, m:].toarray()
        both = 0.5 * (raw.sum() + F[m:][:, :m].sum())
        assert Gs.sum() == pytest.approx(both, rel=1e-12)
        assert np.sqrt(np.mean((Gs - G) ** 2)) < 0.4 * np.sqrt(np.mean((raw - G) ** 2))
