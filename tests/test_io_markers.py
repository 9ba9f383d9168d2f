"""Marker / image-point CSV files: round trips and bad content named by file and line."""

import numpy as np
import pytest

from resection import InputError, read_markers, read_points, write_markers, write_points
from resection.io.markers import link_points, write_residuals


def test_round_trips(tmp_path):
    rng = np.random.default_rng(0)
    ids = [f"M{i}" for i in range(7)] + ["07", "tip"]
    xyz = rng.normal(size=(9, 3))
    diam = np.full(9, 0.004)
    diam[2] = np.nan
    write_markers(tmp_path / "m.csv", ids, xyz, diam)
    m = read_markers(tmp_path / "m.csv")
    assert m.ids == tuple(ids)  # strings, "07" keeps its zero
    np.testing.assert_array_equal(m.xyz, xyz)
    np.testing.assert_array_equal(np.isnan(m.diameter), np.isnan(diam))
    np.testing.assert_array_equal(m.diameter[~np.isnan(diam)], 0.004)
    write_markers(tmp_path / "m2.csv", ids, xyz)
    assert np.isnan(read_markers(tmp_path / "m2.csv").diameter).all()
    uv = rng.uniform(0, 1000, (4, 2))
    write_points(tmp_path / "p.csv", ["tip", "M3", "07", "M0"], uv)
    pid, puv = read_points(tmp_path / "p.csv")
    assert pid == ("tip", "M3", "07", "M0")
    np.testing.assert_array_equal(puv, uv)
    lid, X, U = link_points(m, pid, puv)
    np.testing.assert_array_equal(X, xyz[[8, 3, 7, 0]])
    np.testing.assert_array_equal(m.select(["M3"]), xyz[[3]])
    res = rng.normal(size=(4, 2))
    write_residuals(tmp_path / "r.csv", lid, U, res)
    lines = (tmp_path / "r.csv").read_text().splitlines()
    assert lines[0] == "id,u,v,u_proj,v_proj,du,dv,error"
    f = lines[2].split(",")
    assert f[0] == "M3" and float(f[7]) == pytest.approx(np.hypot(*res[1]), abs=1e-6)
    assert float(f[3]) == pytest.approx(uv[1, 0] - res[1, 0], abs=1e-6)


def test_header_variants_and_comments(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text("# wing markers\nID, X, Y, Z\n\na,0,0,0\nb,1,0,0\n# end\nc,0,1,0.5\n")
    m = read_markers(p)
    assert m.ids == ("a", "b", "c")
    assert m.xyz[2, 2] == 0.5
    q = tmp_path / "cand.csv"  # a matched-candidates file is a valid points file
    q.write_text("u,v,diameter,depth,merit,snr,id\n10.5,20.25,5,0.3,0.9,40,a\n")
    ids, uv = read_points(q)
    assert ids == ("a",) and uv.tolist() == [[10.5, 20.25]]


@pytest.mark.parametrize(
    "text, match",
    [
        ("id,x,y\na,1,2\n", r"m\.csv:1: missing column\(s\) z"),
        ("id,x,y,z,colour\na,1,2,3,red\n", "unknown column"),
        ("id,x,y,z\na,1,2,3\nb,1,2,3\na,4,5,6\n",
         r"m\.csv:4: duplicate id 'a' \(first on line 2\)"),
        ("id,x,y,z\na,1,2,3\nb,1,nan,3\n", r"m\.csv:3: column y: value 'nan' is not finite"),
        ("id,x,y,z\na,1,2,3\nb,1,two,3\n", r"m\.csv:3: column y: not a number"),
        ("id,x,y,z\na,1,2\n", r"m\.csv:2: expected 4 fields, got 3"),
        ("id,x,y,z\n,1,2,3\n", r"m\.csv:2: empty id"),
        ("id,x,y,z,diameter\na,1,2,3,-1\n", "diameter must be positive"),
        ("id,x,y,z\n", "no data rows"),
        ("", "empty marker file"),
        ("id,x,x,y,z\na,1,1,2,3\n", "repeated column"),
    ],
)
def test_bad_marker_files(tmp_path, text, match):
    p = tmp_path / "m.csv"
    p.write_text(text)
    with pytest.raises(InputError, match=match):
        read_markers(p)


def test_bad_points_and_links(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_markers(tmp_path / "none.csv")
    p = tmp_path / "p.csv"
    p.write_text("id,u,v\na,1,inf\n")
    with pytest.raises(InputError, match=r"p\.csv:2: column v"):
        read_points(p)
    m = tmp_path / "m.csv"
    m.write_text("id,x,y,z\na,0,0,0\nb,1,0,0\n")
    p.write_text("id,u,v\na,1,2\nzz,3,4\n")
    ids, uv = read_points(p)
    with pytest.raises(InputError, match="not in the marker file: zz"):
        link_points(read_markers(m), ids, uv)
    with pytest.raises(InputError, match="duplicate"):
        write_markers(tmp_path / "x.csv", ["a", "a"], np.zeros((2, 3)))
    with pytest.raises(InputError, match="directory"):
        read_markers(tmp_path)


def test_spreadsheet_export_with_bom_and_crlf(tmp_path):
    """A CSV saved by a spreadsheet (UTF-8 byte-order mark, CRLF line ends) reads the same."""
    p = tmp_path / "m.csv"
    p.write_bytes("\ufeffid,x,y,z\r\nA,1,2,3\r\nB,4,5,6\r\n".encode())
    m = read_markers(p)
    assert m.ids == ("A", "B")
    np.testing.assert_array_equal(m.xyz, [[1, 2, 3], [4, 5, 6]])
