"""Unseen faces, stated (issue 14): what hidden faces emit, unpainted parts, the share of
the correction resting on them, grazing faces, and the restriction of the solve to the
faces coupled to the seen ones.

References: dense direct solves and dense least squares with NumPy over *every* hidden
face (the full problem, no restriction), the flat-floor closed form (a flat face sees no
face of its own plane, so all of its self-illumination comes from the other plate), and
simulated measurements made with an independent, converged form-factor matrix (another
seed, 4 to 8 times the rays) rather than the matrix used by the correction.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

from resection.errors import InputError
from resection.io.cameras import write_camera
from resection.surface.surface_map import SurfaceMap
from scenes.corner import corner
from scenes.slab_block import BOX_BLOCKS, slab_block, slab_camera, write_slab_block
from selfillum import correct, forward, view_factors
from selfillum.cli.main import main
from selfillum.images.image_correction import correct_image
from selfillum.mesh import face_adjacency_weights
from selfillum.solve.unseen import read_unpainted
from selfillum.transport.coupling import coupled_faces, coupled_view_factors


# ---------------------------------------------------------------- coupling
def test_coupled_faces_follow_the_light_paths():
    """0 seen; 0 sees 1, 1 sees 2 (bounce over a hidden face), 3 sees 0 but nothing seen
    sees 3 (its light never reaches a seen face), 4 sees nothing."""
    F = sp.csr_matrix(([0.2, 0.3, 0.4], ([0, 1, 3], [1, 2, 0])), shape=(5, 5))
    seen = np.array([True, False, False, False, False])
    np.testing.assert_array_equal(coupled_faces(F, seen), [True, True, True, False, False])
    # paths through another seen face count too
    seen2 = np.array([False, False, False, True, False])
    np.testing.assert_array_equal(coupled_faces(F, seen2), [True, True, True, True, False])


def test_coupled_faces_match_scipy_breadth_first_search():
    """A random sparse graph: the faces reached from the seen ones are those SciPy's
    breadth-first search reaches from a super-source linked to them."""
    from scipy.sparse.csgraph import breadth_first_order

    rng = np.random.default_rng(5)
    n = 3000
    F = sp.random(n, n, density=0.6 / n, format="csr", random_state=rng)
    seen = rng.random(n) < 0.01
    link = sp.csr_matrix((np.ones(seen.sum()), (np.zeros(seen.sum(), int),
                                                np.flatnonzero(seen))), shape=(1, n))
    graph = sp.bmat([[F, None], [link, None]], format="csr")
    graph.resize(n + 1, n + 1)
    ref = np.zeros(n + 1, bool)
    ref[breadth_first_order(graph, n, directed=True, return_predecessors=False)] = True
    got = coupled_faces(F, seen)
    assert 0 < got.sum() - seen.sum() < n - seen.sum()  # some reached, not every face
    np.testing.assert_array_equal(got, ref[:n] | seen)


@pytest.fixture(scope="module")
def slab():
    """A small slab carrying a black unpainted box, the camera above it, a converged
    reference F (for the truth) and the correction's F (another seed, fewer rays)."""
    sc = slab_block(2500)
    cam = slab_camera(320, 240)
    smap = SurfaceMap(sc.mesh, cam)
    F_ref = view_factors(sc.mesh, rays_per_face=1024, seed=11)
    F = view_factors(sc.mesh, rays_per_face=128, seed=0)
    B = forward(F_ref, sc.emission, sc.reflectance)
    return sc, cam, smap, F_ref, F, B


def _dense_hidden_solve(F, B, rho, seen, E_hidden):
    """Reference for the 'none'/'given' assumptions: B of *every* hidden face from the
    dense system (I - rho F)_hh B_h = E_h + rho_h F_hs B_s, then E = (I - rho F) B."""
    Fd = F.toarray()
    h, s = ~seen, seen
    A = np.eye(h.sum()) - rho[h, None] * Fd[np.ix_(h, h)]
    Bf = np.where(seen, B, 0.0)
    Bf[h] = np.linalg.solve(A, E_hidden[h] + rho[h] * (Fd[np.ix_(h, s)] @ B[s]))
    return Bf - rho * (Fd @ Bf)


def test_restriction_equals_full_solve_none_and_given(slab):
    """Only the faces coupled to the seen ones enter the solve; the seen faces' emission is
    that of the full dense solve over every hidden face (underside included), for both
    'none' and given values, with or without the rows of the uncoupled faces in F."""
    sc, cam, smap, F_ref, F, B = slab
    seen = smap.pixel_counts > 0
    reach = coupled_faces(F, seen)
    n_coupled = int((reach & ~seen).sum())
    assert 0 < n_coupled < 0.5 * (~seen).sum()  # the underside and rims are not coupled
    assert not reach[sc.part == 1].any()  # no light from the underside reaches the top
    F_rows = sp.diags(reach.astype(float)) @ F  # rows of the uncoupled faces emptied
    given = np.where(sc.painted, 0.9, 0.0)
    for unseen, e_h in (("none", np.zeros(len(B))), (given, given)):
        ref = _dense_hidden_solve(F, B, sc.reflectance, seen, e_h)
        for FF in (F, F_rows):
            E, info = correct(FF, np.where(seen, B, np.nan), sc.reflectance, seen,
                              unseen=unseen, return_info=True)
            assert info.n_coupled == n_coupled and info.n_hidden == int((~seen).sum())
            np.testing.assert_allclose(E[seen], ref[seen], rtol=1e-8, atol=1e-12)
        # hidden faces not coupled carry the assumption itself
        np.testing.assert_allclose(E[~reach], e_h[~reach])


def _dense_continue(F, B, rho, seen, unpainted, mesh, reg):
    """Reference for 'continue': dense least squares over *every* hidden face:
    min |D E|^2 + lam^2 |B_P - prior|^2 with E_U = 0 exactly (B_U eliminated by a dense
    solve), D over the edges between painted faces of the whole mesh."""
    n = len(B)
    M = np.eye(n) - rho[:, None] * F.toarray()
    s = np.flatnonzero(seen)
    P = np.flatnonzero(~seen & ~unpainted)
    U = np.flatnonzero(~seen & unpainted)
    D = face_adjacency_weights(mesh)
    keep = (abs(D) @ unpainted.astype(float)) == 0
    D = D[np.flatnonzero(keep)].toarray()
    # B_U = c + T B_P
    c = -np.linalg.solve(M[np.ix_(U, U)], M[np.ix_(U, s)] @ B[s]) if U.size else np.zeros(0)
    T = -np.linalg.solve(M[np.ix_(U, U)], M[np.ix_(U, P)]) if U.size else np.zeros((0, P.size))
    a = M[:, s] @ B[s] + M[:, U] @ c
    G = M[:, P] + M[:, U] @ T
    col = np.sqrt((D**2).sum(axis=0))[P]
    lam = np.sqrt(reg) * np.median(col[col > 0])
    prior = B[s][~unpainted[s]].mean()
    A = np.vstack([D @ G, lam * np.eye(P.size)])
    rhs = np.concatenate([-D @ a, lam * np.full(P.size, prior)])
    bp = np.linalg.lstsq(A, rhs, rcond=None)[0]
    Bf = np.where(seen, B, 0.0)
    Bf[P] = bp
    Bf[U] = c + T @ bp
    return M @ Bf


def _corner_with_detached_plate():
    """The corner (floor seen, wall hidden) and a plate behind the wall facing away:
    hidden, not coupled (no light from it reaches the corner) and not edge-connected."""
    sc = corner(resolution=5)
    back = trimesh.creation.box(extents=[0.01, 0.5, 0.5])
    back.apply_translation([-0.5, 0.5, 0.5])
    mesh = trimesh.util.concatenate([sc.mesh, back])
    n0 = len(sc.mesh.faces)
    e = np.concatenate([sc.emission, np.ones(len(back.faces))])
    return sc, mesh, n0, e


@pytest.mark.parametrize("with_unpainted", [False, True])
def test_restriction_equals_full_solve_continue(with_unpainted):
    """'continue': the restricted least squares (coupled faces only, unpainted faces eliminated by
    their Neumann series) gives the seen faces' emission of the dense least squares over
    every hidden face."""
    sc, mesh, n0, e = _corner_with_detached_plate()
    n = len(mesh.faces)
    c = np.asarray(mesh.triangles_center)
    F = view_factors(mesh, rays_per_face=64, seed=3)
    rho = np.full(n, 0.6)
    seen = np.zeros(n, bool)
    seen[:n0] = (sc.plate == 0) | (c[:n0, 2] < 0.3)  # floor and the wall's foot
    unpainted = np.zeros(n, bool)
    if with_unpainted:
        unpainted[:n0] = (sc.plate == 1) & (c[:n0, 2] > 0.7)  # the top of the wall
        e = np.where(unpainted, 0.0, e)
    B = forward(F, e, rho)
    reach = coupled_faces(F, seen)
    assert not reach[n0:].any() and reach[:n0].all()
    E, info = correct(F, np.where(seen, B, np.nan), rho, seen, mesh=mesh,
                      unpainted=unpainted, regularization=1e-6, tol=1e-12, return_info=True)
    assert info.method == "pcg" and info.n_coupled == int((reach & ~seen).sum())
    ref = _dense_continue(F, B, rho, seen, unpainted, mesh, 1e-6)
    np.testing.assert_allclose(E[seen], ref[seen], rtol=1e-6)
    assert np.all(np.isnan(E[n0:]))  # not coupled: not estimated under 'continue'
    np.testing.assert_array_equal(E[unpainted], 0.0)


@pytest.mark.parametrize("k", [128, 4096])  # 4096: several chunks a round, worker pool
def test_coupled_rows_are_those_of_the_full_matrix(slab, k):
    """Rays cast from the seen and coupled faces only, round by round: the rows computed
    are exactly the coupled set of the full matrix, each row the full matrix's row."""
    sc, cam, smap, F_ref, F, B = slab
    seen = smap.pixel_counts > 0
    F = F if k == 128 else view_factors(sc.mesh, rays_per_face=k, seed=0)
    Fc, rows = coupled_view_factors(sc.mesh, seen, rays_per_face=k, seed=0)
    np.testing.assert_array_equal(rows, coupled_faces(F, seen))
    assert rows.sum() < 0.5 * len(rows)
    diff = (Fc - sp.diags(rows.astype(float)) @ F).tocsr()
    assert diff.nnz == 0 or abs(diff).max() < 1e-12


def test_coupled_rows_in_the_surface_maps_scene(slab, embree_scenes):
    """Traced in the surface map's Embree scene (``caster=``), the coupled rows are the
    full matrix's rows, and no scene is built for them."""
    from resection.surface.visibility import RayCaster

    sc, cam, smap, F_ref, F, B = slab
    seen = smap.pixel_counts > 0
    caster = RayCaster(sc.mesh)
    assert len(embree_scenes) == 1  # the caster's
    Fc, rows = coupled_view_factors(sc.mesh, seen, rays_per_face=128, seed=0, caster=caster)
    assert len(embree_scenes) == 1
    np.testing.assert_array_equal(rows, coupled_faces(F, seen))
    diff = (Fc - sp.diags(rows.astype(float)) @ F).tocsr()
    assert diff.nnz == 0 or abs(diff).max() < 1e-12
    with pytest.raises(InputError, match="caster: built for"):
        other = corner(resolution=3).mesh
        coupled_view_factors(other, np.ones(len(other.faces), bool), caster=caster)


def test_correct_command_builds_one_embree_scene(slab, tmp_path, embree_scenes, capsys):
    """``selfillum correct`` casts its surface map and its view factors in one scene."""
    sc, cam, smap, F_ref, F, B = slab
    img = smap.to_image(B, background=0.0)
    sc.mesh.export(tmp_path / "slab.ply")
    write_camera(tmp_path / "cam.json", cam)
    np.save(tmp_path / "img.npy", img.astype(np.float32))
    assert main(["correct", "--mesh", str(tmp_path / "slab.ply"), "--camera",
                 str(tmp_path / "cam.json"), "--image", str(tmp_path / "img.npy"),
                 "--reflectance", "0.5", "--out", str(tmp_path / "out.npy"), "--quiet"]) == 0
    assert len(embree_scenes) == 1
    assert np.load(tmp_path / "out.npy").shape == img.shape


# ---------------------------------------------------------------- the assumption
@pytest.fixture(scope="module")
def corner_wall_unseen():
    """The corner, smooth emission continuous across the fold, the wall wholly unseen;
    the truth measured with a converged independent F (2048 rays, another seed)."""
    sc = corner(resolution=12)
    F_ref = view_factors(sc.mesh, rays_per_face=2048, seed=7)
    F = view_factors(sc.mesh, rays_per_face=256, seed=0)
    B = forward(F_ref, sc.emission, sc.reflectance)
    seen = sc.plate == 0
    return sc, F, B, seen


def test_corner_one_plate_unseen_continuation(corner_wall_unseen):
    """Wall unseen and painted (its true emission falls from 1.3 at the fold to 0.7 at its
    top, which the floor cannot tell): continuing the floor's emission onto it leaves a
    median error of 3 % and at most 6.5 % on the floor, where the self-illumination has a
    median of 11 % and reaches 28 % (measured: 2.4 % and 5.3 %; with every face seen the
    256-ray F alone leaves 0.4 % and 2.1 %). Saying the wall emits nothing would leave
    nearly all of the self-illumination in (median error 10 %)."""
    sc, F, B, seen = corner_wall_unseen
    E = sc.emission
    si = (B - E) / B
    assert si[seen].max() > 0.25
    E_c, info = correct(F, np.where(seen, B, np.nan), sc.reflectance, seen, mesh=sc.mesh,
                        return_info=True)
    err = np.abs(E_c - E) / E
    assert np.median(err[seen]) < 0.03 and err[seen].max() < 0.065
    E_0 = correct(F, np.where(seen, B, np.nan), sc.reflectance, seen, unseen="none")
    err0 = np.abs(E_0 - E) / E
    assert np.median(err0[seen]) > 3 * np.median(err[seen]) and err0[seen].max() > 0.25
    # flat floor: no floor face sees another, so all of its correction comes from the wall
    np.testing.assert_allclose(info.unseen_share[seen], 1.0, rtol=0, atol=1e-12)
    assert np.all(np.isnan(info.unseen_share[~seen]))
    # given values: the true emission of the wall gives the truth within the noise of F
    # (that of the correction with every face seen)
    E_g = correct(F, np.where(seen, B, np.nan), sc.reflectance, seen, unseen=E)
    noise = (np.abs(correct(F, B, sc.reflectance) - E) / E)[seen]
    assert (np.abs(E_g - E) / E)[seen].max() < 1.5 * noise.max()


def test_all_seen_has_no_unseen_share(corner_wall_unseen):
    sc, F, B, _ = corner_wall_unseen
    E, info = correct(F, B, sc.reflectance, return_info=True)
    assert info.method == "direct" and info.unseen_share is None
    unpainted = sc.plate == 1
    E2 = correct(F, B, sc.reflectance, unpainted=unpainted)
    np.testing.assert_array_equal(E2[unpainted], 0.0)
    np.testing.assert_allclose(E2[~unpainted], E[~unpainted])


def _write_case(tmp_path, sc, cam, smap, B):
    """Plot3D grid, camera, an image whose pixels carry their face's radiosity (so that
    the per-face mean is B exactly) and the per-face reflectance."""
    grid = tmp_path / "grid.xyz"
    write_slab_block(sc, grid)
    write_camera(tmp_path / "cam.json", cam)
    img = np.where(smap.mask, B[np.maximum(smap.face_index, 0)], 0.0).astype(np.float32)
    np.save(tmp_path / "img.npy", img)
    np.savetxt(tmp_path / "rho.csv", sc.reflectance)
    return ["correct", "--mesh", str(grid), "--camera", str(tmp_path / "cam.json"),
            "--image", str(tmp_path / "img.npy"), "--reflectance", str(tmp_path / "rho.csv"),
            "--out", str(tmp_path / "out.npy"), "--surface", str(tmp_path / "faces.csv"),
            "--quiet"]


def _faces_csv(path):
    table = np.genfromtxt(path, delimiter=",", names=True)
    return table[np.argsort(table["face"])]


def test_black_block_unpainted_matches_truth_else_warning(slab, tmp_path, capsys):
    """The plate with a black unpainted box: with --unpainted (Plot3D block numbers) the
    correction next to the box's base matches the truth; without, the box's unseen sides
    are continued from the bright plate, the correction there is far off and a warning
    says the result rests on unseen faces."""
    sc, cam, smap, F_ref, F, B = slab
    args = _write_case(tmp_path, sc, cam, smap, B)
    c = np.asarray(sc.mesh.triangles_center)
    base = (sc.part == 0) & (np.abs(c[:, 0]) < 0.07) & (np.abs(c[:, 1]) < 0.06)

    assert main(args + ["--unpainted", BOX_BLOCKS]) == 0
    out = capsys.readouterr()
    assert "warning" not in out.err
    assert "unpainted faces from Plot3D blocks 7-11 emit nothing" in out.out
    faces = _faces_csv(tmp_path / "faces.csv")
    ok = base & (faces["seen"] == 1)
    assert ok.sum() > 20
    err = np.abs(faces["emission"] - sc.emission)[ok] / sc.emission[ok]
    assert err.max() < 0.003  # the true SI there is about 1 %
    np.testing.assert_array_equal(faces["unpainted"], (sc.part >= 6).astype(float))
    summary = json.loads((tmp_path / "out.npy.json").read_text())
    assert "unpainted" in summary["assumption"] and summary["warnings"] == []

    assert main(args) == 0  # the same without --unpainted
    out = capsys.readouterr()
    assert "warning: " in out.err and "faces no camera sees" in out.err
    assert "continue (smoothest continuation" in out.out
    faces = _faces_csv(tmp_path / "faces.csv")
    err = np.abs(faces["emission"] - sc.emission)[ok] / sc.emission[ok]
    assert err.max() > 0.05
    assert np.nanmax(faces["unseen_share"][ok]) > 0.9
    summary = json.loads((tmp_path / "out.npy.json").read_text())
    assert len(summary["warnings"]) == 1


def test_grazing_faces_are_unseen(slab):
    """The box's -y side is seen at about 75 degrees from its normal: with the default
    cut-off (70) its faces are unseen although pixels land on them, and they do not enter
    the summary; a cut-off of 80 takes them in."""
    from selfillum.summary import summarize

    sc, cam, smap, F_ref, F, B = slab
    smap90 = SurfaceMap(sc.mesh, cam, max_obliqueness=90.0)
    side = sc.part == 7
    img = np.where(smap90.mask, B[np.maximum(smap90.face_index, 0)], 0.0)
    assert (smap90.pixel_counts[side] > 0).sum() > 10  # pixels do land on the side
    unp = sc.part >= 6
    r = correct_image(img, sc.mesh, cam, sc.reflectance, F=F, unpainted=unp)
    assert r.grazing[side].all() and not r.seen[side].any()
    assert not r.grazing[sc.part == 0].any()
    r80 = correct_image(img, sc.mesh, cam, sc.reflectance, F=F, unpainted=unp,
                        max_obliqueness=80.0)
    assert r80.seen[side].sum() > 10 and not r80.grazing[side].any()
    s = summarize(r)
    assert s.grazing == int(r.grazing.sum()) and s.seen_max == int((r.seen & ~unp).sum())
    assert 0 <= s.si_percentiles["50"] <= s.si_percentiles["95"] <= s.si_percentiles["99"]
    lit = r.seen & sc.painted  # percentiles are over the painted seen faces
    si_seen = (B[lit] - sc.emission[lit]) / B[lit]
    assert s.si_percentiles["99"] < 1.5 * np.percentile(si_seen, 99) + 0.01


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize("extra, match", [
    (["--unpainted", "12"], "block 12 does not exist"),
    (["--unpainted", "0"], "block 0 does not exist"),
    (["--unpainted", "nofile.npy"], "no such unpainted-face file"),
    (["--unseen", "nofile.npy"], "no such unseen-emission file"),
    (["--max-obliqueness", "95"], "max-obliqueness"),
])
def test_cli_bad_unseen_options(slab, tmp_path, capsys, extra, match):
    sc, cam, smap, F_ref, F, B = slab
    args = _write_case(tmp_path, sc, cam, smap, B)
    if extra[0] == "--max-obliqueness":  # argparse refuses it before the library runs
        with pytest.raises(SystemExit) as exc:
            main(args + extra)
        assert exc.value.code == 2
    else:
        assert main(args + extra) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out.npy").exists()


def test_unpainted_files(slab, tmp_path):
    sc, *_ = slab
    n = len(sc.mesh.faces)
    mask = sc.part >= 6
    np.save(tmp_path / "u.npy", mask.astype(np.uint8))
    np.savetxt(tmp_path / "u.csv", mask.astype(int), fmt="%d", header="unpainted",
               comments="")
    for name in ("u.npy", "u.csv"):
        got, source = read_unpainted(str(tmp_path / name), sc.mesh)
        np.testing.assert_array_equal(got, mask)
        assert name in source
    np.save(tmp_path / "short.npy", np.zeros(n - 1))
    with pytest.raises(InputError, match=f"{n - 1} unpainted values for {n} faces"):
        read_unpainted(str(tmp_path / "short.npy"), sc.mesh)
    np.save(tmp_path / "two.npy", np.where(mask, 2, 0))
    with pytest.raises(InputError, match="must be 0 or 1"):
        read_unpainted(str(tmp_path / "two.npy"), sc.mesh)
    got, _ = read_unpainted("7,8-11", sc.mesh)
    np.testing.assert_array_equal(got, mask)
    plain = trimesh.Trimesh(sc.mesh.vertices, sc.mesh.faces, process=False)
    with pytest.raises(InputError, match="need a Plot3D grid"):
        read_unpainted("7-11", plain)
