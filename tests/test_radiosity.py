"""Lambertian forward model and its inverse, against closed forms (two patches, a closed
enclosure) and a dense direct solve (numpy.linalg.solve)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

from resection.errors import InputError, SolveError
from scenes.corner import corner
from selfillum import correct, forward, view_factors


def random_form_factors(n: int, k: int, seed: int) -> sp.csr_matrix:
    """Sparse non-negative matrix, ``k`` entries a row, rows summing to values in
    [0.5, 1]."""
    rng = np.random.default_rng(seed)
    cols = np.stack([rng.choice(n - 1, size=k, replace=False) for _ in range(n)])
    cols = cols + (cols >= np.arange(n)[:, None])  # no diagonal
    w = rng.random((n, k))
    w *= (0.5 + 0.5 * rng.random((n, 1))) / w.sum(axis=1, keepdims=True)
    return sp.csr_matrix((w.ravel(), (np.repeat(np.arange(n), k), cols.ravel())), shape=(n, n))


# ---------------------------------------------------------------- forward
def test_two_patch_closed_form():
    f12, f21 = 0.3, 0.45
    F = sp.csr_matrix([[0.0, f12], [f21, 0.0]])
    E = np.array([2.0, 0.5])
    rho = np.array([0.7, 0.4])
    det = 1 - rho[0] * rho[1] * f12 * f21
    exact = np.array([(E[0] + rho[0] * f12 * E[1]) / det, (E[1] + rho[1] * f21 * E[0]) / det])
    np.testing.assert_allclose(forward(F, E, rho), exact, rtol=1e-9)


@pytest.mark.parametrize("rho_max", [0.4, 0.95])  # Neumann path, BiCGSTAB path
def test_forward_matches_dense_direct_solve(rho_max):
    n = 300
    F = random_form_factors(n, 12, seed=1)
    rng = np.random.default_rng(2)
    E = rng.random(n) + 0.1
    rho = rho_max * rng.random(n)
    rho[0] = rho_max
    B, info = forward(F, E, rho, tol=1e-11, return_info=True)
    exact = np.linalg.solve(np.eye(n) - rho[:, None] * F.toarray(), E)
    np.testing.assert_allclose(B, exact, rtol=1e-9)
    assert info.residual <= 1e-11
    assert info.method == ("neumann" if rho_max <= 0.5 else "bicgstab")


def test_closed_enclosure_closed_form():
    """In a closed enclosure (rows of F sum to 1) with uniform E and rho,
    B = E / (1 - rho) on every face."""
    box = trimesh.creation.box(extents=(1.0, 1.0, 2.0)).subdivide()
    box.invert()
    F = view_factors(box, rays_per_face=64, seed=0)
    B = forward(F, 3.0, 0.8)
    np.testing.assert_allclose(B, 3.0 / (1 - 0.8), rtol=1e-9)


def test_zero_emission_and_zero_reflectance():
    F = random_form_factors(50, 5, seed=3)
    np.testing.assert_array_equal(forward(F, np.zeros(50), 0.5), 0.0)
    E = np.linspace(1, 2, 50)
    np.testing.assert_allclose(forward(F, E, 0.0), E)


def test_no_convergence_is_a_solve_error():
    F = random_form_factors(200, 10, seed=4)
    with pytest.raises(SolveError, match="did not converge"):
        forward(F, np.ones(200), 0.99, tol=1e-14, maxiter=2)


# ---------------------------------------------------------------- inverse
def test_round_trip_all_seen():
    n = 400
    F = random_form_factors(n, 16, seed=5)
    rng = np.random.default_rng(6)
    E = rng.random(n) + 0.5
    rho = 0.9 * rng.random(n)
    B = forward(F, E, rho, tol=1e-12)
    assert np.max(np.abs(B - E) / E) > 0.3  # there is something to correct
    E2, info = correct(F, B, rho, return_info=True)
    np.testing.assert_allclose(E2, E, rtol=1e-10)
    assert info.method == "direct" and info.n_hidden == 0


@pytest.fixture(scope="module")
def small_corner():
    sc = corner(resolution=12, pattern="uniform")
    F = view_factors(sc.mesh, rays_per_face=128, seed=0)
    c = np.asarray(sc.mesh.triangles_center)
    s = np.where(sc.plate == 0, -c[:, 0], c[:, 2])
    return sc, F, c, s


def test_partial_observation_uniform_emission_recovered(small_corner):
    """Upper wall hidden: uniform emission is the smoothest field, so it is recovered
    everywhere, hidden faces included."""
    sc, F, c, _ = small_corner
    E = np.full(len(c), 2.0)
    B = forward(F, E, sc.reflectance)
    seen = ~((sc.plate == 1) & (c[:, 2] > 0.5))
    measured = np.where(seen, B, np.nan)  # hidden values are not used
    E2, info = correct(F, measured, sc.reflectance, seen, mesh=sc.mesh, return_info=True)
    assert info.method == "pcg" and info.n_hidden == int((~seen).sum())
    assert 0 < info.iterations < 60  # preconditioned: tens of iterations, not hundreds
    np.testing.assert_allclose(E2, E, rtol=1e-3)


def test_partial_observation_smooth_emission(small_corner):
    """A smooth non-uniform field: on the seen faces the correction removes nearly all of
    the self-illumination (errors small against the SI present)."""
    sc, F, c, s = small_corner
    E = 1.0 + 0.3 * np.cos(np.pi * s) + 0.1 * c[:, 1]
    B = forward(F, E, sc.reflectance)
    seen = ~((sc.plate == 1) & (c[:, 2] > 0.6))
    si = (B - E) / E
    E2 = correct(F, B, sc.reflectance, seen, mesh=sc.mesh)
    err = np.abs(E2 - E) / E
    assert si[seen].max() > 0.35
    assert err[seen].max() < 0.05 * si[seen].max()
    # ignoring the hidden faces altogether (B_h = 0) would be far worse
    naive = B - sc.reflectance * (F @ np.where(seen, B, 0.0))
    assert (np.abs(naive - E) / E)[seen].max() > 3 * err[seen].max()


# ---------------------------------------------------------------- bad input
def test_bad_reflectance():
    F = random_form_factors(20, 4, seed=7)
    E = np.ones(20)
    for bad in (1.0, 1.2, -0.1, np.nan):
        with pytest.raises(InputError, match="reflectance"):
            forward(F, E, bad)
        with pytest.raises(InputError, match="reflectance"):
            correct(F, E, bad)
    rho = np.full(20, 0.5)
    rho[7] = 1.0
    with pytest.raises(InputError, match="face 7"):
        forward(F, E, rho)
    with pytest.raises(InputError, match="reflectance"):
        forward(F, E, np.full(19, 0.5))


def test_bad_fields_and_matrices():
    F = random_form_factors(20, 4, seed=8)
    E = np.ones(20)
    E[3] = np.nan
    with pytest.raises(InputError, match="emission.*face 3"):
        forward(F, E, 0.5)
    with pytest.raises(InputError, match="radiosity.*face 3"):
        correct(F, E, 0.5)
    with pytest.raises(InputError, match="shape"):
        forward(F, np.ones(21), 0.5)
    with pytest.raises(InputError, match="square"):
        forward(sp.csr_matrix(np.zeros((3, 4))), np.ones(3), 0.5)
    with pytest.raises(InputError, match="sums to"):
        forward(sp.csr_matrix([[0.0, 1.5], [0.2, 0.0]]), np.ones(2), 0.5)
    with pytest.raises(InputError, match="negative"):
        forward(sp.csr_matrix([[0.0, -0.5], [0.2, 0.0]]), np.ones(2), 0.5)


def test_bad_seen_mask(small_corner):
    sc, F, c, _ = small_corner
    B = np.ones(len(c))
    with pytest.raises(InputError, match="seen"):
        correct(F, B, 0.5, np.ones(len(c)))  # not boolean
    with pytest.raises(InputError, match="no face is seen"):
        correct(F, B, 0.5, np.zeros(len(c), bool))
    seen = np.ones(len(c), bool)
    seen[0] = False
    with pytest.raises(InputError, match="mesh"):
        correct(F, B, 0.5, seen)
    with pytest.raises(InputError, match="regularization"):
        correct(F, B, 0.5, seen, mesh=sc.mesh, regularization=0.0)


def test_iterative_solves_keep_blas_on_one_thread():
    """The Krylov solvers' vector norms run on one BLAS thread for long vectors (waking
    OpenBLAS threads for each microsecond-long norm is what made LSMR slow on shared
    cores); short vectors and the state after the solve are left alone."""
    from threadpoolctl import threadpool_info

    from selfillum.solve.radiosity import single_blas_thread

    def blas_threads():
        return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]

    before = blas_threads()
    # NumPy's OpenBLAS (scipy-openblas in NumPy >= 2 wheels) is visible to threadpoolctl
    # >= 3.5; a BLAS that threadpoolctl does not know (Accelerate) has no pool to limit
    blas = np.show_config(mode="dicts")["Build Dependencies"]["blas"]["name"]
    assert bool(before) or "openblas" not in blas.lower(), (blas, before)
    with single_blas_thread(100_000):
        assert blas_threads() == [1] * len(before)
    assert blas_threads() == before
    with single_blas_thread(100):
        assert blas_threads() == before


def test_cg_and_bicgstab_run_under_the_blas_limit(small_corner, monkeypatch):
    import contextlib

    import selfillum.solve.radiosity as rad

    sizes = []

    def record(size):
        sizes.append(size)
        return contextlib.nullcontext()

    monkeypatch.setattr(rad, "single_blas_thread", record)
    sc, F, c, _ = small_corner
    B = forward(F, np.ones(len(c)), 0.9)  # rho > 0.5: BiCGSTAB
    seen = c[:, 2] < 0.5
    _, info = correct(F, np.where(seen, B, np.nan), 0.9, seen, mesh=sc.mesh, return_info=True)
    n = len(c)
    # the forward solve's vectors, then the whole continuation (its CG, norms and the
    # Laplacian's factorisation) over the seen and coupled faces
    assert sizes[0] == n and sizes[1] == info.n_seen + info.n_coupled


def test_adjacency_of_a_mesh_with_unmerged_vertices(small_corner):
    """Every face with its own three vertices (as many readers build meshes): the
    partial-observation inverse still sees which faces touch, and gives the same answer."""
    from selfillum.mesh import face_adjacency_weights

    sc, F, c, _ = small_corner
    tri = np.asarray(sc.mesh.triangles)
    soup = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(tri.size // 3).reshape(-1, 3),
                           process=False)
    np.testing.assert_array_equal(soup.triangles, sc.mesh.triangles)
    D0, D1 = face_adjacency_weights(sc.mesh), face_adjacency_weights(soup)
    assert D1.shape == D0.shape and D0.shape[0] > 0
    np.testing.assert_allclose(np.sort(abs(D1).sum(axis=0).A1), np.sort(abs(D0).sum(axis=0).A1))
    np.testing.assert_allclose((D1.T @ D1).toarray(), (D0.T @ D0).toarray(), atol=1e-12)
    E = np.full(len(c), 2.0)
    B = forward(F, E, sc.reflectance)
    seen = c[:, 2] < 0.5
    np.testing.assert_allclose(correct(F, B, sc.reflectance, seen, mesh=soup), E, rtol=1e-3)


def test_preconditioned_continuation_agrees_with_a_direct_solve(small_corner):
    """The smooth continuation's preconditioned CG gives the minimiser of its least squares
    (``|D E|^2 + lam^2 |B_h - mean(B_seen)|^2`` over the hidden faces' radiosity, ``E =
    (I - rho F) B``), as a direct sparse solve of the normal equations
    (scipy.sparse.linalg.spsolve) gives it: the emission of every face within 1e-6 of the
    largest emission (CG stops at a relative residual of 1e-8), far below the
    self-illumination being corrected (about 30 % here)."""
    import scipy.sparse.linalg as spla

    from selfillum.mesh import face_adjacency_weights
    from selfillum.transport.coupling import coupled_faces

    sc, F, c, s = small_corner
    E = 1.0 + 0.3 * np.cos(np.pi * s) + 0.1 * c[:, 1]
    rho = np.full(len(c), 0.6)
    B = forward(F, E, rho)
    seen = ~((sc.plate == 1) & (c[:, 2] > 0.5))
    assert coupled_faces(F, seen).all()  # every hidden face enters the solve
    E_cg, info = correct(F, np.where(seen, B, np.nan), rho, seen, mesh=sc.mesh,
                         regularization=1e-6, return_info=True)
    assert info.method == "pcg" and info.iterations > 0
    # the same least squares, assembled here and solved directly
    M = (sp.identity(len(c)) - sp.diags(rho) @ F).tocsc()
    hid, vis = np.flatnonzero(~seen), np.flatnonzero(seen)
    D = face_adjacency_weights(sc.mesh).tocsc()
    col = np.sqrt(np.asarray(D.multiply(D).sum(axis=0)).ravel())[hid]
    lam = np.sqrt(1e-6) * np.median(col[col > 0])
    DM_h, DM_s = D @ M[:, hid], D @ M[:, vis]
    base = B[vis].mean()
    lhs = (DM_h.T @ DM_h + lam**2 * sp.identity(hid.size)).tocsc()
    rhs = lam**2 * np.full(hid.size, base) - DM_h.T @ (DM_s @ B[vis])
    B_direct = np.where(seen, B, 0.0)
    B_direct[hid] = spla.spsolve(lhs, rhs)
    E_direct = M @ B_direct
    np.testing.assert_allclose(E_cg, E_direct, rtol=0, atol=1e-6 * np.abs(E_direct).max())
    si = (B - E) / E
    assert si[seen].max() > 0.25  # the tolerance is small against what is corrected


_KERNELS_AFTER_LOAD = """
import numba
import numpy as np
from numba.core.registry import CPUDispatcher

from scenes.corner import corner
from selfillum import view_factors
from selfillum.solve.radiosity import correct, load_kernels

sc = corner(resolution=4)
n = len(sc.mesh.faces)
F = view_factors(sc.mesh, 32, seed=1)  # the traced F, with its own index types
load_kernels({unseen!r})


def compiled():
    import sys
    out = {{}}
    for name, mod in list(sys.modules.items()):
        if name.startswith(("resection", "selfillum")):
            for key, obj in list(vars(mod).items()):
                if isinstance(obj, CPUDispatcher):
                    out[name + "." + key] = len(obj.signatures)
    return out


before = compiled()
seen = np.arange(n) < n // 2
unpainted = np.arange(n) % 7 == 3
E, info = correct(F, np.ones(n), 0.5, seen, mesh=sc.mesh, unseen={unseen!r},
                  unpainted=unpainted, return_info=True)
assert info.method == {method!r}, info.method
after = compiled()
grew = {{k: (before.get(k, 0), v) for k, v in after.items() if v != before.get(k, 0)}}
assert not grew, grew
loaded = {{k for k, v in before.items() if v}}
print(sorted(loaded))
"""


@pytest.mark.parametrize("unseen, method", [("continue", "pcg"), ("none", "neumann")])
def test_load_kernels_leaves_nothing_to_load_for_a_traced_F(unseen, method):
    """``selfillum correct`` loads the solve's compiled kernels on a thread while its rays
    run (:func:`load_kernels`, on a 4-face strip): afterwards, correcting a partial view
    with a traced ``F`` (its own index types) compiles or loads no kernel of the package.
    In a fresh process, so that no earlier test has loaded them."""
    import subprocess
    import sys
    from pathlib import Path

    code = _KERNELS_AFTER_LOAD.format(unseen=unseen, method=method)
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=root, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    loaded = out.stdout
    for kernel in ("csr._blocks", "csr._identity_minus", "coupling._reach"):
        assert kernel in loaded  # the strip ran the solve's kernels
    if unseen == "continue":
        assert "_mesh_graph._shared_edges" in loaded
