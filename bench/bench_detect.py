"""Detection speed: ``detect_markers`` against OpenCV's ``SimpleBlobDetector`` on the same
1 Mpx frames, as a ratio measured in the same run, with both detectors' accuracy.

Run: ``.venv/bin/python bench/bench_detect.py [--quick] [--before REV]``

Frames (``scenes.marker_images``, 16-bit like a camera's): 1024 x 1024 px, 400 dark markers
of 6 px on a background of 1000 counts with a 20 % illumination gradient, PSF sigma 0.7 px,
at SNR 20 and 50; and a 1280 x 800 frame with 410 markers of 8 px at SNR 30. OpenCV runs
with its default parameters (dark blobs of at least 25 px, shape filters on), on the frame
scaled to 8 bits (the scaling counted in its time), one thread like ours. Each time is the
best of ``--repeat`` calls, the two detectors alternating. The detection of one marker in a
41 x 41 px ``roi`` of the frame (the tracker's use) is timed against OpenCV on that crop.

``--before REV`` runs the same measurements with the package as it was at git revision REV
(extracted to a temporary folder, run in a subprocess) after the current one.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(os.environ.get("BENCH_DETECT_ROOT", Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(ROOT))

from resection.markers.detect import detect_markers  # noqa: E402
from scenes.marker_images import random_positions, render_markers  # noqa: E402


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


def opencv_detector():
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


def best_alternating(fns, repeat):
    """Functions called in turn, ``repeat`` rounds: their best wall times, best CPU times
    (this process, the measure least disturbed by other processes on a loaded machine)
    and results."""
    wall = [float("inf")] * len(fns)
    cpu = [float("inf")] * len(fns)
    out = [None] * len(fns)
    for _ in range(repeat):
        for k, fn in enumerate(fns):
            t0, c0 = time.perf_counter(), time.process_time()
            out[k] = fn()
            wall[k] = min(wall[k], time.perf_counter() - t0)
            cpu[k] = min(cpu[k], time.process_time() - c0)
    return wall, cpu, out


def measure(repeat):
    cv = opencv_detector()
    cases = [("1024 x 1024, 400 markers of 6 px, SNR 20", (1024, 1024), 400, 6.0, 20.0),
             ("1024 x 1024, 400 markers of 6 px, SNR 50", (1024, 1024), 400, 6.0, 50.0),
             ("1280 x 800, 410 markers of 8 px, SNR 30", (800, 1280), 410, 8.0, 30.0)]
    t0 = time.perf_counter()
    img, _ = make_frame((256, 256), 20, 6.0, 20.0, 9)
    detect_markers(img, 6.0)  # first call: compiled kernels loaded (or compiled) here
    first = time.perf_counter() - t0
    print(f"\nfirst call (small frame, kernels loaded or compiled): {first:.2f} s\n")
    coarse = _has_refine_option()
    print("wall-clock ms (CPU ms); ratio = detect_markers / SimpleBlobDetector, wall (CPU)\n")
    print("| frame | detect_markers | SimpleBlobDetector | ratio | RMS error px "
          "(ours / OpenCV) | found (ours / OpenCV) |"
          + (" coarse pass (refine=False): ms, ratio, RMS px |" if coarse else ""))
    print("|---|---|---|---|---|---|" + ("---|" if coarse else ""))
    for k, (name, shape, n, d, snr) in enumerate(cases):
        img, uv = make_frame(shape, n, d, snr, k)
        fns = [lambda img=img, d=d: detect_markers(img, d), lambda img=img: cv(img)]
        if coarse:
            fns.append(lambda img=img, d=d: detect_markers(img, d, refine=False))
        t, c, out = best_alternating(fns, repeat)
        ea, fa = accuracy(out[0].uv, uv)
        eb, fb = accuracy(out[1], uv)
        extra = ""
        if coarse:
            extra = (f" {1e3 * t[2]:.0f} ({1e3 * c[2]:.0f}), {t[2] / t[1]:.2f} "
                     f"({c[2] / c[1]:.2f}), {accuracy(out[2].uv, uv)[0]:.4f} |")
        print(f"| {name} | {1e3 * t[0]:.0f} ({1e3 * c[0]:.0f}) | {1e3 * t[1]:.0f} "
              f"({1e3 * c[1]:.0f}) | {t[0] / t[1]:.2f} ({c[0] / c[1]:.2f}) | "
              f"{ea:.4f} / {eb:.4f} | {fa:.0%} / {fb:.0%} |" + extra)
        if k == 0:
            roi_img, roi_uv = img, uv
    # one marker in a 41 x 41 roi of the full frame, and OpenCV on the same crop
    u, v = np.rint(roi_uv[0]).astype(int)
    roi = (u - 20, v - 20, u + 20, v + 20)
    crop = np.ascontiguousarray(roi_img[v - 20:v + 21, u - 20:u + 21])
    t, c, (cand, pts) = best_alternating([lambda: detect_markers(roi_img, 6.0, roi=roi),
                                          lambda: cv(crop)], 5 * repeat)
    ea, _ = accuracy(cand.uv, roi_uv[:1])
    print(f"| one marker, 41 x 41 roi | {1e3 * t[0]:.2f} ({1e3 * c[0]:.2f}) | "
          f"{1e3 * t[1]:.2f} ({1e3 * c[1]:.2f}) | {t[0] / t[1]:.2f} ({c[0] / c[1]:.2f}) | "
          f"{ea:.4f} / - | {len(cand)} / {len(pts)} |")


def _has_refine_option():
    import inspect

    return "refine" in inspect.signature(detect_markers).parameters


def run_before(rev, repeat):
    """The same measurements with the package at git revision ``rev``, in a subprocess."""
    repo = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "-C", str(repo), "archive", rev, "resection", "scenes"],
                                 check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        env = dict(os.environ, BENCH_DETECT_ROOT=tmp)
        print(f"\n## before: the package at {rev}")
        sys.stdout.flush()
        subprocess.run([sys.executable, __file__, "--repeat", str(repeat)], env=env, check=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one call each (a smoke run)")
    ap.add_argument("--repeat", type=int, default=None, help="calls per detector (default 5)")
    ap.add_argument("--before", metavar="REV", help="also measure the package at git REV")
    a = ap.parse_args()
    repeat = a.repeat or (1 if a.quick else 5)
    print(f"## detection: package at {ROOT}")
    measure(repeat)
    if a.before:
        run_before(a.before, repeat)


if __name__ == "__main__":
    main()
