"""uPSP .tgts target files and marker CSV normals: read, write, taps, targets under the
surface (closed-form geometry on a flat plate)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from resection import InputError, read_markers, write_markers
from resection.io.markers import MarkerSet
from resection.io.tgts import read_tgts, snap_to_surface, write_tgts

TGTS = """# uPSP targets, inches
*Targets
1  10.0  2.0  0.5   0.0 0.0 2.0   0.25  1 10 4  T1
2  12.5 -1.0  0.5   0.0 0.0 1.0   0.25  1 20 7  T2
3  14.0  0.0  0.25  1.0 0.0 0.0   0.30  2  3 3  T3
*Taps
1  11.0  0.0  0.5   0.0 0.0 1.0   0.05  1 15 5  P1
# end
"""


def test_read_tgts(tmp_path):
    p = tmp_path / "model.tgts"
    p.write_text(TGTS)
    assert read_markers(p).ids == ("T1", "T2", "T3")  # by default never a tap as target
    ms = read_markers(p, include_taps=True)
    assert ms.ids == ("T1", "T2", "T3", "P1")
    np.testing.assert_array_equal(ms.xyz[2], [14.0, 0.0, 0.25])
    np.testing.assert_array_equal(ms.normals[0], [0.0, 0.0, 1.0])  # normalised
    np.testing.assert_array_equal(ms.diameter, [0.25, 0.25, 0.30, 0.05])
    assert ms.taps.tolist() == [False, False, False, True]
    assert ms.targets.ids == ("T1", "T2", "T3") and ms.tap_set.ids == ("P1",)
    other = tmp_path / "model.txt"  # recognised by content, not by extension
    other.write_text(TGTS)
    assert read_markers(other, include_taps=True).ids == ms.ids


def test_tgts_round_trip(tmp_path):
    src = tmp_path / "a.tgts"
    src.write_text(TGTS)
    ms = read_tgts(src).markers
    out = tmp_path / "b.tgts"
    write_tgts(out, ms)
    back = read_tgts(out).markers
    assert back.ids == ms.ids
    for attr in ("xyz", "normals", "diameter", "taps"):
        np.testing.assert_array_equal(getattr(back, attr), getattr(ms, attr))


def test_marker_csv_normals_round_trip_and_facing(tmp_path):
    xyz = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    nrm = np.array([[0.0, 0, 1], [0, 0, -1], [np.nan] * 3])
    p = tmp_path / "m.csv"
    write_markers(p, ["a", "b", "c"], xyz, [0.01, 0.01, np.nan], normals=nrm)
    ms = read_markers(p)
    np.testing.assert_array_equal(ms.xyz, xyz)
    np.testing.assert_array_equal(ms.normals[:2], nrm[:2])
    assert np.isnan(ms.normals[2]).all() and np.isnan(ms.diameter[2])
    # a camera above the plate sees a, not b (normal away); c has no normal: expected
    assert ms.facing([0.5, 0.0, 3.0]).tolist() == [True, False, True]


@pytest.mark.parametrize(
    "body, match",
    [
        ("*Targets\n1 1 2 3 0 0 1 0.2 1 1 1\n", r":2: 11 columns, expected 12"),
        ("*Targets\n1 1 2 3 0 0 1 0.2 1 1 1 T1\n*Virtuals\n1 1 2 3 0 0 1 0.2 1 1 1\n",
         r":4: 11 columns, expected 12"),
        ("*Targets\n1 1 2 3 0 0 1 0.2 1 1 1 T1\n*Kulites\n1 1 2 3 0 0 1 0.2 1 1 1 T1\n",
         r":4: duplicate name 'T1' \(first on line 2\)"),
        ("*Targets\n1 1 2 x 0 0 1 0.2 1 1 1 T1\n", r":2: a numeric column"),
        ("*Targets\n1 1 2 3 0 0 0 0.2 1 1 1 T1\n", r":2: zero normal"),
        ("*Targets\n1 1 2 3 0 0 1 0.2 1 1 1 T1\n2 1 2 3 0 0 1 0.2 1 1 1 T1\n", "duplicate"),
        ("*Taps\n1 1 2 3 0 0 1 0.2 1 1 1 P1\n", "no targets"),
    ],
)
def test_bad_tgts(tmp_path, body, match):
    p = tmp_path / "bad.tgts"
    p.write_text(body)
    with pytest.raises(InputError, match=match) as err:
        read_markers(p)
    assert str(p) in str(err.value) and "\n" not in str(err.value)


def test_marker_csv_partial_normals_refused(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text("id,x,y,z,nx,ny\na,0,0,0,0,1\n")
    with pytest.raises(InputError, match="nx,ny,nz come together"):
        read_markers(p)


def test_target_under_the_surface_moves_out_along_its_normal(tmp_path):
    # a 1 x 1 plate at z = 0, normal +z, and a 0.2-thick block: targets 2 mm under the
    # plate move to z = 0 along +z; one tilted normal moves along it (closed form)
    plate = trimesh.creation.box(extents=[1.0, 1.0, 0.2])
    plate.apply_translation([0, 0, -0.1])  # top face at z = 0
    n2 = np.array([0.0, 0.6, 0.8])
    ms = MarkerSet(("a", "b", "c"), np.array([[0.1, 0.1, -0.002], [0.2, -0.1, -0.004],
                                               [0.0, 0.0, 0.001]]),
                   np.full(3, 0.01), np.array([[0, 0, 1.0], n2, [0, 0, 1.0]]))
    with pytest.warns(UserWarning, match=r"2 target\(s\) lay under the surface.*a \(0\.002\)"):
        out = snap_to_surface(ms, plate, source="m.tgts")
    np.testing.assert_allclose(out.xyz[0], [0.1, 0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(out.xyz[1], [0.2, -0.1 + 0.004 / 0.8 * 0.6, 0.0], atol=1e-12)
    np.testing.assert_array_equal(out.xyz[2], ms.xyz[2])  # above the surface: untouched
    p = tmp_path / "m.csv"
    write_markers(p, ms.ids, ms.xyz, ms.diameter, normals=ms.normals)
    with pytest.warns(UserWarning, match="m.csv"):
        again = read_markers(p, mesh=plate)
    np.testing.assert_allclose(again.xyz, out.xyz, atol=1e-12)


def test_psp_taps_positions_from_tgts(tmp_path):
    """``selfillum psp --taps P.csv --tap-positions MODEL.tgts``: the pressures come from an
    id,p file, the positions from the .tgts *Taps section."""
    from selfillum.images.psp import read_taps

    (tmp_path / "model.tgts").write_text(TGTS)
    (tmp_path / "p.csv").write_text("id,p\nP1,101.5\n")
    taps = read_taps(tmp_path / "p.csv", positions=tmp_path / "model.tgts")
    assert taps.ids == ["P1"]
    np.testing.assert_array_equal(taps.points, [[11.0, 0.0, 0.5]])
    np.testing.assert_array_equal(taps.pressure, [101.5])
    with pytest.raises(InputError, match="give the tap positions"):
        read_taps(tmp_path / "p.csv")
    (tmp_path / "q.csv").write_text("id,p\nP9,100\n")
    with pytest.raises(InputError, match="P9"):
        read_taps(tmp_path / "q.csv", positions=tmp_path / "model.tgts")


# NASA's TC3 volume file layout: targets, then *Virtuals (the Kulites), then a section we
# do not know; uPSP reads one section at a time and ignores the others
TC3 = """#GRID_FILE: volume.grid
#GRID_TOLERANCE: 0.39
*Targets
1  10.0  2.0  0.5   0.0 0.0 1.0   0.25  1 10 4  st01
2  12.5 -1.0  0.5   0.0 0.0 1.0   0.25  1 20 7  st02
3  14.0  0.0  0.25  1.0 0.0 0.0   0.30  2  3 3  st03
*Virtuals
1  20.0  1.0  0.5   0.0 0.0 1.0   0.10  3 40 9  K01
2  21.0 -1.0  0.5   0.0 1.0 0.0   0.10  3 41 2  K02
*Oilflow
12 lines of something else entirely
*Taps
1  11.0  0.0  0.5   0.0 0.0 1.0   0.05  1 15 5  CP01
"""


def test_tgts_every_section_read(tmp_path):
    p = tmp_path / "fml_tc3_volume.tgts"
    p.write_text(TC3)
    with pytest.warns(UserWarning) as rec:
        tf = read_tgts(p)
    msgs = [str(w.message) for w in rec]
    assert len(msgs) == 1 and "\n" not in msgs[0]
    assert f"{p}:10: section '*Oilflow'" in msgs[0] and "kept" in msgs[0]
    assert [s.name for s in tf.sections] == ["Targets", "Virtuals", "Oilflow", "Taps"]
    assert [s.kind for s in tf.sections] == ["targets", "virtuals", "unknown", "taps"]
    assert tf.unknown == ("Oilflow",)
    assert tf.section("*oilflow")[0].rows == ("12 lines of something else entirely",)
    assert tf.targets.ids == ("st01", "st02", "st03") and not tf.targets.taps.any()
    assert tf.taps.ids == ("CP01",) and tf.taps.taps.all()
    v = tf.virtuals
    assert v.ids == ("K01", "K02") and v.taps.all()  # dark spots, not targets
    np.testing.assert_array_equal(v.xyz, [[20.0, 1.0, 0.5], [21.0, -1.0, 0.5]])
    np.testing.assert_array_equal(v.normals, [[0, 0, 1.0], [0, 1.0, 0]])
    np.testing.assert_array_equal(v.diameter, [0.1, 0.1])
    np.testing.assert_array_equal(tf.section("Virtuals")[0].grid_nodes, [[3, 40, 9], [3, 41, 2]])
    assert tf.markers.ids == ("st01", "st02", "st03", "CP01", "K01", "K02")
    assert tf.markers.taps.tolist() == [False] * 3 + [True] * 3
    # what pose and matching are given: the targets only, never a tap or a Kulite
    with pytest.warns(UserWarning, match="Oilflow"):
        assert read_markers(p).ids == ("st01", "st02", "st03")
    with pytest.warns(UserWarning, match="Oilflow"):
        ms = read_markers(p, include_taps=True)
    assert ms.ids == tf.markers.ids and ms.targets.ids == ("st01", "st02", "st03")
    assert ms.tap_set.ids == ("CP01", "K01", "K02")


def test_tgts_kulites_alias_and_no_targets(tmp_path):
    p = tmp_path / "k.tgts"
    p.write_text("*Kulites\n1 1 2 3 0 0 1 0.1 1 1 1 K7\n")
    tf = read_tgts(p)  # a transducer-only file is read (the unsteady run needs no target)
    assert tf.virtuals.ids == ("K7",) and len(tf.targets) == 0
    with pytest.raises(InputError, match="no targets"):
        read_markers(p)  # pose needs targets and says so


def test_tgts_round_trip_keeps_every_section(tmp_path):
    src = tmp_path / "a.tgts"
    src.write_text(TC3)
    with pytest.warns(UserWarning):
        tf = read_tgts(src)
    out = tmp_path / "b.tgts"
    write_tgts(out, tf)
    with pytest.warns(UserWarning, match="Oilflow"):
        back = read_tgts(out)
    assert [(s.name, s.kind, s.rows if s.kind == "unknown" else s.markers.ids)
            for s in back.sections] == \
        [(s.name, s.kind, s.rows if s.kind == "unknown" else s.markers.ids) for s in tf.sections]
    assert back.header == ("#GRID_FILE: volume.grid", "#GRID_TOLERANCE: 0.39")
    for a, b in zip(tf.sections, back.sections, strict=True):
        np.testing.assert_array_equal(a.grid_nodes, b.grid_nodes)
        np.testing.assert_array_equal(a.markers.xyz, b.markers.xyz)
        np.testing.assert_array_equal(a.markers.diameter, b.markers.diameter)


def test_psp_tap_positions_from_virtuals_and_blame(tmp_path):
    """Kulite positions from *Virtuals serve ``--tap-positions``; a bad .tgts is named as
    the culprit, not the tap CSV."""
    from selfillum.images.psp import read_taps

    (tmp_path / "model.tgts").write_text(TC3)
    (tmp_path / "p.csv").write_text("id,p\nK02,99.0\nCP01,101.5\n")
    with pytest.warns(UserWarning, match="Oilflow"):
        taps = read_taps(tmp_path / "p.csv", positions=tmp_path / "model.tgts")
    assert taps.ids == ["K02", "CP01"]
    np.testing.assert_array_equal(taps.points, [[21.0, -1.0, 0.5], [11.0, 0.0, 0.5]])
    bad = tmp_path / "bad.tgts"
    bad.write_text("*Targets\n1 1 2 3 0 0 1 0.2 1 1 1 T1\n*Virtuals\n1 1 2 x 0 0 1 0.1 1 1 1 K1\n")
    with pytest.raises(InputError) as err:
        read_taps(tmp_path / "p.csv", positions=bad)
    assert str(err.value).startswith(f"{bad}:4:")
