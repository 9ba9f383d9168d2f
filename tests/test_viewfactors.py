"""View factors by Embree ray casting against closed forms (Howell's catalogue, C-11,
C-14, C-41) and exact properties (closed enclosures, reciprocity, determinism)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

from resection.errors import InputError
from selfillum import enforce_reciprocity, view_factors
from selfillum.mesh import check_mesh, face_areas
from selfillum.transport.viewfactors import RowTracer


# ---------------------------------------------------------------- closed forms (Howell)
def howell_perpendicular(w: float, h: float, length: float) -> float:
    """C-14: plate 1 (w x l) to plate 2 (h x l), perpendicular, sharing the edge l."""
    W, H = w / length, h / length
    WH = np.hypot(W, H)
    t = W * np.arctan(1 / W) + H * np.arctan(1 / H) - WH * np.arctan(1 / WH)
    a = (1 + W**2) * (1 + H**2) / (1 + W**2 + H**2)
    b = (W**2 * (1 + W**2 + H**2) / ((1 + W**2) * (W**2 + H**2))) ** (W**2)
    c = (H**2 * (1 + H**2 + W**2) / ((1 + H**2) * (H**2 + W**2))) ** (H**2)
    return float((t + 0.25 * np.log(a * b * c)) / (np.pi * W))


def howell_parallel(a: float, b: float, c: float) -> float:
    """C-11: identical, parallel, directly opposed rectangles a x b at distance c."""
    X, Y = a / c, b / c
    sx, sy = np.sqrt(1 + X**2), np.sqrt(1 + Y**2)
    f = (
        np.log(np.sqrt((1 + X**2) * (1 + Y**2) / (1 + X**2 + Y**2)))
        + X * sy * np.arctan(X / sy)
        + Y * sx * np.arctan(Y / sx)
        - X * np.arctan(X)
        - Y * np.arctan(Y)
    )
    return float(2 / (np.pi * X * Y) * f)


def howell_disks(r1: float, r2: float, h: float) -> float:
    """C-41: disk r1 to a coaxial parallel disk r2 at distance h."""
    R1, R2 = r1 / h, r2 / h
    X = 1 + (1 + R2**2) / R1**2
    return float(0.5 * (X - np.sqrt(X**2 - 4 * (R2 / R1) ** 2)))


# ---------------------------------------------------------------- meshes
def plate(n: int, corner, e1, e2, m: int | None = None):
    """Grid of n x m squares (two triangles each) from ``corner`` spanned by e1, e2;
    normal along e1 x e2."""
    m = n if m is None else m
    u, v = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, m + 1), indexing="ij")
    V = np.asarray(corner, float) + u.reshape(-1, 1) * e1 + v.reshape(-1, 1) * e2
    idx = np.arange((n + 1) * (m + 1)).reshape(n + 1, m + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return V, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def disk(radius: float, z: float, rings: int, segments: int, up: bool):
    r = radius * np.arange(1, rings + 1) / rings
    t = 2 * np.pi * np.arange(segments) / segments
    V = np.vstack(
        [
            [0, 0, z],
            np.column_stack(
                [
                    np.repeat(r, segments) * np.tile(np.cos(t), rings),
                    np.repeat(r, segments) * np.tile(np.sin(t), rings),
                    np.full(rings * segments, z),
                ]
            ),
        ]
    )
    ring = lambda k: 1 + k * segments + np.arange(segments)  # noqa: E731
    nxt = lambda a: np.roll(a, -1)  # noqa: E731
    faces = [np.column_stack([np.zeros(segments, int), ring(0), nxt(ring(0))])]
    for k in range(rings - 1):
        a, b = ring(k), ring(k + 1)
        faces += [np.column_stack([a, b, nxt(b)]), np.column_stack([a, nxt(b), nxt(a)])]
    F = np.vstack(faces)
    if not up:
        F = F[:, ::-1]
    return V, F


def join(*parts):
    Vs, Fs, groups, off = [], [], [], 0
    for g, (V, F) in enumerate(parts):
        Vs.append(V)
        Fs.append(F + off)
        groups.append(np.full(len(F), g))
        off += len(V)
    return trimesh.Trimesh(np.vstack(Vs), np.vstack(Fs), process=False), np.concatenate(groups)


def group_factor(F, mesh, groups, i, j):
    """Area-weighted form factor from group i to group j."""
    a = face_areas(mesh)
    rows = groups == i
    fij = np.asarray(F[rows][:, groups == j].sum(axis=1)).ravel()
    return float(a[rows] @ fij / a[rows].sum())


EX, EY, EZ = np.eye(3)


def perpendicular_mesh(w=1.0, h=1.0, length=1.0, n=10):
    floor = plate(n, [0, 0, 0], w * EX, length * EY)  # normal +z
    wall = plate(n, [0, 0, 0], length * EY, h * EZ)  # normal +x
    return join(floor, wall)


def parallel_mesh(n=10):
    lower = plate(n, [0, 0, 0], EX, EY)  # normal +z
    upper = plate(n, [0, 0, 1], EY, EX)  # normal -z
    return join(lower, upper)


# ---------------------------------------------------------------- accuracy
def test_closed_forms_sanity():
    # published values (Howell): unit squares at 90 degrees 0.20004, opposed at distance 1
    # 0.19982, equal disks r = h 0.38197
    assert howell_perpendicular(1, 1, 1) == pytest.approx(0.200044, abs=2e-6)
    assert howell_parallel(1, 1, 1) == pytest.approx(0.199825, abs=2e-6)
    assert howell_disks(1, 1, 1) == pytest.approx((3 - np.sqrt(5)) / 2, abs=1e-12)


def test_perpendicular_rectangles_common_edge():
    mesh, g = perpendicular_mesh(w=1.0, h=0.5, length=1.0)
    F = view_factors(mesh, rays_per_face=1024, seed=1)
    exact12 = howell_perpendicular(1.0, 0.5, 1.0)
    exact21 = howell_perpendicular(0.5, 1.0, 1.0)
    assert abs(group_factor(F, mesh, g, 0, 1) / exact12 - 1) < 0.005
    assert abs(group_factor(F, mesh, g, 1, 0) / exact21 - 1) < 0.005
    assert F.nnz <= 1024 * F.shape[0]
    assert np.diff(F.indptr).max() <= 1024


def test_parallel_aligned_rectangles():
    mesh, g = parallel_mesh()
    F = view_factors(mesh, rays_per_face=1024, seed=2)
    exact = howell_parallel(1, 1, 1)
    assert abs(group_factor(F, mesh, g, 0, 1) / exact - 1) < 0.005
    assert abs(group_factor(F, mesh, g, 1, 0) / exact - 1) < 0.005


def test_coaxial_parallel_disks():
    r1, r2, h = 1.0, 0.7, 0.8
    mesh, g = join(disk(r1, 0.0, 4, 128, up=True), disk(r2, h, 4, 128, up=False))
    F = view_factors(mesh, rays_per_face=512, seed=3)
    exact12 = howell_disks(r1, r2, h)
    exact21 = howell_disks(r2, r1, h)
    assert abs(group_factor(F, mesh, g, 0, 1) / exact12 - 1) < 0.005
    assert abs(group_factor(F, mesh, g, 1, 0) / exact21 - 1) < 0.005


def test_error_falls_as_inverse_sqrt_rays():
    """RMS error over seeds with 16x more rays is at most ~1/4 (1/sqrt(16)); the
    stratified sampling usually does better."""
    mesh, g = perpendicular_mesh(n=6)
    exact = howell_perpendicular(1, 1, 1)

    def rms(k):
        e = [
            group_factor(view_factors(mesh, k, seed), mesh, g, 0, 1) / exact - 1
            for seed in range(10)
        ]
        return float(np.sqrt(np.mean(np.square(e))))

    coarse, fine = rms(16), rms(256)
    assert fine < 0.35 * coarse


def test_unit_sphere_interior_rows_are_area_fractions():
    """Inside a sphere every face sees every face: F_ij = A_j / A (closed form)."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    mesh.invert()  # painted side inwards
    a = face_areas(mesh)
    F = view_factors(mesh, rays_per_face=4096, seed=0)
    # per-face estimates are noisy: compare the column sums (what each face receives)
    got = np.asarray(F.sum(axis=0)).ravel() / len(a)
    want = a / a.sum()
    assert np.abs(got / want - 1).max() < 0.05
    assert np.allclose(F.sum(axis=1), 1.0, atol=1e-12)


# ---------------------------------------------------------------- exact properties
def closed_box(n=4):
    box = trimesh.creation.box(extents=(1.0, 2.0, 0.5))
    for _ in range(n // 2):
        box = box.subdivide()
    box.invert()  # inwards: the painted side is inside
    return box


def test_closed_box_rows_sum_to_one():
    box = closed_box()
    F = view_factors(box, rays_per_face=256, seed=4)
    np.testing.assert_allclose(np.asarray(F.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    assert F.diagonal().max() == 0.0  # flat faces do not see themselves


def test_outward_box_sees_nothing():
    box = closed_box()
    box.invert()  # back to outward normals: every ray escapes
    F = view_factors(box, rays_per_face=64, seed=4)
    assert F.nnz == 0


def test_reciprocity_enforced():
    mesh, g = perpendicular_mesh(w=1.0, h=0.5, n=6)
    a = face_areas(mesh)
    F0 = view_factors(mesh, rays_per_face=128, seed=5)
    AF0 = sp.diags(a) @ F0
    assert abs(AF0 - AF0.T).max() > 1e-6  # the raw estimate is not reciprocal
    F = view_factors(mesh, rays_per_face=128, seed=5, reciprocity=True)
    AF = (sp.diags(a) @ F).toarray()
    np.testing.assert_allclose(AF, AF.T, rtol=0, atol=1e-15)
    assert F.sum(axis=1).max() <= 1.0 + 1e-12
    # the plate-to-plate factors keep their accuracy
    assert group_factor(F, mesh, g, 0, 1) == pytest.approx(
        howell_perpendicular(1, 0.5, 1), rel=0.02
    )


def test_reciprocity_keeps_rows_at_most_one():
    box = closed_box()
    F = view_factors(box, rays_per_face=64, seed=6, reciprocity=True)
    rows = np.asarray(F.sum(axis=1)).ravel()
    assert rows.max() <= 1.0 + 1e-12
    np.testing.assert_allclose(rows, 1.0, atol=1e-8)  # balanced back to the raw row sums
    a = face_areas(box)
    AF = sp.diags(a) @ F
    assert abs(AF - AF.T).max() < 1e-15


def test_enforce_reciprocity_bad_input():
    with pytest.raises(InputError, match="areas"):
        enforce_reciprocity(sp.identity(3), [1.0, 0.0, 1.0])
    with pytest.raises(InputError, match="do not match"):
        enforce_reciprocity(sp.identity(3), [1.0, 1.0])


def test_two_sided_faces():
    """A plate turned away from its partner only exchanges light with it when two-sided:
    half its rays leave from the back, so F = F_exact / 2."""
    lower = plate(10, [0, 0, 0], EY, EX)  # normal -z: faces away from the upper plate
    upper = plate(10, [0, 0, 1], EY, EX)  # normal -z: faces the lower plate
    mesh, g = join(lower, upper)
    one = view_factors(mesh, rays_per_face=64, seed=7)
    assert group_factor(one, mesh, g, 0, 1) == 0.0
    assert group_factor(one, mesh, g, 1, 0) == 0.0  # hits on the unpainted back absorbed
    two = view_factors(mesh, rays_per_face=1024, seed=7, two_sided=True)
    exact = howell_parallel(1, 1, 1)
    assert group_factor(two, mesh, g, 0, 1) == pytest.approx(exact / 2, rel=0.01)
    assert group_factor(two, mesh, g, 1, 0) == pytest.approx(exact / 2, rel=0.01)


def test_occlusion():
    """A large plate between two parallel plates hides them from each other."""
    lower = plate(4, [0, 0, 0], EX, EY)
    upper = plate(4, [0, 0, 1], EY, EX)
    blocker = plate(2, [-2, -2, 0.5], 5 * EY, 5 * EX)  # painted side down
    mesh, g = join(lower, upper, blocker)
    F = view_factors(mesh, rays_per_face=256, seed=8)
    assert group_factor(F, mesh, g, 0, 1) == 0.0
    assert group_factor(F, mesh, g, 0, 2) > 0.9


def test_deterministic_for_a_seed_and_any_chunk_size():
    mesh, _ = perpendicular_mesh(n=20)  # 1600 faces: several random blocks
    a = view_factors(mesh, rays_per_face=32, seed=11)
    b = view_factors(mesh, rays_per_face=32, seed=11, chunk_size=512)
    c = view_factors(mesh, rays_per_face=32, seed=12)
    assert (a != b).nnz == 0
    assert (a != c).nnz > 0


def test_chunking_bounds_memory():
    """Rays are made, traced and filtered chunk by chunk, with no ray arrays: the tracing's
    peak memory (NumPy allocations, traced by tracemalloc; the hits kept, before ``F`` is
    assembled) with chunks of 512 faces is a fraction of that of one chunk of all 6400
    faces, while F is the same."""
    import tracemalloc

    mesh, _ = perpendicular_mesh(n=40)  # 6400 faces

    def peak(chunk):
        with RowTracer(mesh, 64, 1, chunk_size=chunk) as rt:
            rt.hits(np.arange(1))  # the scene built and the kernels loaded
            tracemalloc.start()
            try:
                counts, hits = rt.hits(None)
                return tracemalloc.get_traced_memory()[1], rt.assemble(counts, hits)
            finally:
                tracemalloc.stop()

    small, F1 = peak(512)
    large, F2 = peak(6400)
    assert (F1 != F2).nnz == 0
    assert (F1 != view_factors(mesh, rays_per_face=64, seed=1)).nnz == 0
    assert small < 0.4 * large


def test_progress_callback():
    mesh, _ = perpendicular_mesh(n=20)
    calls = []
    view_factors(mesh, rays_per_face=4, chunk_size=512, progress=lambda d, t: calls.append((d, t)))
    # chunks of at most 512 faces, as many as the workers share evenly
    done = [d for d, _ in calls]
    assert all(t == 1600 for _, t in calls) and done[-1] == 1600 and len(calls) >= 4
    assert all(0 < b - a <= 512 for a, b in zip([0, *done], done, strict=False))


# ---------------------------------------------------------------- bad input
def test_bad_meshes():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], float)
    with pytest.raises(InputError, match=r"degenerate.*face 1"):
        view_factors(trimesh.Trimesh(V, [[0, 1, 2], [0, 1, 3]], process=False), 8)
    Vn = V.copy()
    Vn[2, 1] = np.nan
    with pytest.raises(InputError, match="NaN.*vertex 2"):
        view_factors(trimesh.Trimesh(Vn, [[0, 1, 2]], process=False), 8)
    with pytest.raises(InputError, match="empty"):
        view_factors(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int)), 8)
    with pytest.raises(InputError, match="Trimesh"):
        check_mesh(np.zeros((3, 3)))


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"rays_per_face": 0}, "rays_per_face"),
        ({"rays_per_face": 2.5}, "rays_per_face"),
        ({"seed": -1}, "seed"),
        ({"chunk_size": 0}, "chunk_size"),
    ],
)
def test_bad_parameters(kw, match):
    mesh, _ = perpendicular_mesh(n=2)
    with pytest.raises(InputError, match=match):
        view_factors(mesh, **kw)


@pytest.mark.slow
@pytest.mark.parametrize("case", ["perpendicular", "parallel", "disks"])
def test_error_slope_against_rays(case):
    """Slow: RMS error over 12 seeds at K = 16 ... 1024 rays a face; the fitted slope of
    log(error) against log(K) is at most -0.5 (1/sqrt(rays)) and the error at K = 1024
    is below 0.2% of the exact value."""
    if case == "perpendicular":
        mesh, g = perpendicular_mesh(n=8)
        exact = howell_perpendicular(1, 1, 1)
    elif case == "parallel":
        mesh, g = parallel_mesh(n=8)
        exact = howell_parallel(1, 1, 1)
    else:
        mesh, g = join(disk(1.0, 0.0, 3, 128, up=True), disk(1.0, 1.0, 3, 128, up=False))
        exact = howell_disks(1, 1, 1)
    ks = np.array([16, 64, 256, 1024])
    rms = []
    for k in ks:
        e = [
            group_factor(view_factors(mesh, int(k), seed), mesh, g, 0, 1) / exact - 1
            for seed in range(12)
        ]
        rms.append(np.sqrt(np.mean(np.square(e))))
    slope = np.polyfit(np.log(ks), np.log(rms), 1)[0]
    assert slope < -0.5, rms
    assert rms[-1] < 0.002, rms


def test_far_from_the_origin():
    """Float32 ray casting is done in a frame centred on the mesh: a model 10 km away
    from the origin gets the same factors."""
    mesh, g = perpendicular_mesh(n=6)
    far = mesh.copy()
    far.apply_translation([1.0e4, -2.0e4, 5.0e3])
    a = view_factors(mesh, rays_per_face=256, seed=3)
    b = view_factors(far, rays_per_face=256, seed=3)
    assert group_factor(b, far, g, 0, 1) == pytest.approx(group_factor(a, mesh, g, 0, 1), rel=1e-3)
    assert abs(a - b).max() <= 2 / 256  # at most a ray or two a pair changes its hit


# ---------------------------------------------------------------- rows, workers, RQMC


def test_rows_subset_and_workers_give_the_full_rows():
    """A row depends on its face only: computing a subset of rows, or sharing the chunks
    among processes, gives the rows of the full computation (up to a ray or two that
    float32 rounding may flip at an edge: 2/K per row at most)."""
    mesh, _ = perpendicular_mesh(n=8)
    k = 64
    full = view_factors(mesh, k, seed=5, workers=1)
    rows = np.array([3, 70, 71, 200, 255])
    part = view_factors(mesh, k, seed=5, rows=rows, workers=1)
    assert part.shape == full.shape
    others = np.setdiff1d(np.arange(len(mesh.faces)), rows)
    assert part[others].nnz == 0
    diff = abs(part[rows] - full[rows]).sum(axis=1)
    assert np.all(np.asarray(diff).ravel() <= 2.0 / k + 1e-12)
    mask = np.zeros(len(mesh.faces), bool)
    mask[rows] = True
    assert abs(view_factors(mesh, k, seed=5, rows=mask, workers=1) - part).sum() <= 2.0 * 5 / k
    par = view_factors(mesh, k, seed=5, workers=2, chunk_size=32)
    assert np.all(np.asarray(abs(par - full).sum(axis=1)).ravel() <= 2.0 / k + 1e-12)
    with pytest.raises(InputError, match="rows"):
        view_factors(mesh, k, rows=[0, 10_000])
    with pytest.raises(InputError, match="reciprocity"):
        view_factors(mesh, k, rows=rows, reciprocity=True)


def test_rqmc_points_are_uniform_and_unbiased():
    """Every RQMC point is uniform on the unit cube: over many faces, each coordinate's
    mean is 1/2 and its variance 1/12 within the sampling error (4 sigma)."""
    from selfillum.transport.viewfactors import rqmc_points

    pts = rqmc_points(16, np.arange(20_000), seed=1, dims=4).reshape(-1, 4)
    n = len(pts)
    assert np.all((pts > 0) & (pts < 1))
    assert np.all(np.abs(pts.mean(axis=0) - 0.5) < 4 * np.sqrt(1 / 12 / n))
    assert np.all(np.abs(pts.var(axis=0) - 1 / 12) < 4 * np.sqrt(1 / 180 / n))
    # and the 16 points of one face are a net: one in each of the 16 strata of [0, 1)
    one = rqmc_points(16, np.array([7]), seed=1, dims=4)[0]
    for d in range(4):
        assert np.array_equal(np.sort(np.floor(one[:, d] * 16)), np.arange(16))


@pytest.mark.parametrize("dims", [1, 4, 5])
def test_sobol_base_is_scipys_sobol_sequence(dims):
    """The Sobol points made without importing scipy.stats are exactly SciPy's unscrambled
    ``qmc.Sobol`` points (same direction numbers, same Gray-code order), for power-of-2
    and other counts; more than 5 dimensions are refused."""
    from scipy.stats import qmc

    from selfillum.transport.sampling import _sobol_base

    for k in (1, 2, 3, 100, 256, 1000, 4096, 1 << 16):
        m = max(0, int(np.ceil(np.log2(k))))
        ref = qmc.Sobol(dims, scramble=False).random_base2(m)[:k]
        ref = np.round(ref * 2.0**32).astype(np.uint64).astype(np.uint32)
        assert np.array_equal(_sobol_base(k, dims), ref), k
    with pytest.raises(ValueError, match="dims"):
        _sobol_base(16, 6)


@pytest.mark.slow  # 10 s
def test_view_factors_from_two_threads_on_numbas_workqueue_layer(tmp_path):
    """numba's fallback threading layer (workqueue: no libgomp, no TBB) aborts the process
    when two Python threads launch parallel kernels at once; view_factors from two threads
    must still finish there, with the rows one thread gives."""
    import os
    import subprocess
    import sys

    script = tmp_path / "two_threads.py"
    script.write_text(
        "import threading\n"
        "import numba, trimesh\n"
        "from selfillum.transport.viewfactors import view_factors\n"
        "m = trimesh.creation.icosphere(subdivisions=3)\n"
        "m.faces = m.faces[:, ::-1]\n"  # painted inside: every ray hits
        "ref = view_factors(m, 32, workers=2)\n"
        "out = []\n"
        "def go():\n"
        "    for _ in range(4):\n"
        "        out.append(view_factors(m, 32, workers=2))\n"
        "ts = [threading.Thread(target=go) for _ in range(2)]\n"
        "[t.start() for t in ts]\n"
        "[t.join() for t in ts]\n"
        "assert numba.threading_layer() == 'workqueue'\n"
        "assert len(out) == 8 and all(abs(F - ref).max() == 0 for F in out)\n"
        "print('ok')\n")
    env = dict(os.environ, NUMBA_THREADING_LAYER="workqueue")
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                       env=env, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-2000:]


@pytest.mark.parametrize("blocks,threads", [(512, 16), (64, 2), (10, 3), (5, 8), (1, 1)])
def test_interleaved_blocks_give_each_thread_the_whole_mesh(blocks, threads):
    """numba's prange gives each thread one contiguous share of the iterations (static
    scheduling: ``ceil`` / ``floor`` of ``blocks / threads``); taken in the order of
    ``interleaved``, each share is a permutation slice whose blocks spread over the whole
    mesh: every thread's blocks cover each quarter of the faces where it has 4 or more."""
    from selfillum.transport.rowtrace import interleaved

    order = interleaved(blocks, threads)
    assert np.array_equal(np.sort(order), np.arange(blocks))
    t = min(threads, blocks)
    edges = np.linspace(0, blocks, t + 1).round().astype(int)  # contiguous shares
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        share = order[a:b]
        if share.size >= 4 and blocks >= 4 * t:
            quarters = np.unique(share * 4 // blocks)
            assert quarters.size == 4, (share, quarters)
