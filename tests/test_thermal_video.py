"""IR video formats (resection.io.video): Telops ``.hcc`` written by ``fasthcc``'s own
writer and read back through ``open_frames`` (counts, size, rate); a TIFF stack's rate from
its ImageJ metadata (``finterval``) as tifffile writes it; a FLIR ``.seq`` made of a
frame a FLIR camera wrote, read against flirpy; a truncated file named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from resection.errors import InputError
from resection.io.video import open_frames


def _frames(n=5, h=24, w=32):
    rng = np.random.default_rng(1)
    return rng.integers(0, 65535, size=(n, h, w), dtype=np.uint16)


def test_hcc_written_by_fasthcc(tmp_path):
    from fasthcc import read_hcc, write_hcc

    frames = _frames()
    p = tmp_path / "run.hcc"
    write_hcc(p, frames, frame_rate=250.0, calibration_mode=0)
    src = open_frames(p)
    assert len(src) == 5 and tuple(src.shape) == (24, 32)
    assert src.frame_rate == pytest.approx(250.0)
    for k in range(5):
        np.testing.assert_array_equal(src.native(k), frames[k])
    np.testing.assert_array_equal(np.stack([src.native(k) for k in range(5)]), read_hcc(p))
    src.close()
    # saturated counts masked when asked
    frames[2, 3, 4] = 65535
    q = tmp_path / "sat.hcc"
    write_hcc(q, frames, frame_rate=250.0, calibration_mode=0)
    s2 = open_frames(q, mask_saturated=True)
    assert np.isnan(s2[2][3, 4])
    s2.close()


def test_truncated_hcc_named(tmp_path):
    from fasthcc import write_hcc

    p = tmp_path / "cut.hcc"
    write_hcc(p, _frames(), frame_rate=100.0, calibration_mode=0)
    data = p.read_bytes()
    p.write_bytes(data[:-100])
    with pytest.raises(InputError) as ei:
        open_frames(p)
    assert str(p) in str(ei.value) and "\n" not in str(ei.value)


def test_tiff_stack_rate_from_imagej_finterval(tmp_path):
    import tifffile

    frames = _frames(4)
    p = tmp_path / "stack.tif"
    tifffile.imwrite(p, frames, imagej=True, metadata={"finterval": 0.02, "axes": "TYX"})
    src = open_frames(p)
    assert src.frame_rate == pytest.approx(50.0)
    np.testing.assert_array_equal(src.native(3), frames[3])
    src.close()
    q = tmp_path / "plain.tif"
    tifffile.imwrite(q, frames, photometric="minisblack")
    s2 = open_frames(q)
    assert s2.frame_rate is None  # no rate stated: the run asks for --fps
    s2.close()


# A frame a FLIR camera wrote (a FLIR T420, 320 x 240, FFF with its radiometric tags):
# flirpy's test file test/test_data/frame_000000_le.fff (MIT licence, (c) 2019-present
# Josh Veitch-Michaelis), copied as tests/data/flir_t420_frame.fff.
FLIR_FFF = Path(__file__).parent / "data" / "flir_t420_frame.fff"


def test_flir_seq_of_a_camera_frame(tmp_path):
    """A .seq is FFF frames one after another (as FLIR's cameras record them): three copies
    of the camera's frame, read back through open_frames against flirpy's own Fff."""
    from flirpy.io.fff import Fff

    blob = FLIR_FFF.read_bytes()
    p = tmp_path / "run.seq"
    p.write_bytes(blob * 3)
    ref = Fff(blob).get_image()
    src = open_frames(p)
    assert len(src) == 3 and tuple(src.shape) == (240, 320)
    assert src.frame_rate == pytest.approx(30.0)  # the camera's FrameRate tag
    for k in range(3):
        np.testing.assert_array_equal(src.native(k), ref)
    src.close()
    bad = tmp_path / "cut.seq"
    bad.write_bytes(b"not a FLIR file" * 10)
    with pytest.raises(InputError) as ei:
        open_frames(bad)
    assert str(bad) in str(ei.value)
    csq = tmp_path / "run.csq"
    csq.write_bytes(blob)
    with pytest.raises(InputError, match="csq"):
        open_frames(csq)


def test_temperature_of_the_camera_frame_as_flirpy():
    """The camera's own frame and tags through our Planck form and flirpy's raw2temp (FLIR's
    formula; no atmosphere: object distance 0)."""
    from flirpy.io.fff import Fff
    from flirpy.util.raw import raw2temp

    from selfillum.thermal.radiometry import Emissivity, Planck, Radiometry

    f = Fff(FLIR_FFF.read_bytes())
    raw = f.get_image().astype(np.float64)
    meta = dict(f.meta, **{"Object Distance": 0.0})
    ref = raw2temp(raw, meta) + 273.15
    rad = Radiometry(Planck.from_exif(meta), Emissivity("constant", meta["Emissivity"]),
                     meta["Reflected Apparent Temperature"] + 273.15)
    np.testing.assert_allclose(rad.temperature(raw), ref, atol=1e-6)
    assert 270.0 < np.median(ref) < 320.0  # a scene near room temperature
