"""``selfillum unsteady`` at scale: Welch spectra against SciPy on the same series and
against a known tone's amplitude and frequency; pictures; the memory budget (a Phase 2
over data 4x the budget stays within it, measured by tracemalloc in a subprocess); blocks
never change the answer; progress and peak memory printed."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import h5py
import numpy as np
import pytest
from scipy import signal

from resection.errors import InputError
from selfillum.unsteady.budget import plan_blocks
from selfillum.unsteady.spectra import Spectra, band_average, band_edges, welch_block

# ---------------------------------------------------------------------------- spectra


def test_welch_block_tone_and_noise_levels():
    """A tone of amplitude A at f0 carries A^2/2 of power around f0; white noise of
    variance s^2 has a flat one-sided density s^2 / (fs / 2)."""
    fs, T = 1000.0, 4096
    t = np.arange(T) / fs
    rng = np.random.default_rng(0)
    A, f0, s = 0.03, 125.0, 0.01  # f0 on a bin of nperseg = 256 (3.90625 Hz bins)
    d = np.column_stack([A * np.sin(2 * np.pi * f0 * t), s * rng.standard_normal(T)])
    f, p = welch_block(d, fs, 256)
    df = f[1] - f[0]
    k = np.argmax(p[0])
    assert f[k] == pytest.approx(f0, abs=df / 2)
    assert p[0, k - 3:k + 4].sum() * df == pytest.approx(A**2 / 2, rel=0.02)
    level = np.median(p[1, 5:-5])
    assert level == pytest.approx(s**2 / (fs / 2), rel=0.1)
    # and SciPy's welch on each series alone gives the same
    for j in range(2):
        fr, pr = signal.welch(d[:, j], fs=fs, nperseg=256)
        np.testing.assert_allclose(f, fr)
        np.testing.assert_allclose(p[j], pr, rtol=1e-8, atol=1e-10 * pr.max())


def test_welch_block_unseen_frames_keep_the_power():
    """Frames unseen (NaN) are zeros and the PSD is scaled by the share seen: the tone's
    power is kept within 3 % with 10 % of the frames missing; a node never seen is NaN."""
    fs, T = 1000.0, 4096
    t = np.arange(T) / fs
    d = 0.02 * np.sin(2 * np.pi * 125.0 * t)
    rng = np.random.default_rng(1)
    miss = rng.random(T) < 0.1
    block = np.column_stack([np.where(miss, np.nan, d), np.full(T, np.nan)])
    f, p = welch_block(block, fs, 256)
    assert np.trapezoid(p[0], f) == pytest.approx(0.02**2 / 2, rel=0.03)
    assert np.all(np.isnan(p[1]))


def test_band_average_hand_computed():
    f = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    edges = band_edges(f, 2)
    np.testing.assert_allclose(edges, [1.0, 2.0, 4.0])
    psd = np.array([[9.0, 1.0, 2.0, 4.0, 8.0]])
    # band [1, 2): bin 1 -> 1; band [2, 4]: bins 2, 3, 4 -> (2 + 4 + 8) / 3
    np.testing.assert_allclose(band_average(f, psd, edges), [[1.0, 14.0 / 3]])


def test_spectra_by_blocks_equal_scipy_and_refuse_bad_probes():
    fs, T, N = 500.0, 600, 37
    rng = np.random.default_rng(2)
    d = rng.standard_normal((T, N))
    sp_ = Spectra(N, fs, T, probes=[3, 30], n_bands=4, nperseg=128)
    for a in range(0, N, 10):  # blocks of 10 nodes
        sp_.add(a, d[:, a:a + 10])
    fr, pr = signal.welch(d, fs=fs, nperseg=128, axis=0)
    np.testing.assert_allclose(sp_.probe_psd, pr[:, [3, 30]].T, rtol=1e-10)
    np.testing.assert_allclose(sp_.mean_psd, pr.mean(axis=1), rtol=1e-10)
    np.testing.assert_allclose(sp_.band, band_average(fr, pr.T, sp_.edges), rtol=1e-6)
    with pytest.raises(InputError, match="node 37"):
        Spectra(N, fs, T, probes=[37])


# ---------------------------------------------------------------------------- work file


def test_work_file_codes_within_the_stated_error():
    """uint16 codes with a power-of-two scale per frame: every intensity comes back within
    max_frame / 65535 (12-bit counts: within 1/32 of a count); NaN, 0 and negative values
    are unseen (code 0); a tiny positive value stays seen; dCp from the codes equals dCp
    from the float32 intensities within that error carried through I' (hand bound)."""
    from selfillum.unsteady.phase2 import dcp_block, phase2_block
    from selfillum.unsteady.work import decode_columns, encode_rows

    rng = np.random.default_rng(5)
    x = rng.uniform(0, 4095, (6, 1000)).astype(np.float32)
    x[0, :3] = [np.nan, 0.0, -5.0]
    x[1, 0] = 1e-6
    x[2] *= 1000.0  # a frame of large values: its own scale
    codes, scale = encode_rows(x)
    assert codes.dtype == np.uint16 and scale.shape == (6,)
    assert np.all(np.log2(scale) == np.round(np.log2(scale)))  # powers of two
    back = decode_columns(codes, scale)
    assert np.all(np.isnan(back[0, :3])) and back[1, 0] > 0
    ok = np.isfinite(x) & (x > 0)
    top = np.nanmax(np.where(ok, x, 0), axis=1, keepdims=True)
    err = np.abs(back - x)[ok & (np.arange(1000) > 0)]
    assert np.all(err <= (top / 65535 * np.ones_like(x))[ok & (np.arange(1000) > 0)])
    twelve = np.rint(x[3:] / x[3:].max() * 4095).astype(np.float32)  # 12-bit counts
    c12, s12 = encode_rows(twelve)
    assert np.abs(decode_columns(c12, s12) - twelve).max() <= 1 / 32
    # dCp from codes and from float32: an intensity's relative error is at most e, so
    # I' = mean / I moves by at most 2 e I' (to first order), and the residual after the
    # fit (I - V P) by at most (1 + |V P|_inf) times that
    from selfillum.unsteady.phase2 import legendre_basis

    T, n = 400, 50
    I = (1500 * (1 + 0.01 * rng.standard_normal((T, n)))).astype(np.float32)
    c, sc = encode_rows(I)
    a = dcp_block(I, np.arange(T), np.full(n, 2.0), 600.0)
    b = phase2_block(c, np.arange(T), np.full(n, 2.0), 600.0, scale=sc)[0]
    e = I.max() / 65535 / I.min()
    V, P = legendre_basis(np.arange(T))
    lebesgue = np.abs(V @ P).sum(axis=1).max()
    ratio_max = (I.mean(axis=0) / I.min(axis=0)).max()
    bound = (1 + lebesgue) * 2.02 * e * ratio_max * 2.0 * 144 / 600
    assert np.abs(a - b).max() <= bound


# ---------------------------------------------------------------------------- memory


def test_plan_blocks_within_budget():
    T, N = 2000, 600_000
    p = plan_blocks(T, N, (15, 4369), memory_mb=4096)
    assert p.bytes_phase1(N) <= 4096 * 2**20 and p.bytes_phase2(T) <= 4096 * 2**20
    assert p.frames_per_block % 15 == 0 and p.nodes_per_block % 4369 == 0
    small = plan_blocks(T, N, (15, 4369), memory_mb=4)  # below a chunk: partial chunks
    assert small.nodes_per_block < 4369 and small.bytes_phase2(T) <= 4 * 2**20
    with pytest.raises(InputError, match="--memory"):
        plan_blocks(T, N, (15, 4369), memory_mb=0)


_MEMORY_CHILD = textwrap.dedent("""
    import sys, tracemalloc
    import h5py, numpy as np, scipy.signal  # imports: the fixed part, before tracing
    from selfillum.unsteady.budget import plan_blocks
    from selfillum.unsteady.output import chunk_shape
    from selfillum.unsteady.phase2 import phase2_block, run_phase2
    from selfillum.unsteady.spectra import Spectra, welch_block
    path, budget_mb = sys.argv[1], float(sys.argv[2])
    # the compiled kernels loaded (the fixed part, like the imports)
    x = np.ones((64, 3), np.uint16)
    welch_block(phase2_block(x, np.arange(64), np.ones(3), 1.0, scale=np.ones(64), raw=x,
                             raw_scale=np.ones(64))[0], 1.0, 16)
    with h5py.File(path, "r+") as f:
        vals, raw = f["values"], f["raw"]
        T, N = vals.shape
        chunks = chunk_shape(T, N)
        plan = plan_blocks(T, N, chunks, budget_mb)
        dcp = f.create_dataset("dcp", (T, N), "f4", chunks=chunks)
        band = f.create_dataset("band", (N, 8), "f4")
        spectra = Spectra(N, 1000.0, T, probes=[0, N - 1], n_bands=8, band_out=band)
        tracemalloc.start()
        run_phase2(vals, dcp, np.arange(T), np.full(N, 2.0), 600.0, raw=raw,
                   scale=f["values_scale"][()], raw_scale=f["raw_scale"][()],
                   block=plan.nodes_per_block, spectra=spectra)
        peak = tracemalloc.get_traced_memory()[1]
    print(peak, plan.nodes_per_block)
""")


def test_phase2_on_data_4x_the_budget_stays_within_it(tmp_path):
    """Phase 2 with the SI change and spectra over (T, N) intensities whose dCp takes
    32 MiB (the work file's uint16 codes: values and raw, 32 MiB read) within an 8 MiB
    budget: the peak of the arrays allocated (tracemalloc, in a fresh process) stays under
    the budget, and dCp equals the one-block answer."""
    from selfillum.unsteady.work import decode_columns, encode_rows

    T, N = 1024, 8192  # dCp: 32 MiB
    budget = 8.0
    rng = np.random.default_rng(3)
    path = tmp_path / "p1.h5"
    with h5py.File(path, "w") as f:
        v = f.create_dataset("values", (T, N), "u2", chunks=(64, 1024))
        r = f.create_dataset("raw", (T, N), "u2", chunks=(64, 1024))
        vs = f.create_dataset("values_scale", (T,), "f8")
        rs = f.create_dataset("raw_scale", (T,), "f8")
        for a in range(0, T, 64):
            x = 1000 + 5 * rng.standard_normal((64, N)).astype(np.float32)
            v[a:a + 64], vs[a:a + 64] = encode_rows(x)
            r[a:a + 64], rs[a:a + 64] = encode_rows(x * 1.01)
    assert T * N * 4 >= 4 * budget * 2**20
    res = subprocess.run([sys.executable, "-c", _MEMORY_CHILD, str(path), str(budget)],
                         capture_output=True, text=True, check=True)
    peak, npb = (int(v) for v in res.stdout.split())
    assert npb < N  # it did work in blocks
    assert peak < budget * 2**20, f"peak {peak / 2**20:.1f} MiB over {budget} MiB"
    from selfillum.unsteady.phase2 import dcp_block

    with h5py.File(path) as f:
        cols = [5, N // 2, N - 3]
        got = f["dcp"][:, cols]
        want = dcp_block(decode_columns(f["values"][:, cols], f["values_scale"][()]),
                         np.arange(T), np.full(3, 2.0), 600.0)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)


_PEAK_CHILD = ("import sys; from selfillum.cli import main; "
               "from selfillum.unsteady.budget import peak_rss_mb; rc = main(sys.argv[1:]); "
               "print('PEAK_MB', peak_rss_mb()); sys.exit(rc)")


def _peak_rss_mb(folder, frames: int, memory_mb: float) -> float:
    """Peak RSS (MiB) of the whole command in a fresh process (fixed model, no SI): its
    own high-water mark (``VmHWM``: ``ru_maxrss`` would also hold this test process's)."""
    import os
    import re
    import shutil

    out = folder / f"m{frames}_{memory_mb:g}.h5"
    cmd = [sys.executable, "-c", _PEAK_CHILD, "unsteady", "--grid", str(folder / "model.grid"),
           "--sds", str(folder / "run.wtd"), "--video", str(folder / "cam01.npy"),
           "--calibration", str(folder / "cam01.json"), "--paint-calibration",
           str(folder / "paint.txt"), "--steady", str(folder / "steady.f"), "--fps", "2000",
           "--out", str(out), "--registration", "none", "--no-si", "--no-plots", "--quiet",
           "--overlap", "average_view", "--memory", str(memory_mb), "--number-frames",
           str(frames)]
    res = subprocess.run(cmd, capture_output=True, text=True,
                         env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)))
    assert res.returncode == 0, res.stderr[-2000:]
    for p in folder.glob(out.stem + "*"):
        shutil.rmtree(p) if p.is_dir() else p.unlink()
    return float(re.search(r"PEAK_MB ([\d.]+)", res.stdout).group(1))


@pytest.mark.slow
def test_whole_command_on_data_4x_the_budget_stays_within_it(tmp_path):
    """The whole command (set-up, Phase 1, Phase 2, the outputs) on 1,800 frames of a
    9,800-node grid, whose dCp alone (frames x nodes x 4 bytes, 67 MiB) is 4x the 16 MiB
    budget: its peak RSS exceeds the fixed part by less than the budget plus a 25 %
    allowance for the allocator. The fixed part (interpreter, libraries, compiled kernels,
    grid, frame 0's map and operators) is the peak of the same command on 16 frames. The
    same run with a budget that holds everything (4 GiB) goes well over: the measurement
    sees the blocks."""
    from scenes.unsteady_large import make_large_run

    T, budget = 1800, 16.0
    info = make_large_run(tmp_path, 10_000, T, 200, 150)
    N = info["nodes"]
    assert T * N * 4 >= 4 * budget * 2**20
    fixed = _peak_rss_mb(tmp_path, 16, budget)
    within = _peak_rss_mb(tmp_path, T, budget)
    whole = _peak_rss_mb(tmp_path, T, 4096)
    assert within - fixed < 1.25 * budget, (fixed, within)
    assert whole - fixed > 2 * budget, (fixed, whole)


# ---------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from scenes.unsteady_run import make_unsteady_run

    return make_unsteady_run(tmp_path_factory.mktemp("unsteady_scale"), frames=200)


def _cli(run, out, *extra):
    from selfillum.cli import main

    return main(["unsteady", str(run.deck), "--paint-calibration", str(run.paint),
                 "--steady", str(run.steady), "--fps", str(run.fps), "--out", str(out),
                 "--registration", "none", *extra])


def test_run_spectra_pictures_budget_and_progress(run, capsys):
    """The run's stored spectra equal SciPy's welch on its own /dcp; the probe on the
    plate shows the tone (0.03 at 120 Hz) at its frequency with its power; a run in a
    tiny budget (blocks of a few frames and nodes) gives the same dCp; progress, frames/s,
    the time left and the peak memory are printed; the pictures are PNG with colour."""
    import matplotlib.image as mpimg

    from selfillum.unsteady.grid import load_run_grid

    pts = load_run_grid(run.grid).points
    plate = np.flatnonzero(run.plate)
    # two plate nodes away from the block (its footprint is |x| < 0.04, |y| < 0.03)
    probe = [int(plate[np.argmin(np.hypot(pts[plate, 0] - x, pts[plate, 1] - y))])
             for x, y in ((0.2, 0.1), (-0.15, -0.1))]
    out = run.folder / "a.h5"
    assert _cli(run, out, "--psd", ",".join(map(str, probe)), "--psd-nperseg", "100") == 0
    text = capsys.readouterr().out
    assert "frames/s" in text and "s left" in text and "phase 2: node" in text
    assert "peak memory" in text
    with h5py.File(out) as f:
        d = f["dcp"][()]
        fr = f["psd/frequency"][()]
        pp = f["psd/probe_psd"][()]
        mean = f["psd/mean"][()]
        band = f["psd/band_psd"][()]
        edges = f["psd/band_edges"][()]
        assert list(f["psd/probe_nodes"][()]) == probe
    ok = np.isfinite(d).all(axis=0)
    fs_, ps_ = signal.welch(d[:, probe].astype(np.float64), fs=run.fps, nperseg=100, axis=0)
    np.testing.assert_allclose(fr, fs_)
    np.testing.assert_allclose(pp, ps_.T, rtol=1e-5, atol=1e-6 * ps_.max())
    _, pall = signal.welch(d[:, ok].astype(np.float64), fs=run.fps, nperseg=100, axis=0)
    np.testing.assert_allclose(mean, pall.mean(axis=1), rtol=1e-4)
    np.testing.assert_allclose(band[ok], band_average(fs_, pall.T, edges), rtol=1e-4)
    assert np.all(np.isnan(band[~np.isfinite(d).any(axis=0)]))
    # the tone at the far probe: its frequency and power (0.03^2 / 2 within 10 %:
    # the 6th-order detrend takes under 1 %, noise and the wave add some)
    df = fr[1] - fr[0]
    k = np.argmax(pp[0])
    assert fr[k] == pytest.approx(run.freqs["tone"], abs=df)
    assert pp[0, k - 2:k + 3].sum() * df == pytest.approx(run.amps["tone"] ** 2 / 2,
                                                           rel=0.10)
    for name in ("a_rms.png", "a_psd.png"):
        img = mpimg.imread(run.folder / name)
        assert img.ndim == 3 and img.shape[0] > 200
        rgb = img[..., :3].reshape(-1, 3)
        assert (np.ptp(rgb, axis=1) > 0.2).mean() > 0.01  # coloured pixels, not blank
    # a budget of 0.05 MiB: blocks of a few frames and nodes, the same answer
    small = run.folder / "b.h5"
    assert _cli(run, small, "--memory", "0.05", "--no-plots", "--quiet") == 0
    with h5py.File(small) as f:  # same NaN pattern; values to float32 rounding (the BLAS
        # products of narrower blocks may round differently)
        np.testing.assert_array_equal(np.isnan(f["dcp"][()]), np.isnan(d))
        np.testing.assert_allclose(f["dcp"][()], d, rtol=1e-5, atol=1e-7)
        import json

        mem = json.loads(f.attrs["memory"])
        T, N = d.shape
        assert mem["frames_per_block"] < 15 and mem["nodes_per_block"] < N
    assert not (run.folder / "b_rms.png").exists()


# ---------------------------------------------------------------------------- resume


def test_resume_skips_finished_blocks_and_refuses_stale_work(run, capsys, monkeypatch):
    """A run interrupted at frame 100 (blocks of 45 frames: 90 committed) resumes with
    --resume, maps only frame 0 again (its references) and the 110 frames not done, and
    gives the uninterrupted run's dCp; without --resume the work folder is refused; with an
    input changed since, the resume is refused by name."""
    import selfillum.unsteady.phase1 as phase1
    from selfillum.unsteady.work import work_folder

    whole = run.folder / "whole.h5"
    common = ("--memory", "0.25", "--no-plots", "--quiet", "--psd-bands", "0")
    assert _cli(run, whole, *common) == 0
    real = phase1.FrameNodes  # made once a frame mapped, either way
    calls = []

    def counting(*a, **k):
        calls.append(1)
        if stop_at is not None and len(calls) == stop_at:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(phase1, "FrameNodes", counting)
    out = run.folder / "resumed.h5"
    stop_at = 101  # frame 100
    assert _cli(run, out, *common) == 130
    capsys.readouterr()
    work = work_folder(out)
    assert (work / "phase1.h5").exists() and not out.exists()
    with h5py.File(work / "phase1.h5") as f:
        assert f.attrs["frames_done"] == 90
    # without --resume: refused, the work kept
    assert _cli(run, out, *common) == 2
    assert "--resume" in capsys.readouterr().err and work.exists()
    calls.clear()
    stop_at = None
    assert _cli(run, out, *common, "--resume") == 0
    assert len(calls) == 1 + (200 - 90)  # frame 0 again, then frames 90..199
    assert not work.exists()
    with h5py.File(out) as f, h5py.File(whole) as g:
        np.testing.assert_array_equal(f["dcp"][()], g["dcp"][()])
    # stale work: interrupted, then a setting changed -> refused by name
    out2 = run.folder / "stale.h5"
    calls.clear()
    stop_at = 60
    assert _cli(run, out2, *common) == 130
    capsys.readouterr()
    assert _cli(run, out2, *common, "--resume", "--oblique-angle", "60") == 2
    err = capsys.readouterr().err
    assert "other inputs (oblique_angle)" in err and work_folder(out2).exists()
    # ... and an input file rewritten since (its content: the key holds a digest of it)
    text = run.targets.read_text()
    try:
        run.targets.write_text(text + "# edited\n")
        assert _cli(run, out2, *common, "--resume") == 2
        assert "other inputs (files)" in capsys.readouterr().err
    finally:
        run.targets.write_text(text)


# ---------------------------------------------------------------------------- fast path


def test_fast_phase1_agrees_with_the_full_per_frame_map(monkeypatch):
    """Frames mapped by sparse products (frame 0's operator; for a moving model the frame
    sampled where a reference's surface points project with the frame's own pose) against
    the full way (a SurfaceMap ray cast and merge every frame), on a vibrating model (1
    degree, points moving up to about 2 pixels; the true pose of every frame),
    self-illumination removed: a fixed map gives the same node values (1e-6), the moving
    model the same within a stated tolerance (median 0.1 %, 99th percentile 3 %, under
    0.5 % of the values seen by one way and not the other)."""
    import tempfile
    from pathlib import Path

    from resection.io.cameras import read_camera
    from resection.io.markers import read_markers
    from resection.io.video import open_frames
    from scenes.unsteady_run import make_unsteady_run
    from selfillum.transport.viewfactors import view_factors
    from selfillum.unsteady.grid import load_run_grid
    from selfillum.unsteady.phase1 import CameraRun, SelfIllumination, map_run
    from selfillum.unsteady.spots import DarkSpots

    T = 30
    with tempfile.TemporaryDirectory() as d:
        run = make_unsteady_run(Path(d), frames=T, vibration_deg=1.0)
        grid = load_run_grid(run.grid)
        cam = read_camera(run.calibration)
        src = open_frames(run.video)
        frames = [np.asarray(src[k]) for k in range(T)]
        src.close()
        spots = DarkSpots.from_markers(read_markers(run.targets, include_taps=True),
                                       str(run.targets))
    poses = [cam.with_pose(R=run.poses[0, k, :3], t=run.poses[0, k, 3]) for k in range(T)]
    F = view_factors(grid.mesh, rays_per_face=256, seed=0, progress=False)

    def values(reg, fast, with_si=True, video=frames):
        si = SelfIllumination(grid.mesh, F, 0.6) if with_si else None
        res = map_run(grid, [CameraRun(1, cam, video, poses)], range(T), spots=spots,
                      registration=reg, si=si, fast=fast)
        return np.array([r.values for r in res], dtype=np.float64)

    a, b = values("none", False), values("none", True)
    np.testing.assert_array_equal(np.isfinite(a), np.isfinite(b))
    np.testing.assert_allclose(b[np.isfinite(a)], a[np.isfinite(a)], rtol=1e-6)
    # without SI the fixed map goes from the video's stored counts to the nodes in one
    # product (Wn A): the same node values as the full per-frame map
    import selfillum.unsteady.fastmap as fastmap

    real_nodes, direct = fastmap.FrameOperator.nodes, []

    def spied(self, images, *a):
        direct.append(images[0].dtype)
        return real_nodes(self, images, *a)

    monkeypatch.setattr(fastmap.FrameOperator, "nodes", spied)
    with tempfile.TemporaryDirectory() as d:
        np.save(Path(d) / "v.npy", np.rint(np.asarray(frames)).astype(np.uint16))
        src = open_frames(Path(d) / "v.npy")
        try:
            a = values("none", False, False, src)
            b = values("none", True, False, src)
        finally:
            src.close()
    assert direct == [np.uint16] * (T - 1)  # frames after frame 0, counts as stored
    assert np.isfinite(a).mean() > 0.25
    np.testing.assert_array_equal(np.isfinite(a), np.isfinite(b))
    np.testing.assert_allclose(b[np.isfinite(a)], a[np.isfinite(a)], rtol=1e-6)

    real, used = fastmap.FrameOperator.faces_of_samples, []

    def counted(self, *a, **k):  # a moving frame's fast way: its samples made into faces
        B = real(self, *a, **k)
        used.append(B is not None)
        return B

    monkeypatch.setattr(fastmap.FrameOperator, "faces_of_samples", counted)
    a, b = values("track", False), values("track", True)
    # the frames take the fast way: the references are planned from the known poses
    # (here frame 0's covers every frame: points move up to 2.4 px) and points moving off
    # the sensor are left out instead of forcing a cast (before: 21 of 29 frames)
    assert sum(used) >= T - 3
    both = np.isfinite(a) & np.isfinite(b)
    assert both.sum() > 0.25 * a.size
    assert (np.isfinite(a) != np.isfinite(b)).mean() < 0.005
    rel = np.abs(b[both] - a[both]) / np.abs(a[both])
    assert np.median(rel) < 1e-3 and np.percentile(rel, 99) < 0.03


# ---------------------------------------------------------------------------- Dask


@pytest.mark.slow  # 11-13 s; Dask's parity is also tested by test_sequence and test_entry_fast
def test_dask_two_workers_give_the_one_process_dcp(run, capsys):
    """Phase 1 over blocks of frames and Phase 2 over blocks of nodes on a local Dask
    cluster: 1 worker and 2 workers write the dCp, statistics and spectra of the run in one
    process (blocks finishing in any order, one writer)."""
    common = ("--memory", "0.5", "--no-plots", "--quiet", "--psd", "100")
    outs = {}
    for name, extra in (("local", ()), ("w1", ("--workers", "1")),
                        ("w2", ("--workers", "2"))):
        outs[name] = run.folder / f"dask_{name}.h5"
        assert _cli(run, outs[name], *common, *extra) == 0, capsys.readouterr().err
    with h5py.File(outs["local"]) as f:
        ref = {k: f[k][()] for k in ("dcp", "stats/dcp_rms", "psd/band_psd",
                                     "psd/probe_psd")}
        assert np.isfinite(ref["dcp"]).any()
    for name in ("w1", "w2"):
        with h5py.File(outs[name]) as f:
            for k, v in ref.items():
                got = f[k][()]  # same NaN pattern; values to float32 rounding (worker
                # processes may run another BLAS thread count)
                np.testing.assert_array_equal(np.isnan(got), np.isnan(v), err_msg=f"{name}: {k}")
                np.testing.assert_allclose(got, v, rtol=1e-5, atol=1e-7 * np.nanmax(np.abs(v)),
                                           err_msg=f"{name}: {k}")


def _true_track(run, folder):
    """A ``--track`` folder holding the scene's true pose of every frame (camera 1)."""
    from scipy.spatial.transform import Rotation

    from resection.sequence.results import MARKER_COLUMNS, POSE_COLUMNS

    folder.mkdir(exist_ok=True)
    rows = [",".join(POSE_COLUMNS)]
    for k, P in enumerate(run.poses[0]):
        rv = Rotation.from_matrix(P[:3]).as_rotvec()
        rows.append(",".join([str(k), f"f{k}", "ok", "", "0", "0", "0", "0", "0", "0", "0.1",
                              "20", *(repr(float(v)) for v in rv),
                              *(repr(float(v)) for v in P[3])]))
    (folder / "poses.csv").write_text("\n".join(rows) + "\n")
    (folder / "markers.csv").write_text(",".join(MARKER_COLUMNS) + "\n")
    return folder


@pytest.mark.slow  # 10-15 s: the untracked Dask test stays in the default run
def test_dask_tracked_run_gives_the_one_process_dcp(run, capsys):
    """``--registration track`` (each frame's own pose, here the true ones as a track
    folder) with a map cast every frame (``--full-maps``) on 2 Dask workers gives the
    one-process dCp to float32 rounding (rtol 1e-5, the same NaN pattern); each Phase 1
    task is sent every frame's pose (once a worker, as arrays)."""
    track = _true_track(run, run.folder / "true_track")
    common = ("--registration", "track", "--track", str(track), "--no-si", "--memory",
              "0.5", "--no-plots", "--quiet", "--psd-bands", "0", "--full-maps")
    outs = {}
    for name, extra in (("local", ()), ("w2", ("--workers", "2"))):
        outs[name] = run.folder / f"dask_track_{name}.h5"
        assert _cli(run, outs[name], *common, *extra) == 0, capsys.readouterr().err
    with h5py.File(outs["local"]) as f, h5py.File(outs["w2"]) as g:
        a, b = f["dcp"][()], g["dcp"][()]
        np.testing.assert_array_equal(g["cameras/cam01/R"][()], f["cameras/cam01/R"][()])
    assert np.isfinite(a).any(axis=0).mean() > 0.2
    np.testing.assert_array_equal(np.isnan(b), np.isnan(a))
    np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-7 * np.nanmax(np.abs(a)))


@pytest.mark.slow  # 9-15 s
def test_dask_tracked_fast_run_plans_the_one_process_references(tmp_path, capsys,
                                                                monkeypatch):
    """``--registration track`` with the fast way (references planned from the poses) on 2
    Dask workers gives the one-process dCp (rtol 1e-5, the same NaN pattern) on a run that
    needs several references (a 3-degree vibration): every task plans over all the
    frames, as one process does. The scene is checked to tell: the references planned over
    a task's own block (frame 0 and its frames, as before) differ from the whole run's."""
    from scenes.unsteady_run import make_unsteady_run
    from selfillum.unsteady import cluster, references

    run = make_unsteady_run(tmp_path / "scene", frames=100, vibration_deg=3.0)
    track = _true_track(run, run.folder / "true_track")
    plans, blocks = [], []
    real_plan, real_blocks = references.plan_references, cluster.phase1_blocks

    class Plan(references.ReferencePlan):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            plans.append((a, k, self))

    def phase1(client, job, F, bl, poses=None):
        blocks.extend(bl)
        yield from real_blocks(client, job, F, bl, poses)

    monkeypatch.setattr(references, "ReferencePlan", Plan)
    monkeypatch.setattr(cluster, "phase1_blocks", phase1)
    common = ("--registration", "track", "--track", str(track), "--no-si", "--memory",
              "0.5", "--no-plots", "--quiet", "--psd-bands", "0")
    outs = {}
    for name, extra in (("local", ()), ("w2", ("--workers", "2"))):
        outs[name] = run.folder / f"dask_fast_{name}.h5"
        assert _cli(run, outs[name], *common, *extra) == 0, capsys.readouterr().err
    assert len(plans) == 1  # the local run's (the workers plan in their processes)
    (poses, probes, frames, refresh), kw, planned = plans[0]
    assert list(frames) == list(range(100))
    whole = {k: planned(k) for k in frames}
    assert len(set(whole.values())) >= 2  # several references
    assert len(blocks) >= 2
    own = [real_plan(poses, probes, [0, *range(a, b)], refresh, **kw) for a, b in blocks
           if a > 0]
    assert any(p[k] != whole[k] for p in own for k in p if k > 0)  # the old way differs
    with h5py.File(outs["local"]) as f, h5py.File(outs["w2"]) as g:
        a, b = f["dcp"][()], g["dcp"][()]
        np.testing.assert_array_equal(g["cameras/cam01/R"][()], f["cameras/cam01/R"][()])
    assert np.isfinite(a).any(axis=0).mean() > 0.2
    np.testing.assert_array_equal(np.isnan(b), np.isnan(a))
    np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-7 * np.nanmax(np.abs(a)))


def test_pose_arrays_give_the_cameras_back():
    """The compact poses sent to the workers give back each frame's Camera exactly."""
    from resection.camera.model import Camera
    from selfillum.unsteady.cluster import PoseArrays

    cam = Camera(width=64, height=48, K=np.array([[50.0, 0, 32], [0, 50, 24], [0, 0, 1]]),
                 dist=np.zeros(5), R=np.eye(3), t=np.zeros(3))
    poses = [cam.with_pose(rvec=[0.01 * k, -0.02, 0.003 * k], t=[0.1, -0.2 * k, 1.5])
             for k in range(5)]
    got = PoseArrays.of(poses)
    assert len(got) == 5
    for k, c in enumerate(poses):
        np.testing.assert_array_equal(got[k].R, c.R)
        np.testing.assert_array_equal(got[k].t, c.t)
        np.testing.assert_array_equal(got[k].K, c.K)
    # the plan from the arrays is the plan from the cameras (a 2 px move a frame)
    from selfillum.unsteady.references import plan_references

    X = np.random.default_rng(1).uniform(-0.3, 0.3, (40, 3))
    a = plan_references([poses], [X], range(5), 3.0, first=0)
    assert plan_references([got], [X], range(5), 3.0, first=0) == a
    assert len(set(a.values())) >= 2
