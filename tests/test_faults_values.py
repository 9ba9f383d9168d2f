"""Fault cases of values: checked where they enter (header sizes, counts and offsets, focal
lengths, boxes, ray memory, nesting, truncated tables), saturated pixels masked and counted,
and side files that are the user's never replaced (issue 25 items 2, 3, 7, 8, 13-15). The
family of tests/test_faults.py."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from fault_files import corner_files

from resection import InputError


def _run(main, argv, capsys):
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _one_line(rc, err):
    return rc == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def _front(tmp_path, resolution=6):
    """The corner seen from its painted side (for correct), as a user's files."""
    from resection.io.cameras import write_camera
    from resection.surface.plots import virtual_camera
    from scenes.corner import corner

    sc = corner(resolution=resolution)
    sc.mesh.export(tmp_path / "corner.ply")
    cam = virtual_camera(sc.mesh, 45.0, 30.0, width=96, height=72)
    write_camera(tmp_path / "cam.json", cam)
    return sc, cam


# --------------------------------------------------------------------------------------
# side files and files named inside an output folder (items 2, 3)
# --------------------------------------------------------------------------------------


def test_correct_never_replaces_a_json_of_the_users(tmp_path, capsys):
    """`selfillum correct --out a.tif` replaced an unrelated a.tif.json. Now refused by
    name; the summary the command wrote itself is replaced by the next run."""
    from resection.io.images import write_image
    from selfillum.cli import main

    _front(tmp_path)
    write_image(tmp_path / "img.tif", np.full((72, 96), 3000, np.uint16))
    mine = tmp_path / "a.tif.json"
    mine.write_text('{"my": "notes"}')
    args = ["correct", "--mesh", tmp_path / "corner.ply", "--camera", tmp_path / "cam.json",
            "--image", tmp_path / "img.tif", "--reflectance", "0.5", "--rays", "16",
            "--quiet"]
    rc, _, err = _run(main, [*args, "--out", tmp_path / "a.tif"], capsys)
    assert _one_line(rc, err) and "a.tif.json" in err and "refusing" in err, err
    assert mine.read_text() == '{"my": "notes"}' and not (tmp_path / "a.tif").exists()
    rc, _, err = _run(main, [*args, "--out", tmp_path / "b.tif"], capsys)
    assert rc == 0, err
    summary = json.loads((tmp_path / "b.tif.json").read_text())
    assert summary["written_by"] == "selfillum correct" and summary["side_file_of"] == "b.tif"
    assert _run(main, [*args, "--out", tmp_path / "b.tif"], capsys)[0] == 0  # ours: replaced


def test_psp_never_replaces_its_own_inputs_in_its_folder(tmp_path, capsys, monkeypatch):
    """`selfillum psp --out .` overwrote its own `--taps pressure_faces.csv`."""
    from selfillum.cli import main

    _front(tmp_path)
    np.save(tmp_path / "off.npy", np.full((72, 96), 1000.0))
    taps = tmp_path / "pressure_faces.csv"
    taps.write_text("id,x,y,z,p\nA,0.1,0.1,0,1\nB,0.2,0.3,0,2\n")
    raw = taps.read_bytes()
    monkeypatch.chdir(tmp_path)
    rc, _, err = _run(main, ["psp", "--mesh", "corner.ply", "--camera", "cam.json",
                             "--wind-off", "off.npy", "--wind-on", "off.npy", "--taps",
                             "pressure_faces.csv", "--p-ref", "1", "--out", "."], capsys)
    assert _one_line(rc, err) and "pressure_faces.csv" in err, err
    assert taps.read_bytes() == raw


# --------------------------------------------------------------------------------------
# values checked where they enter (items 7, 13, 14, 15)
# --------------------------------------------------------------------------------------


def test_absurd_focal_length_and_empty_view_box_are_refused(tmp_path, capsys):
    """A camera with fx = fy = 1e308 mapped '1 of 144 faces seen', exit 0; `view --box 0 0
    0 0 0 0` drew a picture with no coloured face."""
    from resection.cli import main

    sc, cam, img = corner_files(tmp_path)
    d = json.loads((tmp_path / "cam.json").read_text())
    d["K"][0][0] = d["K"][1][1] = 1e308
    (tmp_path / "far.json").write_text(json.dumps(d))
    rc, _, err = _run(main, ["map", "--mesh", tmp_path / "corner.ply", "--camera",
                             tmp_path / "far.json", "--image", tmp_path / "img.npy", "--out",
                             tmp_path / "m.vtk"], capsys)
    assert _one_line(rc, err) and "focal length" in err and "far.json" in err, err
    np.save(tmp_path / "v.npy", np.arange(len(sc.mesh.faces), dtype=float))
    view = ["view", "--mesh", tmp_path / "corner.ply", "--values", tmp_path / "v.npy",
            "--size", "80x60", "--out", tmp_path / "v.png"]
    for box in (["0"] * 6, ["5", "5", "5", "6", "6", "6"]):
        rc, _, err = _run(main, [*view, "--box", *box], capsys)
        assert _one_line(rc, err) and "box" in err, err
        assert not (tmp_path / "v.png").exists()
    lo, hi = sc.mesh.bounds
    rc, _, err = _run(main, [*view, "--box", *map(str, lo), *map(str, hi)], capsys)
    assert rc == 0, err


@pytest.mark.parametrize("first", ["nan", "inf", "-inf", "1e999"])
def test_plot3d_with_a_non_finite_block_count(tmp_path, capsys, first):
    """An ASCII Plot3D whose first number is nan or inf: ValueError / OverflowError
    traceback on today's main."""
    from resection.cli import main

    corner_files(tmp_path)
    grid = tmp_path / "g.xyz"
    grid.write_text(f"{first}\n2 2 1\n0 1 0 1\n0 0 1 1\n0 0 0 0\n")
    rc, _, err = _run(main, ["map", "--mesh", grid, "--camera", tmp_path / "cam.json",
                             "--image", tmp_path / "img.npy", "--out", tmp_path / "m.vtk"],
                      capsys)
    assert _one_line(rc, err) and "g.xyz" in err, err


def test_ray_count_beyond_memory_is_refused_before_allocating(tmp_path, capsys):
    """`correct --rays 1000000000000`: _ArrayMemoryError "Unable to allocate 10.9 TiB"."""
    from selfillum.cli import main

    _front(tmp_path)
    np.save(tmp_path / "img.npy", np.full((72, 96), 1000.0, np.float32))
    rc, _, err = _run(main, ["correct", "--mesh", tmp_path / "corner.ply", "--camera",
                             tmp_path / "cam.json", "--image", tmp_path / "img.npy",
                             "--reflectance", "0.5", "--rays", "1000000000000", "--quiet",
                             "--out", tmp_path / "o.npy"], capsys)
    assert _one_line(rc, err) and "GiB" in err and "rays per face" in err, err
    assert not (tmp_path / "o.npy").exists()


def test_deeply_nested_json_and_truncated_poses_csv(tmp_path, capsys):
    """A JSON camera nested 100,000 deep: RecursionError traceback; `map --track` on a
    truncated poses.csv: IndexError traceback."""
    from resection.cli import main

    corner_files(tmp_path)
    (tmp_path / "deep.json").write_text("[" * 100000 + "]" * 100000)
    base = ["map", "--mesh", tmp_path / "corner.ply", "--image", tmp_path / "img.npy"]
    rc, _, err = _run(main, [*base, "--camera", tmp_path / "deep.json", "--out",
                             tmp_path / "m.vtk"], capsys)
    assert _one_line(rc, err) and "nested" in err and "deep.json" in err, err
    np.save(tmp_path / "stack.npy", np.stack([np.load(tmp_path / "img.npy")] * 2))
    trk = tmp_path / "trk"
    trk.mkdir()
    from resection.sequence.results import MARKER_COLUMNS, POSE_COLUMNS

    (trk / "poses.csv").write_text(",".join(POSE_COLUMNS) + "\n0,f.npy,ok,,0,0\n")
    (trk / "markers.csv").write_text(",".join(MARKER_COLUMNS) + "\n")
    rc, _, err = _run(main, ["map", "--mesh", tmp_path / "corner.ply", "--camera",
                             tmp_path / "cam.json", "--image", tmp_path / "stack.npy",
                             "--track", trk, "--out", tmp_path / "h.h5"], capsys)
    assert _one_line(rc, err) and "poses.csv" in err and "line 2" in err, err


def test_video_header_values_are_checked_where_they_enter(tmp_path, capsys):
    """A .cine header claiming 2^31 frames was read until killed at 24 GB; a .cine with a
    negative frame offset gave a ValueError from `map`; a .cih with a negative width an
    OverflowError."""
    import pyMRAW
    from test_io_video import _frames, _write_cine

    from resection.cli import main
    from resection.io.video import open_frames

    p = tmp_path / "run.cine"
    _write_cine(p, _frames())
    data = bytearray(p.read_bytes())
    many = bytearray(data)
    struct.pack_into("<I", many, 20, 2**31)  # ImageCount
    (tmp_path / "many.cine").write_bytes(bytes(many))
    with pytest.raises(InputError, match="2147483648 frames"):
        open_frames(tmp_path / "many.cine")
    neg = bytearray(data)
    off_table = struct.unpack_from("<I", data, 32)[0]  # OffImageOffsets
    struct.pack_into("<q", neg, off_table + 8, -4096)  # frame 1 at a negative offset
    (tmp_path / "neg.cine").write_bytes(bytes(neg))
    with pytest.raises(InputError, match="frame 1's offset"):
        open_frames(tmp_path / "neg.cine")
    mraw, cih = pyMRAW.save_mraw(_frames(bits=16), str(tmp_path / "w.cih"), bit_depth=16)
    text = open(cih).read().replace("Image Width : 36", "Image Width : -36")
    assert "Image Width : -36" in text
    open(cih, "w").write(text)
    with pytest.raises(InputError, match=r"-36"):
        open_frames(cih)
    # through the command: one line each
    corner_files(tmp_path)
    for bad in (tmp_path / "many.cine", tmp_path / "neg.cine", cih):
        rc, _, err = _run(main, ["map", "--mesh", tmp_path / "corner.ply", "--camera",
                                 tmp_path / "cam.json", "--image", bad, "--out",
                                 tmp_path / "h.h5"], capsys)
        assert _one_line(rc, err) and str(bad.name if hasattr(bad, "name") else bad) in err, err


# --------------------------------------------------------------------------------------
# saturated pixels are unknown, not values (item 8)
# --------------------------------------------------------------------------------------


def test_saturated_pixels_are_not_corrected_into_values(tmp_path, capsys):
    """An 8-bit image at 255 everywhere gave 179-182; a 65535 patch on a 16-bit image gave
    49571-64103; no warning. Now saturated pixels stay unknown (at full scale in an integer
    image), their faces count as unseen, and one line says how many."""
    from resection.io.images import read_native, write_image
    from selfillum.cli import main

    _front(tmp_path)
    args = ["correct", "--mesh", tmp_path / "corner.ply", "--camera", tmp_path / "cam.json",
            "--reflectance", "0.5", "--rays", "64", "--quiet"]
    img = np.full((72, 96), 30000, np.uint16)
    img[20:40, 30:60] = 65535
    write_image(tmp_path / "a.tif", img)
    rc, _, err = _run(main, [*args, "--image", tmp_path / "a.tif", "--out",
                             tmp_path / "o.tif"], capsys)
    assert rc == 0, err
    out = read_native(tmp_path / "o.tif")
    np.testing.assert_array_equal(out[img == 65535], 65535)
    line = [s for s in err.splitlines() if "saturated" in s]
    assert len(line) == 1 and "600 at or above 65535" in line[0], err
    summary = json.loads((tmp_path / "o.tif.json").read_text())
    assert summary["saturated_pixels"] == 600 and summary["saturated_faces"] > 0
    # a stated level: 30000 and above is saturated; a float image: NaN
    np.save(tmp_path / "f.npy", img.astype(np.float32))
    rc, _, err = _run(main, [*args, "--image", tmp_path / "f.npy", "--out",
                             tmp_path / "o.npy", "--saturation", "60000"], capsys)
    assert rc == 0, err
    o = np.load(tmp_path / "o.npy")
    assert np.isnan(o[img == 65535]).all() and np.isfinite(o[img < 60000]).all()
    write_image(tmp_path / "b.png", np.full((72, 96), 255, np.uint8))
    rc, _, err = _run(main, [*args, "--image", tmp_path / "b.png", "--out",
                             tmp_path / "o8.png"], capsys)
    assert _one_line(rc, err) and "saturated" in err and not (tmp_path / "o8.png").exists()


def test_map_masks_saturated_pixels_and_counts_them(tmp_path, capsys):
    """`map` averaged saturated pixels into face values. Now the faces they fall on are
    unknown (NaN, not seen) and one line counts them."""
    from resection.cli import main
    from resection.io.images import write_image
    from resection.io.meshes import read_face_fields

    sc, cam, _ = corner_files(tmp_path)
    img = np.full((72, 96), 1000, np.uint16)
    img[30:34, 40:44] = 65535
    write_image(tmp_path / "s.tif", img)
    rc, _, err = _run(main, ["map", "--mesh", tmp_path / "corner.ply", "--camera",
                             tmp_path / "cam.json", "--image", tmp_path / "s.tif", "--out",
                             tmp_path / "m.vtk"], capsys)
    assert rc == 0, err
    assert "saturated pixels: 16 at or above 65535" in err
    f = read_face_fields(tmp_path / "m.vtk", len(sc.mesh.faces))
    vals, seen = f["s"], f["s_seen"].astype(bool)
    assert np.all(np.isnan(vals[~seen]))
    assert np.nanmax(vals) == pytest.approx(1000.0)  # no saturated count in any value
    from resection.surface.surface_map import SurfaceMap

    smap = SurfaceMap(sc.mesh, cam)
    hit = np.unique(smap.face_index[30:34, 40:44][smap.mask[30:34, 40:44]])
    assert hit.size and np.all(np.isnan(vals[hit]))


def test_time_history_masks_saturated_pixels_and_counts_them(tmp_path, capsys):
    """`map --out P.h5` took saturated counts as values. Now they are unknown (the same
    history as with those pixels NaN in float frames) and counted in one line."""
    from resection.cli import main
    from resection.io.history import read_history
    from resection.io.images import write_image

    corner_files(tmp_path)
    ints, floats = [], []
    for k in range(2):
        img = np.full((72, 96), 1000 + 10 * k, np.uint16)
        img[30:34, 40:44] = 65535
        write_image(tmp_path / f"s{k}.tif", img)
        f = img.astype(np.float32)
        f[img == 65535] = np.nan
        np.save(tmp_path / f"s{k}.npy", f)
        ints.append(tmp_path / f"s{k}.tif")
        floats.append(tmp_path / f"s{k}.npy")
    base = ["map", "--mesh", tmp_path / "corner.ply", "--camera", tmp_path / "cam.json",
            "--fps", "10"]
    rc, _, err = _run(main, [*base, "--image", *ints, "--out", tmp_path / "a.h5"], capsys)
    assert rc == 0 and "saturated pixels: 32 at or above 65535" in err, err
    assert len([s for s in err.splitlines() if "saturated" in s]) == 1
    rc, _, err = _run(main, [*base, "--image", *floats, "--out", tmp_path / "b.h5"], capsys)
    assert rc == 0 and "saturated" not in err, err
    a, b = read_history(tmp_path / "a.h5").values, read_history(tmp_path / "b.h5").values
    np.testing.assert_array_equal(a, b)
    assert np.nanmax(a) <= 1010.0 + 1e-3


def test_merged_map_counts_saturated_pixels(tmp_path, capsys):
    """Several cameras (`map` merging views): the saturated pixels of every image are
    unknown (in no camera's value) and counted in one line."""
    from resection.cli import main
    from resection.io.images import write_image
    from resection.io.meshes import read_face_fields

    sc, cam, _ = corner_files(tmp_path)
    for k in range(2):
        img = np.full((72, 96), 1000, np.uint16)
        img[30:34, 40:44 + k] = 65535
        write_image(tmp_path / f"c{k}.tif", img)
    rc, _, err = _run(main, ["map", "--mesh", tmp_path / "corner.ply", "--camera",
                             tmp_path / "cam.json", "--camera", tmp_path / "cam.json",
                             "--image", tmp_path / "c0.tif", tmp_path / "c1.tif", "--out",
                             tmp_path / "m.vtk"], capsys)
    assert rc == 0, err
    assert "saturated pixels: 36 at or above 65535" in err, err  # 16 + 20
    f = read_face_fields(tmp_path / "m.vtk", len(sc.mesh.faces))
    assert np.nanmax(f["merged"]) < 1000.0 * 1.5  # no saturated count averaged in
