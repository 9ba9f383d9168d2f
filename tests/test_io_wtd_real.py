"""The ``.wtd`` as NASA's data system writes it: uPSP's own test file (``tests/data/upsp/
wtd_test.wtd``, a ``RUN 3016 2`` line first, no-data values), read beside files of our own
and checked against uPSP's two reading routines, written out here from their source
(``python/upsp/cam_cal_utils/parsers.py: read_wind_tunnel_data`` and
``cpp/lib/non_cv_upsp.cpp: read_tunnel_conditions``)."""

from __future__ import annotations

import csv
import warnings

import numpy as np
import pytest

from resection.errors import InputError
from resection.io.wtd import read_wtd


def upsp_python_reader(path, items=("ALPHA", "BETA", "PHI", "STRUTZ")) -> dict:
    """uPSP's ``read_wind_tunnel_data``: skip the first line, a tab-separated DictReader,
    the first row, the items asked for."""
    with open(path) as f:
        f.readline()
        row = next(csv.DictReader(f, delimiter="\t"))
    vals = {k: float(v) for k, v in row.items()}
    return {k: v for k, v in vals.items() if k in items}


def upsp_cpp_reader(path) -> dict:
    """uPSP's ``read_tunnel_conditions``: the first line whose first word is ``#`` alone
    names the columns, the next line holds the values."""
    names = ("ALPHA", "BETA", "PHI", "MACH", "RNU", "PTOT", "Q", "TTF", "PS", "TCAVG")
    with open(path) as f:
        lines = f.read().splitlines()
    for i, line in enumerate(lines):
        terms = line.split()
        if terms and terms[0] == "#":
            vals = lines[i + 1].split()
            assert len(vals) == len(terms) - 1
            return {t: float(v) for t, v in zip(terms[1:], vals, strict=True) if t in names}
    raise AssertionError("no header")


def test_real_wtd_as_uPSP_reads_it(upsp_samples):
    p = upsp_samples / "wtd_test.wtd"
    w = read_wtd(p)
    assert (w.run, w.sequence) == (3016, 2)
    ref_py = upsp_python_reader(p)
    ref_cpp = upsp_cpp_reader(p)
    assert ref_py and ref_cpp
    for k, v in {**ref_py, **ref_cpp}.items():
        assert w.value(k) == v, k
    assert len(w.columns) == 24
    # every tap holds uPSP's no-data Cp: none is taken as data
    assert w.taps == {}
    assert len(w.no_data_taps) > 0 and w.no_data_taps[:3] == (1, 2, 3)
    # PS = Q = 0: a wind-off point, said so
    assert w.wind_off and w.label == "run 3016 point 2"
    with pytest.raises(InputError, match=r"wtd_test\.wtd: column T102 holds the no-data value"):
        w.value("T102")


def test_real_wtd_wind_off_refused_by_name(upsp_samples):
    from selfillum.unsteady.conditions import Conditions

    with pytest.raises(InputError, match=r"wtd_test\.wtd: PS = Q = 0, a wind-off point "
                                         r"\(run 3016 point 2\)"):
        Conditions.from_wtd(read_wtd(upsp_samples / "wtd_test.wtd"))


def test_wtd_run_line_and_no_data_taps_in_a_wind_on_file(tmp_path):
    """The real layout with a wind-on point: a RUN line, the header with its '#  ' and tabs,
    two taps read and one no-data."""
    p = tmp_path / "pt.wtd"
    p.write_text("RUN 3016 7\n#  MACH\tALPHA\tPS\tQ\tTTF\n0.85\t2.0\t1500.0\t600.0\t100.0\n"
                 "\n# Tap        CP\n    1        -0.250000\n    2        9.999900\n"
                 "    3        0.125000\n")
    w = read_wtd(p)
    assert (w.run, w.sequence) == (3016, 7) and not w.wind_off
    assert w.taps == {1: -0.25, 3: 0.125} and w.no_data_taps == (2,)
    assert upsp_cpp_reader(p)["Q"] == w.value("Q") == 600.0
    assert upsp_python_reader(p, ("ALPHA",)) == {"ALPHA": w.value("ALPHA")}


@pytest.mark.parametrize("first, msg", [
    ("RUN abc 2\n", r"x\.wtd:1: run number 'abc' is not an integer"),
    ("hello\n", r"x\.wtd:1: 'hello' before the '# NAME \.\.\.' header line"),
    ("RUN 1 2\nRUN 1 3\n", r"x\.wtd:2: 'RUN 1 3' before"),
    ("RUN 1 2\n" + "9" * 5000 + "\n", r"x\.wtd:2: '9{50,60}\.\.\.' before"),
])
def test_wtd_lines_before_the_header(tmp_path, first, msg):
    p = tmp_path / "x.wtd"
    p.write_text(first + "# MACH\tQ\n0.8\t1\n")
    with pytest.raises(InputError, match=msg) as e:
        read_wtd(p)
    assert len(str(e.value)) < 200 + len(str(p))


def test_wtd_column_twice_and_two_value_rows_warn(tmp_path):
    p = tmp_path / "x.wtd"
    p.write_text("# MACH\tQ\tmach\n0.8\t1\t0.9\n")
    with pytest.warns(UserWarning, match=r"x\.wtd:1: column mach named twice; the first "
                                         r"\(column 1\) is used"):
        w = read_wtd(p)
    assert w.value("MACH") == 0.8
    p.write_text("# MACH\tQ\n0.8\t1\n0.9\t2\n")
    with pytest.warns(UserWarning, match=r"x\.wtd:3: a second value row under the header; "
                                         r"the values of line 2 are used"):
        w = read_wtd(p)
    assert w.value("Q") == 1.0


def test_wtd_tap_cp_not_finite(tmp_path):
    p = tmp_path / "x.wtd"
    p.write_text("# MACH\tQ\n0.8\t1\n# Tap CP\n1 nan\n")
    with pytest.raises(InputError, match=r"x\.wtd:4: Cp of tap 1 is not finite"):
        read_wtd(p)
    p.write_text("# MACH\tQ\n0.8\t1\n# Tap CP\n1 0.1\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isclose(read_wtd(p).taps[1], 0.1)


def test_psp_taps_from_the_real_wtd(upsp_samples, tmp_path):
    """``psp --taps`` on NASA's file: every tap is no-data, and the point is wind-off; the
    taps of a wind-on file with one no-data tap are read without it, warned."""
    from selfillum.images.psp import read_taps

    tgts = upsp_samples / "fml_tc3_volume.tgts"
    with pytest.raises(InputError, match=r"wtd_test\.wtd: all \d+ taps hold the no-data Cp"):
        read_taps(upsp_samples / "wtd_test.wtd", tgts)
    p = tmp_path / "pt.wtd"
    p.write_text("RUN 3016 7\n#  MACH\tPS\tQ\n0.85\t1500.0\t600.0\n# Tap CP\n1 -0.25\n"
                 "2 9.9999\n")
    with pytest.warns(UserWarning, match=r"pt\.wtd: 1 tap\(s\) hold the no-data Cp 9\.9999 and "
                                         r"are left out \(taps 2\)"):
        taps = read_taps(p, tgts)
    assert taps.ids == ["CP01"] and taps.pressure[0] == pytest.approx(1500.0 - 0.25 * 600.0)
    assert np.allclose(taps.points[0], [-5.0002, -2.5998, -7.0])
    p.write_text("RUN 3016 7\n#  MACH\tPS\tQ\n0.85\t0\t0\n# Tap CP\n1 -0.25\n")
    with pytest.raises(InputError, match=r"pt\.wtd: PS = Q = 0, a wind-off point"):
        read_taps(p, tgts)
