"""``selfillum unsteady``'s work folder, resumes and faults (issue 34 items 13, 14, 15, 17):
the folder is the run's own (marker and token) and locked, so that a folder of the
user's or a second run's is never used nor removed; a resume is refused when a video's
content or --full-maps changed; a damaged F.npz or phase1.h5 is named; a full disk while
the output is written is one line; Ctrl-C at start-up ends in exit 130."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from unsteady_cases import args, copy_run, refused, run_cli, small_run  # noqa: F401


@pytest.fixture
def case(small_run, tmp_path):  # noqa: F811 - the fixture imported above
    return copy_run(small_run, tmp_path / "case")


def _interrupted(case, capsys, monkeypatch, *extra) -> Path:
    """A run stopped by Ctrl-C after its first committed block of Phase 1 (blocks of 4
    frames): its work folder, kept for --resume."""
    from selfillum.unsteady.work import Phase1Store

    real = Phase1Store.write_block

    def stop_after(self, *a, **k):
        real(self, *a, **k)
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(Phase1Store, "write_block", stop_after)
        rc, _, err = run_cli(args(case, "--memory", "0.01", *extra), capsys)
    assert rc == 130, err
    work = case / "out.h5.work"
    assert (work / "phase1.h5").exists()
    return work


# ------------------------------------------------------------------- item 13


def test_users_folder_of_the_work_name_is_never_used_nor_removed(case, capsys):
    """Issue 34 item 13: a folder of the user's named OUT.h5.work was adopted by --resume,
    then deleted with the user's files when the run succeeded."""
    work = case / "out.h5.work"
    work.mkdir()
    (work / "notes.txt").write_text("mine")
    err = refused(case, capsys, "--resume", "--registration", "none", "--no-si")
    assert "out.h5.work: not a work folder of selfillum unsteady" in err
    assert (work / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in work.iterdir()) == ["notes.txt"]


def test_a_second_run_on_the_same_out_touches_nothing(case, capsys):
    """Issue 34 item 13: two --resume runs started at once on a fresh --out: the second
    replaced the first's work file and removed its folder when done. Here the first run
    has just made and claimed its folder (marker written, lock held, no phase1.h5 yet):
    the second is refused and leaves the folder as it is."""
    from resection.io.lock import lock_folder
    from selfillum.unsteady.work import MARKER, PRODUCER

    work = case / "out.h5.work"
    work.mkdir()
    (work / MARKER).write_text(json.dumps({"written_by": PRODUCER, "token": "0123abcd"}))
    with lock_folder(work, command="selfillum unsteady (the first run)"):
        before = sorted(p.name for p in work.iterdir())
        rc, _, err = run_cli(args(case, "--resume", "--registration", "none", "--no-si"),
                             capsys)
        assert rc == 2 and "out.h5.work: another run is working in it" in err, err
        assert "the first run" in err
        assert sorted(p.name for p in work.iterdir()) == before
    assert not (case / "out.h5").exists()


@pytest.mark.slow
def test_two_resumes_started_at_once(case):
    """Issue 34 item 13 as the sweep met it (8 of 25 tries both failed): two processes
    with --resume on the same fresh --out, three times. Never both fail; the one refused
    says why in one line; the output is whole."""
    import h5py

    exe = Path(sys.executable).with_name("selfillum")
    for k in range(3):
        out = f"out{k}.h5"
        argv = [str(exe), *args(case, "--resume", "--registration", "none", out=out)]
        procs = [subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True) for _ in range(2)]
        res = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
        codes = sorted(rc for rc, _ in res)
        assert codes in ([0, 0], [0, 2]), res
        for rc, err in res:
            if rc == 2:
                assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
        with h5py.File(case / out) as f:
            assert np.isfinite(f["dcp"][()]).any()
        assert not (case / (out + ".work")).exists()


# ------------------------------------------------------------------- item 14: resume key


def test_resume_refused_after_a_video_rewritten_with_its_times_restored(case, capsys,
                                                                      monkeypatch):
    """Issue 34 item 14: a video rewritten with the same size and its mtime restored
    resumed from the stale frames (the key held size and mtime). The key holds a digest
    of the content now."""
    _interrupted(case, capsys, monkeypatch, "--registration", "none", "--no-si")
    v = case / "cam02.npy"
    st = os.stat(v)
    frames = np.load(v)
    np.save(v, frames[::-1].copy())  # the same size, other frames
    os.utime(v, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert os.stat(v).st_size == st.st_size and os.stat(v).st_mtime_ns == st.st_mtime_ns
    err = refused(case, capsys, "--resume", "--registration", "none", "--no-si",
                  "--memory", "0.01")
    assert "made from other inputs (files)" in err


def test_resume_refused_when_full_maps_is_toggled(case, capsys, monkeypatch):
    """Issue 34 item 14: --full-maps was missing from the resume key: a resume that
    toggled it mixed two methods in one run."""
    _interrupted(case, capsys, monkeypatch, "--registration", "none", "--no-si")
    err = refused(case, capsys, "--resume", "--registration", "none", "--no-si",
                  "--memory", "0.01", "--full-maps")
    assert "made from other inputs (fast_maps)" in err


def test_resume_of_the_same_inputs_carries_on(case, capsys, monkeypatch):
    """The digests refuse no honest resume: the same inputs (the videos touched, not
    changed) carry on and finish, and the work folder is removed."""
    work = _interrupted(case, capsys, monkeypatch, "--registration", "none", "--no-si")
    os.utime(case / "cam01.npy")  # a new mtime, the same content
    rc, _, err = run_cli(args(case, "--resume", "--registration", "none", "--no-si",
                              "--memory", "0.01"), capsys)
    assert rc == 0, err
    assert (case / "out.h5").exists() and not work.exists()


# ------------------------------------------------------------------- item 15: damaged work


def test_damaged_form_factors_named_on_resume(case, capsys, monkeypatch):
    """Issue 34 item 15: a damaged F.npz in the work folder gave a traceback."""
    work = _interrupted(case, capsys, monkeypatch, "--registration", "none")
    assert (work / "F.npz").exists()
    (work / "F.npz").write_bytes(b"PK\x03\x04 not a zip archive")
    rc, _, err = run_cli(args(case, "--resume", "--registration", "none", "--memory",
                              "0.01"), capsys)
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert "out.h5.work/F.npz: damaged form factors" in err


def test_damaged_work_file_named_on_resume(case, capsys, monkeypatch):
    """Issue 34 item 15: a damaged phase1.h5 got one line that did not name the file."""
    work = _interrupted(case, capsys, monkeypatch, "--registration", "none", "--no-si")
    (work / "phase1.h5").write_bytes(b"\0" * 4096)
    err = refused(case, capsys, "--resume", "--registration", "none", "--no-si",
                  "--memory", "0.01")
    assert "out.h5.work/phase1.h5: damaged work file" in err


# ------------------------------------------------------------------- item 15: full disk


def test_full_disk_while_the_output_is_written(case, tmp_path):
    """Issue 34 item 15: a full disk while the output was written gave 47 lines of HDF5
    tracebacks, then a segfault (exit 139). The disk is made full for the output only:
    a process limit on the size of a file (RLIMIT_FSIZE, EFBIG as a full disk's ENOSPC),
    under which the work (phase1.h5, 47 kB) fits and the output (127 kB) does not. One
    line naming the output, exit 2, no output left; the work stays for --resume."""
    code = textwrap.dedent("""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (90_000, 90_000))
        from selfillum.cli import main
        sys.exit(main(sys.argv[1:]))
    """)
    p = subprocess.run([sys.executable, "-c", code,
                        *args(case, "--registration", "none", "--psd-bands", "0")],
                       capture_output=True, text=True, timeout=300)
    err = p.stderr.strip()
    assert p.returncode == 2, (p.returncode, err[-2000:])
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"{case / 'out.h5'}: File too large" in err
    assert not (case / "out.h5").exists() and not (case / "out.xdmf").exists()
    assert not [q for q in case.iterdir() if q.name.startswith(".out")]
    assert (case / "out.h5.work" / "phase1.h5").exists()


def test_guarded_file_reads_back_what_could_not_be_written(tmp_path):
    """The file object under the output: after a failed write, HDF5 still reads back what
    it wrote (kept in memory), and check() names the file."""
    import errno

    from resection.io.guarded import GuardedFile

    g = GuardedFile(tmp_path / "x.bin")
    g.write(b"abcdef")

    class Full:  # the disk fills: every write from now on fails
        def __init__(self, f):
            self.f = f

        def write(self, b):
            raise OSError(errno.ENOSPC, "No space left on device")

        def __getattr__(self, name):
            return getattr(self.f, name)

    g._f = Full(g._f)
    g.seek(3)
    assert g.write(b"XYZW") == 4
    g.seek(0)
    buf = bytearray(7)
    assert g.readinto(buf) == 7 and bytes(buf) == b"abcXYZW"
    with pytest.raises(OSError, match=r"No space left on device") as exc:
        g.check()
    assert exc.value.filename == str(tmp_path / "x.bin")
    g.close()


# ------------------------------------------------------------------- item 17: Ctrl-C


def test_ctrl_c_during_an_import_that_catches_base_exception(tmp_path):
    """Issue 34 item 17: trimesh guards its imports with ``except BaseException``: a Ctrl-C
    during one was swallowed and the run finished with exit 0. A package shaped like it
    (its import catches BaseException while Ctrl-C arrives) under the console script's
    handler: the interrupt is held during the import and raised after it."""
    pkg = tmp_path / "site" / "trimesh"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(textwrap.dedent("""
        import os, signal, time
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.2)
        except BaseException as E:
            SWALLOWED = E
    """))
    code = textwrap.dedent("""
        import sys
        from resection.cli.interrupts import install, interrupted
        install()
        try:
            import trimesh
        except KeyboardInterrupt:
            assert interrupted()
            sys.exit(130)
        sys.exit(0)
    """)
    env = dict(os.environ, PYTHONPATH=str(tmp_path / "site"))
    p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 130, p.stderr


def test_ctrl_c_silences_the_finalizers_of_what_it_tore():
    """An object that Ctrl-C interrupted in its construction fails in its finalizer when
    collected (llvmlite's, when numba was compiling at that moment: a clean clone's run
    printed 10 lines of "Exception ignored in ... __del__" after the command's one line):
    once Ctrl-C was pressed, such failures print nothing; before it they still do."""
    code = textwrap.dedent("""
        import os, signal, sys
        from resection.cli.interrupts import install
        install()

        class Torn:
            def __init__(self):
                os.kill(os.getpid(), signal.SIGINT)
                self.handle = 1

            def __del__(self):
                del self.handle  # never set: AttributeError in the finalizer

        class Broken:
            def __del__(self):
                raise ValueError("before any Ctrl-C")

        Broken()  # reported as usual
        sys.stderr.write("--\\n")
        try:
            Torn()
        except KeyboardInterrupt:
            pass
        sys.exit(130)
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 130, p.stderr
    before, _, after = p.stderr.partition("--\n")
    assert "ValueError: before any Ctrl-C" in before
    assert after == "", after


@pytest.mark.parametrize("delay", [0.6, 1.0, 1.5, 2.0])
def test_ctrl_c_in_the_first_seconds_ends_in_130(case, delay):
    """Issue 34 item 17: Ctrl-C in the first 2 s of a run ends in exit 130 and one line,
    and no output (the interpreter's own start-up, its first tenth of a second, is before
    any program code)."""
    exe = Path(sys.executable).with_name("selfillum")
    # 262,144 rays a face: the view factors alone outlast the 2 s many times
    p = subprocess.Popen([str(exe), *args(case, "--registration", "none", "--rays", "262144")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err[-2000:]
    assert len(err.strip().splitlines()) == 1 and "interrupted" in err, err
    assert not (case / "out.h5").exists()
