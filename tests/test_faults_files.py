"""Fault cases in reading users' files (camera JSON, images, meshes, Plot3D): a bad
file ends in a one-line error naming the file and the problem, never a traceback.
The family of tests/test_faults.py."""

from __future__ import annotations

import numpy as np
import pytest

from resection import InputError
from resection.io.cameras import read_camera

# --------------------------------------------------------------------------------------
# File parsing (io): camera JSON
# --------------------------------------------------------------------------------------


def _camera_dict() -> dict:
    from resection import Camera

    K = [[800.0, 0.0, 128.0], [0.0, 800.0, 96.0], [0.0, 0.0, 1.0]]
    return Camera(256, 192, K, t=[0.0, 0.0, 2.0]).to_dict()


def test_camera_json_with_byte_order_mark_is_accepted(tmp_path):

    p = tmp_path / "cam.json"
    import json

    p.write_bytes(b"\xef\xbb\xbf" + json.dumps(_camera_dict()).encode())
    cam = read_camera(p)
    assert (cam.width, cam.height) == (256, 192) and cam.K[0, 0] == 800.0


@pytest.mark.parametrize(
    "key, value, match",
    [
        ("width", "256", r"width must be an integer, got '256'"),
        ("K", [["800", 0, 128], [0, 800, 96], [0, 0, 1]], r"K\[0\]\[0\]: not a number"),
        ("K", [[True, 0, 128], [0, 800, 96], [0, 0, 1]], r"K\[0\]\[0\]: not a number"),
        ("t", [[0.0], [0.0], [2.0]], r"camera t: expected a flat list, got shape 3x1"),
        ("dist", [["0", 0, 0, 0, 0]], r"camera dist"),
    ],
)
def test_camera_json_wrong_types_and_shapes_are_errors(tmp_path, key, value, match):
    """String numbers, booleans and 3x1 vectors were accepted silently (or reported as a
    distortion error, or as 'got 256, 256'): each is now a one-line error naming the key."""
    import json


    d = _camera_dict()
    d[key] = value
    p = tmp_path / "cam.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match=match) as err:
        read_camera(p)
    msg = str(err.value)
    assert msg.startswith(str(p)) and "\n" not in msg
    assert "256, 256" not in msg


# --------------------------------------------------------------------------------------
# File parsing (io): images
# --------------------------------------------------------------------------------------


def test_detect_on_an_empty_npy_is_a_one_line_error(tmp_path, capsys):
    from resection.cli.main import main

    p = tmp_path / "empty.npy"
    p.write_bytes(b"")
    assert main(["detect", str(p), "--diameter", "6", "--out", str(tmp_path / "c.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "empty.npy" in err and "empty" in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("content", [b"", b"\x93NUMPY\x01\x00v\x00{'descr': '<f8', 'fo"])
def test_read_image_on_empty_or_truncated_npy(tmp_path, content):
    from resection import read_image

    p = tmp_path / "frame.npy"
    p.write_bytes(content)
    with pytest.raises(InputError, match="frame.npy"):
        read_image(p)


def test_corrupt_npy_never_advises_allow_pickle(tmp_path):
    from resection import read_image

    p = tmp_path / "obj.npy"
    np.save(p, np.array([{"a": 1}, None], dtype=object), allow_pickle=True)
    with pytest.raises(InputError) as err:
        read_image(p)
    assert "allow_pickle" not in str(err.value) and "obj.npy" in str(err.value)


def test_write_image_into_a_missing_folder_is_an_input_error(tmp_path):
    from resection import write_image

    with pytest.raises(InputError, match="does not exist"):
        write_image(tmp_path / "nope" / "a.tif", np.zeros((4, 4), np.float32))
    assert not (tmp_path / "nope").exists()


# --------------------------------------------------------------------------------------
# File parsing (io): meshes
# --------------------------------------------------------------------------------------


def _stl_bytes():
    import trimesh

    return trimesh.creation.box().export(file_type="stl")


@pytest.mark.parametrize("kind", ["random", "truncated", "ascii-truncated"])
def test_random_or_truncated_stl_names_the_problem(tmp_path, kind):
    """A random or truncated STL reported "No module named 'charset_normalizer'"."""
    import trimesh

    from resection import load_mesh

    p = tmp_path / "model.stl"
    if kind == "random":
        p.write_bytes(np.random.default_rng(0).bytes(3000))
    elif kind == "truncated":
        p.write_bytes(_stl_bytes()[:-70])
    else:
        text = trimesh.creation.box().export(file_type="stl_ascii")
        p.write_text(text[: len(text) // 2])
    with pytest.raises(InputError) as err:
        load_mesh(p)
    msg = str(err.value)
    assert "model.stl" in msg and "STL" in msg and "charset" not in msg
    assert "\n" not in msg


def test_duplicate_faces_are_named(tmp_path):
    import trimesh

    from resection import load_mesh

    box = trimesh.creation.box()
    faces = np.vstack([box.faces, box.faces[[3]]])  # face 3 twice: face 12 is its copy
    dup = trimesh.Trimesh(box.vertices, faces, process=False)
    p = tmp_path / "dup.stl"
    dup.export(p)
    with pytest.raises(InputError, match=r"dup.stl: 1 duplicate face.*faces 3 and 12"):
        load_mesh(p)


def test_byte_swapped_plot3d_is_read_or_named(tmp_path):
    """Coordinates written in the other byte order than the record markers gave "200
    degenerate triangles": they are now detected and read in the right order; a file whose
    coordinates are garbage in both orders is refused naming the byte order."""
    import struct

    from resection import load_mesh, write_plot3d

    x, y = np.meshgrid(np.linspace(0, 1, 11), np.linspace(0, 2, 11), indexing="ij")
    grid = np.stack([x, y, 0.1 * x * y], -1)[:, :, None, :]
    p = tmp_path / "wing.x"
    write_plot3d(p, [grid], endian="<")
    ref = load_mesh(p)
    d = bytearray(p.read_bytes())
    pos, recs = 0, []
    while pos < len(d):
        n = struct.unpack("<i", d[pos:pos + 4])[0]
        recs.append((pos + 4, n))
        pos += 8 + n
    s, n = recs[2]
    d[s:s + n] = np.frombuffer(bytes(d[s:s + n]), "<f8").astype(">f8").tobytes()
    p.write_bytes(bytes(d))
    got = load_mesh(p)
    np.testing.assert_array_equal(got.vertices, ref.vertices)
    d[s:s + n] = np.full(n // 8, 1e200).tobytes()  # implausible in both byte orders
    p.write_bytes(bytes(d))
    with pytest.raises(InputError, match=r"wing.x: block 1: .*implausible.*byte order"):
        load_mesh(p)


def test_no_npy_reader_advises_allow_pickle(tmp_path, capsys):
    """Every .npy the commands read (reflectance, per-face values, images) goes through one
    loader: an object array or an empty file is a one-line error that never advises
    allow_pickle."""
    from selfillum.images.image_correction import read_reflectance

    obj = tmp_path / "rho.npy"
    np.save(obj, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    empty = tmp_path / "empty.npy"
    empty.write_bytes(b"")
    for path in (obj, empty):
        with pytest.raises(InputError) as err:
            read_reflectance(str(path), 4)
        assert path.name in str(err.value) and "allow_pickle" not in str(err.value)
