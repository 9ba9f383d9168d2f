"""Scenes and peers shared by the suite's benchmarks: the frames, cases, rays and files
the package and its peers are timed on (moved here from the former ``bench/`` scripts)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from resection import Camera
from resection.io.cameras import write_camera
from resection.surface.surface_map import SurfaceMap
from scenes.marker_images import random_positions, render_markers
from scenes.slab_block import slab_block, slab_camera
from selfillum.mesh import face_normals
from selfillum.transport.viewfactors import _OFFSET, RayScene, sample_rays

W, H = 1280, 960  # the pose cases' image
#: requested face counts of ``scenes.slab_block`` give about 0.93 times as many triangles
FACE_FACTOR = 1.076


def make_frame(shape, n, diameter, snr, seed):
    """A 16-bit frame of dark markers on a background with an illumination gradient."""
    rng = np.random.default_rng(seed)
    uv = random_positions(shape, n, min_separation=2.5 * diameter + 6, margin=diameter + 4,
                          rng=rng)
    img = render_markers(shape, uv, diameter, contrast=100.0, background=0.0, blur=0.7,
                         snr=None, dtype=np.float64)
    H, W = shape
    gain = 1.0 + 0.2 * (np.arange(W)[None, :] / W) - 0.1 * (np.arange(H)[:, None] / H)
    img = gain * (1000.0 + img) + rng.normal(0.0, 100.0 / snr, shape)
    return np.clip(np.rint(img), 0, 65535).astype(np.uint16), uv


def opencv_default_detector():
    import cv2

    cv2.setNumThreads(1)
    det = cv2.SimpleBlobDetector_create()  # defaults: dark blobs, area >= 25 px, shape filters

    def run(img):
        lo, hi = float(img.min()), float(img.max())
        im8 = ((img - lo) * (255.0 / max(hi - lo, 1e-12))).astype(np.uint8)
        kp = det.detect(im8)
        return np.array([k.pt for k in kp]).reshape(-1, 2)

    return run


def accuracy(found, truth, gate=1.5):
    """(RMS error per coordinate of the markers found within ``gate`` px, share found)."""
    if len(found) == 0:
        return float("nan"), 0.0
    d, i = cKDTree(found).query(truth)
    ok = d < gate
    return float(np.sqrt(np.mean((found[i[ok]] - truth[ok]) ** 2))), float(ok.mean())



def opencv_target_detector(diameter: float):
    import cv2

    cv2.setNumThreads(1)
    p = cv2.SimpleBlobDetector_Params()
    p.filterByColor = True
    p.blobColor = 0
    p.filterByArea = True
    area = np.pi * diameter**2 / 4
    p.minArea, p.maxArea = 0.3 * area, 3.0 * area
    p.filterByCircularity = p.filterByConvexity = p.filterByInertia = False
    p.minThreshold, p.maxThreshold, p.thresholdStep = 10, 250, 10
    p.minDistBetweenBlobs = diameter
    det = cv2.SimpleBlobDetector_create(p)

    def run(img):
        return np.array([k.pt for k in det.detect(img)]).reshape(-1, 2)

    return run



def pose_case(rng, n, planar, noise=0.1):
    f = rng.uniform(900, 2500)
    K = np.array([[f, 0, W / 2 + rng.normal(scale=15)], [0, f, H / 2 + rng.normal(scale=15)],
                  [0, 0, 1.0]])
    dist = np.array([rng.uniform(-0.25, 0.1), rng.uniform(-0.1, 0.1),
                     *rng.normal(scale=1e-3, size=2), 0.0])
    while True:
        X = rng.uniform(-0.3, 0.3, (n, 3))
        if planar:
            X[:, 2] = 0
        d = rng.normal(size=3)
        eye = d / np.linalg.norm(d) * rng.uniform(1.2, 4.0) * 1800 / f
        try:
            cam = Camera.look_at(eye, rng.normal(scale=0.05, size=3), rng.normal(size=3),
                                 K=K, width=W, height=H, dist=dist)
        except Exception:
            continue
        uv, ok = cam.project(X, return_valid=True)
        if ok.all() and cam.in_image(uv, margin=5).all():
            return cam, X, uv + rng.normal(scale=noise, size=uv.shape)



def _scene_frame(mesh):
    """A bare ``embreex`` scene (the peer: its own copy of the buffers), triangles in
    its centred frame (``RayScene``'s), normals and the ray-origin lift, as view_factors
    prepares them."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    v = np.asarray(mesh.vertices, dtype=np.float64)
    origin = RayScene(v, mesh.faces).origin
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene=scene, vertices=np.ascontiguousarray(v - origin, dtype=np.float32),
                 indices=np.ascontiguousarray(mesh.faces, dtype=np.int32))
    tri = (v - origin)[np.asarray(mesh.faces)]
    return scene, tri, face_normals(mesh), _OFFSET * float(np.ptp(v, axis=0).max())


def same_rays(mesh, k, seed):
    """The rays view_factors casts (same RQMC points), as Embree's float32 arrays."""
    scene, tri, nrm, offset = _scene_frame(mesh)
    o, d = [], []
    step = max(1, (1 << 20) // k)
    for b0 in range(0, len(tri), step):
        ids = np.arange(b0, min(b0 + step, len(tri)))
        p, dd, _ = sample_rays(tri[ids], nrm[ids], k, offset=offset, face_ids=ids, seed=seed)
        o.append(p)
        d.append(dd)
    return scene, np.concatenate(o), np.concatenate(d)


def bare_embree(mesh, k: int = 256, seed: int = 0, rays_per_chunk: int = 1 << 20) -> float:
    """Seconds spent in Embree building the scene and intersecting ``k`` cosine rays from
    every face (making the rays is not counted)."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    v = np.asarray(mesh.vertices, dtype=np.float64)
    origin = 0.5 * (v.min(axis=0) + v.max(axis=0))
    vs = np.ascontiguousarray(v - origin, dtype=np.float32)
    fs = np.ascontiguousarray(mesh.faces, dtype=np.int32)
    t0 = time.perf_counter()
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene=scene, vertices=vs, indices=fs)
    spent = time.perf_counter() - t0  # the BVH build is part of the pass
    tri = vs[fs]
    nrm = face_normals(mesh).astype(np.float32)
    helper = np.where((np.abs(nrm[:, 0]) < 0.9)[:, None], [1.0, 0, 0], [0, 1.0, 0])
    t1 = np.cross(nrm, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(nrm, t1)
    rng = np.random.default_rng(seed)
    lift = 1e-6 * float(np.ptp(v, axis=0).max())
    step = max(1, rays_per_chunk // k)
    for f0 in range(0, len(fs), step):  # chunks of faces (memory), not a loop over rays
        f1 = min(f0 + step, len(fs))
        m = f1 - f0
        r = rng.random((m, k, 4), dtype=np.float32)
        s = np.sqrt(r[..., 0])
        b1, b2 = s * (1 - r[..., 1]), s * r[..., 1]
        T = tri[f0:f1]
        o = (T[:, None, 0] + b1[..., None] * (T[:, None, 1] - T[:, None, 0])
             + b2[..., None] * (T[:, None, 2] - T[:, None, 0]) + lift * nrm[f0:f1, None])
        rad, phi = np.sqrt(r[..., 2]), 2 * np.pi * r[..., 3]
        z = np.sqrt(np.maximum(0.0, 1.0 - r[..., 2]))
        d = (rad[..., None] * np.cos(phi)[..., None] * t1[f0:f1, None]
             + rad[..., None] * np.sin(phi)[..., None] * t2[f0:f1, None]
             + z[..., None] * nrm[f0:f1, None])
        o = np.ascontiguousarray(o.reshape(-1, 3), dtype=np.float32)
        d = np.ascontiguousarray(d.reshape(-1, 3), dtype=np.float32)
        t0 = time.perf_counter()
        scene.run(o, d)
        spent += time.perf_counter() - t0
    return spent



def slab_files(faces: int, cache: Path) -> tuple[dict, object]:
    """The slab-and-block grid's files (PLY, camera JSON, image NPY, unpainted faces NPY)
    written once to ``cache``; their paths and the mesh."""
    sc = slab_block(int(faces * FACE_FACTOR))
    out = {"mesh": cache / "grid.ply", "camera": cache / "camera.json",
           "image": cache / "image.npy", "unpainted": cache / "unpainted.npy"}
    if not all(p.is_file() for p in out.values()):
        cam = slab_camera(1280, 1024, zoom=1.25)
        smap = SurfaceMap(sc.mesh, cam)
        img = np.where(smap.mask, sc.emission[np.maximum(smap.face_index, 0)], 0.0) * 100.0
        sc.mesh.export(out["mesh"])
        write_camera(out["camera"], cam)
        np.save(out["image"], img.astype(np.float32))
        np.save(out["unpainted"], (~sc.painted).astype(np.uint8))
    return {k: str(v) for k, v in out.items()}, sc.mesh



def opencv_pipeline(frames, camera, ids, points3d, rvec0, tvec0, diameter, *,
                    step: int = 10):
    """The same job from OpenCV parts; returns (rvecs, tvecs, uv (F, K, 2)). 8-bit frames
    are detected as they are (no scaling); ``step``: the blob detector's threshold step."""
    import cv2
    from scipy.spatial import cKDTree

    from resection.io.images import read_image

    K, dist, _, _ = camera.to_opencv()
    params = cv2.SimpleBlobDetector_Params()
    params.filterByColor = True
    params.blobColor = 0
    params.filterByArea = True
    area = np.pi * diameter**2 / 4
    params.minArea = 0.3 * area
    params.maxArea = 3.0 * area
    params.filterByCircularity = False
    params.filterByConvexity = False
    params.filterByInertia = False
    params.minThreshold = 10
    params.maxThreshold = 250
    params.thresholdStep = step
    params.minDistBetweenBlobs = diameter
    detector = cv2.SimpleBlobDetector_create(params)
    rvec, tvec = rvec0.reshape(3, 1).copy(), tvec0.reshape(3, 1).copy()
    X = np.ascontiguousarray(points3d, dtype=np.float64)
    rv, tv, uvs = [], [], []
    for f in frames:
        img = np.load(f) if str(f).endswith(".npy") else read_image(f)
        if img.dtype == np.uint8:
            img8 = img
        else:
            lo, hi = np.percentile(img, [0.1, 99.9])
            img8 = np.clip((img - lo) * (255.0 / max(hi - lo, 1e-9)), 0, 255).astype(np.uint8)
        kps = detector.detect(img8)
        cand = np.array([k.pt for k in kps], dtype=np.float64).reshape(-1, 2)
        pred, _ = cv2.projectPoints(X, rvec, tvec, K, dist)
        pred = pred.reshape(-1, 2)
        uv = np.full((len(X), 2), np.nan)
        if len(cand):
            d, j = cKDTree(cand).query(pred, distance_upper_bound=5.0)
            ok = np.isfinite(d)
            uv[ok] = cand[j[ok]]
        ok = np.isfinite(uv).all(axis=1)
        if ok.sum() >= 6:
            _, rvec, tvec = cv2.solvePnP(X[ok], uv[ok], K, dist, rvec, tvec,
                                         useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
        rv.append(rvec.ravel().copy())
        tv.append(tvec.ravel().copy())
        uvs.append(uv)
    return np.array(rv), np.array(tv), np.array(uvs)



def plate(n: int) -> trimesh.Trimesh:
    xs = np.linspace(-0.5, 0.5, n)
    X, Y = np.meshgrid(xs, xs)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), \
        idx[1:, :-1].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return trimesh.Trimesh(V, F, process=False)



def grid_blocks(n_points: int):
    side = int(np.sqrt(n_points / 4))
    blocks = []
    for k in range(4):
        x, y = np.meshgrid(np.linspace(0, 1, side) + k, np.linspace(0, 1, side), indexing="ij")
        blocks.append(np.stack([x, y, 0.1 * np.sin(3 * x) * y], -1)[:, :, None, :])
    return blocks



def upsp_way(mesh, cam0, frames):
    import cv2

    """Frame-0 map + affine ECC warp of every frame onto frame 0 (uPSP)."""
    smap = SurfaceMap(mesh, cam0)
    template = frames[0]
    warp = np.eye(2, 3, dtype=np.float32)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-6)
    h, w = template.shape
    for k, img in enumerate(frames):
        if k:
            try:
                _, warp = cv2.findTransformECC(template, img, warp, cv2.MOTION_AFFINE, crit,
                                               None, 5)
            except cv2.error:  # not converged: keep the previous warp, as a pipeline would
                pass
            img = cv2.warpAffine(img, warp, (w, h), flags=cv2.INTER_LINEAR
                                 + cv2.WARP_INVERSE_MAP, borderValue=float("nan"))
        yield smap.to_nodes(img).values



def rss_mb() -> float:
    """Resident memory of this process now, MB (Linux /proc)."""
    import os

    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
