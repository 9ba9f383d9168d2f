"""uPSP run inputs: the ``.wtd`` wind-tunnel data, the ``psp_process`` input deck and the
paint gain file, read as uPSP's file-format document lays them out (its own examples)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from resection.errors import InputError
from resection.io.upsp_inputs import read_deck, read_paint_calibration
from resection.io.wtd import is_wtd, read_wtd, tap_name

WTD = ("# MACH\tALPHA\tBETA\tPHI\tSTRUTZ_UNC\tPTOT\tTTF\tPS\tQ\n"
       "0.838751\t-0.041887\t0.011826\t-90.000000\t3.012192\t2390.5\t104.25\t1523.75\t603.5\n"
       "# Tap CP\n1\t-0.25\n2\t0.125\n12\t-1.5\n")


def test_wtd_conditions_and_taps(tmp_path):
    p = tmp_path / "123456.wtd"
    p.write_text(WTD)
    w = read_wtd(p)
    assert w.value("MACH") == 0.838751 and w.value("q") == 603.5 and w.value("PS") == 1523.75
    assert w.value("T0", "TTF") == 104.25  # first name present wins
    assert w.taps == {1: -0.25, 2: 0.125, 12: -1.5}
    assert is_wtd(p)
    (tmp_path / "x.txt").write_text(WTD)
    assert is_wtd(tmp_path / "x.txt")  # by its tap table
    with pytest.raises(InputError, match=r"123456\.wtd: no 'RE' column"):
        w.value("RE")


def test_wtd_bad(tmp_path):
    p = tmp_path / "bad.wtd"
    p.write_text("# MACH\tQ\n0.8\n")
    with pytest.raises(InputError, match=r"bad\.wtd:2: 1 values for 2 columns"):
        read_wtd(p)
    p.write_text("# MACH\tQ\n0.8\tx\n")
    with pytest.raises(InputError, match=r"bad\.wtd:2: column Q 'x' is not a number"):
        read_wtd(p)
    p.write_text("# MACH\tQ\n0.8\t1\n# Tap CP\n1 0.1\n1 0.2\n")
    with pytest.raises(InputError, match=r"bad\.wtd:5: tap 1 listed twice"):
        read_wtd(p)
    with pytest.raises(InputError, match="not found"):
        read_wtd(tmp_path / "none.wtd")


def test_tap_names():
    """The documented pairing: tap n is CPnn (two digits), else CPn, else n."""
    assert tap_name(1, ["CP01", "CP1", "1"]) == "CP01"
    assert tap_name(1, ["CP1", "1"]) == "CP1"
    assert tap_name(7, ["7", "T7"]) == "7"
    assert tap_name(123, ["CP123"]) == "CP123"
    assert tap_name(3, ["CP01"]) is None


DECK = """%Version 1.0
# a comment
@general
    test = my-test
    run = 1234
    sequence = 56
    tunnel = ames_unitary
@vars
    dir = {dir}
    inp = $dir/inputs
@all
    sds = $inp/123456.wtd
    grid = $inp/model.grid
    targets = ${{dir}}/inputs/model.tgts
@camera
    number = 2
    filename = $inp/12345602.mraw
    calibration = $inp/cam02-to-model.json
    aedc = false
@camera
    number = 1
    cine = $inp/12345601.cine
    calibration = $inp/cam01-to-model.json
@options
    target_patcher = polynomial
    registration = pixel
    overlap = best_view
    filter = gaussian
    filter_size = 3
    oblique_angle = 70
    number_frames = 2000
@output
    dir = $dir/outputs
"""


def _deck_files(tmp_path) -> Path:
    inp = tmp_path / "inputs"
    inp.mkdir()
    for n in ("123456.wtd", "model.grid", "model.tgts", "12345602.mraw", "12345601.cine",
              "cam01-to-model.json", "cam02-to-model.json"):
        (inp / n).write_text("x")
    p = tmp_path / "run.inp"
    p.write_text(DECK.format(dir=tmp_path))
    return p


def test_deck_read(tmp_path):
    d = read_deck(_deck_files(tmp_path))
    inp = tmp_path / "inputs"
    assert d.general["run"] == "1234" and d.sds == inp / "123456.wtd"
    assert d.grid == inp / "model.grid" and d.targets == inp / "model.tgts"
    assert [c.number for c in d.cameras] == [1, 2]  # sorted as uPSP sorts them
    assert d.cameras[0].video == inp / "12345601.cine"  # the legacy 'cine' key
    assert d.cameras[1].video == inp / "12345602.mraw"
    assert d.cameras[1].calibration == inp / "cam02-to-model.json"
    assert d.cameras[0].targets == inp / "model.tgts"  # from @all
    assert d.options == {"target_patcher": "polynomial", "registration": "pixel",
                         "overlap": "best_view", "filter": "gaussian", "filter_size": "3",
                         "oblique_angle": "70", "number_frames": "2000"}
    assert d.output_dir == tmp_path / "outputs"


def test_deck_bad(tmp_path):
    p = _deck_files(tmp_path)
    (tmp_path / "inputs" / "model.grid").unlink()
    with pytest.raises(InputError, match=r"run\.inp:\d+: @all grid: file not found"):
        read_deck(p)
    (tmp_path / "inputs" / "model.grid").write_text("x")
    text = p.read_text()
    p.write_text(text.replace("    cine = $inp/12345601.cine\n", ""))
    with pytest.raises(InputError, match=r"run\.inp:\d+: @camera 1 has no video"):
        read_deck(p)
    p.write_text(text.replace("overlap = best_view", "overlaps = best_view"))
    with pytest.raises(InputError, match=r"run\.inp:\d+: unknown key 'overlaps' in @options"):
        read_deck(p)
    p.write_text(text.replace("aedc = false", "aedc = true"))
    with pytest.raises(InputError, match=r"run\.inp:\d+: @camera 2 aedc = true: AEDC"):
        read_deck(p)
    p.write_text(text.replace("$inp/model.grid", "$nope/model.grid"))
    with pytest.raises(InputError, match=r"@all grid: \$nope is not defined"):
        read_deck(p)


def test_paint_calibration(tmp_path):
    p = tmp_path / "paint.txt"
    p.write_text("a = 1.1\nb = 2.2\nc = 3.3\nd = 4.4\ne = 5.5\nf = 6.6\n")
    cal = read_paint_calibration(p)
    # hand-computed: T = 2, Pss = 10: 1.1 + 4.4 + 13.2 + (4.4 + 11 + 26.4) * 10 = 436.7
    assert cal.gain(2.0, 10.0) == pytest.approx(436.7, rel=1e-12)
    p.write_text("a = 1.1\nb = 2.2\nc = 3.3\nd = 4.4\nf = 6.6\n")
    with pytest.raises(InputError, match=r"paint\.txt: coefficient 'e' missing"):
        read_paint_calibration(p)
    p.write_text("a = 1.1\ng = 2\n")
    with pytest.raises(InputError, match=r"paint\.txt:2: unknown coefficient 'g'"):
        read_paint_calibration(p)


def test_deck_var_expansion_is_capped(tmp_path):
    """Issue 34 item 19: vars repeating vars (each 10 times, 7 levels) expanded to 100 MB
    and a 'one-line' error of that size. The expansion stops at MAX_EXPANDED characters,
    naming the line."""
    from resection.io.upsp_inputs import MAX_EXPANDED

    p = _deck_files(tmp_path)
    chain = "    v0 = abcdefghij\n" + "".join(
        f"    v{k} = {('$v' + str(k - 1)) * 10}\n" for k in range(1, 8))
    p.write_text(p.read_text().replace("@all\n", chain + "@all\n").replace(
        "sds = $inp/123456.wtd", "sds = $inp/$v7.wtd"))
    with pytest.raises(InputError) as exc:
        read_deck(p)
    msg = str(exc.value)
    assert re.match(rf"{re.escape(str(p))}:\d+: @all sds: \$vars expand to more than "
                    rf"{MAX_EXPANDED} characters", msg) and len(msg) < 400, msg[:300]


def test_deck_key_given_twice_warns_naming_the_one_used(tmp_path):
    """Issue 34 item 19: an @options key given twice was taken silently (the last, as
    uPSP's reader does). It is warned, naming both lines and the one used."""
    p = _deck_files(tmp_path)
    text = p.read_text().replace("    filter_size = 3\n",
                                 "    filter_size = 3\n    filter_size = 5\n")
    p.write_text(text)
    lines = text.splitlines()
    first = lines.index("    filter_size = 3") + 1
    with pytest.warns(UserWarning) as rec:
        d = read_deck(p)
    msgs = [str(w.message) for w in rec]
    assert msgs == [f"{p}:{first + 1}: @options filter_size given twice (also line {first}); "
                    f"the value of line {first + 1} is used"]
    assert d.options["filter_size"] == "5"


def test_an_error_line_is_capped_on_the_command_line(tmp_path, capsys):
    """A message quoting 10 MB of input prints at most MAX_MESSAGE characters, one line,
    saying how many were left out."""
    from resection.cli.main import main
    from resection.cli.util import MAX_MESSAGE

    cam = tmp_path / "cam.json"
    cam.write_text('{"' + "k" * 10_000_000 + '": 1}')
    assert main(["convert-camera", str(cam), "--out", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1
    assert len(err) < MAX_MESSAGE + 100 and "characters left out" in err
    assert str(cam) in err
