"""Fault cases of `track` resumes and output folders: a resume is right or recomputes (a
frame's identity includes a digest of its content, results computed from a changed frame
are recomputed, an unknown manifest keeps no frame), temporary files of a killed run are
removed, bad pose options are refused up front, and the files track writes into --out
never replace the user's or an input (issue 25 items 3, 4, 5, 18, 19). The family of
tests/test_faults.py."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest


def _track_args(files, out, frames=None, *extra):
    frames = frames if frames is not None else files["frames"]
    return ["track", *map(str, frames), "--camera", files["camera"], "--markers",
            files["markers"], "--diameter", "5.6", "--out", str(out), "--no-progress",
            "--workers", "1", "--chunk-size", "50", *extra]


@pytest.fixture(scope="module")
def seqs(tmp_path_factory):
    """Sequences A and B: the same model, camera and markers pitching opposite ways."""
    from scenes.moving_model import pitch_oscillation, write_sequence

    base = tmp_path_factory.mktemp("seq25")
    a = pitch_oscillation(10, amplitude_deg=2.0, frequency_hz=3.0)
    b = pitch_oscillation(10, amplitude_deg=-2.0, frequency_hz=3.0, seed=1)
    return write_sequence(a, base / "A"), write_sequence(b, base / "B")


def _copy_frames(files, dest):
    dest.mkdir()
    out = []
    for p in files["frames"]:
        shutil.copy2(p, dest / os.path.basename(p))
        out.append(dest / os.path.basename(p))
    return out


def _run(argv, capsys):
    from resection.cli import main

    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _frame_file(out, i):
    return json.loads((out / "frames" / f"frame_{i:06d}.json").read_text())


@pytest.mark.parametrize("how", ["cp-p", "mv", "in-place"])
def test_resume_recomputes_a_replaced_frame_and_what_was_tracked_from_it(seqs, tmp_path,
                                                                         capsys, how):
    """Issue 25 item 4: frame 7 replaced by another frame (``cp -p``, ``mv``, or rewritten
    in place with its times restored). On today's main the resume recomputed frame 7 only
    and kept frame 8, tracked from frame 7's old result, so the result differed from a
    clean run. Now every frame computed from frame 7 (8, 9, ...) is computed again, and
    the result equals a clean run's on the same files."""
    from resection.sequence import read_track

    fa, fb = seqs
    frames = _copy_frames(fa, tmp_path / "in")
    out = tmp_path / "out"
    assert _run(_track_args(fa, out, frames), capsys)[0] == 0
    other = fb["frames"][7]
    target = frames[7]
    st = os.stat(target)
    if how == "cp-p":
        subprocess.run(["cp", "-p", str(other), str(target)], check=True)
    elif how == "mv":
        shutil.copy2(other, tmp_path / "x.npy")
        os.replace(tmp_path / "x.npy", target)
    else:
        with open(target, "r+b") as fh:
            fh.write(open(other, "rb").read())
        os.utime(target, ns=(st.st_atime_ns, st.st_mtime_ns))
    rc, outp, _ = _run(_track_args(fa, out, frames), capsys)
    assert rc == 0
    assert "(3 computed now)" in outp, outp  # frames 7, 8 and 9
    f7, f8 = _frame_file(out, 7), _frame_file(out, 8)
    assert f8["matched_from"] == 7 and f8["ref_source"] == f7["source"]
    clean = tmp_path / "clean"
    assert _run(_track_args(fa, clean, frames), capsys)[0] == 0
    a, b = read_track(out), read_track(clean)
    np.testing.assert_array_equal(a.n_markers, b.n_markers)
    np.testing.assert_array_equal(a.marker_id, b.marker_id)
    np.testing.assert_allclose(a.marker_uv, b.marker_uv, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.rvec, b.rvec, rtol=0, atol=1e-12)


def test_resume_sees_new_content_behind_the_same_metadata(seqs, tmp_path):
    """The identity of a frame includes a digest of a sample of its content: two files of
    one size, whose metadata were made equal, still differ."""
    from resection.sequence.frames import changed, content_digest, fingerprint

    fa, fb = seqs
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    shutil.copy(fa["frames"][3], a)
    rec = fingerprint(a)
    data = bytearray(a.read_bytes())
    data[(len(data) - 256) // 32 + 100] ^= 0xFF  # one byte of the pixels, in the sample
    st = os.stat(a)
    b.write_bytes(bytes(data))
    assert content_digest(a) != content_digest(b)
    # the same metadata (size, times, inode) with other content: only the digest differs
    fake = list(rec)
    fake[-1] = content_digest(b)
    assert fake[:4] == [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino]
    assert changed(a, fake) and not changed(a, rec)


@pytest.mark.parametrize("manifest", ["corrupt", "missing"])
def test_resume_with_an_unknown_manifest_keeps_no_frame(seqs, tmp_path, capsys, manifest):
    """Issue 25 item 5: track.json corrupt (or removed), and the run resumed with other
    settings (--diameter 7 after 5.6): on today's main the old frames were kept (0
    computed) and written out as results of the new settings. The settings of those frames
    are unknown: the run is refused with the reason (by the command and the library),
    nothing in the folder changed."""
    fa, _ = seqs
    out = tmp_path / "out"
    frames = fa["frames"][:5]
    assert _run(_track_args(fa, out, frames), capsys)[0] == 0
    if manifest == "corrupt":
        (out / "track.json").write_text('{"written_by": "resection track", "diam')
    else:
        (out / "track.json").unlink()
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    args = _track_args(fa, out, frames)
    args[args.index("--diameter") + 1] = "7"
    rc, outp, err = _run(args, capsys)
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert "track.json" in err and ("damaged" in err) == (manifest == "corrupt"), err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    from resection import InputError
    from resection.io.cameras import read_camera
    from resection.sequence import track

    with pytest.raises(InputError, match="track.json"):
        track(frames, read_camera(fa["camera"]), fa["markers"], diameter=7.0, out_dir=out,
              workers=1, progress=False)
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


def test_leftover_temporary_files_of_a_killed_run_are_removed(seqs, tmp_path, capsys):
    """Issue 25 item 19: after kill -9 in the middle of track a
    ``.frame_NNNNNN.<pid>-<hex>.tmp.json`` stayed in frames/ for ever. The next run into
    the folder removes those of dead processes (and never those of live ones)."""
    fa, _ = seqs
    out = tmp_path / "out"
    frames = fa["frames"][:3]
    assert _run(_track_args(fa, out, frames), capsys)[0] == 0
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        left = out / "frames" / f".frame_000002.{dead.pid}-0123abcd.tmp.json"
        left.write_text('{"half": ')
        top = out / f".poses.{dead.pid}-89abcdef.tmp.csv"
        top.write_text("frame,")
        busy = out / "frames" / f".frame_000001.{alive.pid}-0123abcd.tmp.json"
        busy.write_text("{")
        assert _run(_track_args(fa, out, frames), capsys)[0] == 0
        assert not left.exists() and not top.exists()
        assert busy.exists()  # another live process is writing it
    finally:
        alive.kill()
        alive.wait()


def test_bad_pose_options_are_refused_up_front(seqs, tmp_path, capsys):
    """Issue 25 item 18: `--pose-options '{"robust": 5}'` made every frame fail, and track
    exited 1 with nothing on stderr. Now refused before any frame, in one line, nothing
    written."""
    fa, _ = seqs
    out = tmp_path / "out"
    rc, _, err = _run(_track_args(fa, out, fa["frames"][:3], "--pose-options",
                                  '{"robust": 5}'), capsys)
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert "robust" in err and "unknown robust loss 5" in err
    assert not out.exists()


def test_track_never_replaces_inputs_or_user_files_in_its_folder(seqs, tmp_path, capsys):
    """Issue 25 item 3: `track --out seq` with `--markers seq/markers.csv` (the layout of
    write_sequence) overwrote the marker file; so did `cd seq; track --out .`; and a
    poses.csv of the user's in --out was replaced."""
    fa, _ = seqs
    seq = tmp_path / "seq"
    seq.mkdir()
    for key in ("camera", "markers"):
        shutil.copy(fa[key], seq / os.path.basename(fa[key]))
    files = {"camera": seq / os.path.basename(fa["camera"]),
             "markers": seq / os.path.basename(fa["markers"])}
    assert files["markers"].name == "markers.csv"
    raw = files["markers"].read_bytes()
    frames = fa["frames"][:3]
    rc, _, err = _run(_track_args(files, seq, frames), capsys)
    assert rc == 2 and "markers.csv" in err and len(err.strip().splitlines()) == 1, err
    assert files["markers"].read_bytes() == raw
    cwd = os.getcwd()
    try:
        os.chdir(seq)
        rc, _, err = _run(_track_args({"camera": "camera.json", "markers": "markers.csv"},
                                      ".", frames), capsys)
    finally:
        os.chdir(cwd)
    assert rc == 2 and "markers.csv" in err, err
    assert files["markers"].read_bytes() == raw
    # a folder of the user's holding a poses.csv: refused by name
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "poses.csv").write_text("my,own\n")
    rc, _, err = _run(_track_args(fa, mine, frames), capsys)
    assert rc == 2 and "poses.csv" in err and "refusing" in err, err
    assert (mine / "poses.csv").read_text() == "my,own\n"
    # the library refuses it as well
    from resection import InputError
    from resection.io.cameras import read_camera
    from resection.sequence import track

    with pytest.raises(InputError, match="poses.csv"):
        track(frames, read_camera(fa["camera"]), fa["markers"], diameter=5.6,
              out_dir=mine, workers=1, progress=False)
    # a track output is ours: resumed, its files replaced
    out = tmp_path / "out"
    assert _run(_track_args(fa, out, frames), capsys)[0] == 0
    assert _run(_track_args(fa, out, frames), capsys)[0] == 0
