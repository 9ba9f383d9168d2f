"""Fault cases of `track` runs: resume recomputes changed frames, the output folder is
locked and a stale lock is taken over, failures name the file (issue 10 items 2-3).
The family of tests/test_faults.py."""

from __future__ import annotations

import os

import numpy as np
import pytest

from resection import InputError

# --------------------------------------------------------------------------------------
# track: resume knows changed frames, the output folder is locked, failures name the file
# --------------------------------------------------------------------------------------


def _track_args(files, out, frames=None):
    frames = frames if frames is not None else files["frames"]
    return ["track", *map(str, frames), "--camera",
            files["camera"], "--markers", files["markers"], "--diameter", "5.6", "--out",
            str(out), "--no-progress", "--workers", "1"]


@pytest.fixture(scope="module")
def two_sequences(tmp_path_factory):
    """Sequences A and B: the same model, camera and markers pitching opposite ways."""
    from scenes.moving_model import pitch_oscillation, write_sequence

    base = tmp_path_factory.mktemp("seqAB")
    a = pitch_oscillation(8, amplitude_deg=2.0, frequency_hz=3.0)
    b = pitch_oscillation(8, amplitude_deg=-2.0, frequency_hz=3.0, seed=1)
    return a, write_sequence(a, base / "A"), b, write_sequence(b, base / "B")


def test_track_resume_recomputes_frames_whose_files_were_replaced(two_sequences, tmp_path,
                                                                   capsys):
    """Issue 10 item 2: B's frames copied over A's names (``cp -p``: same names, same sizes,
    same modification times). On today's main the second run said '0 computed now' and
    reported A's motion; it recomputes every frame and reports B's."""
    import shutil

    from resection.cli.main import main
    from resection.sequence import read_track

    a, fa, b, fb = two_sequences
    frames = [shutil.copy2(f, tmp_path / os.path.basename(f)) for f in fa["frames"]]
    out = tmp_path / "out"
    assert main(_track_args(fa, out, frames)) == 0
    assert "8/8 frames solved (8 computed now)" in capsys.readouterr().out
    np.testing.assert_allclose(read_track(out).angles, np.degrees(a.angles), atol=0.01)
    for src, dst in zip(fb["frames"], frames, strict=True):
        shutil.copy2(src, dst)  # keeps the size and the modification time
        assert os.stat(src).st_mtime_ns == os.stat(dst).st_mtime_ns
    assert main(_track_args(fa, out, frames)) == 0
    assert "8/8 frames solved (8 computed now)" in capsys.readouterr().out
    got = read_track(out).angles
    np.testing.assert_allclose(got, np.degrees(b.angles), atol=0.01)
    assert np.abs(got[1:, 1] - np.degrees(a.angles[1:, 1])).max() > 1.0  # not A's any more
    # untouched files are not recomputed
    assert main(_track_args(fa, out, frames)) == 0
    assert "(0 computed now)" in capsys.readouterr().out


def test_track_resume_recomputes_a_repaired_frame_and_names_failed_files(two_sequences,
                                                                         tmp_path, capsys):
    """Issue 10 item 2 (a repaired corrupt frame stayed 'failed' with its old reason) and
    item 6 (a failed frame's reason did not name its file)."""
    import shutil

    from resection.cli.main import main
    from resection.sequence import read_track

    a, fa, _, _ = two_sequences
    frames = [shutil.copy2(f, tmp_path / os.path.basename(f)) for f in fa["frames"]]
    good3 = np.load(frames[3])
    np.save(frames[3], np.full((100, 256), 1000.0, np.float32))  # wrong size
    np.save(frames[5], np.full((256, 256), np.nan, np.float32))  # nothing to see
    out = tmp_path / "out"
    assert main(_track_args(fa, out, frames)) == 0
    text = capsys.readouterr().out
    assert "6/8 frames solved" in text
    back = read_track(out)
    assert back.status.tolist() == ["ok"] * 3 + ["failed", "ok", "failed", "ok", "ok"]
    for i in (3, 5):  # the API's reason (and poses.csv's) names the file
        assert str(frames[i]) in back.reason[i], back.reason[i]
    assert "256x100" in back.reason[3]
    np.save(frames[3], good3)  # repaired
    assert main(_track_args(fa, out, frames)) == 0
    assert "7/8 frames solved (1 computed now)" in capsys.readouterr().out
    back = read_track(out)
    assert back.ok[3] and back.reason[3] == ""
    np.testing.assert_allclose(back.angles[3], np.degrees(a.angles[3]), atol=0.01)


_HOLDER = """
import sys, time
from resection.io.lock import lock_folder
with lock_folder(sys.argv[1], command="test holder"):
    print("held", flush=True)
    time.sleep(120)
"""


def _holder(folder):
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    p = subprocess.Popen([sys.executable, "-c", _HOLDER, str(folder)], env=env,
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    return p


def test_track_refuses_an_output_folder_in_use_and_takes_over_a_stale_lock(two_sequences,
                                                                           tmp_path, capsys):
    """Issue 10 item 3: two runs into one --out both exited 0 and the folder held only one
    of them. The second run now gets a one-line error naming the holder (pid, host, start);
    the lock of a process that died (kill -9) is taken over."""
    import signal
    import socket

    from resection.cli.main import main
    from resection.io.lock import LOCK_NAME, read_lock

    _, fa, _, _ = two_sequences
    out = tmp_path / "out"
    out.mkdir()
    holder = _holder(out)
    try:
        rec = read_lock(out)
        assert rec["pid"] == holder.pid and rec["host"] == socket.gethostname()
        assert rec["started"].endswith("Z")
        assert main(_track_args(fa, out, fa["frames"][:3])) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1
        assert f"process {holder.pid} on {socket.gethostname()}" in err and "in use" in err
        assert rec["started"] in err
        assert not (out / "poses.csv").exists() and not list((out / "frames").glob("*.json"))
    finally:
        os.kill(holder.pid, signal.SIGKILL)
        holder.wait()
        holder.stdout.close()
    # the dead holder's lock file is still there, naming it: a stale lock, taken over
    assert (out / LOCK_NAME).exists() and read_lock(out)["pid"] == holder.pid
    assert main(_track_args(fa, out, fa["frames"][:3])) == 0
    assert "3/3 frames solved" in capsys.readouterr().out
    assert not (out / LOCK_NAME).exists()  # released at the end of the run


def test_lock_is_exclusive_within_one_process_too(tmp_path):
    """Two runs of the API in one process (two threads, or nested calls) into one folder."""
    from resection.io.lock import lock_folder

    with lock_folder(tmp_path, command="first"):
        with pytest.raises(InputError, match=rf"in use by process {os.getpid()} .*first"):
            with lock_folder(tmp_path, command="second"):
                pass
    with lock_folder(tmp_path, command="third") as me:  # released: free again
        assert me["command"] == "third"


def test_lock_without_flock_uses_the_holder_pid(tmp_path, monkeypatch):
    """Where flock is missing (Windows, some network filesystems) the lock file is created
    exclusively: refused while its process lives, taken over once it is dead."""
    import json
    import socket
    import subprocess
    import sys

    from resection.io import lock

    monkeypatch.setattr(lock, "fcntl", None)
    with lock.lock_folder(tmp_path, command="first"):
        with pytest.raises(InputError, match=rf"in use by process {os.getpid()} "):
            with lock.lock_folder(tmp_path, command="second"):
                pass
    assert not (tmp_path / lock.LOCK_NAME).exists()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / lock.LOCK_NAME).write_text(json.dumps(
        {"pid": dead.pid, "host": socket.gethostname(), "started": "x", "command": "old"}))
    with lock.lock_folder(tmp_path, command="third") as me:
        assert lock.read_lock(tmp_path)["pid"] == os.getpid() == me["pid"]


def test_track_interrupted_counts_the_frames_of_a_stack(two_sequences, tmp_path, monkeypatch,
                                                        capsys):
    """Issue 34 item 19: a 300-frame stack in one file, interrupted under --workers, said
    '66/1 frames finished' (the count of files). It counts the stack's frames."""
    from resection.cli.main import main
    from resection.sequence import run

    _, fa, _, _ = two_sequences
    stack = np.stack([np.load(f) for f in fa["frames"]]).astype(np.float32)
    np.save(tmp_path / "run.npy", stack)

    def interrupted(*a, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(run, "run_frames", interrupted)
    assert main(_track_args(fa, tmp_path / "out", [tmp_path / "run.npy"])) == 130
    err = capsys.readouterr().err
    assert f"interrupted: 0/{len(stack)} frames finished" in err, err
