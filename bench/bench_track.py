"""Frames per second of ``resection.sequence.track`` on 1 Mpx frames, with 1 and 2 workers,
against the same pipeline built from OpenCV parts.

The sequence is ``scenes.moving_model.pitch_oscillation`` rendered at 1024 x 1024 (markers
about 8 px across, 34 markers, pitch oscillation of 2 degrees at 1 Hz, 50 fps). Three runs
on the same frame files (NPY):

* ``track``, 1 worker (in this process, no Dask);
* ``track``, 2 workers on a Dask ``LocalCluster`` (started, the package imported and its
  compiled kernels loaded on the workers before timing; that start-up time is printed
  separately);
* the OpenCV pipeline, frame after frame in this process: ``read_image``, conversion to 8
  bits, ``cv2.SimpleBlobDetector`` (dark blobs), nearest-neighbour matching of the markers
  projected with the previous frame's pose (``cv2.projectPoints`` + ``scipy.spatial.cKDTree``,
  5 px gate), ``cv2.solvePnP`` (iterative, previous pose as the start). It is seeded with the
  exact frame-0 pose, as ``track`` is given a linking by hand of frame 0 (``--no-link``:
  ``track`` matches frame 0 from an approximate camera, 1 degree and 1 cm off, with the
  statistical matcher). ``track`` matches the first frame of every other chunk
  (``--chunk-size``) from frame 0 with the statistical matcher, and tracks the others by
  prediction.

The three runs are interleaved (``--repeat`` rounds of 1 worker, OpenCV, 2 workers) and the
best of each is kept, so that a change of the machine's load hits them alike. It prints
frames per second (every run, and the best), the ratios, and the accuracy of both
pipelines against the known motion (attitude error, marker position RMS).

Run: ``.venv/bin/python bench/bench_track.py [--frames 200] [--size 1024] [--chunk-size 50]``
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import numpy as np

from resection.io.cameras import read_camera


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


def _warm_up() -> None:
    """Import the package and load its compiled kernels (numba, from the on-disk cache) in
    a worker, as a long run amortises them."""
    import resection.markers.match  # noqa: F401
    import resection.pose.solve  # noqa: F401
    import resection.sequence  # noqa: F401
    from resection.markers.detect import refine_markers

    yy, xx = np.mgrid[0:32, 0:32]
    img = 100.0 * (np.hypot(xx - 15.3, yy - 16.1) < 4.0)
    refine_markers(img, np.array([[15.0, 16.0]]), 8.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--chunk-size", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=2,
                    help="interleaved repetitions (track 1 worker, OpenCV, track 2 workers); "
                    "the best of each is reported")
    ap.add_argument("--link", action=argparse.BooleanOptionalAction, default=True,
                    help="link frame 0 by hand, as the OpenCV pipeline starts from the exact "
                    "frame-0 pose (--no-link: match it from the approximate camera)")
    args = ap.parse_args()

    import dask
    from dask.distributed import Client, LocalCluster
    from scipy.spatial import cKDTree

    from resection.sequence import relative_motion, track
    from scenes.moving_model import pitch_oscillation, write_sequence

    n, size = args.frames, args.size
    model = pitch_oscillation(n, shape=(size, size), marker_diameter=3.8 / size)
    diameter = float(np.median(model.diameters_px(0)))
    truth_ang = np.degrees(model.angles)
    truth_uv = np.stack([model.uv(k) for k in range(n)])

    def accuracy(angles, uv):
        e_ang = np.nanmax(np.abs(angles - truth_ang))
        e_uv = np.sqrt(np.nanmean(np.sum((uv - truth_uv) ** 2, axis=-1)))
        found = np.isfinite(uv).all(axis=-1).mean()
        return e_ang, e_uv, found

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t = time.perf_counter()
        files = write_sequence(model, tmp / "frames")
        print(f"{n} frames {size}x{size}, {len(model.ids)} markers of {diameter:.1f} px, "
              f"rendered in {time.perf_counter() - t:.1f} s")
        cam = read_camera(files["camera"])
        frames = files["frames"]
        rows = []

        # frame 0 linked by hand (candidate numbers of detect_markers on it, paired with the
        # true projections): the same start as the OpenCV pipeline's exact frame-0 pose
        from resection.io.images import read_image
        from resection.markers.detect import detect_markers

        cands = detect_markers(read_image(frames[0], mask_saturated=True), diameter)
        dist, near = cKDTree(cands.uv).query(model.uv(0))
        link = {str(k): int(j) for k, j, e in zip(model.ids, near, dist, strict=True)
                if e < 1.0} if args.link else None
        cam0 = model.camera_at(0)

        def run_one():
            out = tmp / f"o{time.perf_counter_ns()}"
            return track(frames, cam, files["markers"], diameter=diameter, out_dir=out,
                         workers=1, progress=False, chunk_size=args.chunk_size, link=link)

        def run_two():
            out = tmp / f"o{time.perf_counter_ns()}"
            return track(frames, cam, files["markers"], diameter=diameter, out_dir=out,
                         scheduler=cluster.scheduler_address, progress=False,
                         chunk_size=args.chunk_size, link=link)

        def run_cv():
            return opencv_pipeline(frames, cam, model.ids, model.points3d, cam0.rvec,
                                   np.asarray(cam0.t), diameter)

        t = time.perf_counter()
        # the nanny's MALLOC_TRIM_THRESHOLD_ freezes glibc's mmap threshold: every
        # frame-sized array is then mmap'ed afresh (twice the CPU of a tracked frame)
        with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_":
                              None}):
            cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=logging.ERROR)
        times = {"one": [], "two": [], "cv": []}
        out = {}
        try:
            with Client(cluster) as client:  # workers import the package before the timing
                client.run(_warm_up)
            t_start = time.perf_counter() - t
            # interleaved: the machine's load moves during the runs; best of each
            for _ in range(args.repeat):
                for key, fn in (("one", run_one), ("cv", run_cv), ("two", run_two)):
                    t = time.perf_counter()
                    out[key] = fn()
                    times[key].append(time.perf_counter() - t)
        finally:
            cluster.close()
        r1, r2, (rv, tv, uv) = out["one"], out["two"], out["cv"]
        rows.append(("track, 1 worker", n / min(times["one"]),
                     *accuracy(r1.angles, r1.marker_positions(model.ids))))
        rows.append(("track, 2 workers (Dask)", n / min(times["two"]),
                     *accuracy(r2.angles, r2.marker_positions(model.ids))))
        ang_cv, _ = relative_motion(rv, tv, 0)
        rows.append(("OpenCV parts, 1 process", n / min(times["cv"]), *accuracy(ang_cv, uv)))
        print("all runs, frames/s: " + "; ".join(
            f"{k} " + ", ".join(f"{n / x:.1f}" for x in v) for k, v in times.items()))

    print(f"\n{'pipeline':28s} {'frames/s':>9s} {'max att. err':>13s} {'marker RMS':>11s} "
          f"{'found':>6s}")
    for name, fps, ea, eu, fo in rows:
        print(f"{name:28s} {fps:9.2f} {ea:11.4f} deg {eu:8.4f} px {100 * fo:5.1f}%")
    print(f"\nLocalCluster start-up (2 workers): {t_start:.1f} s (not in the 2-worker time); "
          f"chunks of {args.chunk_size} frames")
    print(f"ratio track 2 workers / 1 worker:        {rows[1][1] / rows[0][1]:.2f}")
    print(f"ratio track 1 worker / OpenCV pipeline:  {rows[0][1] / rows[2][1]:.2f}")
    print(f"ratio track 2 workers / OpenCV pipeline: {rows[1][1] / rows[2][1]:.2f}")


if __name__ == "__main__":
    main()
