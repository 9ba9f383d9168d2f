"""The self-illumination reference of the unsteady run (issue 23): the smooth-continuation
solve of a frame whose camera sees part of the model, on form factors of few rays a face
(noisy, as the run uses them).

Reference: the same least squares (smoothness of the emission over the seen and coupled
faces plus the small Tikhonov term) written out as explicit sparse matrices and solved by
SciPy's direct ``spsolve`` on its normal equations, independent of the preconditioned CG.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import trimesh

from resection.surface.surface_map import SurfaceMap
from scenes.slab_block import slab_block
from scenes.unsteady_run import _camera
from selfillum import correct, forward, view_factors
from selfillum.mesh import face_adjacency_weights
from selfillum.transport.coupling import coupled_faces


@pytest.fixture(scope="module")
def slab_frame():
    """A 55k-face slab and block (both painted, rho 0.6), 16 rays a face, the unsteady
    run's camera (320 x 200) seeing part of it."""
    sc = slab_block(60_000, box=(0.04, 0.03, 0.04), rho_paint=0.6, rho_box=0.6)
    mesh = sc.mesh
    n = len(mesh.faces)
    F = view_factors(mesh, rays_per_face=16, seed=1)
    sm = SurfaceMap(mesh, _camera(320, 200), max_obliqueness=70.0)
    fi = sm.face_index.ravel()
    seen = np.zeros(n, bool)
    seen[fi[fi >= 0]] = True
    B = forward(F, sc.emission + 0.2, sc.reflectance)
    return mesh, F, sc.reflectance, seen, B


def _direct_continue(mesh, F, rho, seen, B, reg):
    """Seen + coupled faces ``sub``; min |D E|^2 + lam^2 |B_P - prior|^2 over the hidden
    faces' radiosity ``B_P``, ``E = (I - rho F) B`` on ``sub``, ``D`` the edges between
    faces of ``sub``; normal equations solved by ``spsolve``."""
    n = len(B)
    sub = np.flatnonzero(coupled_faces(F, seen))
    M = (sp.identity(n) - sp.diags(rho) @ F).tocsr()[sub][:, sub].tocsc()
    loc = seen[sub]
    s, P = np.flatnonzero(loc), np.flatnonzero(~loc)
    D = face_adjacency_weights(trimesh.Trimesh(mesh.vertices, mesh.faces[sub],
                                               process=False)).tocsr()
    col = np.sqrt(np.asarray(D.multiply(D).sum(axis=0)).ravel())[P]
    lam = np.sqrt(reg) * np.median(col[col > 0])
    prior = B[sub][s].mean()
    a = M[:, s] @ B[sub][s]
    DG = (D @ M[:, P]).tocsc()
    N = (DG.T @ DG + lam**2 * sp.identity(P.size)).tocsc()
    bp = spla.spsolve(N, -(DG.T @ (D @ a)) + lam**2 * prior)
    Bs = np.zeros(sub.size)
    Bs[s], Bs[P] = B[sub][s], bp
    E = np.full(n, np.nan)
    E[sub] = M @ Bs
    return E, P.size


def test_continuation_matches_direct_solve_in_few_iterations(slab_frame):
    """The preconditioned CG gives the direct solve's emission on the seen faces within
    1e-7 (relative), in a few hundred iterations at most. The Laplacian preconditioner
    it replaced took 1,362 iterations on this frame (tol 1e-10) and 8,353 on the
    unsteady bench's 1.1 M-face grid (docs/benchmark_history.md)."""
    mesh, F, rho, seen, B = slab_frame
    E, info = correct(F, np.where(seen, B, np.nan), rho, seen, mesh=mesh, tol=1e-10,
                      return_info=True)
    ref, n_hidden = _direct_continue(mesh, F, rho, seen, B, 1e-6)
    assert info.method == "pcg" and info.n_coupled == n_hidden > 500
    np.testing.assert_allclose(E[seen], ref[seen], rtol=1e-7)
    assert info.iterations <= 400


def test_references_planned_cover_every_frame_with_few():
    """A vibrating model's references, planned from the known poses: every frame is within
    ``refresh_px`` of its reference (distance measured here with Camera.project on every
    probe point), and a pitch oscillation of amplitude A pixels (about 15) needs at most
    A / refresh + 1 references (5 here; a reference cast at each frame that moved past
    the others gives 7)."""
    from scipy.spatial.transform import Rotation

    from scenes.slab_block import slab_camera
    from selfillum.unsteady.references import plan_references

    cam = slab_camera(640, 480)
    rng = np.random.default_rng(2)
    X = np.column_stack([rng.uniform(-0.2, 0.2, 200), rng.uniform(-0.15, 0.15, 200),
                         np.zeros(200)])
    T, refresh = 300, 3.0
    theta = np.radians(5.0) * np.sin(2 * np.pi * np.arange(T) / 67.0 + 0.3)
    poses = [cam.with_pose(R=cam.R @ Rotation.from_rotvec([th, 0, 0]).as_matrix(), t=cam.t)
             for th in theta]
    uv = np.stack([p.project(X) for p in poses])
    amp = np.abs(uv - uv[0]).max()
    plan = plan_references([poses], [X], range(T), refresh, first=0)
    refs = sorted(set(plan.values()))
    assert set(plan) == set(range(T)) and 0 in refs
    for k, j in plan.items():
        assert np.abs(uv[k] - uv[j]).max() <= refresh
    assert amp > 4 * refresh and len(refs) <= np.ceil(amp / refresh) + 1


def test_freed_heap_memory_is_given_back():
    """release_freed_memory (glibc malloc_trim) gives back pages the C heap keeps after a
    free: 200 MB of 4 kB blocks freed below a block still in use stay resident without it
    (checked in the same subprocess) and leave with it."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import sys
        from resection.memory import release_freed_memory
        def rss():
            with open('/proc/self/status') as f:
                return next(int(l.split()[1]) // 1024 for l in f if l.startswith('VmRSS'))
        r0 = rss()
        blocks = [bytes(4000) + bytes([i % 256]) for i in range(50_000)]
        pin = bytes(4000) + b"x"
        del blocks
        kept = rss() - r0
        ok = release_freed_memory()
        print(kept, rss() - r0, ok)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    kept, after, ok = int(out[0]), int(out[1]), out[2] == "True"
    assert ok  # glibc (Linux)
    assert kept > 150 and after < 50
