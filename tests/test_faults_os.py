"""Fault cases of the operating system: a read-only output folder, a full disk, Ctrl-C, a
symlink loop, a FIFO or a device given as input, a name too long, and an output that cannot
be written after another was (issue 25 items 9-12, 15-17). Each ends in one line and exit
status 2 (130 for Ctrl-C), never a traceback nor a hang, and leaves no partial output.
The family of tests/test_faults.py."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from fault_files import corner_files, isolated

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _env():
    return {**os.environ, "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}


def _inputs(folder):
    """The user's files for one run of each command."""
    from resection.io.cameras import write_camera
    from resection.surface.plots import virtual_camera

    sc, cam, img = corner_files(folder)
    # a camera facing the painted side of the corner (for correct)
    write_camera(folder / "front.json", virtual_camera(sc.mesh, 45.0, 30.0, width=96,
                                                       height=72))
    np.save(folder / "values.npy", np.arange(len(sc.mesh.faces), dtype=float))
    (folder / "markers.csv").write_text("id,x,y,z\nA,0,0,0\nB,1,0,0\nC,0,1,0\nD,1,1,0\n")
    np.save(folder / "img2.npy", img)
    return folder


def _commands(i, o):
    """(program, argv) of the commands of the issue, reading from ``i``, writing into
    ``o``."""
    return {
        "map": ("resection", ["map", "--mesh", i / "corner.ply", "--camera", i / "cam.json",
                              "--image", i / "img.npy", "--out", o / "m.vtk"]),
        "map-h5": ("resection", ["map", "--mesh", i / "corner.ply", "--camera",
                                 i / "cam.json", "--image", i / "img.npy", i / "img2.npy",
                                 "--out", o / "h.h5"]),
        "correct": ("selfillum", ["correct", "--mesh", i / "corner.ply", "--camera",
                                  i / "front.json", "--image", i / "img.npy", "--reflectance",
                                  "0.5", "--rays", "8", "--quiet", "--out", o / "c.npy"]),
        "detect": ("resection", ["detect", i / "img.npy", "--diameter", "5", "--out",
                                 o / "d.csv"]),
        "track": ("resection", ["track", i / "img.npy", i / "img2.npy", "--camera",
                                i / "cam.json", "--markers", i / "markers.csv", "--diameter",
                                "5", "--out", o / "t", "--workers", "1", "--no-progress"]),
        "corner": ("selfillum", ["corner", "--out", o / "corner", "--resolution", "4",
                                 "--rays", "16", "--quiet"]),
        "view": ("resection", ["view", "--mesh", i / "corner.ply", "--values",
                               i / "values.npy", "--out", o / "v.png", "--size", "80x60"]),
        "convert-camera": ("resection", ["convert-camera", i / "cam.json", "--out",
                                         o / "c.yml"]),
    }


_DRIVER = textwrap.dedent("""
    import contextlib, io, json, os, resource, signal, subprocess, sys
    from pathlib import Path
    i, o, mode, cmds = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], json.loads(sys.argv[4])
    mount = sys.argv[-1] == "mount"
    if mode == "ro" and mount:
        subprocess.run(["mount", "-t", "tmpfs", "tmpfs", str(o)], check=True)
        subprocess.run(["mount", "-o", "remount,ro", str(o)], check=True)
    elif mode == "ro":  # no namespace (and not root): a folder without write permission
        os.chmod(o, 0o555)
    elif mount:
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(o)],
                       check=True)
        fd = os.open(o / "filler", os.O_WRONLY | os.O_CREAT)
        try:
            while True:
                os.write(fd, b"x" * 4096)
        except OSError:
            pass
        os.close(fd)
    else:  # no namespace: no file may grow at all (EFBIG), as on a full disk
        (o / "filler").write_bytes(b"")
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (0, resource.RLIM_INFINITY))
    import resection.cli, selfillum.cli
    out = {}
    for name, (prog, argv) in cmds.items():
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            main = resection.cli.main if prog == "resection" else selfillum.cli.main
            try:
                rc = main(argv)
            except BaseException as exc:
                rc = repr(exc)
        out[name] = [rc, err.getvalue(), sorted(os.listdir(o))]
    print(json.dumps(out))
""")


@pytest.mark.parametrize("mode", ["ro", "full"])
def test_read_only_folder_and_full_disk_give_one_line(tmp_path, mode):
    """Items 9 and 10: a read-only output folder (a read-only tmpfs) and a full disk (a
    small tmpfs filled up) gave an OSError traceback (Errno 30, 28) from map, correct,
    detect, track, corner, view and convert-camera on today's main, and corner left a
    partial folder. Now one line naming the file and the reason, exit 2, nothing left."""
    i = _inputs(tmp_path)
    o = tmp_path / "o"
    o.mkdir()
    cmds = {k: (p, [str(a) for a in argv]) for k, (p, argv) in _commands(i, o).items()}
    r = subprocess.run(isolated([_DRIVER, i, o, mode, json.dumps(cmds)]),
                       capture_output=True, text=True, env=_env(), timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    res = json.loads(r.stdout.strip().splitlines()[-1])
    want = ("read-only file system", "no write permission") if mode == "ro" else \
        ("no space left on device", "file too large")
    for name, (rc, err, left) in res.items():
        assert rc == 2, (name, rc, err)
        # the command's own lines (without a namespace the file-size limit also makes a
        # library warn that it cannot write its cache: not the command's output)
        ours = [s for s in err.splitlines() if s.startswith(("resection", "selfillum"))]
        assert len(ours) == 1 and "Traceback" not in err, (name, err)
        assert any(w in ours[0].lower() for w in want), (name, err)
        assert left == ([] if mode == "ro" else ["filler"]), (name, left)


def _run(main, argv, capsys):
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _main(prog):
    import resection.cli
    import selfillum.cli

    return resection.cli.main if prog == "resection" else selfillum.cli.main


@pytest.mark.parametrize("name,target", [
    ("map", "resection.surface.surface_map.SurfaceMap.to_surface"),
    ("correct", "selfillum.images.image_correction.correct_image"),
    ("corner", "selfillum.corner._write_corner_files"),
])
def test_ctrl_c_is_one_line_exit_130_and_leaves_only_complete_files(tmp_path, capsys,
                                                                     monkeypatch, name,
                                                                     target):
    """Item 11: SIGINT on map, correct and corner printed a KeyboardInterrupt traceback.
    Ctrl-C arrives during the work (here: in the step named); one line, exit 130, no
    output file nor folder made by the run."""
    i = _inputs(tmp_path)
    o = tmp_path / "o"
    o.mkdir()
    prog, argv = _commands(i, o)[name]
    module, attr = target.rsplit(".", 1)
    import importlib

    try:
        owner = importlib.import_module(module)
    except ImportError:
        mod, cls = module.rsplit(".", 1)
        owner = getattr(importlib.import_module(mod), cls)
    original = getattr(owner, attr)

    def interrupted(*a, **k):
        if name == "corner":  # after the first file is written
            folder = a[1]
            (folder / "corner_profile.png").write_bytes(b"png")
        raise KeyboardInterrupt

    monkeypatch.setattr(owner, attr, interrupted)
    rc, _, err = _run(_main(prog), argv, capsys)
    monkeypatch.setattr(owner, attr, original)
    assert rc == 130 and len(err.strip().splitlines()) == 1 and "interrupted" in err, err
    assert sorted(os.listdir(o)) == []


def test_ctrl_c_signal_on_a_running_map(tmp_path):
    """A real SIGINT to a running `map` process: one line, exit 130."""
    import signal
    import time

    i = _inputs(tmp_path)
    code = ("import time, resection.surface.surface_map as s\n"
            "orig = s.SurfaceMap.to_surface\n"
            "def slow(*a, **k):\n"
            "    print('working', flush=True); time.sleep(30)\n"
            "s.SurfaceMap.to_surface = slow\n"
            "import sys, resection.cli\n"
            "sys.exit(resection.cli.main(sys.argv[1:]))\n")
    prog, argv = _commands(i, tmp_path)["map"]
    p = subprocess.Popen([sys.executable, "-c", code, *map(str, argv)], env=_env(),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "working"
    p.send_signal(signal.SIGINT)
    t0 = time.time()
    _, err = p.communicate(timeout=60)
    assert time.time() - t0 < 20
    assert p.returncode == 130 and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "m.vtk").exists()


def test_symlink_loops_fifos_and_devices_are_refused_without_hanging(tmp_path):
    """Items 12 and 16: a symlink loop given as --camera or --markers gave an OSError
    (Errno 40) traceback; a FIFO that nobody writes, or /dev/zero, given as --camera hung
    for ever. Refused by name in one line, at once."""
    i = _inputs(tmp_path)
    os.symlink(tmp_path / "loop_b", tmp_path / "loop_a")
    os.symlink(tmp_path / "loop_a", tmp_path / "loop_b")
    os.mkfifo(tmp_path / "fifo")
    prog, base = _commands(i, tmp_path)["track"]
    cases = []
    for bad, why in ((tmp_path / "loop_a", "symbolic link loop"),
                     (tmp_path / "fifo", "FIFO"), ("/dev/zero", "character device")):
        for opt in ("--camera", "--markers"):
            argv = [str(a) for a in base]
            argv[argv.index(opt) + 1] = str(bad)
            cases.append((argv, str(bad), why))
    m_argv = [str(a) for a in _commands(i, tmp_path)["map"][1]]
    m_argv[m_argv.index("--camera") + 1] = str(tmp_path / "fifo")
    cases.append((m_argv, "fifo", "FIFO"))
    for argv, bad, why in cases:
        r = subprocess.run([sys.executable, "-m", "resection.cli", *argv], env=_env(),
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 2, (argv, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert bad in r.stderr and why in r.stderr, r.stderr
    assert not (tmp_path / "t").exists()


def test_name_too_long_is_one_line(tmp_path, capsys):
    """Item 15: an --out name over 255 characters: OSError (Errno 36) traceback."""
    i = _inputs(tmp_path)
    prog, argv = _commands(i, tmp_path)["map"]
    argv = [str(a) for a in argv]
    argv[argv.index("--out") + 1] = str(tmp_path / ("x" * 300 + ".vtk"))
    rc, _, err = _run(_main(prog), argv, capsys)
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "longer than" in err, err


def test_every_output_is_checked_before_any_is_written(tmp_path, capsys):
    """Item 17: `pose --out p.json --plot nope/x.png` exited 2 with p.json already written;
    so did --residuals, `match --pose` and `link --suggest`. Now nothing is written."""
    from resection.io.cameras import write_camera
    from resection.io.images import write_image
    from resection.io.markers import write_markers
    from resection.surface.plots import virtual_camera
    from scenes.marker_images import render_markers

    rng = np.random.default_rng(3)
    xyz = np.column_stack([rng.uniform(-0.2, 0.2, 20), rng.uniform(-0.14, 0.14, 20),
                           rng.uniform(0.0, 0.05, 20)])
    import trimesh

    cam = virtual_camera(trimesh.points.PointCloud(xyz), 20, 60, width=640, height=480)
    img = render_markers((480, 640), cam.project(xyz), 6.0, contrast=80, background=600,
                         blur=0.7, snr=40, rng=1, dtype=np.uint16)
    write_image(tmp_path / "img.tif", img)
    write_markers(tmp_path / "m.csv", [f"T{k}" for k in range(20)], xyz)
    write_camera(tmp_path / "cam.json", cam)
    from resection.cli import main

    rc, _, err = _run(main, ["detect", tmp_path / "img.tif", "--diameter", "6", "--out",
                             tmp_path / "c.csv"], capsys)
    assert rc == 0, err
    nope = tmp_path / "nope"
    pose = ["pose", "--camera", tmp_path / "cam.json", "--markers", tmp_path / "m.csv",
            "--image", tmp_path / "img.tif", "--diameter", "6"]
    match = ["match", "--candidates", tmp_path / "c.csv", "--markers", tmp_path / "m.csv",
             "--camera", tmp_path / "cam.json"]
    cases = [
        ([*pose, "--out", tmp_path / "p.json", "--plot", nope / "x.png"], "p.json"),
        ([*pose, "--out", tmp_path / "p.json", "--residuals", nope / "r.csv"], "p.json"),
        ([*match, "--out", tmp_path / "mm.csv", "--pose", nope / "p.json"], "mm.csv"),
        (["link", tmp_path / "img.tif", "--candidates", tmp_path / "c.csv", "--markers",
          tmp_path / "m.csv", "--camera",
          tmp_path / "cam.json", "--png", tmp_path / "l.png", "--suggest",
          nope / "s.csv"], "l.png"),
    ]
    for argv, first in cases:
        rc, _, err = _run(main, argv, capsys)
        assert rc == 2 and "nope" in err and "does not exist" in err, err
        assert len(err.strip().splitlines()) == 1
        assert not (tmp_path / first).exists(), first
    # the same runs with every folder present succeed (the inputs were good)
    nope.mkdir()
    for argv, first in cases:
        rc, _, err = _run(main, argv, capsys)
        assert rc == 0 and (tmp_path / first).exists(), (argv, err)


def test_leftover_temporaries_beside_an_output_file_are_removed(tmp_path, capsys):
    """Item 19, for file outputs: the temporary file a killed run left beside --out (its
    process dead) is removed by the next run into the folder; one of a live process, and
    any file of the user's, stay."""
    import subprocess as sp

    i = _inputs(tmp_path)
    dead = sp.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    left = tmp_path / f".m.{dead.pid}-0a1b2c3d.tmp.vtk"
    left.write_text("half")
    mine = tmp_path / ".m.notes.tmp.vtk"  # not a name the commands make
    mine.write_text("keep")
    own = tmp_path / f".m.{os.getpid()}-0a1b2c3d.tmp.vtk"  # a live process's
    own.write_text("busy")
    prog, argv = _commands(i, tmp_path)["map"]
    rc, _, err = _run(_main(prog), argv, capsys)
    assert rc == 0, err
    assert not left.exists() and mine.exists() and own.exists()


def test_option_values_that_are_not_paths_are_not_taken_for_files(tmp_path, capsys):
    """The input check stats every option value: a JSON text longer than a file name, or
    a number, is no path and must pass (refused only for what it says)."""
    i = _inputs(tmp_path)
    prog, argv = _commands(i, tmp_path)["track"]
    long_json = json.dumps({"robust": "huber", "robust_scale": 1.0 + 1e-9,
                            "max_rms": 2.0, "max_nfev": 200} | {"ids": None}).replace(
        " ", " " * 80)
    assert len(long_json) > 300
    rc, _, err = _run(_main(prog), [*map(str, argv), "--pose-options", long_json], capsys)
    assert "file name" not in err and "too long" not in err, err


def test_track_with_every_frame_failed_says_so_on_stderr(tmp_path, capsys):
    """Item 18: track exited 1 with nothing on stderr when every frame failed. Now one
    line on stderr says no frame was solved and why frame 0 failed."""
    i = _inputs(tmp_path)
    prog, argv = _commands(i, tmp_path)["track"]
    rc, out, err = _run(_main(prog), argv, capsys)
    assert rc == 1, (out, err)
    lines = [s for s in err.splitlines() if s.strip()]
    assert len(lines) == 1 and "no frame solved" in lines[0] and "frame 0" in lines[0], err
