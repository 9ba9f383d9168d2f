"""``selfillum unsteady`` on bad inputs (issue 34, items 2, 14, 15, 16): every case a one-line
error naming the option or file (exit 2) before any heavy step, or a correct run; never a
traceback, a hang, or exit 0 with a wrong or missing result. The family of
tests/test_faults.py; the run is tests/unsteady_cases.py's small two-camera scene."""

from __future__ import annotations

import json
import os
import re

import numpy as np
import pytest
from unsteady_cases import args, copy_run, refused, run_cli, small_run  # noqa: F401


@pytest.fixture
def case(small_run, tmp_path):  # noqa: F811 - the fixture imported above
    return copy_run(small_run, tmp_path / "case")


_TIMES = {"setup": 0.0, "phase1": 0.0, "phase2": 0.0, "first_frame": 0.0}


def _no_view_factors(monkeypatch):
    """Make the first heavy step (the view factors) fail the test if it is reached."""
    # the modules that bind these names when imported, imported first (with the real
    # functions: the patch must not outlive the test through them)
    import selfillum.corner  # noqa: F401
    import selfillum.images.image_correction  # noqa: F401
    import selfillum.transport.coupling as coupling
    import selfillum.transport.viewfactors as vf
    import selfillum.unsteady.run  # noqa: F401

    def boom(*a, **k):
        raise AssertionError("the view factors were computed before the input check")

    monkeypatch.setattr(vf, "view_factors", boom)
    monkeypatch.setattr(coupling, "coupled_view_factors", boom)


# ------------------------------------------------------------------- item 2: one frame


def test_one_frame_refused_with_the_frames_it_needs(case, capsys, monkeypatch):
    """Issue 34 item 2: one frame exited 0 with an all-NaN dCp. Refused, naming the frames
    the run needs (Phase 2's polynomial of order 6 in time needs 8), before the view
    factors; a one-frame video the same way."""
    _no_view_factors(monkeypatch)
    err = refused(case, capsys, "--number-frames", "1")
    assert "number_frames = 1" in err and "needs at least 8 frames" in err
    v = np.load(case / "cam01.npy")
    np.save(case / "cam01.npy", v[:1])
    np.save(case / "cam02.npy", np.load(case / "cam02.npy")[:1])
    err = refused(case, capsys)
    assert "cam01.npy: 1 frame;" in err and "needs at least 8 frames" in err


def test_si_line_never_names_a_flag_not_given(case, capsys, monkeypatch):
    """Issue 34 item 2: a run with the SI removal whose change could not be measured
    printed 'not removed (--no-si)' although --no-si was not given."""
    import selfillum.unsteady as su
    from selfillum.unsteady import UnsteadyResult

    def fake(cfg):
        return UnsteadyResult(cfg.out, 12, 10, (12, 10), 0.5, float("nan"), float("nan"), 0,
                              (cfg.out,), 100.0, 10.0, (12, 10), _TIMES, si=cfg.si)

    monkeypatch.setattr(su, "run_unsteady", fake)
    rc, out, _ = run_cli(args(case), capsys)
    assert rc == 0 and "--no-si" not in out and "self-illumination: removed" in out
    rc, out, _ = run_cli(args(case, "--no-si"), capsys)
    assert rc == 0 and "not removed (--no-si)" in out


# ------------------------------------------------------------------- item 14/15: options


@pytest.mark.parametrize("flag, value, named", [
    ("--fps", "inf", "--fps inf"),
    ("--fps", "1e-320", "--fps 1e-320"),
    ("--tinf", "-500", "--tinf -500"),
    ("--tinf", "1e300", "--tinf 1e+300"),
    ("--memory", "inf", "--memory inf"),
    ("--seed", str(10**23), f"--seed {10**23}: out of range"),
    ("--scheduler", "not-a-url", "--scheduler 'not-a-url'"),
    ("--workers", "-1", "--workers -1"),
    ("--psd-bands", "1000000", "--psd-bands 1000000"),
    ("--rays", "0", "--rays 0"),
])
def test_numeric_options_checked_before_any_work(case, capsys, monkeypatch, flag, value,
                                                 named):
    """Issue 34 items 14-15: --fps inf / 1e-320 wrote times of 0 or inf, --tinf below
    absolute zero was taken, --memory inf, --tinf 1e300, a 24-digit --seed, a
    --scheduler that is no address and --workers -1 gave tracebacks, --psd-bands 1e6 took
    10 GB: each is now one line naming the option, before the view factors."""
    _no_view_factors(monkeypatch)
    err = refused(case, capsys, flag, value)
    assert named in err, err


def test_workers_capped_at_the_cores_with_a_message(case, capsys, monkeypatch):
    """Issue 34 item 14: --workers 1000 started up to 86 processes. Capped at the cores
    this process may use, and said so."""
    import selfillum.unsteady as su
    from selfillum.unsteady import UnsteadyResult

    seen = {}

    def fake(cfg):
        seen["workers"] = cfg.workers
        return UnsteadyResult(cfg.out, 12, 10, (12, 10), 0.5, 0.0, 0.0, 0, (cfg.out,), 100.0,
                              10.0, (12, 10), _TIMES)

    monkeypatch.setattr(su, "run_unsteady", fake)
    cores = len(os.sched_getaffinity(0))
    rc, _, err = run_cli(args(case, "--workers", "1000"), capsys)
    assert rc == 0 and seen["workers"] == cores
    assert f"--workers 1000: capped at the {cores} core" in err


@pytest.mark.parametrize("column, value, named", [
    ("TTF", "-500", "TTF) = -500 deg F is at or below absolute zero"),
    ("PS", "-3", "PS = -3"),
    ("MACH", "1e200", "MACH = 1e+200 is out of range"),
])
def test_tunnel_conditions_checked(case, capsys, monkeypatch, column, value, named):
    """Issue 34 item 14: TTF below absolute zero, a negative PS and MACH 1e200 were
    accepted (and made a Tinf of absolute zero, a gain from a negative pressure)."""
    _no_view_factors(monkeypatch)
    lines = (case / "run.wtd").read_text().splitlines()
    h = next(i for i, line in enumerate(lines) if line.startswith("#") and "MACH" in line)
    names, vals = lines[h].lstrip("# ").split("\t"), lines[h + 1].split("\t")
    vals[names.index(column)] = value
    lines[h + 1] = "\t".join(vals)
    (case / "run.wtd").write_text("\n".join(lines) + "\n")
    err = refused(case, capsys)
    assert "run.wtd" in err and named in err, err


def test_paint_coefficients_that_make_an_infinite_gain(case, capsys, monkeypatch):
    """Issue 34 item 14: coefficients of 1e308 wrote infinite dCp with exit 0."""
    _no_view_factors(monkeypatch)
    text = (case / "paint.txt").read_text()
    (case / "paint.txt").write_text(re.sub(r"(?m)^c = .*$", "c = 1e308", text))
    err = refused(case, capsys)
    assert "paint.txt" in err and "gain is not finite" in err


def test_all_black_video_refused(case, capsys, monkeypatch):
    """Issue 34 item 14: an all-black video exited 0 with 100 % NaN."""
    _no_view_factors(monkeypatch)
    np.save(case / "cam02.npy", np.zeros_like(np.load(case / "cam02.npy")))
    err = refused(case, capsys)
    assert "cam02.npy: frame 0 is blank (every pixel 0)" in err


def _swap_calibrations(case):
    text = (case / "run.inp").read_text()
    text = text.replace("cam01.json", "camXX.json").replace("cam02.json", "cam01.json")
    (case / "run.inp").write_text(text.replace("camXX.json", "cam02.json"))


def test_swapped_or_shared_calibrations_refused(case, capsys, monkeypatch):
    """Issue 34 item 14: two cameras' calibrations swapped, or both given the same one,
    exited 0 with an error 2-4x the signal. map's camera checks now hold here: each
    camera's targets must land on the dark spots of its first frame, and no two cameras
    share a calibration."""
    _no_view_factors(monkeypatch)
    _swap_calibrations(case)
    err = refused(case, capsys)
    assert re.search(r"cam0[12]\.json does not fit .*cam0[12]\.npy \(frame 0, camera \d\)",
                     err), err
    text = (case / "run.inp").read_text()
    (case / "run.inp").write_text(text.replace("cam02.json", "cam01.json"))
    err = refused(case, capsys)
    assert "camera 2 has the same calibration as camera 1" in err


def test_a_correct_run_passes_the_camera_checks(case, capsys):
    """The checks refuse no good run: the two cameras' own calibrations map, and the
    output holds a dCp (the accuracy itself is tests/test_unsteady.py's)."""
    import h5py

    rc, out, err = run_cli(args(case, "--registration", "none", "--no-si"), capsys)
    assert rc == 0, err
    with h5py.File(case / "out.h5") as f:
        assert np.isfinite(f["dcp"][()]).any(axis=0).mean() > 0.2


# ------------------------------------------------------------------- videos and targets


@pytest.mark.parametrize("rate, shown", [("inf", "inf"), ("1e-320", "1e-320"),
                                         ("abc", "nan"), ("nan", "nan")])
def test_cih_rate_checked(case, capsys, rate, shown):
    """Issue 34 item 15: a .cih rate of inf, 1e-320 or abc gave a traceback (and NaN
    blamed --fps, never given): without --fps the video is named, with --fps the header's
    rate is not needed and the run goes on."""
    import pyMRAW

    frames = np.clip(np.load(case / "cam01.npy"), 0, 65535).astype(np.uint16)
    pyMRAW.save_mraw(frames, str(case / "cam01.cih"), bit_depth=16,
                     info_dict={"Record Rate(fps)": 1000})
    cih = (case / "cam01.cih").read_text()
    (case / "cam01.cih").write_text(re.sub(r"Record Rate\(fps\)\s*:\s*\S+",
                                           f"Record Rate(fps) : {rate}", cih))
    (case / "run.inp").write_text((case / "run.inp").read_text().replace("cam01.npy",
                                                                         "cam01.mraw"))
    argv = args(case)
    k = argv.index("--fps")
    del argv[k:k + 2]
    before = sorted(p.name for p in case.iterdir())
    rc, _, err = run_cli(argv, capsys)
    err = err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert f"cam01.mraw: its header's frame rate {shown} is not a frame rate" in err, err
    assert "give --fps" in err and sorted(p.name for p in case.iterdir()) == before
    rc, _, err = run_cli(args(case, "--registration", "none", "--no-si"), capsys)
    assert rc == 0, err


@pytest.mark.parametrize("rate", [float("inf"), 1e-320])
def test_cine_rate_checked(tmp_path, rate):
    """Issue 34 item 15: a .cine whose frame rate is inf or 1e-320 gave a traceback (or
    times of 0): without --fps the video is named."""
    import struct
    import types

    from test_io_video import _write_cine

    from resection.errors import InputError
    from selfillum.unsteady.inputs import open_videos

    p = tmp_path / "run.cine"
    _write_cine(p, np.full((10, 8, 8), 100, np.uint16))
    data = bytearray(p.read_bytes())
    data[84 + 10400:84 + 10408] = struct.pack("<d", rate)  # the setup's dFrameRate
    p.write_bytes(bytes(data))
    cfg = types.SimpleNamespace(cameras=[types.SimpleNamespace(video=p, number=1)],
                                number_frames=-1, fps=None, source="deck", filter="none",
                                filter_size=3)
    with pytest.raises(InputError, match=rf"run\.cine: its header's frame rate {rate!r} is "
                       r"not a frame rate"):
        open_videos(cfg)


def test_npy_video_of_no_frames(case, capsys):
    """Issue 34 item 15: an NPY video of 0 frames gave a traceback."""
    np.save(case / "cam02.npy", np.zeros((0, 150, 200), np.float32))
    err = refused(case, capsys)
    assert "cam02.npy: a stack of 0 frames" in err


def test_camera_number_of_30_digits(case, capsys, monkeypatch):
    """Issue 34 item 15: a 30-digit @camera number gave a traceback after the whole
    run (writing it into the output)."""
    _no_view_factors(monkeypatch)
    text = (case / "run.inp").read_text()
    (case / "run.inp").write_text(text.replace("number = 2", "number = " + "9" * 30))
    err = refused(case, capsys)
    assert "run.inp:" in err and "@camera number 999999" in err and "out of range" in err


def test_target_diameter_of_1e30(case, capsys, monkeypatch):
    """Issue 34 item 15: a .tgts diameter of 1e30 gave a traceback in the tracking."""
    _no_view_factors(monkeypatch)
    lines = (case / "model.tgts").read_text().splitlines()
    parts = lines[2].split()
    parts[7] = "1e30"
    lines[2] = " ".join(parts)
    (case / "model.tgts").write_text("\n".join(lines) + "\n")
    err = refused(case, capsys, "--registration", "track")
    assert "model.tgts: T1's diameter 1e+30 is not between 0 and the model's size" in err


def test_filter_size_beyond_the_frame(case, capsys, monkeypatch):
    """Issue 34 item 16: filter_size = 100001 hung (a Gaussian of that size per frame)."""
    _no_view_factors(monkeypatch)
    text = (case / "run.inp").read_text()
    text = text.replace("filter = none", "filter = gaussian")
    (case / "run.inp").write_text(text.replace("filter_size = 3", "filter_size = 100001"))
    err = refused(case, capsys)
    assert "run.inp: filter_size 100001 is too large (at most 101 pixels" in err


@pytest.mark.parametrize("key", ["sds", "targets", "calibration"])
@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_deck_paths_get_the_command_line_checks(case, capsys, key, kind):
    """Issue 34 item 16: a deck naming a FIFO or /dev/zero as its sds, targets or
    calibration hung: the command line's checks were skipped for a deck's paths."""
    if kind == "fifo":
        target = case / "pipe"
        os.mkfifo(target)
    else:
        target = "/dev/zero"
    text = (case / "run.inp").read_text()
    old = {"sds": "$dir/run.wtd", "targets": "$dir/model.tgts",
           "calibration": "$dir/cam01.json"}[key]
    (case / "run.inp").write_text(text.replace(old, str(target), 1))
    err = refused(case, capsys)
    what = "a FIFO (named pipe)" if kind == "fifo" else "a character device"
    assert "run.inp:" in err and f"{key} {target}: is {what}" in err, err


def test_options_recorded_as_given(case, capsys):
    """The flags' default --psd-bands is 8, or the spectrum's frequencies when fewer (12
    frames: 6); an explicit value above them is refused (test above)."""
    import h5py

    rc, _, err = run_cli(args(case, "--registration", "none", "--no-si"), capsys)
    assert rc == 0, err
    with h5py.File(case / "out.h5") as f:
        assert f["psd/band_psd"].shape[1] == 6
        assert json.loads(f.attrs["options"])["psd_bands"] == 6
