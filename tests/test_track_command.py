"""The pieces of ``resection track`` that run beside the tracking: the motion plot drawn
by a second process (:mod:`resection.sequence.plot_worker`), the frame files written by a
thread (:class:`resection.sequence.outputs.FrameWriter`), numba's cache folder.

References: the plot process's picture against the same figure drawn in this process by
``plot_motion`` (whose curves ``test_sequence.py`` checks against the result); the frame
files against the records written.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from resection import InputError
from resection.sequence import motion_plots, plot_worker
from resection.sequence.outputs import FrameWriter, frame_path, read_frame
from resection.sequence.results import TrackResult


def _result(n: int = 40, failed=(7, 8)) -> TrackResult:
    """A small result with a known motion (a pitch oscillation) and two failed frames."""
    k = np.arange(n)
    ang = np.column_stack([0.1 * np.sin(k / 5), 2.0 * np.sin(k / 7), 0.05 * k / n])
    tr = np.column_stack([1e-3 * np.cos(k / 6), np.zeros(n), 2e-4 * k / n])
    status = np.array(["ok"] * n, dtype=object)
    status[list(failed)] = "failed"
    bad = status != "ok"
    ang[bad], tr[bad] = np.nan, np.nan
    rms = np.where(bad, np.nan, 0.15 + 0.01 * np.cos(k))
    z3 = np.zeros((n, 3))
    return TrackResult(
        frame=k, file=np.array([f"f{i}.tif" for i in k]), status=status.astype(str),
        reason=np.where(bad, "SolveError: x", "").astype(str), angles=ang, translation=tr,
        rms=rms, n_markers=np.full(n, 12), rvec=z3, tvec=z3, marker_frame=np.zeros(0, int),
        marker_id=np.zeros(0, str), marker_uv=np.zeros((0, 2)),
        marker_residual=np.zeros((0, 2)), fixed_camera=True, reference=0, n_computed=n,
        out_dir=None)


def _pixels(path) -> np.ndarray:
    import imageio.v3 as iio

    return np.asarray(iio.imread(path), float)


def test_plot_process_draws_the_figure_of_plot_motion(tmp_path, monkeypatch):
    res = _result()
    motion_plots.plot_motion(res, tmp_path / "here.png", fps=50.0)
    drawn_here = []
    monkeypatch.setattr(motion_plots, "plot_motion",
                        lambda *a, **k: drawn_here.append(a))  # the fallback, not used
    with plot_worker.MotionPlotter() as plotter:
        proc = plotter._proc
        assert proc is not None and proc.poll() is None  # started, waiting
        plotter.plot(res, tmp_path / "there.png", fps=50.0)
    assert not drawn_here  # the process drew it
    assert proc.returncode == 0
    a, b = _pixels(tmp_path / "here.png"), _pixels(tmp_path / "there.png")
    assert a.shape == b.shape == (840, 1080, 4)
    # the same figure: the same pixels but for a few of antialiasing, if any
    assert np.mean(np.any(a != b, axis=-1)) < 1e-3
    assert not list(tmp_path.glob(".*tmp*"))  # written through a temporary name


def test_plot_falls_back_to_this_process(tmp_path, monkeypatch):
    res = _result()

    def dead():  # a process that cannot draw (it exits at once, with an error)
        return subprocess.Popen([sys.executable, "-c", "import sys; sys.exit(3)"],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE)

    drawn_here = []
    plot_motion = motion_plots.plot_motion

    def spy(*a, **k):
        drawn_here.append(a)
        return plot_motion(*a, **k)

    monkeypatch.setattr(motion_plots, "plot_motion", spy)
    monkeypatch.setattr(plot_worker, "_start", dead)
    with plot_worker.MotionPlotter() as plotter:
        plotter.plot(res, tmp_path / "m.png")
    assert len(drawn_here) == 1
    assert _pixels(tmp_path / "m.png").shape == (840, 1080, 4)
    # no process at all (it could not be started): drawn here too
    monkeypatch.setattr(plot_worker, "_start", lambda: None)
    with plot_worker.MotionPlotter() as plotter:
        plotter.plot(res, tmp_path / "n.png")
    assert len(drawn_here) == 2 and (tmp_path / "n.png").is_file()


def test_plot_process_errors_are_plot_motions(tmp_path):
    res = _result()
    with plot_worker.MotionPlotter() as plotter, pytest.raises(InputError, match="fps"):
        plotter.plot(res, tmp_path / "m.png", fps=-1.0)
    with plot_worker.MotionPlotter() as plotter, \
            pytest.raises(InputError, match="unknown picture format"):
        plotter.plot(res, tmp_path / "m.xyz")
    assert not list(tmp_path.iterdir())


def test_plot_process_ignores_ctrl_c_and_ends_unused():
    with plot_worker.MotionPlotter() as plotter:
        proc = plotter._proc
        deadline = time.monotonic() + 60.0
        while not _ignores_sigint(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.02)  # until the process has set its handler
        proc.send_signal(signal.SIGINT)  # the terminal sends it to the process group
        time.sleep(0.3)
        assert proc.poll() is None
    assert proc.returncode == 0 and proc.stderr.closed


def _ignores_sigint(pid: int) -> bool:
    """Whether the process ignores SIGINT (Linux: the SigIgn mask in /proc)."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as fh:
            mask = next(line for line in fh if line.startswith("SigIgn:")).split()[1]
    except (OSError, StopIteration):
        return False
    return bool(int(mask, 16) & (1 << (signal.SIGINT - 1)))


def test_frame_writer_writes_every_record_and_raises_its_errors(tmp_path, monkeypatch):
    from resection.sequence import outputs

    records = [{"frame": i, "version": 3, "status": "ok", "x": list(range(i))}
               for i in range(40)]
    writer = FrameWriter(tmp_path)
    for d in records:
        writer.write(d)
    writer.flush()
    writer.close()
    for d in records:
        assert read_frame(frame_path(tmp_path, d["frame"])) == d
    # a full disk in the thread: raised by write() or flush(), as a direct write would
    real = outputs.atomic_write_text

    def full(path, text, **kw):
        if path.name == frame_path(tmp_path, 7).name:
            raise OSError(28, "No space left on device")
        real(path, text, **kw)

    monkeypatch.setattr(outputs, "atomic_write_text", full)
    writer = FrameWriter(tmp_path / "again")
    (tmp_path / "again").mkdir()
    with pytest.raises(OSError, match="No space left"):
        for d in records:
            writer.write(d)
        writer.flush()
    writer.close()
    written = sorted(p.name for p in (tmp_path / "again").glob("frame_*.json"))
    assert frame_path(tmp_path, 6).name in written
    assert frame_path(tmp_path, 7).name not in written
    assert json.loads((tmp_path / "again" / written[0]).read_text()) == records[0]


def test_numba_cache_falls_back_to_a_writable_folder(tmp_path, monkeypatch):
    from numba.core import config

    from resection._numba_cache import ensure_numba_cache

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setattr(config, "CACHE_DIR", config.CACHE_DIR)  # restored afterwards
    blocked = tmp_path / "blocked"
    blocked.write_text("a file where a folder should be: unwritable, even for root")
    ok = tmp_path / "ok"
    # the sources' folders writable: numba's own choice
    assert ensure_numba_cache([str(ok / "a"), str(ok / "b")], str(blocked / "u"),
                              str(blocked / "f")) is None
    # read-only sources, writable user-wide folder: numba's own choice too
    assert ensure_numba_cache([str(blocked / "a")], str(ok / "u"), str(blocked / "f")) is None
    # neither: the fallback folder, given to numba
    fb = tmp_path / "fallback"
    assert ensure_numba_cache([str(blocked / "a")], str(blocked / "u"), str(fb)) == str(fb)
    assert config.CACHE_DIR == str(fb) and fb.is_dir()
    # nowhere to write: one line that says what to do
    with pytest.raises(InputError, match="NUMBA_CACHE_DIR"):
        ensure_numba_cache([str(blocked / "a")], str(blocked / "u"), str(blocked / "f"))
    # a cache folder set by the user is left alone
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert ensure_numba_cache([str(blocked / "a")], str(blocked / "u"),
                              str(blocked / "f")) is None


def test_every_command_checks_numba_cache_first(tmp_path, monkeypatch, capsys):
    """Both command lines check numba's cache before any work: where no folder can be
    written, a ``resection`` and a ``selfillum`` command end with the one-line error
    (not numba's traceback at the kernels' import); the folders checked are those of
    every cached kernel of both packages."""
    from resection import _numba_cache
    from resection.cli.main import main as resection_main
    from selfillum.cli.main import main as selfillum_main

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setattr(_numba_cache, "_writable", lambda folder: False)
    monkeypatch.setattr(_numba_cache, "_user_wide", lambda: None)
    out = tmp_path / "corner"
    assert selfillum_main(["corner", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "NUMBA_CACHE_DIR" in err and "selfillum corner" in err
    assert not out.exists()
    # every folder of the packages with a cached kernel is among those checked
    from pathlib import Path

    root = Path(_numba_cache.__file__).resolve().parents[1]
    kernels = {p.parent.relative_to(root).as_posix() for pkg in ("resection", "selfillum")
               for p in (root / pkg).rglob("*.py") if "cache=True" in p.read_text()}
    assert kernels and kernels <= set(_numba_cache.KERNEL_FOLDERS), kernels
    img = tmp_path / "img.npy"
    np.save(img, np.zeros((32, 32), np.float32))
    assert resection_main(["detect", str(img), "--diameter", "5", "--out",
                           str(tmp_path / "c.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "NUMBA_CACHE_DIR" in err and "resection detect" in err
    assert not (tmp_path / "c.csv").exists()
