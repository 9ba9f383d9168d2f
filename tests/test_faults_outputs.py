"""Fault cases in writing: outputs never destroy inputs, files appear whole or not at
all, and image sizes that cannot be allocated are refused before allocating (issue 10
items 4 and 6). The family of tests/test_faults.py."""

from __future__ import annotations

import os

import numpy as np
import pytest
from fault_files import corner_files

from resection import InputError
from resection.io.cameras import write_camera

# --------------------------------------------------------------------------------------
# Outputs never destroy inputs; files appear whole or not at all (issue 10 item 4)
# --------------------------------------------------------------------------------------


def test_correct_refuses_out_equal_to_image(tmp_path, capsys):
    """``selfillum correct --image X --out X`` destroyed the raw image on today's main:
    refused before any work, through any spelling of the same file (a hard link too)."""

    from selfillum.cli.main import main

    corner_files(tmp_path)
    raw = (tmp_path / "img.npy").read_bytes()
    os.link(tmp_path / "img.npy", tmp_path / "hard.npy")
    base = ["correct", "--mesh", str(tmp_path / "corner.ply"), "--camera",
            str(tmp_path / "cam.json"), "--reflectance", "0.5", "--rays", "8", "--quiet"]
    for out in (tmp_path / "img.npy", tmp_path / "sub" / ".." / "img.npy",
                tmp_path / "hard.npy"):
        (tmp_path / "sub").mkdir(exist_ok=True)
        rc = main([*base, "--image", str(tmp_path / "img.npy"), "--out", str(out)])
        err = capsys.readouterr().err
        assert rc == 2 and "is an input" in err and len(err.splitlines()) == 1, err
        assert (tmp_path / "img.npy").read_bytes() == raw
    # the library function refuses it as well
    from selfillum.images.image_correction import correct_image_file

    with pytest.raises(InputError, match="is an input"):
        correct_image_file(tmp_path / "corner.ply", tmp_path / "cam.json",
                           tmp_path / "img.npy", 0.5, tmp_path / "img.npy")
    assert (tmp_path / "img.npy").read_bytes() == raw


def test_detect_refuses_out_equal_to_frame(tmp_path, capsys):
    """``resection detect X.npy --out X.npy`` wrote CSV text over the frame."""
    from resection.cli.main import main

    frame = np.full((40, 50), 100.0, dtype=np.float32)
    frame[18:23, 20:25] = 10.0
    np.save(tmp_path / "f.npy", frame)
    raw = (tmp_path / "f.npy").read_bytes()
    rc = main(["detect", str(tmp_path / "f.npy"), "--diameter", "5",
               "--out", str(tmp_path / "f.npy")])
    err = capsys.readouterr().err
    assert rc == 2 and "is an input" in err and "f.npy" in err
    assert (tmp_path / "f.npy").read_bytes() == raw
    np.testing.assert_array_equal(np.load(tmp_path / "f.npy"), frame)


def test_two_outputs_with_one_name_refused(tmp_path, capsys):
    """Two outputs of one command naming the same file: the second would replace the
    first."""
    from resection import Camera
    from resection.cli.main import main
    from resection.io.markers import write_markers, write_points

    board = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.2], [0.5, 0.3, 0.1]])
    ids = [f"M{i}" for i in range(5)]
    write_markers(tmp_path / "m.csv", ids, board)
    write_points(tmp_path / "p.csv", ids, np.arange(10.0).reshape(5, 2) * 20 + 100)
    write_camera(tmp_path / "c.json",
                 Camera(640, 480, [[600, 0, 319.5], [0, 600, 239.5], [0, 0, 1]]))
    rc = main(["pose", "--camera", str(tmp_path / "c.json"), "--markers",
               str(tmp_path / "m.csv"), "--points", str(tmp_path / "p.csv"),
               "--out", str(tmp_path / "r.csv"), "--residuals", str(tmp_path / "r.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and "same file as --out" in err


@pytest.mark.parametrize("prog, argv, victim", [
    ("resection", "map --mesh m.ply --camera c.json --image a.npy --out a.npy", "a.npy"),
    ("resection", "backproject --mesh m.ply --camera c.json --values v.npy "
                  "--background a.npy --out a.npy", "a.npy"),
    ("resection", "align --mesh m.ply --source-camera c.json --target-camera c.json "
                  "--image a.npy --out a.npy", "a.npy"),
    ("resection", "view --mesh m.ply --values v.npy --camera c.json --out m.ply", "m.ply"),
    ("resection", "link a.npy --candidates k.csv --png a.npy", "a.npy"),
    ("resection", "match --candidates k.csv --markers p.csv --camera c.json --out k.csv",
     "k.csv"),
    ("resection", "match --candidates k.csv --markers p.csv --camera c.json --out o.csv "
                  "--pose c.json", "c.json"),
    ("resection", "pose --camera c.json --markers p.csv --points q.csv --out c.json",
     "c.json"),
    ("resection", "calibrate --markers p.csv --points q.csv --size 640x480 --out q.csv",
     "q.csv"),
    ("resection", "convert-camera c.json --out c.json", "c.json"),
    ("selfillum", "correct --mesh m.ply --camera c.json --image a.npy --reflectance 0.5 "
                  "--out o.npy --surface m.ply", "m.ply"),
    ("selfillum", "render --mesh m.ply --camera c.json --emission v.npy --reflectance 0.5 "
                  "--out v.npy", "v.npy"),
])
def test_every_writing_command_refuses_to_overwrite_an_input(tmp_path, capsys, monkeypatch,
                                                             prog, argv, victim):
    """The refusal is checked on the parsed command line before anything is read or
    computed, for every command that writes: the input is left byte for byte."""
    import importlib

    monkeypatch.chdir(tmp_path)
    for name in ("m.ply", "c.json", "a.npy", "v.npy", "k.csv", "p.csv", "q.csv"):
        (tmp_path / name).write_bytes(f"input {name}".encode())
    main = importlib.import_module(f"{prog}.cli").main
    rc = main(argv.split())
    err = capsys.readouterr().err
    assert rc == 2 and "is an input of this command" in err and victim in err, err
    assert len(err.splitlines()) == 1
    assert (tmp_path / victim).read_bytes() == f"input {victim}".encode()


def test_atomic_write_keeps_the_old_file_when_the_writer_fails(tmp_path):
    """A writer that dies half-way (disk full, bad value) leaves the previous file intact
    and no temporary file behind; a writer that succeeds replaces it whole."""
    from resection.io.images import read_image, write_image
    from resection.io.outputs import atomic_write

    out = tmp_path / "out.tif"
    write_image(out, np.ones((8, 8), np.float32))
    before = out.read_bytes()

    def dies_half_way(path, data):
        with open(path, "wb") as fh:
            fh.write(data[: len(data) // 2])
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="No space"):
        atomic_write(out, dies_half_way, b"x" * 1000)
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.tif"]
    # a value the format cannot hold: the message names the user's file, not a temp name
    with pytest.raises(InputError) as err:
        atomic_write(tmp_path / "out.png", write_image, np.full((4, 4), -1.0))
    assert "out.png" in str(err.value) and ".tmp" not in str(err.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.tif"]
    atomic_write(out, write_image, np.full((8, 8), 3.0, np.float32))
    np.testing.assert_array_equal(read_image(out), np.full((8, 8), 3.0, np.float32))
    with pytest.raises(InputError, match="does not exist"):
        atomic_write(tmp_path / "missing" / "x.tif", write_image, np.ones((2, 2)))


def test_render_preview_never_replaces_an_unrelated_png(tmp_path, capsys):
    """``selfillum render --out a.tif`` replaced an unrelated ``a.png`` with its preview.
    The preview is named from --out (``a.preview.png``); an existing preview that no
    ``a.tif`` goes with is refused before rendering."""
    from resection.io.images import read_image, write_image
    from selfillum.cli.main import main

    corner_files(tmp_path)
    photo = np.arange(12, dtype=np.uint8).reshape(3, 4)
    write_image(tmp_path / "a.png", photo)
    raw = (tmp_path / "a.png").read_bytes()
    args = ["render", "--mesh", str(tmp_path / "corner.ply"), "--camera",
            str(tmp_path / "cam.json"), "--emission", "1", "--reflectance", "0.3",
            "--bounces", "1", "--spp", "1", "--variant", "scalar"]
    rc = main([*args, "--out", str(tmp_path / "a.tif")])
    assert rc == 0, capsys.readouterr().err
    assert (tmp_path / "a.png").read_bytes() == raw
    prev = read_image(tmp_path / "a.preview.png")
    assert prev.shape == read_image(tmp_path / "a.tif").shape == (72, 96)
    # a second run into the same --out replaces its own pair
    assert main([*args, "--out", str(tmp_path / "a.tif")]) == 0
    # a file named like a preview, but without its image: not ours, refused
    write_image(tmp_path / "b.preview.png", photo)
    capsys.readouterr()
    rc = main([*args, "--out", str(tmp_path / "b.tif")])
    err = capsys.readouterr().err
    assert rc == 2 and "b.preview.png" in err and "refusing" in err
    assert not (tmp_path / "b.tif").exists()
    np.testing.assert_array_equal(read_image(tmp_path / "b.preview.png"), photo)


def test_failing_psp_leaves_no_output_folder(tmp_path, capsys):
    """A ``selfillum psp`` run that fails (here: wind-on = wind-off, so the ratio does
    not follow the taps' pressures) left an empty output folder behind on today's main."""
    from resection.io.images import write_image
    from selfillum.cli.main import main

    sc, _, img = corner_files(tmp_path)
    write_image(tmp_path / "off.tif", img)
    write_image(tmp_path / "on.tif", img)
    c = np.asarray(sc.mesh.triangles_center)
    (tmp_path / "taps.csv").write_text("id,x,y,z,p\n" + "".join(
        f"K{i},{c[i, 0]},{c[i, 1]},{c[i, 2]},{90 + 5 * k}\n"
        for k, i in enumerate((3, 10, 20, 27))))
    out = tmp_path / "run" / "psp"
    rc = main(["psp", "--mesh", str(tmp_path / "corner.ply"), "--camera",
               str(tmp_path / "cam.json"), "--wind-off", str(tmp_path / "off.tif"),
               "--wind-on", str(tmp_path / "on.tif"), "--taps", str(tmp_path / "taps.csv"),
               "--p-ref", "100", "--no-correction", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "not significantly" in err, err
    assert not out.exists() and not out.parent.exists()


def test_output_folder_removed_only_when_this_run_made_it(tmp_path):
    """The folder helper behind ``psp``: a failure removes what the run created, never a
    folder that was there before (nor the files in it)."""
    from resection.io.outputs import output_folder

    with pytest.raises(RuntimeError):
        with output_folder(tmp_path / "new" / "deep") as out:
            (out / "half.csv").write_text("1,2\n")
            raise RuntimeError("solver failed")
    assert not (tmp_path / "new").exists()
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "keep.txt").write_text("mine")
    with pytest.raises(RuntimeError):
        with output_folder(tmp_path / "old") as out:
            raise RuntimeError("solver failed")
    assert (tmp_path / "old" / "keep.txt").read_text() == "mine"


# --------------------------------------------------------------------------------------
# Image sizes that cannot be allocated are refused before allocating (issue 10 item 6)
# --------------------------------------------------------------------------------------


def test_view_size_that_cannot_be_allocated_is_refused(tmp_path, capsys):
    """``resection view --size 100000x100000`` ended in a MemoryError traceback: 1e10
    pixels need terabytes for the per-pixel rays; refused in one line, nothing written."""
    from resection.cli.main import main

    sc, _, _ = corner_files(tmp_path)
    np.save(tmp_path / "v.npy", np.arange(len(sc.mesh.faces), dtype=float))
    out = tmp_path / "view.png"
    rc = main(["view", "--mesh", str(tmp_path / "corner.ply"), "--values",
               str(tmp_path / "v.npy"), "--size", "100000x100000", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "100000x100000" in err and "GiB" in err and len(err.splitlines()) == 1
    assert not out.exists()
    # a size that fits still works
    rc = main(["view", "--mesh", str(tmp_path / "corner.ply"), "--values",
               str(tmp_path / "v.npy"), "--size", "120x90", "--out", str(out)])
    assert rc == 0 and out.exists()


def test_pixel_memory_decision_against_a_stated_budget():
    """The decision itself, with the budget given (independent of this machine)."""
    from resection.memory import check_pixel_memory

    check_pixel_memory(1000, 1000, 100, "x", available=100_000_000)  # exactly fits
    with pytest.raises(InputError, match="1001x1000"):
        check_pixel_memory(1001, 1000, 100, "x", available=100_000_000)
    with pytest.raises(InputError, match="positive"):
        check_pixel_memory(0, 10, 100, "x", available=100)
