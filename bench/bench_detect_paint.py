"""Detection on real-looking paint: ``detect_markers`` against OpenCV's ``SimpleBlobDetector``
on 1280 x 800 8-bit frames of ``scenes.revolution.paint_frame`` (speckled paint, grain 1-3
px, RMS contrast 5-15 %, glare, 16-24 targets of 4-6 px facing the camera, pressure taps of
2-3 px), several seeds, the two detectors alternating, best of ``--repeat``.

Per frame: times (ms) and their ratio, the local maxima of the merit, how many the screen
sent to the disk fit ("fitted") and how many candidates came out ("kept"), the targets
found (within 1.5 px of their true centre; the targets facing the camera at 60 degrees
or less), and the median and RMS error of those found, for both detectors; for ours also
the targets not found but reported inside saturated glare (``Candidates.saturated``,
within 1.5 px) and those missed (neither).

The default seeds (100-111) were not used to develop the detector (seeds 0-15 were).
``--no-screen`` adds the same detection without the screen (``screen_contrast=None``).

OpenCV runs on the 8-bit frame as it is, one thread, with its area filter set for the
targets (0.3 to 3 times a disk of the nominal diameter; its default minimum area of 25 px
would drop 4-5 px targets) and the shape filters off, thresholds 10 to 250 by 10, as
``bench/bench_track.py``'s OpenCV pipeline.

SNR: that of the median target as drawn (``paint_frame``'s default), or with ``--snr-of
face-on`` of a target face-on at the image's centre (the definition before 2026-11-27).

``--draws N`` (instead of the timing): for each frame, the Cramér-Rao bound of each target's
centre from the noise-free render (``scenes.paint_bound``; for the sets of unknowns there)
against both detectors' errors over ``N`` noise draws of the same frame: the pooled median
error, the median an unbiased estimator on the bound would have, the per-target RMS error
over the bound and the bias over the bound (``--save``: the per-target figures as CSV).
About 1-2 minutes a frame at the default 32 x 32 sub-samples.

Run: ``.venv/bin/python bench/bench_detect_paint.py [--seeds 100 101 ...] [--snr 20]
[--speckle 0] [--draws 12]``
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from resection.markers import detect_markers  # noqa: E402
from scenes.revolution import paint_frame  # noqa: E402


def opencv_detector(diameter: float):
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


def errors(found: np.ndarray, truth: np.ndarray, gate: float = 1.5, pool=None):
    """(found share, median error, RMS error) of the targets against the found points; the
    errors of those found are appended to ``pool`` (a list)."""
    if len(found) == 0:
        return 0.0, float("nan"), float("nan")
    d, _ = cKDTree(found).query(truth)
    ok = d < gate
    if pool is not None:
        pool.append(d[ok])
    if not ok.any():
        return 0.0, float("nan"), float("nan")
    return float(ok.mean()), float(np.median(d[ok])), float(np.sqrt(np.mean(d[ok] ** 2)))


def bound_run(args) -> None:
    """Per target, the Cramér-Rao bound of its centre from the noise-free render
    (``scenes.paint_bound``) against both detectors' errors over ``--draws`` noise draws of
    the same frame (8-bit, the generator's noise)."""
    from scenes.paint_bound import median_at_bound, target_bounds

    sets = ("known", "fit", "shape", "shading")
    pooled = {"ours": [], "opencv": [], "cov": {k: [] for k in sets}, "ratio": [],
              "bias": [], "snr": [], "bias_ratio": []}
    per_target = []
    for seed in args.seeds:
        img, truth, d, model = paint_frame(seed, snr=args.snr, speckle=args.speckle,
                                           snr_of=args.snr_of)
        keep = model.visible(0, min_cos=0.5)
        t = time.perf_counter()
        b = target_bounds(model, 0, keep, supersample=args.bound_supersample)
        t_b = time.perf_counter() - t
        if not np.allclose(b["uv"], truth):
            raise RuntimeError(f"seed {seed}: the bound's targets are not the frame's")
        clean = model.render(0)
        cv = opencv_detector(d)
        rng = np.random.default_rng([seed, 555])
        E = {"ours": [], "opencv": []}
        for _ in range(args.draws):
            noise = rng.standard_normal(clean.shape, dtype=np.float32)
            noisy = np.clip(np.rint(clean + noise * np.float32(model.noise_sigma)), 0, 255)
            noisy = noisy.astype(np.uint8)
            for name, pts in (("ours", detect_markers(noisy, d).uv), ("opencv", cv(noisy))):
                e = np.full((len(truth), 2), np.nan)
                if len(pts):
                    dist, idx = cKDTree(pts).query(truth)
                    ok = dist < 1.5
                    e[ok] = pts[idx[ok]] - truth[ok]
                E[name].append(e)
        E = {k: np.array(v) for k, v in E.items()}  # (draws, targets, 2)
        mse = np.nanmean((E["ours"] ** 2).sum(-1), axis=0)
        bias = np.hypot(*np.nanmean(E["ours"], axis=0).T)
        tr = np.trace(b["cov"]["shape"], axis1=1, axis2=2)
        clear = ~b["saturated"]
        snr = b["drawn"] / b["sigma"]
        peak = np.median(b["peak"] / b["sigma"])
        for k in sets:
            pooled["cov"][k].append(b["cov"][k])
        for k in ("ours", "opencv"):
            pooled[k].append(np.hypot(E[k][..., 0], E[k][..., 1]).ravel())
        pooled["ratio"].append(np.sqrt(mse / tr)[clear])
        pooled["bias_ratio"].append((bias / np.sqrt(tr))[clear])
        pooled["snr"].append(snr)
        if args.save:
            P, N = model.points3d[keep], model.normals[keep]
            C = model.camera_at(0).center
            per_target.append(np.column_stack([
                np.full(len(truth), seed), truth, snr, np.sqrt(tr), np.sqrt(mse), bias,
                np.einsum("ij,ij->i", N, C - P) / np.linalg.norm(C - P, axis=1),
                b["saturated"]]))
        med = {k: np.nanmedian(pooled[k][-1]) for k in ("ours", "opencv")}
        r = pooled["ratio"][-1]
        print(f"seed {seed}: d {d:.2f} px, {len(truth)} targets ({int((~clear).sum())} with "
              f"saturated pixels in the window), SNR as drawn median {np.median(snr):.1f} "
              f"({snr.min():.1f}-{snr.max():.1f}; peak after blur {peak:.1f}) | "
              f"median error over {args.draws} draws ours {med['ours']:.4f} / OpenCV "
              f"{med['opencv']:.4f} px, at the bound (known / fit / shape / shading) "
              + " / ".join(f"{median_at_bound(b['cov'][k]):.4f}" for k in sets)
              + f" px | per target RMS error / bound (shape): median {np.median(r):.2f} "
              f"({r.min():.2f}-{r.max():.2f}), bias / bound median "
              f"{np.median(pooled['bias_ratio'][-1]):.2f} | bound {t_b:.0f} s")
    ratio = np.concatenate(pooled["ratio"])
    snr = np.concatenate(pooled["snr"])
    print(f"\npooled ({len(snr)} targets, {args.draws} draws): SNR as drawn median "
          f"{np.median(snr):.1f} ({snr.min():.1f}-{snr.max():.1f}); median error ours "
          f"{np.nanmedian(np.concatenate(pooled['ours'])):.4f} px, OpenCV "
          f"{np.nanmedian(np.concatenate(pooled['opencv'])):.4f} px; at the bound "
          + ", ".join(f"{k} {median_at_bound(np.concatenate(pooled['cov'][k])):.4f}"
                      for k in sets)
          + f" px; per target RMS error / bound (shape, windows without saturation): median "
          f"{np.median(ratio):.3f}, 10-90 % {np.percentile(ratio, 10):.2f}-"
          f"{np.percentile(ratio, 90):.2f}; bias / bound median "
          f"{np.median(np.concatenate(pooled['bias_ratio'])):.2f} (the draws' own spread "
          f"gives ~{np.sqrt(np.pi / 4 / args.draws):.2f})")
    if args.save:
        np.savetxt(args.save, np.concatenate(per_target), delimiter=",", fmt="%.6g",
                   header="seed,u,v,snr_drawn,bound_px,rms_error_px,bias_px,cos_view,"
                   "saturated")
    print(f"load average: {os.getloadavg()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(100, 112)))
    ap.add_argument("--snr", type=float, default=20.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-screen", action="store_true")
    ap.add_argument("--speckle", type=float, default=None,
                    help="RMS speckle contrast of every frame (default: drawn, 5-15 %%; 0: "
                    "plain paint, the accuracy without the paint's texture)")
    ap.add_argument("--snr-of", default="targets", choices=("targets", "face-on"),
                    help="SNR of the median target as drawn (default) or of a target "
                    "face-on at the image's centre (the former definition)")
    ap.add_argument("--draws", type=int, default=0,
                    help="instead of the timing: the per-target Cramér-Rao bound against "
                    "the errors over this many noise draws of each frame")
    ap.add_argument("--bound-supersample", type=int, default=32)
    ap.add_argument("--save", default=None,
                    help="with --draws: write the per-target figures to this CSV file")
    args = ap.parse_args()
    print(f"load average: {os.getloadavg()}")
    if args.draws:
        bound_run(args)
        return
    # compile / load the kernels before timing
    img0, _, d0, _ = paint_frame(args.seeds[0], snr=args.snr, speckle=args.speckle,
                                 snr_of=args.snr_of)
    detect_markers(img0, d0)
    rows, pool_o, pool_c = [], [], []
    for seed in args.seeds:
        img, truth, d, model = paint_frame(seed, snr=args.snr, speckle=args.speckle,
                                           snr_of=args.snr_of)
        cv = opencv_detector(d)
        fns = {"ours": functools.partial(detect_markers, img, d),
               "opencv": functools.partial(cv, img)}
        if args.no_screen:
            fns["unscreened"] = functools.partial(detect_markers, img, d,
                                                  screen_contrast=None)
        best = {k: np.inf for k in fns}
        out = {}
        for _ in range(args.repeat):
            for k, f in fns.items():
                t = time.perf_counter()
                out[k] = f()
                best[k] = min(best[k], time.perf_counter() - t)
        c = out["ours"]
        rej = c.n_rejected
        maxima = len(c) + sum(rej.values())
        fitted = maxima - rej["screen"]
        f_o, med_o, rms_o = errors(c.uv, truth, pool=pool_o)
        f_c, med_c, rms_c = errors(out["opencv"], truth, pool=pool_c)
        unfound = truth[cKDTree(c.uv).query(truth)[0] >= 1.5] if len(c) else truth
        n_sat = int((cKDTree(c.saturated).query(unfound)[0] < 1.5).sum()) \
            if len(c.saturated) and len(unfound) else 0
        n_miss = len(unfound) - n_sat
        row = (seed, d, model.speckle, model.grain, len(truth), best["ours"] * 1e3,
               best["opencv"] * 1e3, best["ours"] / best["opencv"], maxima, fitted, len(c),
               f_o, med_o, rms_o, f_c, med_c, rms_c, n_sat, n_miss)
        rows.append(row)
        extra = ""
        if args.no_screen:
            u = out["unscreened"]
            f_u, med_u, _ = errors(u.uv, truth)
            extra = (f"  | unscreened {best['unscreened'] * 1e3:.0f} ms, kept {len(u)}, "
                     f"found {100 * f_u:.0f} %, median {med_u:.3f} px")
        print(f"seed {seed}: d {d:.2f} px, speckle {100 * model.speckle:.1f} %, grain "
              f"{model.grain:.1f} px, {len(truth)} targets | ours {best['ours'] * 1e3:.1f} ms,"
              f" OpenCV {best['opencv'] * 1e3:.1f} ms, ratio {row[7]:.2f} | maxima {maxima},"
              f" fitted {fitted}, kept {len(c)} | found ours {100 * f_o:.0f} % (median "
              f"{med_o:.3f}, RMS {rms_o:.3f} px; saturated {n_sat}, missed {n_miss}), OpenCV "
              f"{100 * f_c:.0f} % (median "
              f"{med_c:.3f}, RMS {rms_c:.3f} px){extra}")
    r = np.array([x[7] for x in rows])
    print(f"\nratio ours / OpenCV: median {np.median(r):.2f}, worst {r.max():.2f}; "
          f"all targets found in {sum(x[11] == 1.0 for x in rows)}/{len(rows)} frames "
          f"(OpenCV {sum(x[14] == 1.0 for x in rows)}/{len(rows)}), the rest reported "
          f"saturated in {sum(x[11] < 1.0 and x[18] == 0 for x in rows)}; targets reported "
          f"saturated {sum(x[17] for x in rows)}, missed {sum(x[18] for x in rows)}; "
          f"median error over "
          f"frames ours {np.median([x[12] for x in rows]):.3f} px, OpenCV "
          f"{np.nanmedian([x[15] for x in rows]):.3f} px; pooled over the targets found "
          f"ours {np.median(np.concatenate(pool_o)):.4f} px ({sum(map(len, pool_o))}), "
          f"OpenCV {np.median(np.concatenate(pool_c)):.4f} px ({sum(map(len, pool_c))})")
    print(f"load average: {os.getloadavg()}")


if __name__ == "__main__":
    main()
