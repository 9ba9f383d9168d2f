"""Figure 23 of the paper on a synthetic run: the model's attitude and position against time,
tracked by ``resection.sequence.track`` over a sequence with a known motion (pitch
oscillation of 2 degrees at 1 Hz with a small heave and roll, 50 fps), the truth drawn as
wide grey bands, one corrupt frame in the middle recorded as failed.

Run: ``.venv/bin/python examples/figure23_motion.py [OUTDIR] [--frames N] [--workers W]``
(default 100 frames; ``--workers 1`` runs in this process, more start a local Dask cluster).
"""
import argparse
import tempfile
from pathlib import Path

import numpy as np

from resection.io.cameras import read_camera
from resection.sequence import track
from resection.sequence.motion_plots import plot_motion
from scenes.moving_model import pitch_oscillation, write_sequence


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("outdir", nargs="?", default=".")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()
    out = Path(args.outdir)
    out.mkdir(parents=True, exist_ok=True)
    model = pitch_oscillation(args.frames)
    with tempfile.TemporaryDirectory() as tmp:
        files = write_sequence(model, Path(tmp) / "frames")
        frames = list(files["frames"])
        bad = len(frames) // 2
        np.save(frames[bad], np.full((256, 256), np.nan, np.float32))  # a corrupt frame
        res = track(frames, read_camera(files["camera"]), files["markers"], diameter=5.6,
                    out_dir=Path(tmp) / "track", workers=args.workers)
    ok = res.ok
    err = np.abs(res.angles[ok] - np.degrees(model.angles[ok])).max()
    truth = np.stack([model.uv(k) for k in range(len(frames))])
    uv = res.marker_positions(model.ids)
    rms = np.sqrt(np.nanmean(np.sum((uv - truth)[ok] ** 2, axis=-1)))
    print(f"{int(ok.sum())}/{len(res)} frames solved; failed: "
          f"{[(int(f), str(r)) for f, r in zip(res.frame[~ok], res.reason[~ok], strict=True)]}")
    print(f"max attitude error {err:.4f} deg, marker position RMS error {rms:.4f} px")
    path = out / "figure23_motion.png"
    plot_motion(res, path, fps=50.0, length_unit="mm", length_scale=1000.0,
                truth=(np.degrees(model.angles), model.translation))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
