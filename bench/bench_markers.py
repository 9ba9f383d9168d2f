"""Marker detection and matching: speed against trackpy and OpenCV, accuracy against the
Cramér-Rao bound.

Run: ``.venv/bin/python bench/bench_markers.py [--quick] [--png bench/markers_error.png]``

1. Detection time per megapixel on the same images (1024 x 1024, 200 dark markers of 6 px,
   SNR 20) for ``resection.detect_markers``, ``trackpy.locate`` and OpenCV's
   ``SimpleBlobDetector``, with each one's RMS position error: printed as ratios.
2. Matching time per frame (30 markers, 30 % hidden, as many spurious candidates as real
   ones, approximate camera reference), as a ratio to detecting the markers of a 1 Mpx
   frame and to one bare ``cv2.solvePnP`` call on the known pairs.
3. RMS position error (per coordinate) against diameter and SNR, with the Cramér-Rao bound
   of the blurred-disk model as the floor (table printed in Markdown, plot written).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import best_of  # noqa: E402  (bench/ is on sys.path when run as a script)

from resection.camera.model import Camera  # noqa: E402
from resection.markers.detect import detect_markers, position_crb  # noqa: E402
from resection.markers.match import match_markers  # noqa: E402
from scenes.marker_images import make_scene  # noqa: E402


def _rms(found, truth, gate=1.5):
    d, i = cKDTree(found).query(truth)
    ok = d < gate
    e = found[i[ok]] - truth[ok]
    return float(np.sqrt(np.mean(e**2))), float(ok.mean())



def _trackpy(img, diameter):
    import trackpy as tp

    tp.quiet()
    f = tp.locate(img, int(2 * np.ceil(diameter / 2 + 1.5) + 1), invert=True, minmass=0)
    return f


def _opencv(img):
    import cv2

    p = cv2.SimpleBlobDetector_Params()
    p.filterByColor, p.blobColor = True, 0
    p.filterByCircularity = p.filterByConvexity = p.filterByInertia = False
    p.minArea = 2  # thresholds: OpenCV's defaults (50 to 220 by 10)
    p.minDistBetweenBlobs = 3
    det = cv2.SimpleBlobDetector_create(p)
    im8 = np.clip((img - img.min()) / np.ptp(img) * 255, 0, 255).astype(np.uint8)
    return np.array([k.pt for k in det.detect(im8)])


def bench_detection(repeat):
    sc = make_scene((1024, 1024), 200, 6.0, snr=20.0, blur=0.7, rng=0)
    img = sc.image
    mpx = img.size / 1e6
    t_ours, cand = best_of(lambda: detect_markers(img, 6.0), repeat)
    t_tp, f = best_of(lambda: _trackpy(img, 6.0), repeat)
    t_cv, cv_uv = best_of(lambda: _opencv(img), 1)
    tp_uv = f.nlargest(200, "mass")[["x", "y"]].to_numpy()
    rows = [("resection.detect_markers", t_ours, _rms(cand.uv, sc.uv)),
            ("trackpy.locate", t_tp, _rms(tp_uv, sc.uv)),
            ("cv2.SimpleBlobDetector", t_cv, _rms(cv_uv, sc.uv))]
    print("\n## Detection, 1024 x 1024, 200 markers of 6 px, SNR 20\n")
    print("| detector | ms / Mpx | time / ours | RMS error (px) | found |")
    print("|---|---|---|---|---|")
    for name, t, (rms, hit) in rows:
        print(f"| {name} | {1e3 * t / mpx:.0f} | {t / t_ours:.2f} | {rms:.4f} | {hit:.0%} |")
    return t_ours


def bench_matching(t_detect, frames):
    import cv2

    rng = np.random.default_rng(1)
    K = [[1500.0, 0, 512], [0, 1500.0, 384], [0, 0, 1]]
    base = Camera.look_at([0.2, -0.3, 1.6], [0, 0, 0], [0, 1, 0], K=K, width=1024, height=768)
    n = 30
    X = np.column_stack([rng.uniform(-0.4, 0.4, n), rng.uniform(-0.25, 0.25, n), np.zeros(n)])
    X[:, 2] = 0.08 * np.exp(-((X[:, 1] / 0.08) ** 2))
    ids = tuple(f"M{k}" for k in range(n))
    data = []
    for _ in range(frames):
        dR = Rotation.from_rotvec(rng.normal(0, 0.004, 3)).as_matrix()
        cam = base.with_pose(R=dR @ base.R, t=base.t + rng.normal(0, 0.004, 3))
        uv = cam.project(X)
        vis = cam.in_image(uv, margin=8) & (rng.random(n) > 0.3)
        real = uv[vis] + rng.normal(0, 0.05, (vis.sum(), 2))
        spur = np.column_stack([rng.uniform(5, 1019, vis.sum()), rng.uniform(5, 763, vis.sum())])
        Q = np.vstack([real, spur])
        perm = rng.permutation(len(Q))
        truth = np.array([ids[i] for i in np.flatnonzero(vis)] + [None] * vis.sum(),
                         dtype=object)
        data.append((Q[perm], truth[perm], X[vis], real))
    t0 = time.perf_counter()
    ok = 0
    for Q, truth, _, _ in data:
        r = match_markers(Q, (ids, X), base)
        ok += np.array_equal(np.array(r.ids, dtype=object), truth)
    t_match = (time.perf_counter() - t0) / frames
    Kc = np.array(K)
    t0 = time.perf_counter()
    for _, _, Xv, real in data:
        cv2.solvePnP(Xv, real, Kc, None, flags=cv2.SOLVEPNP_ITERATIVE)
    t_pnp = (time.perf_counter() - t0) / frames
    print(f"\n## Matching, {frames} frames: 30 markers, 30 % hidden, as many spurious\n")
    print("| quantity | value |")
    print("|---|---|")
    print(f"| frames matched correctly | {ok} / {frames} |")
    print(f"| matching time / detection time of a 1 Mpx frame | {t_match / t_detect:.2f} |")
    print(f"| matching time / one cv2.solvePnP on the known pairs | {t_match / t_pnp:.0f} |")
    print(f"| matching time per frame (this machine) | {1e3 * t_match:.0f} ms |")


def bench_accuracy(diameters, snrs, n_images, png):
    blur, contrast = 0.7, 100.0
    table = np.zeros((len(diameters), len(snrs)))
    peers = {"trackpy": np.zeros(len(diameters)), "opencv": np.zeros(len(diameters))}
    crb = np.zeros_like(table)
    for i, d in enumerate(diameters):
        for j, snr in enumerate(snrs):
            errs = []
            for k in range(n_images):
                sc = make_scene((320, 320), 40, d, snr=snr, blur=blur, contrast=contrast,
                                rng=1000 * i + 10 * j + k)
                cand = detect_markers(sc.image, d)
                dist, idx = cKDTree(cand.uv).query(sc.uv)
                ok = dist < 1.5
                errs.append(cand.uv[idx[ok]] - sc.uv[ok])
                if snr == 20:
                    f = _trackpy(sc.image, d).nlargest(40, "mass")[["x", "y"]].to_numpy()
                    peers["trackpy"][i] += _rms(f, sc.uv)[0] ** 2 / n_images
                    peers["opencv"][i] += _rms(_opencv(sc.image), sc.uv)[0] ** 2 / n_images
            table[i, j] = np.sqrt(np.mean(np.vstack(errs) ** 2))
            crb[i, j] = position_crb(d, blur, contrast, contrast / snr)
    peers = {k: np.sqrt(v) for k, v in peers.items()}
    has20 = 20 in snrs
    print("\n## RMS position error per coordinate (px): measured / Cramér-Rao bound\n")
    print("| diameter (px) | " + " | ".join(f"SNR {s:g}" for s in snrs)
          + (" | trackpy, SNR 20 | OpenCV, SNR 20 |" if has20 else " |"))
    print("|---" * (len(snrs) + 1 + 2 * has20) + "|")
    for i, d in enumerate(diameters):
        cells = " | ".join(f"{table[i, j]:.4f} / {crb[i, j]:.4f}" for j in range(len(snrs)))
        extra = f" | {peers['trackpy'][i]:.4f} | {peers['opencv'][i]:.4f} |" if has20 else " |"
        print(f"| {d:g} | {cells}" + extra)
    if png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(1, 3, figsize=(16, 4.8))
        colors = plt.cm.viridis(np.linspace(0, 0.9, len(diameters)))
        for i, d in enumerate(diameters):
            ax[0].loglog(snrs, table[i], "o-", color=colors[i], ms=4, label=f"D = {d:g} px")
            ax[0].loglog(snrs, crb[i], "--", color=colors[i], lw=1)
        ax[0].axhline(0.05, color="red", lw=0.8, label="0.05 px target")
        ax[0].set_xlabel("SNR (contrast / noise std)")
        ax[0].set_ylabel("RMS error per coordinate (px)")
        ax[0].set_title("measured (o-) and Cramér-Rao bound (--)")
        ax[0].grid(True, which="both", alpha=0.3)
        ax[0].legend(fontsize=8, ncol=2)
        j20 = list(snrs).index(20) if has20 else len(snrs) // 2
        ax[1].plot(diameters, table[:, j20], "o-", label="resection.detect_markers")
        ax[1].plot(diameters, crb[:, j20], "k--", label="Cramér-Rao bound (floor)")
        if has20:
            ax[1].plot(diameters, peers["trackpy"], "s:", label="trackpy.locate")
            ax[1].plot(diameters, peers["opencv"], "^:", label="cv2.SimpleBlobDetector")
        ax[1].axhline(0.05, color="red", lw=0.8, label="0.05 px target")
        ax[1].set_yscale("log")
        ax[1].set_xlabel("marker diameter (px)")
        ax[1].set_ylabel("RMS error per coordinate (px)")
        ax[1].set_title(f"SNR {snrs[j20]:g}, PSF sigma {blur} px, same images")
        ax[1].grid(True, which="both", alpha=0.3)
        ax[1].legend(fontsize=8)
        scol = plt.cm.plasma(np.linspace(0, 0.85, len(snrs)))
        for j, snr in enumerate(snrs):
            ax[2].plot(diameters, table[:, j] / crb[:, j], "o-", color=scol[j], ms=4,
                       label=f"SNR {snr:g}")
        ax[2].axhline(1.0, color="k", ls="--", lw=1, label="on the bound")
        ax[2].set_ylim(0.7, 1.4)
        ax[2].set_xlabel("marker diameter (px)")
        ax[2].set_ylabel("measured RMS / Cramér-Rao bound")
        ax[2].set_title(f"efficiency ({40 * n_images} markers a point, ~6 % sampling noise)")
        ax[2].grid(True, alpha=0.3)
        ax[2].legend(fontsize=8, ncol=2)
        fig.tight_layout()
        fig.savefig(png, dpi=110)
        print(f"\nplot written to {png}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer cases (a smoke run)")
    ap.add_argument("--png", help="plot file (default bench/markers_error.png; none with "
                    "--quick, so that a smoke run does not overwrite the published plot)")
    a = ap.parse_args()
    if a.png is None and not a.quick:
        a.png = str(Path(__file__).with_name("markers_error.png"))
    t_detect = bench_detection(1 if a.quick else 3)
    bench_matching(t_detect, 20 if a.quick else 100)
    if a.quick:
        bench_accuracy([3, 6], [10, 20], 1, a.png)
    else:
        bench_accuracy([3, 4, 5, 6, 7, 8, 9, 10], [5, 10, 20, 50, 100], 3, a.png)


if __name__ == "__main__":
    main()
