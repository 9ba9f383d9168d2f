"""IR video formats (resection.io.video): Telops ``.hcc`` written by ``fasthcc``'s own
writer and read back through ``open_frames`` (counts, size, rate); a TIFF stack's rate from
its ImageJ metadata (``finterval``) as tifffile writes it; a FLIR ``.seq`` made of a
frame a FLIR camera wrote, read against flirpy; a FLIR ``.csq`` a camera wrote (JPEG-LS
frames) read against exiftool (the frames' tags and streams) and FFmpeg's own JPEG-LS
decoder; a truncated file named."""

from __future__ import annotations

import json
import subprocess
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


# Two frames a FLIR T1030sc wrote (1024 x 768, each frame's counts a JPEG-LS stream): the
# start of the Thermimage R package's SampleCSQ.csq (GPL >= 2; see
# tests/data/LICENSE-Thermimage-GPL.txt).
FLIR_CSQ = Path(__file__).parent / "data" / "flir_t1030sc_2frames.csq"


def _exiftool(*args) -> bytes:
    """ExifTool (the copy flirpy ships, run by perl): FLIR's FFF records read by the
    maintained reader of FLIR metadata."""
    import flirpy

    exe = Path(flirpy.__file__).parent / "bin" / "exiftool"
    return subprocess.run(["perl", str(exe), *map(str, args)], capture_output=True,
                          check=True).stdout


def _ffmpeg_jpegls(stream: bytes, shape) -> np.ndarray:
    """A JPEG-LS stream decoded by FFmpeg's own decoder (libavcodec's, not CharLS)."""
    import imageio_ffmpeg

    out = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-f",
                          "jpegls_pipe", "-i", "-", "-f", "rawvideo", "-pix_fmt",
                          "gray16le", "-"], input=stream, capture_output=True, check=True)
    return np.frombuffer(out.stdout, "<u2").reshape(shape)


def test_flir_csq_of_a_camera_against_exiftool_and_ffmpeg(tmp_path):
    """Each frame of the camera's .csq through open_frames: its size and rate as exiftool
    reads the frame's tags, its counts as FFmpeg decodes the JPEG-LS stream exiftool
    extracts (the frames split at their FFF headers); its temperature through our Planck
    form with exiftool's constants as flirpy's raw2temp."""
    from flirpy.util.raw import raw2temp

    from selfillum.thermal.radiometry import Emissivity, Planck, Radiometry

    blob = FLIR_CSQ.read_bytes()
    starts = [i for i in range(len(blob)) if blob.startswith(b"FFF\x00", i)]
    assert starts == [0, 213196]
    src = open_frames(FLIR_CSQ)
    assert len(src) == 2
    for k, a in enumerate(starts):
        fr = tmp_path / f"frame{k}.fff"
        fr.write_bytes(blob[a:(starts + [len(blob)])[k + 1]])
        tags = json.loads(_exiftool("-j", "-n", fr))[0]
        shape = (tags["RawThermalImageHeight"], tags["RawThermalImageWidth"])
        assert tuple(src.shape) == shape == (768, 1024)
        assert src.frame_rate == pytest.approx(tags["FrameRate"])
        ref = _ffmpeg_jpegls(_exiftool("-b", "-RawThermalImage", fr), shape)
        img = src.native(k)
        assert img.dtype == np.uint16
        np.testing.assert_array_equal(img, ref)
    assert not np.array_equal(src.native(0), src.native(1))  # two frames, each its own
    names = ("Planck R1", "Planck R2", "Planck B", "Planck F", "Planck O", "Emissivity",
             "Reflected Apparent Temperature", "Atmospheric Temperature",
             "IR Window Temperature", "IR Window Transmission", "Relative Humidity",
             "Atmospheric Trans Alpha 1", "Atmospheric Trans Alpha 2",
             "Atmospheric Trans Beta 1", "Atmospheric Trans Beta 2", "Atmospheric Trans X")
    meta = {n: tags[n.replace(" ", "")] for n in names} | {"Object Distance": 0.0}
    raw = src.native(1).astype(np.float64)
    rad = Radiometry(Planck.from_exif(meta), Emissivity("constant", meta["Emissivity"]),
                     meta["Reflected Apparent Temperature"] + 273.15)
    np.testing.assert_allclose(rad.temperature(raw), raw2temp(raw, meta) + 273.15,
                               atol=1e-6)
    src.close()


def test_flir_csq_bad_stream_named(tmp_path):
    """A .csq whose JPEG-LS stream is cut short: one line naming the file and frame."""
    blob = FLIR_CSQ.read_bytes()[:213196]
    p = tmp_path / "cut.csq"
    p.write_bytes(blob[:8000])
    with pytest.raises(InputError) as ei:
        open_frames(p)
    msg = str(ei.value)
    assert str(p) in msg and "\n" not in msg
