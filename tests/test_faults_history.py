"""Fault cases of time histories (``resection map --out P.h5``): a full disk, kill -9 and
failed writes leave the committed frames readable, and a resume carries on or refuses with
the reason; a resume checks what it appends to (issue 25 items 1, 6). The family of
tests/test_faults.py."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import trimesh
from fault_files import corner_files, isolated

from resection import InputError
from resection.io.history import HistoryWriter, read_history, xdmf_path

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _values(k, n):
    return (np.arange(n) * 0.5 + k).astype(np.float32)


class _FullDisk:
    """An ``opener`` whose history file refuses writes with ENOSPC once ``budget`` bytes
    were written to it (the disk fills up), as a kernel write would."""

    def __init__(self, budget):
        self.budget = budget

    def __call__(self, path, mode):
        fh = open(path, mode)
        if not str(path).endswith(".h5"):
            return fh
        outer = self

        class Wrapped:
            def __getattr__(self, name):
                return getattr(fh, name)

            def write(self, b):
                if len(b) > outer.budget:
                    n = outer.budget
                    fh.write(bytes(b)[:n])  # a part goes through, as on a real disk
                    outer.budget = 0
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                outer.budget -= len(b)
                return fh.write(b)

        return Wrapped()


def test_failed_appends_never_touch_committed_frames(tmp_path):
    """The disk fills at every possible point of an append (ENOSPC injected in the write
    path of the file, a part of the failing write going through): the error is an OSError
    naming the file, the frames committed before stay readable and exact, and a resume
    with room again completes the run. On today's main such a failure corrupted the file
    ("invalid dataset size") or crashed the process."""
    mesh = trimesh.creation.icosphere(subdivisions=1)
    n = len(mesh.vertices)
    path = tmp_path / "P.h5"
    with HistoryWriter(path, mesh) as w:
        for k in range(3):
            w.append(_values(k, n), time=0.1 * k, index=k)
    size0 = path.stat().st_size
    seen_counts = set()
    for budget in [0, 1, 40, 300, 2000, 9000, 30000, 70000, 150000, 400000, 1000000, 2500000]:
        before = read_history(path).n_frames
        with pytest.raises(OSError) as exc:
            with HistoryWriter(path, mesh, resume=True, opener=_FullDisk(budget)) as w:
                for k in range(w.n_frames, 400):
                    w.append(_values(k, n), time=0.1 * k, index=k)
        assert exc.value.errno == errno.ENOSPC and str(path) in str(exc.value)
        h = read_history(path)
        assert h.n_frames >= before
        seen_counts.add(h.n_frames)
        for k in range(h.n_frames):
            np.testing.assert_array_equal(h.values[k], _values(k, n))
        np.testing.assert_allclose(h.times, 0.1 * np.arange(h.n_frames), rtol=1e-15)
        assert not (tmp_path / "P.h5.journal").exists()
    assert len(seen_counts) > 3 and path.stat().st_size > size0  # failures at many points
    with HistoryWriter(path, mesh, resume=True) as w:
        for k in range(w.n_frames, 60):
            w.append(_values(k, n), time=0.1 * k, index=k)
    h = read_history(path)
    assert h.n_frames == 60
    np.testing.assert_array_equal(h.values[59], _values(59, n))


def test_a_journal_left_by_a_dead_writer_is_read_through_and_rolled_back(tmp_path):
    """A writer that died between a commit and the next (its journal left beside the
    file): a reader sees the committed frames without writing; the next writer rolls the
    file back and carries on."""
    mesh = trimesh.creation.icosphere(subdivisions=1)
    n = len(mesh.vertices)
    path = tmp_path / "P.h5"
    w = HistoryWriter(path, mesh)
    for k in range(4):
        w.append(_values(k, n), time=float(k), index=k)
    # frame 4 half written: values and tables changed in place, never committed
    w._f["values"].create_dataset("000004", data=np.zeros(n, np.float32))
    w._f["frames/time"].resize(5, axis=0)
    w._f.attrs["n_frames"] = 5
    w._f.flush()
    # what the process leaves when it dies now: the file as it is and its journal
    raw = path.read_bytes()
    journal = (tmp_path / "P.h5.journal").read_bytes()
    w._abandon()
    path.write_bytes(raw)
    (tmp_path / "P.h5.journal").write_bytes(journal)
    assert len(journal) > 16
    h = read_history(path)  # through the journal, read-only
    assert h.n_frames == 4 and path.read_bytes() == raw
    np.testing.assert_array_equal(h.values[3], _values(3, n))
    with HistoryWriter(path, mesh, resume=True) as w2:
        assert w2.n_frames == 4
        w2.append(_values(4, n), time=4.0, index=4)
    assert read_history(path).n_frames == 5
    assert not (tmp_path / "P.h5.journal").exists()


def test_a_second_writer_is_refused_and_never_undoes_the_first(tmp_path):
    """While a writer works (its journal holds the bytes of its frame in progress), a second
    writer (another process) is refused; the first writer's journal is untouched and its
    run ends with every frame."""
    mesh = trimesh.creation.icosphere(subdivisions=1)
    n = len(mesh.vertices)
    path = tmp_path / "P.h5"
    w = HistoryWriter(path, mesh)
    w.append(_values(0, n), time=0.0, index=0)
    w._f["frames/time"][0] = 5.0  # a change in progress, not committed yet
    w._f.flush()
    journal = (tmp_path / "P.h5.journal").read_bytes()
    assert len(journal) > 16  # the committed bytes it overwrote
    code = ("import sys, trimesh\nfrom resection.io.history import HistoryWriter\n"
            "HistoryWriter(sys.argv[1], trimesh.creation.icosphere(subdivisions=1), "
            "resume=True)\n")
    r = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True,
                       text=True, env=_env())
    assert r.returncode != 0 and "another process has this time history open" in r.stderr, \
        r.stderr
    assert (tmp_path / "P.h5.journal").read_bytes() == journal
    w.append(_values(1, n), time=1.0, index=1)
    w.close()
    h = read_history(path)
    np.testing.assert_array_equal(h.values[1], _values(1, n))
    assert h.times.tolist() == [5.0, 1.0]  # the first writer's change, committed by it


def test_a_file_of_the_users_named_like_the_journal_is_never_touched(tmp_path):
    """P.h5.journal that is not a journal of ours (the user's notes): the writer refuses by
    name instead of truncating or removing it; a reader reads the history as it is."""
    mesh = trimesh.creation.icosphere(subdivisions=1)
    n = len(mesh.vertices)
    path = tmp_path / "P.h5"
    with HistoryWriter(path, mesh) as w:
        w.append(_values(0, n), time=0.0, index=0)
    notes = tmp_path / "P.h5.journal"
    notes.write_text("my notes on run P\n")
    with pytest.raises(InputError, match="P.h5.journal: exists and is not the journal"):
        HistoryWriter(path, mesh, resume=True)
    assert notes.read_text() == "my notes on run P\n"
    assert read_history(path).n_frames == 1
    path.unlink()  # a new history of that name: still refused, the notes kept
    with pytest.raises(InputError, match="P.h5.journal: exists and is not the journal"):
        HistoryWriter(path, mesh)
    assert notes.read_text() == "my notes on run P\n"


def test_a_journal_of_a_removed_history_is_not_applied_to_a_new_one(tmp_path):
    """A run died (its journal left), the user removed P.h5 and starts again: the old
    journal's records belong to the old file and must not be rolled into the new one."""
    mesh = trimesh.creation.icosphere(subdivisions=1)
    n = len(mesh.vertices)
    path = tmp_path / "P.h5"
    w = HistoryWriter(path, mesh)
    w.append(_values(0, n), time=0.0, index=0)
    w._f["frames/time"][0] = 7.0  # uncommitted
    w._f.flush()
    journal = (tmp_path / "P.h5.journal").read_bytes()
    w._abandon()
    (tmp_path / "P.h5.journal").write_bytes(journal)  # as a dead process leaves it
    path.unlink()
    finer = trimesh.creation.icosphere(subdivisions=3)  # another grid: another layout
    m = len(finer.vertices)
    with HistoryWriter(path, finer) as w2:
        for k in range(3):
            w2.append(_values(10 + k, m), time=float(k), index=k)
    h = read_history(path)
    assert h.times.tolist() == [0.0, 1.0, 2.0]
    np.testing.assert_array_equal(h.values[0], _values(10, m))


def _map_args(folder, out, frames, *extra):
    return [sys.executable, "-m", "resection.cli", "map", "--mesh",
            str(folder / "corner.ply"), "--camera", str(folder / "cam.json"), "--out",
            str(out), "--image", *map(str, frames), "--fps", "50", *extra]


def _frames(folder, n):
    img = np.load(folder / "img.npy")
    out = []
    for k in range(n):
        p = folder / f"f{k:03d}.npy"
        np.save(p, img + np.float32(k))
        out.append(p)
    return out


def _env():
    return {**os.environ, "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}


_DISK_SCRIPT = textwrap.dedent("""
    import json, os, resource, signal, subprocess, sys
    disk, args_first, args_all = sys.argv[1], json.loads(sys.argv[2]), json.loads(sys.argv[3])
    mount = sys.argv[-1] == "mount"
    if mount:
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=%s" % sys.argv[4], "tmpfs",
                        disk], check=True)
    res = {}
    r = subprocess.run(args_first, capture_output=True, text=True)
    res["first"] = [r.returncode, r.stderr]
    filler = os.path.join(disk, "filler")
    if mount:
        fd = os.open(filler, os.O_WRONLY | os.O_CREAT)  # the disk is filled up
        try:
            while True:
                os.write(fd, b"x" * 4096)
        except OSError:
            pass
        os.close(fd)
    else:  # no namespace: no file may grow past its size now (EFBIG), inherited by map
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        size = os.path.getsize(os.path.join(disk, "P.h5"))
        resource.setrlimit(resource.RLIMIT_FSIZE, (size + 3000, resource.RLIM_INFINITY))
    r = subprocess.run(args_all + ["--resume"], capture_output=True, text=True)
    res["full"] = [r.returncode, r.stderr]
    from resection.io.history import read_history
    h = read_history(os.path.join(disk, "P.h5"))
    res["after_full"] = h.values.tolist()
    if mount:
        os.unlink(filler)  # room again: the resume carries on
    else:
        resource.setrlimit(resource.RLIMIT_FSIZE, (resource.RLIM_INFINITY,) * 2)
    r = subprocess.run(args_all + ["--resume"], capture_output=True, text=True)
    res["resumed"] = [r.returncode, r.stderr]
    h = read_history(os.path.join(disk, "P.h5"))
    res["final"] = h.values.tolist()
    res["files"] = sorted(os.listdir(disk))
    # a fresh run on a disk that fills up in its middle (room for a few frames only)
    for name in ("P.h5", "P.xdmf", "filler"):
        if os.path.exists(os.path.join(disk, name)):
            os.unlink(os.path.join(disk, name))
    if mount:
        subprocess.run(["mount", "-o", "remount,size=128k", disk], check=True)
    else:
        resource.setrlimit(resource.RLIMIT_FSIZE, (109000, resource.RLIM_INFINITY))
    r = subprocess.run(args_all, capture_output=True, text=True)
    res["mid"] = [r.returncode, r.stderr]
    res["mid_values"] = read_history(os.path.join(disk, "P.h5")).values.tolist()
    if mount:
        subprocess.run(["mount", "-o", "remount,size=16m", disk], check=True)
    else:
        resource.setrlimit(resource.RLIMIT_FSIZE, (resource.RLIM_INFINITY,) * 2)
    r = subprocess.run(args_all + ["--resume"], capture_output=True, text=True)
    res["mid_resumed"] = [r.returncode, r.stderr]
    res["mid_final"] = read_history(os.path.join(disk, "P.h5")).values.tolist()
    res["mid_files"] = sorted(os.listdir(disk))
    print(json.dumps(res))
""")


@pytest.mark.slow
def test_map_history_survives_a_full_tmpfs(tmp_path):
    """Issue 25 item 1: `map --out P.h5` commits frames on a small tmpfs, the disk is
    filled, the run is resumed over more frames; then a fresh run on a tmpfs that fills up
    in its middle (without a mount namespace: a file-size limit, see
    fault_files.isolated). On today's main the process died with a
    segmentation fault and the committed frames became unreadable. Now: one line, exit 2,
    the committed frames intact; with room again the resume completes the run with the
    values of a clean run."""
    corner_files(tmp_path)
    frames = _frames(tmp_path, 12)
    disk = tmp_path / "disk"
    disk.mkdir()
    out = disk / "P.h5"
    first = _map_args(tmp_path, out, frames[:4])
    full = _map_args(tmp_path, out, frames)
    r = subprocess.run(isolated([_DISK_SCRIPT, disk, json.dumps(first), json.dumps(full),
                                 "4m"]), capture_output=True, text=True, env=_env(),
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert res["first"][0] == 0, res["first"]
    rc, err = res["full"]
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert ("No space left on device" in err or "File too large" in err) \
        and "Traceback" not in err
    committed = np.array(res["after_full"], dtype=np.float32)
    assert 4 <= len(committed) < 12
    assert res["resumed"][0] == 0, res["resumed"]
    final = np.array(res["final"], dtype=np.float32)
    # a clean run of the 12 frames, on a normal disk
    clean = tmp_path / "clean.h5"
    subprocess.run(_map_args(tmp_path, clean, frames), check=True, env=_env(),
                   capture_output=True)
    ref = read_history(clean).values
    np.testing.assert_array_equal(final, ref)
    np.testing.assert_array_equal(committed, ref[:len(committed)])
    assert set(res["files"]) - {"filler"} == {"P.h5", "P.xdmf"}  # no journal nor temporary
    # the disk filled in the middle of a fresh run: the frames before it stay, exact
    rc, err = res["mid"]
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    mid = np.array(res["mid_values"], dtype=np.float32)
    assert 1 <= len(mid) < 12, len(mid)
    np.testing.assert_array_equal(mid, ref[:len(mid)])
    assert res["mid_resumed"][0] == 0, res["mid_resumed"]
    np.testing.assert_array_equal(np.array(res["mid_final"], dtype=np.float32), ref)
    assert res["mid_files"] == ["P.h5", "P.xdmf"]


@pytest.mark.slow
def test_map_history_survives_kill_9(tmp_path):
    """kill -9 of `map --out P.h5` at random moments of a run (after a random number of
    committed frames, plus a random delay into the next): the file always reads, holding a
    prefix of the frames with their exact values; a resume completes it to what a clean run
    gives."""
    corner_files(tmp_path)
    frames = _frames(tmp_path, 60)
    clean = tmp_path / "clean.h5"
    subprocess.run(_map_args(tmp_path, clean, frames), check=True, env=_env(),
                   capture_output=True)
    ref = read_history(clean).values
    rng = np.random.default_rng(25)
    counts = []
    for trial in range(4):
        target, delay = int(rng.integers(1, 50)), float(rng.uniform(0.0, 0.03))
        out = tmp_path / f"k{trial}.h5"
        p = subprocess.Popen(_map_args(tmp_path, out, frames), env=_env(),
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        while p.poll() is None:  # watch the committed frames, read-only, as a reader would
            try:
                if read_history(out).n_frames >= target:
                    break
            except Exception:  # noqa: BLE001 - not there yet, or caught mid-commit
                pass
            time.sleep(0.002)
        time.sleep(delay)
        p.send_signal(signal.SIGKILL)
        p.wait()
        h = read_history(out)
        counts.append(h.n_frames)
        np.testing.assert_array_equal(h.values, ref[:h.n_frames])
        r = subprocess.run(_map_args(tmp_path, out, frames, "--resume"), env=_env(),
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        np.testing.assert_array_equal(read_history(out).values, ref)
        assert not (tmp_path / f"k{trial}.h5.journal").exists()
    assert sum(0 < c < 60 for c in counts) >= 3, counts  # the kills landed mid-run


def test_a_reader_holding_the_file_briefly_does_not_refuse_the_writer(tmp_path):
    """HDF5 readers hold a shared lock while the file is open: a writer that starts (or
    resumes) while a viewer reads waits for it (up to 2 s) instead of being refused."""
    import threading

    import h5py

    mesh = trimesh.creation.icosphere(subdivisions=1)
    n = len(mesh.vertices)
    path = tmp_path / "P.h5"
    with HistoryWriter(path, mesh) as w:
        w.append(_values(0, n), time=0.0, index=0)
    reader = h5py.File(path, "r")  # HDF5's shared lock on the file
    threading.Timer(0.3, reader.close).start()
    with HistoryWriter(path, mesh, resume=True) as w:
        w.append(_values(1, n), time=1.0, index=1)
    assert read_history(path).n_frames == 2


def test_ctrl_c_on_a_running_map_history(tmp_path):
    """Ctrl-C (SIGINT) in the middle of `map --out P.h5`: one line, exit 130; the frames
    committed before it stay, exact; no journal nor temporary file is left."""
    corner_files(tmp_path)
    frames = _frames(tmp_path, 200)
    out = tmp_path / "P.h5"
    p = subprocess.Popen(_map_args(tmp_path, out, frames), env=_env(),
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    while p.poll() is None:
        try:
            if read_history(out).n_frames >= 3:
                break
        except Exception:  # noqa: BLE001 - not there yet
            pass
        time.sleep(0.002)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130 and len(err.strip().splitlines()) == 1, err
    assert "interrupted" in err and "Traceback" not in err
    h = read_history(out)
    assert 3 <= h.n_frames < 200
    clean = tmp_path / "clean.h5"
    subprocess.run(_map_args(tmp_path, clean, frames[:h.n_frames]), check=True, env=_env(),
                   capture_output=True)
    np.testing.assert_array_equal(h.values, read_history(clean).values)
    clean.unlink()
    (tmp_path / "clean.xdmf").unlink()
    assert sorted(q.name for q in tmp_path.iterdir() if q.name.startswith((".P", "P."))) \
        == ["P.h5", "P.xdmf"]


# --------------------------------------------------------------------------------------
# a resume checks what it appends to (issue 25 item 6)
# --------------------------------------------------------------------------------------


def _run(argv, capsys):
    from resection.cli import main

    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_map_resume_refuses_other_fps_images_camera_or_settings(tmp_path, capsys):
    """On today's main another --fps, other images, another camera or another
    --max-obliqueness were all appended to the earlier frames, exit 0."""
    corner_files(tmp_path)
    frames = _frames(tmp_path, 5)
    out = tmp_path / "P.h5"
    base = ["map", "--mesh", tmp_path / "corner.ply", "--out", out]
    cam = ["--camera", tmp_path / "cam.json"]
    assert _run([*base, *cam, "--image", *frames[:3], "--fps", "50"], capsys)[0] == 0
    raw = out.read_bytes()
    other = tmp_path / "other.npy"
    np.save(other, np.load(frames[1]) * 2)
    from resection.io.cameras import read_camera, write_camera

    c = read_camera(tmp_path / "cam.json")
    write_camera(tmp_path / "cam2.json", c.replace(K=c.K * [[1.01], [1.01], [1]]))
    cases = [
        ([*cam, "--image", *frames, "--fps", "40"], "another frame rate"),
        ([*cam, "--image", frames[0], other, *frames[2:], "--fps", "50"], "another image"),
        (["--camera", tmp_path / "cam2.json", "--image", *frames, "--fps", "50"],
         "other inputs (camera)"),
        ([*cam, "--image", *frames, "--fps", "50", "--max-obliqueness", "60"],
         "other inputs (max_obliqueness)"),
        ([*cam, "--image", *frames, "--fps", "50", "--per", "face"], "per node"),
    ]
    for extra, why in cases:
        rc, _, err = _run([*base, *extra, "--resume"], capsys)
        assert rc == 2 and why in err and len(err.strip().splitlines()) == 1, (why, err)
        assert out.read_bytes() == raw  # the file is never changed by a refusal
    rc, outp, _ = _run([*base, *cam, "--image", *frames, "--fps", "50", "--resume"], capsys)
    assert rc == 0 and "2 frames mapped" in outp


def test_map_resume_refuses_a_history_whose_frame_count_lies(tmp_path, capsys):
    """A hand-edited n_frames larger than the frames stored was resumed with exit 0 on
    today's main, and the file then failed to read."""
    import h5py

    corner_files(tmp_path)
    frames = _frames(tmp_path, 4)
    out = tmp_path / "P.h5"
    base = ["map", "--mesh", tmp_path / "corner.ply", "--camera", tmp_path / "cam.json",
            "--out", out, "--fps", "50", "--image"]
    assert _run([*base, *frames[:2]], capsys)[0] == 0
    with h5py.File(out, "r+") as f:
        f.attrs["n_frames"] = 9
    rc, _, err = _run([*base, *frames, "--resume"], capsys)
    assert rc == 2 and "damaged" in err and "n_frames says 9" in err, err
    with pytest.raises(InputError, match="damaged"):
        read_history(out)


def test_map_history_fps_format_and_sidecar(tmp_path, capsys):
    """`map --fps inf` wrote every time as 0; --format was ignored for .h5 outputs; an
    unrelated P.xdmf beside P.h5 was replaced (issue 25 items 2, 7)."""
    corner_files(tmp_path)
    frames = _frames(tmp_path, 2)
    out = tmp_path / "P.h5"
    base = ["map", "--mesh", tmp_path / "corner.ply", "--camera", tmp_path / "cam.json",
            "--out", out, "--image", *frames]
    for fps in ("inf", "nan", "0"):
        rc, _, err = _run([*base, "--fps", fps], capsys)
        assert rc == 2 and "--fps" in err and not out.exists(), err
    (tmp_path / "corner.ply").rename(tmp_path / "corner.mesh")
    base[2] = tmp_path / "corner.mesh"
    rc, _, err = _run([*base, "--fps", "50", "--format", "ply"], capsys)
    assert rc == 0, err
    assert read_history(out).points.shape[1] == 3
    mine = tmp_path / "Q.xdmf"
    mine.write_text("<Xdmf>my own sidecar</Xdmf>")
    q = tmp_path / "Q.h5"
    rc, _, err = _run([*base[:6], q, *base[7:], "--fps", "50", "--format", "ply"], capsys)
    assert rc == 2 and "Q.xdmf" in err and "refusing" in err, err
    assert mine.read_text() == "<Xdmf>my own sidecar</Xdmf>" and not q.exists()
    # our own sidecar is replaced by a resume
    assert "side_file_of" in xdmf_path(out).read_text()
