"""A tunnel entry at the issue's size built from one single-camera run already on disk,
nothing rendered again (issue 35: 4 datapoints x 2 cameras x 500 frames of a 1280 x 800
12-bit ``.mraw`` on uPSP's kind of 609,000-face grid).

The source is a folder with ``model.grid``, ``model.tgts``, ``paint.txt``, ``steady.f``,
``run.wtd``, ``cam01.mraw`` / ``.cih`` and ``cam01.json`` (the camera-to-model pose of
frame 0), as :func:`scenes.unsteady_run.make_unsteady_run` writes them with
``video_format="mraw"``:

- the video is made ``frames`` long by playing the source forward and then backward (a
  continuous motion); the even cameras' copy is moved by :data:`SHIFT` pixels (a camera
  with its principal point moved: each camera its own calibration, as the run requires);
  every datapoint's camera is a link to one of these;
- each camera's camera-to-tunnel calibration is the source's camera carried back by the
  source ``.wtd``'s attitude about a centre of rotation (``test_config.json``), so the
  tunnel's prediction is right at the source's ALPHA;
- each datapoint has its own ``.wtd``: ALPHA stepped by ``alpha_step`` degrees about the
  source's, so each calibration from the tunnel starts off by that much and refines onto
  the video's targets (the video is the same: the refined pose is the same).

``processing.json`` has uPSP's options for every frame, ``processing-warmup.json`` the same
on 8 frames (a short entry whose ``camNN-to-model.json`` serve as the calibrations of the
datapoints run alone: :func:`datapoint_deck`).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

RUN = "2001"
#: the centre of rotation in model units (the model's nose region; any point will do: the
#: tunnel calibration is made for it).
COR = (0.2, 0.0, 0.0)
#: the even cameras' images moved by this many pixels (dx, dy): a camera of its own (its
#: principal point moved), so no two cameras share a calibration.
SHIFT = (24, -16)


def _frames_of(cih: Path) -> tuple[int, int, int]:
    t = cih.read_text()
    get = {k: int(re.search(rf"{k}\s*:\s*(\d+)", t).group(1))
           for k in ("Total Frame", "Image Width", "Image Height")}
    return get["Total Frame"], get["Image Height"], get["Image Width"]


def _write_video(src: Path, dst: Path, frames: int, shift: tuple = (0, 0)) -> None:
    """``frames`` frames of ``src`` (16-bit ``.mraw``): forward, then backward; each
    image moved by ``shift`` = (dx, dy) pixels (the strip uncovered: zero, no light)."""
    n, h, w = _frames_of(src.with_suffix(".cih"))
    order = list(range(n))
    k = n - 2
    step = -1
    while len(order) < frames:  # ping-pong: a continuous motion
        order.append(k)
        if k in (0, n - 1):
            step = -step
        k += step
    a = np.memmap(src, np.uint16, "r", shape=(n, h, w))
    out = np.memmap(dst, np.uint16, "w+", shape=(frames, h, w))
    dx, dy = shift
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h),
                                                                slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w),
                                                                slice(0, w + dx))
    for i, j in enumerate(order[:frames]):
        if dx or dy:
            out[i] = 0
            out[i, yd, xd] = a[j, ys, xs]
        else:
            out[i] = a[j]
    out.flush()
    del out
    cih = src.with_suffix(".cih").read_text()
    cih = re.sub(r"(Total Frame\s*:\s*)\d+", rf"\g<1>{frames}", cih)
    cih = re.sub(r"(Original Total Frame\s*:\s*)\d+", rf"\g<1>{frames}", cih)
    dst.with_suffix(".cih").write_text(cih)


def make_big_entry(out: Path, source: Path, *, datapoints: int = 4, cameras: int = 2,
                   frames: int = 500, alpha_step: float = 0.1) -> list[str]:
    """Write the entry (module notes) into ``out``; returns the datapoint ids."""
    from resection.io.cameras import read_camera, write_camera
    from resection.io.wtd import read_wtd
    from selfillum.entry.tunnel import Attitude, TunnelConfig, model_to_tunnel

    out.mkdir(parents=True, exist_ok=True)
    for d in ("inputs", "camera-tunnel-calibration", "videos", "wtd", "decks"):
        (out / d).mkdir(exist_ok=True)
    for name in ("model.grid", "model.tgts", "paint.txt", "steady.f"):
        link = out / "inputs" / name
        if not link.exists():
            link.symlink_to(source / name)
    shifts = {n: SHIFT if n % 2 == 0 else (0, 0) for n in range(1, cameras + 1)}
    videos = {}
    for n in range(1, cameras + 1):
        videos[n] = out / "videos" / f"source{frames}_{shifts[n][0]}_{shifts[n][1]}.mraw"
        if not videos[n].exists():
            _write_video(source / "cam01.mraw", videos[n], frames, shifts[n])
    wtd = read_wtd(source / "run.wtd")
    alpha0 = wtd.value("ALPHA")
    cfg = TunnelConfig(np.array(COR))
    M, d = model_to_tunnel(Attitude(alpha0, 0.0, 0.0, 0.0), cfg)
    cam = read_camera(source / "cam01.json")  # camera-to-model: R X + t
    R_ct = cam.R @ M.T  # so that R_ct (M X + d) + t_ct = R X + t
    cam_t = cam.with_pose(R=R_ct, t=cam.t - R_ct @ d)
    for n in range(1, cameras + 1):
        K = np.array(cam_t.K, float)  # a moved image: the principal point moved with it
        K[0, 2] += shifts[n][0]
        K[1, 2] += shifts[n][1]
        write_camera(out / "camera-tunnel-calibration" / f"camera{n:02d}.json",
                     cam_t.replace(K=K), format="upsp")
    rows = [ln for ln in (source / "run.wtd").read_text().splitlines()
            if ln.strip() and not ln.startswith(("RUN", "#"))]
    taps = [ln for ln in rows[1:] if len(ln.split()) == 2]
    head = ["MACH", "ALPHA", "BETA", "PHI", "PTOT", "TTF", "PS", "Q", "STRUTZ"]
    ids = []
    for s in range(1, datapoints + 1):
        dp = f"{RUN}{s:02d}"
        ids.append(dp)
        a = alpha0 + alpha_step * ((s - 1) // 2 + 1) * (1 if s % 2 else -1) \
            if s > 1 else alpha0
        vals = [wtd.value("MACH"), a, 0.0, 0.0, wtd.value("PTOT"), wtd.value("TTF"),
                wtd.value("PS"), wtd.value("Q"), 0.0]
        (out / "wtd" / f"{dp}.wtd").write_text(
            f"RUN {RUN} {s}\n#  " + "\t".join(head) + "\n" +
            "\t".join(f"{v:g}" for v in vals) + "\n# Tap CP\n" + "\n".join(taps) + "\n")
        for n in range(1, cameras + 1):
            for ext in (".mraw", ".cih"):
                link = out / "videos" / f"{dp}{n:02d}{ext}"
                if not link.exists():
                    link.symlink_to(videos[n].with_suffix(ext).name)
    tc = {"oblique_angle": 70, "tunnel-cor_to_tgts_tvec": list(COR),
          "tunnel-cor_to_tgts_rmat": np.eye(3).tolist(),
          "tunnel-cor_to_tunnel-origin_tvec": [0.0, 0.0, 0.0],
          "tunnel-cor_to_tunnel-origin_rmat": np.eye(3).tolist()}
    (out / "inputs" / "test_config.json").write_text(json.dumps(tc, indent=1))
    common = {"camera_tunnel_calibration_dir": "camera-tunnel-calibration",
              "camera_video_dir": "videos", "grid_file": "inputs/model.grid",
              "paint_calibration_file": "inputs/paint.txt",
              "steady_psp_file": "inputs/steady.f", "targets_file": "inputs/model.tgts"}
    (out / "index.json").write_text(json.dumps(
        {"__meta__": {"test_name": "entry-big"},
         "datapoints": {dp: dict(common, wtd_file=f"wtd/{dp}.wtd") for dp in ids}},
        indent=1))
    for nf, name in ((-1, "processing.json"), (8, "processing-warmup.json")):
        (out / name).write_text(json.dumps({"processing": {
            "defaults": {"psp_process": {"target_patcher": "polynomial",
                                         "registration": "pixel",
                                         "overlap": "average_view", "filter": "none",
                                         "filter_size": 3, "oblique_angle": 70,
                                         "number_frames": nf},
                         "external-calibration": tc},
            "__overlays__": [["defaults", {".*": ".*"}]]}}, indent=1))
    return ids


def datapoint_deck(out: Path, dp: str, cameras: int, cal_dir: Path) -> Path:
    """uPSP's deck of one datapoint alone, with the entry's calibrated first frames."""
    lines = ["@general", "    test = entry-big", f"    run = {RUN}", f"    sequence = {dp[4:]}",
             "@all", f"    sds = {out / 'wtd' / (dp + '.wtd')}",
             f"    grid = {out / 'inputs' / 'model.grid'}",
             f"    targets = {out / 'inputs' / 'model.tgts'}"]
    for n in range(1, cameras + 1):
        lines += ["@camera", f"    number = {n}",
                  f"    filename = {out / 'videos' / f'{dp}{n:02d}.mraw'}",
                  f"    calibration = {cal_dir / dp / f'cam{n:02d}-to-model.json'}"]
    lines += ["@options", "    target_patcher = polynomial", "    registration = pixel",
              "    overlap = average_view", "    filter = none", "    filter_size = 3",
              "    oblique_angle = 70", "    number_frames = -1",
              "@output", f"    dir = {out / 'decks'}"]
    p = out / "decks" / f"{dp}.inp"
    p.write_text("\n".join(lines) + "\n")
    return p
