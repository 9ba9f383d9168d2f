"""Compiled kernels of :mod:`selfillum.unsteady.fastmap`: a moving model's points projected
with a frame's pose and the frame sampled there, and the rows of a sparse product; and the
entries of a few columns of a sparse matrix (the faces a few left-out pixels reach)."""

from __future__ import annotations

import functools

import numpy as np


@functools.cache
def project_sample_kernel():
    import numba

    # fastmath's algebra (contraction, reciprocals, reassociation), not its no-NaN
    # assumption: a background pixel's point is NaN and is tested for (measured on 850,000
    # points of the 609k run's operator: 13.7 -> 10.4 ms a frame on one core, the samples
    # equal to 2e-9 counts). By runs of ``RUN`` points, the projection first, without a
    # branch (the compiler's vector lanes), then the tests and the samples: 11.6 -> 8.6 ms
    # on 850,000 points of a plane (2026-12-03, one core)
    @numba.njit(cache=True, nogil=True,
                fastmath={"nsz", "arcp", "contract", "afn", "reassoc"})
    def project_sample(X, R, t, K, dist, max_radius, uv0, img, refresh, out, status,
                       r0, r1):  # pragma: no cover - compiled
        """Project the points ``r0:r1`` (as Camera.project), flag a move over ``refresh``
        pixels (status 1), a point off the sensor or not projectable (status 2), else
        sample the image bilinearly there (pixel centres at integers, edges clamped) into
        ``out[i]`` (left as it was where the status is not 0). A point of NaN
        (a background pixel) reads the image at its own pixel ``uv0``. One thread, without
        the GIL: the caller's threads take blocks of points."""
        H, W = img.shape
        k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
        R00, R01, R02 = R[0, 0], R[0, 1], R[0, 2]
        R10, R11, R12 = R[1, 0], R[1, 1], R[1, 2]
        R20, R21, R22 = R[2, 0], R[2, 1], R[2, 2]
        tx, ty, tz = t[0], t[1], t[2]
        fx, skew, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
        mr2 = max_radius * max_radius
        umax, vmax = (W - 2 if W > 1 else 0), (H - 2 if H > 1 else 0)
        Wm, Hm = W - 1.0, H - 1.0
        RUN = 256
        us, vs, zs, rs = np.empty(RUN), np.empty(RUN), np.empty(RUN), np.empty(RUN)
        for s in range(r0, r1, RUN):
            n = min(RUN, r1 - s)
            for j in range(n):  # the projection (NaN through for a background point)
                x0, x1, x2 = X[s + j, 0], X[s + j, 1], X[s + j, 2]
                zc = R20 * x0 + R21 * x1 + R22 * x2 + tz
                iz = 1.0 / zc
                x = (R00 * x0 + R01 * x1 + R02 * x2 + tx) * iz
                y = (R10 * x0 + R11 * x1 + R12 * x2 + ty) * iz
                r2 = x * x + y * y
                radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
                xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
                yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
                us[j] = fx * xd + skew * yd + cx
                vs[j] = fy * yd + cy
                zs[j] = zc
                rs[j] = r2
            for j in range(n):
                i = s + j
                status[i] = 0
                if X[i, 0] != X[i, 0]:  # a pixel on the background: sampled where it is
                    u = min(max(np.float64(uv0[i, 0]), 0.0), Wm)
                    v = min(max(np.float64(uv0[i, 1]), 0.0), Hm)
                    out[i] = img[int(v + 0.5), int(u + 0.5)]
                    continue
                u, v = us[j], vs[j]
                if not zs[j] > 0 or rs[j] > mr2:
                    status[i] = 2
                elif abs(u - uv0[i, 0]) > refresh or abs(v - uv0[i, 1]) > refresh:
                    status[i] = 1
                elif u < -0.5 or v < -0.5 or u > W - 0.5 or v > H - 0.5:
                    status[i] = 2
                if status[i] != 0:
                    continue
                u = min(max(u, 0.0), Wm)
                v = min(max(v, 0.0), Hm)
                u0 = min(int(u), umax)
                v0 = min(int(v), vmax)
                fu = u - u0
                fv = v - v0
                u1 = min(u0 + 1, W - 1)
                v1 = min(v0 + 1, H - 1)
                out[i] = ((1.0 - fv) * ((1.0 - fu) * img[v0, u0] + fu * img[v0, u1])
                          + fv * ((1.0 - fu) * img[v1, u0] + fu * img[v1, u1]))

    return project_sample


@functools.cache
def spmv_kernel():
    import numba

    @numba.njit(cache=True, nogil=True)
    def spmv_add(indptr, cols, data, x, out, r0, r1, add):  # pragma: no cover - compiled
        """Rows ``r0 .. r1`` of ``out (+)= M x`` for a CSR ``M`` whose columns index ``x``
        directly; False if an ``x`` it reads is not finite."""
        ok = True
        for r in range(r0, r1):
            acc = 0.0
            for k in range(indptr[r], indptr[r + 1]):
                acc += np.float64(data[k]) * x[cols[k]]
            if acc - acc != 0.0:  # NaN or inf
                ok = False
            out[r] = out[r] + acc if add else acc
        return ok

    return spmv_add


#: Points a block of :func:`project_sample` shared with a waiting caller.
SHARED_BLOCK = 65536


def project_sample(X, *args, workers=None, share=None):
    """:func:`project_sample_kernel` over all of ``X``'s points, in blocks on the available
    cores (the threads of :func:`resection._threads.run_blocks`; numba's parallel loops
    spun on the shared cores, the sampling then cost several times its work); returns the
    statuses. With ``share`` (a :class:`selfillum.unsteady.frames.Helping`), in blocks
    of :data:`SHARED_BLOCK` points taken by this thread and by a caller that waits for
    it."""
    from resection._threads import run_blocks, split_range

    n = len(X)
    status = np.empty(n, np.uint8)
    kern = project_sample_kernel()  # compiled on first use (and cached on disk by numba)
    if share is not None:
        share.run(lambda b: kern(X, *args, status, b[0], b[1]), n, SHARED_BLOCK)
        return status
    run_blocks(lambda b: kern(X, *args, status, b[0], b[1]),
               split_range(n, workers, min_size=32768), workers)
    return status


def column_entries(M, columns) -> tuple[np.ndarray, np.ndarray]:
    """Row numbers and values of the entries of the CSC matrix ``M``'s ``columns`` (a
    few), gathered from its index arrays."""
    columns = np.asarray(columns, dtype=np.int64)
    starts, ends = M.indptr[columns], M.indptr[columns + 1]
    n = ends - starts
    if n.sum() == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    at = np.repeat(starts - np.cumsum(n) + n, n) + np.arange(n.sum())
    return M.indices[at].astype(np.int64), M.data[at]
