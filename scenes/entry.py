"""A synthetic wind-tunnel entry in the real files' layouts: a polar of datapoints of the
painted plate-and-block model of :mod:`scenes.unsteady_run`, each pitched by its ``.wtd``'s
ALPHA about the tunnel's centre of rotation, seen by a camera fixed in the tunnel.

What is written (``folder/``), as uPSP's tools find it:

* ``inputs/``: the grid, the ``.tgts`` (targets, taps, and the Kulites as ``*Virtuals``),
  the paint calibration, the steady Cp, ``test_config.json`` (centre of rotation);
* ``camera-tunnel-calibration/camera01.json``: the camera in the tunnel (uPSP's
  camera-to-tunnel JSON, principal point from the image centre);
* ``videos/<id>01.mraw`` + ``.cih``: 12-bit frames (Photron layout, 16-bit words), glare
  free but with the scene's noise, texture and vibration;
* ``wtd/<id>.wtd``: NASA's layout (``RUN n m`` line, ``#`` header, values, ``# Tap CP``);
* ``kulites/T<run>p<seq>t1.info`` with ``.fast`` and ``.slow``: the Kulites as the UPWT
  data system writes them (uPSP's ``kulite_utilities``), sampled at ``kulite_rate``;
* ``index.json`` (uPSP's datapoint index), ``entry.yaml`` (the project's schema),
  ``processing.json`` (uPSP's processing parameters, with an overlay).

The model's true attitude differs from the ``.wtd``'s by ``deflection_deg`` of pitch and
``heave`` of height (the sting's bending the data system did not correct): the tunnel
prediction misses the targets by a few pixels, which the calibration on the first frame
must take out. Datapoint ids are ``3011SS`` (run 3011, point SS). A wind-off point (Q = 0)
and a datapoint whose video is cut short can be added.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenes.unsteady_run import BOX, CONDITIONS, _camera, make_unsteady_run, plate_targets

__all__ = ["SyntheticEntry", "make_entry", "write_kulite_files", "COR", "RUN"]

#: the tunnel's centre of rotation to the model origin (model axes, m)
COR = np.array([-0.05, 0.0, 0.0])
#: the run number of the datapoints
RUN = 3011
STRUTZ = 0.02


@dataclass(frozen=True)
class SyntheticEntry:
    """``folder``, ``index`` (uPSP JSON), ``yaml`` (project schema), ``processing``,
    ``ids`` (every datapoint), ``alphas`` ({id: the .wtd's ALPHA}), ``wind_off`` and
    ``corrupt`` (ids or None), ``cameras`` ({id: the true camera-to-model camera of the
    first frame, its vibration included}), ``truth`` ({id: UnsteadyRun}), ``kulites``
    ({name: (x, y, z)}), ``camera_tunnel`` (the tunnel camera), ``fps``, ``kulite_rate``."""

    folder: Path
    index: Path
    yaml: Path
    processing: Path
    ids: tuple
    alphas: dict
    wind_off: str | None
    corrupt: str | None
    cameras: dict
    truth: dict
    kulites: dict
    camera_tunnel: object
    fps: float
    kulite_rate: float


def _write_wtd(path, alpha, q, ps, seq, taps_cp):
    names = ["MACH", "ALPHA", "BETA", "PHI", "PTOT", "TTF", "PS", "Q", "STRUTZ"]
    vals = [CONDITIONS["MACH"], alpha, 0.0, 0.0, CONDITIONS["PTOT"], CONDITIONS["TTF"], ps, q,
            STRUTZ]
    path.write_text(f"RUN {RUN} {seq}\n#  " + "\t".join(names) + "\n"
                    + "\t".join(f"{v:.6f}" for v in vals) + "\n\n# Tap        CP\n"
                    + "".join(f"{k + 1:5d}        {c:.6f}\n" for k, c in enumerate(taps_cp)))


def write_kulite_files(folder, stem, names, psi, rate, slow_every: int = 4) -> Path:
    """uPSP's Kulite files ``stem.info``, ``stem.fast``, ``stem.slow`` (the slow stream one
    sample in ``slow_every``); ``psi`` (K, n). Channels: the Kulites, then a static
    pressure channel ``PT1`` that is not one. Returns the ``.info`` path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    k1, k0, c1, gain_db, c0 = 1e-6, 0.0, 100.0, 20.0, 0.0
    data = np.vstack([psi, np.full((1, psi.shape[1]), 14.7)])
    counts = np.rint(((data - c0) * 10 ** (gain_db / 20) / c1 - k0) / k1).astype("<i4")
    fast, slow = counts.T, counts.T[::slow_every]
    (folder / f"{stem}.fast").write_bytes(np.ascontiguousarray(fast).tobytes())
    (folder / f"{stem}.slow").write_bytes(np.ascontiguousarray(slow).tobytes())
    rows = []

    def block(b, header, body):
        rows.append([str(b), str(len(body))] + header)
        rows.extend([str(b), str(i)] + r for i, r in enumerate(body))

    block(1, ["Type", "File Name"], [["info", f"{stem}.info"], ["fast", f"{stem}.fast"],
                                      ["slow", f"{stem}.slow"]])
    nch = data.shape[0]
    block(2, ["Stream", "Sampling Rate", "Number Channels", "Samples Acquired"],
          [["fast", repr(float(rate)), str(nch), str(len(fast))],
           ["slow", repr(float(rate) / slow_every), str(nch), str(len(slow))]])
    block(3, ["Parameter", "Value"], [["Device", "PXI-4462"]])
    head = ["User Name", "Physical Channel", "User Channel", "Coeff k1", "Coeff k0",
            "EU C1", "EU Gain (dB)", "EU C0", "EU Units", "Excitation (V)", "Range (V)",
            "Coupling", "Filter (Hz)", "Serial", "Sensitivity", "Location", "Comment",
            "Enabled", "Type"]
    body = []
    for i, n in enumerate([*names, "PT1"]):
        body.append([n, f"PXI1Slot2/ai{i}", str(i + 1), repr(k1), repr(k0), repr(c1),
                     repr(gain_db), repr(c0), "psi", "10", "10", "DC", "0", f"S{i:04d}",
                     "1", "model", "", "1", "K" if n != "PT1" else "P"])
    block(4, head, body)
    info = folder / f"{stem}.info"
    info.write_text("".join("\t".join(r) + "\n" for r in rows))
    return info


def make_entry(folder: str | os.PathLike, *, alphas=(-5.0, 5.0, 15.0), wind_off: bool = True,
               corrupt: bool = True, faces: int = 1000, frames: int = 32, fps: float = 1000.0,
               width: int = 200, height: int = 150, deflection_deg: float = 0.4,
               heave: float = 0.003, kulite_rate: float = 4000.0, noise: float = 0.003,
               seed: int = 0) -> SyntheticEntry:
    """Write the entry (module notes) and return its paths and truth."""
    from resection.io.cameras import write_camera
    from resection.io.tgts import read_tgts
    from selfillum.entry.tunnel import Attitude, TunnelConfig, model_to_tunnel

    out = Path(folder)
    for d in ("inputs", "camera-tunnel-calibration", "videos", "wtd", "kulites", "_runs"):
        (out / d).mkdir(parents=True, exist_ok=True)
    cfg = TunnelConfig(COR)
    base = _camera(width, height)  # on the model at ALPHA = 0, no deflection
    M0, d0 = model_to_tunnel(Attitude(0.0, 0.0, 0.0, STRUTZ), cfg)
    R_ct = base.R @ M0.T
    cam_tunnel = base.with_pose(R=R_ct, t=base.t - R_ct @ d0)
    write_camera(out / "camera-tunnel-calibration" / "camera01.json", cam_tunnel,
                 format="upsp")

    def true_camera(alpha):
        M, d = model_to_tunnel(Attitude(alpha + deflection_deg, 0.0, 0.0, STRUTZ + heave),
                               cfg)
        return cam_tunnel.with_pose(R=cam_tunnel.R @ M, t=cam_tunnel.t + cam_tunnel.R @ d)

    cams = [true_camera(a) for a in alphas]
    tg = plate_targets(cams, BOX, margin=15.0)
    ids, al, truth, trues = [], {}, {}, {}
    rng = np.random.default_rng(seed + 99)
    kul_names = ("K01", "K02")
    for s, (a, cam) in enumerate(zip(alphas, cams, strict=True), start=1):
        dp = f"{RUN}{s:02d}"
        run = make_unsteady_run(out / "_runs" / dp, faces=faces, frames=frames, fps=fps,
                                width=width, height=height, noise=noise, cameras0=[cam],
                                targets=tg, seed=seed + s)
        if s == 1:
            for n in ("model.grid", "model.tgts", "paint.txt", "steady.f"):
                shutil.copy(run.folder / n, out / "inputs" / n)
        video = np.load(run.video)
        _write_mraw(out / "videos" / f"{dp}01", video, fps)
        taps_cp = _taps_cp(run)
        _write_wtd(out / "wtd" / f"{dp}.wtd", a, CONDITIONS["Q"], CONDITIONS["PS"], s, taps_cp)
        # the Kulites: the truth at their places, at the data system's rate
        v = read_tgts(out / "inputs" / "model.tgts").virtuals
        tk = np.arange(int(round(frames / fps * kulite_rate)) + 8) / kulite_rate
        psi = []
        for name in kul_names:
            x = v.xyz[list(v.ids).index(name)]
            dcp = (run.amps["tone"] * np.sin(2 * np.pi * run.freqs["tone"] * tk)
                   + run.amps["wave"] * np.sin(2 * np.pi * (run.freqs["wave"] * tk
                                                            - x[0] / run.amps["lam"])))
            cp = -0.3 + 0.4 * x[0]
            p = (cp * CONDITIONS["Q"] + CONDITIONS["PS"] + dcp * CONDITIONS["Q"]) / 144.0
            psi.append(p + 2e-5 * rng.standard_normal(len(tk)))
        write_kulite_files(out / "kulites", f"T{RUN}p{s}t1", kul_names, np.array(psi),
                           kulite_rate)
        ids.append(dp)
        al[dp] = a
        truth[dp] = run
        trues[dp] = cam.with_pose(R=run.poses[0, 0, :3], t=run.poses[0, 0, 3])  # frame 0
    off = bad = None
    if wind_off:  # the first alpha's frames, the tunnel at rest
        s = len(ids) + 1
        off = f"{RUN}{s:02d}"
        shutil.copy(out / "videos" / f"{ids[0]}01.mraw", out / "videos" / f"{off}01.mraw")
        shutil.copy(out / "videos" / f"{ids[0]}01.cih", out / "videos" / f"{off}01.cih")
        _write_wtd(out / "wtd" / f"{off}.wtd", alphas[0], 0.0, 0.0, s, [])
        ids.append(off)
        al[off] = alphas[0]
        trues[off] = trues[ids[0]]
    if corrupt:  # the second alpha's video, cut in its first frame
        s = len(ids) + 1
        bad = f"{RUN}{s:02d}"
        src = out / "videos" / f"{ids[1]}01.mraw"
        data = src.read_bytes()
        (out / "videos" / f"{bad}01.mraw").write_bytes(data[: width * height])
        shutil.copy(out / "videos" / f"{ids[1]}01.cih", out / "videos" / f"{bad}01.cih")
        shutil.copy(out / "wtd" / f"{ids[1]}.wtd", out / "wtd" / f"{bad}.wtd")
        ids.append(bad)
        al[bad] = alphas[1]
    (out / "inputs" / "test_config.json").write_text(json.dumps({
        "oblique_angle": 70, "tunnel-cor_to_tgts_tvec": COR.tolist(),
        "tunnel-cor_to_tgts_rmat": np.eye(3).tolist(),
        "tunnel-cor_to_tunnel-origin_tvec": [0.0, 0.0, 0.0],
        "tunnel-cor_to_tunnel-origin_rmat": np.eye(3).tolist(),
        "dot_pad": 4, "max_dist": 6, "min_dist": 8}, indent=1))
    common = {"camera_tunnel_calibration_dir": "camera-tunnel-calibration",
              "camera_video_dir": "videos", "grid_file": "inputs/model.grid",
              "kulites_files_path": "kulites", "paint_calibration_file": "inputs/paint.txt",
              "steady_psp_file": "inputs/steady.f", "targets_file": "inputs/model.tgts"}
    index = {"__meta__": {"config_name": "default", "test_name": "synthetic-entry"},
             "datapoints": {dp: dict(common, wtd_file=f"wtd/{dp}.wtd") for dp in ids}}
    (out / "index.json").write_text(json.dumps(index, indent=1))
    tc = json.loads((out / "inputs" / "test_config.json").read_text())
    proc = {"__meta__": {"name": "default"}, "processing": {
        "defaults": {"psp_process": {"target_patcher": "polynomial", "registration": "pixel",
                                     "overlap": "average_view", "filter": "none",
                                     "filter_size": 3, "oblique_angle": 70,
                                     "number_frames": -1},
                     "external-calibration": tc},
        "slab": {"psp_process": {"oblique_angle": 75}},
        "__overlays__": [["defaults", {".*": ".*"}], ["slab", {"grid_file": ".*model.grid"}]]}}
    (out / "processing.json").write_text(json.dumps(proc, indent=1))
    lines = ["entry:", "  name: synthetic-entry", "  grid: inputs/model.grid",
             "  targets: inputs/model.tgts", "  test_config: inputs/test_config.json",
             "  paint_calibration: inputs/paint.txt", "  steady: inputs/steady.f",
             "  camera_tunnel:", "    1: camera-tunnel-calibration/camera01.json",
             "  options:", "    target_patcher: polynomial", "    registration: pixel",
             "    overlap: average_view", "datapoints:"]
    for dp in ids:
        lines += [f'  "{dp}":', f"    wtd: wtd/{dp}.wtd", "    videos:",
                  f"      1: videos/{dp}01.mraw", "    kulites: kulites"]
    (out / "entry.yaml").write_text("\n".join(lines) + "\n")
    v = read_tgts(out / "inputs" / "model.tgts").virtuals
    return SyntheticEntry(out, out / "index.json", out / "entry.yaml", out / "processing.json",
                          tuple(ids), al, off, bad, trues, truth,
                          {k: tuple(x) for k, x in zip(v.ids, v.xyz, strict=True)},
                          cam_tunnel, fps, kulite_rate)


def _taps_cp(run):
    from resection.io.tgts import read_tgts

    t = read_tgts(run.targets).taps
    return -0.3 + 0.4 * t.xyz[:, 0]


def _write_mraw(stem: Path, video, fps):
    """12-bit counts (the brightest pixel near 3500) in Photron's 16-bit layout."""
    import warnings

    import pyMRAW

    v = np.clip(np.rint(video * (3500.0 / float(np.max(video)))), 0, 4095).astype(np.uint16)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pyMRAW.save_mraw(v, str(stem.with_suffix(".cih")), bit_depth=16,
                         info_dict={"Record Rate(fps)": int(fps)})
