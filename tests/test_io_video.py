"""Frame sequences read lazily: Photron .mraw/.cih (files written by pyMRAW's own writer),
Phantom .cine (files written below from the published file layout, read through the
cine-handler package), multi-page TIFF (tifffile), 3-D NPY and lists of image files."""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
import tifffile

from resection import InputError
from resection.io.images import write_image
from resection.io.video import iter_frames, open_frames

N, H, W = 5, 24, 36


def _frames(bits=12, seed=0):
    rng = np.random.default_rng(seed)
    f = rng.integers(0, 2**bits - 1, (N, H, W)).astype(np.uint16)
    f[:, 0, 0] = 2**bits - 1  # one saturated pixel a frame
    return f


def _pack_p12l(f):
    """Phantom P12L packing: two 12-bit pixels in three bytes, most significant first."""
    v = f.astype(np.uint16).reshape(-1, 2)
    out = np.empty((v.shape[0], 3), np.uint8)
    out[:, 0] = v[:, 0] >> 4
    out[:, 1] = ((v[:, 0] & 0x0F) << 4) | (v[:, 1] >> 8)
    out[:, 2] = v[:, 1] & 0xFF
    return out.tobytes()


def _pack_p10(f):
    """Phantom P10 packing: four 10-bit pixels in five bytes, most significant first."""
    v = f.astype(np.uint64).reshape(-1, 4)
    word = (v[:, 0] << 30) | (v[:, 1] << 20) | (v[:, 2] << 10) | v[:, 3]  # 40 bits
    out = np.stack([(word >> s) & 0xFF for s in (32, 24, 16, 8, 0)], axis=1)
    return out.astype(np.uint8).tobytes()


def _write_cine(path, frames, *, bits=12, bottom_up=True, first_no=-3, packed=False):
    """A grey 16-bit-container Phantom .cine laid out as the Vision Research "Cine File
    Format" document describes: CINEFILEHEADER (44 bytes), BITMAPINFOHEADER (40), SETUP
    (16 kB of zeros except Length at byte 142, SoftwareVersion at 800, RealBPP at 896 and
    dFrameRate at 10400 of the setup block; recent cameras write a setup of that size),
    the tagged blocks of image times (type 1002) and exposures (1003), the 64-bit image
    offset table, then per image an annotation block (its size, then the image size) and
    the pixels.

    Rows: unpacked frames bottom-up when ``bottom_up`` (the DIB convention of a positive
    biHeight); packed frames (P12L) top-down, as Phantom cameras write them (what uPSP's
    CineReader and pims read). ``packed``: False, True (P12L) or ``"p10"``."""
    n, h, w = frames.shape
    off_bih = 44
    off_setup = off_bih + 40
    setup = bytearray(16384)
    setup[800:804] = struct.pack("<I", 702)  # SoftwareVersion: the layout of recent cameras
    setup[896:900] = struct.pack("<I", bits)
    setup[10400:10408] = struct.pack("<d", 25000.0)
    setup[142:144] = struct.pack("<H", len(setup))
    times = struct.pack("<IHH", 8 + 8 * n, 1002, 1) + np.arange(n, dtype="<u8").tobytes()
    expos = struct.pack("<IHH", 8 + 4 * n, 1003, 0) + np.full(n, 2**20, "<u4").tobytes()
    setup += times + expos
    off_offsets = off_setup + len(setup)
    data_start = off_offsets + 8 * n
    img_bytes = {False: h * w * 2, True: h * w * 3 // 2, "p10": h * w * 10 // 8}[packed]
    ann = 8
    offsets = [data_start + k * (ann + img_bytes) for k in range(n)]
    header = struct.pack("<2sHHHiIiIIIIQ", b"CI", 44, 0, 1, first_no, n, first_no, n,
                         off_bih, off_setup, off_offsets, 0)
    bih = struct.pack("<IiiHHIIiiII", 40, w, h if bottom_up else -h, 1, 16,
                      {False: 0, True: 1024, "p10": 256}[packed], img_bytes, 0, 0, 0, 0)
    with open(path, "wb") as fh:
        fh.write(header + bih + bytes(setup))
        fh.write(np.asarray(offsets, "<u8").tobytes())
        for f in frames:
            rows = f[::-1] if bottom_up and not packed else f
            fh.write(struct.pack("<II", ann, img_bytes))
            fh.write(_pack_p10(rows) if packed == "p10" else _pack_p12l(rows) if packed
                     else rows.astype("<u2").tobytes())


@pytest.mark.parametrize("bottom_up", [True, False])
def test_cine_frames(tmp_path, bottom_up):
    frames = _frames()
    p = tmp_path / "run.cine"
    _write_cine(p, frames, bottom_up=bottom_up)
    n, it = iter_frames(p)
    assert n == N
    got = list(it)
    assert [lab for lab, _ in got] == [f"{p}#{k}" for k in range(N)]
    for k, (_, img) in enumerate(got):
        assert img.dtype == np.float32 and img.shape == (H, W)
        np.testing.assert_array_equal(img, frames[k].astype(np.float32))
    src = open_frames(p, mask_saturated=True)
    assert src.bits == 12 and src.frame_rate == 25000.0
    assert np.isnan(src[2][0, 0]) and np.isfinite(src[2][0, 1])
    src.close()


@pytest.mark.parametrize("bottom_up", [True, False])
def test_cine_p12l_packed(tmp_path, bottom_up):
    """12-bit packed frames (P12L, uPSP's usual recording) unpack to the written counts,
    top row first whatever the sign of biHeight: uPSP's CineReader never flips a packed
    frame, and pims (an independent reader) agrees."""
    import pims

    frames = _frames()
    p = tmp_path / "packed.cine"
    _write_cine(p, frames, packed=True, bottom_up=bottom_up)
    n, it = iter_frames(p)
    got = np.stack([img for _, img in it])
    assert n == N
    np.testing.assert_array_equal(got, frames.astype(np.float32))
    if bottom_up:  # pims reads a positive biHeight only
        ref = np.stack([np.asarray(f) for f in pims.Cine(str(p))])
        np.testing.assert_array_equal(got, ref.astype(np.float32))
        assert not np.array_equal(got, ref[:, ::-1])


def test_cine_p10_packed_orientation_and_bits(tmp_path):
    """P10 (10-bit packed) takes the same path: never flipped (pims agrees once its raw
    10-bit counts go through the linearisation table), 12-bit counts after the table."""
    import pims
    from cine_reader.unpack import unpack_10bit_data

    frames = _frames(bits=10)
    p = tmp_path / "p10.cine"
    _write_cine(p, frames, packed="p10", bits=10)
    lut = np.asarray(unpack_10bit_data(_pack_p10(np.arange(1024))))  # Phantom's 10->12 table
    raw = np.stack([np.asarray(f) for f in pims.Cine(str(p))])
    np.testing.assert_array_equal(raw, frames)  # pims: top-down, raw counts
    src = open_frames(p, mask_saturated=True)
    got = np.stack([src[k] for k in range(N)])
    assert src.bits == 12
    np.testing.assert_array_equal(np.nan_to_num(got, nan=4095), lut[raw].astype(np.float32))
    assert np.isnan(got[:, 0, 0]).all()  # 1023 -> 4095: full scale of the 12-bit counts
    assert np.isfinite(got[:, 1:, :]).sum() > 0.99 * got[:, 1:, :].size
    src.close()


def test_cine_unpacked_matches_pims(tmp_path):
    """An unpacked bottom-up frame reads as pims reads it (row 0 at the top)."""
    import pims

    frames = _frames()
    p = tmp_path / "run.cine"
    _write_cine(p, frames, bottom_up=True)
    ref = np.stack([np.asarray(f) for f in pims.Cine(str(p))])
    got = np.stack([img for _, img in iter_frames(p)[1]])
    np.testing.assert_array_equal(got, ref.astype(np.float32))
    np.testing.assert_array_equal(got, frames.astype(np.float32))


def test_cine_truncated(tmp_path):
    p = tmp_path / "run.cine"
    _write_cine(p, _frames())
    data = p.read_bytes()
    p.write_bytes(data[: len(data) - 700])  # the last frame loses its end
    src = open_frames(p)
    src[0]
    with pytest.raises(InputError, match=r"run.cine#4"):
        src[N - 1]
    p.write_bytes(data[:30])
    with pytest.raises(InputError, match="run.cine"):
        open_frames(p)


@pytest.mark.parametrize("bits", [8, 16])
def test_mraw_written_by_pymraw(tmp_path, bits, recwarn):
    import pyMRAW

    frames = _frames(bits=bits).astype(np.uint8 if bits == 8 else np.uint16)
    mraw, cih = pyMRAW.save_mraw(frames, str(tmp_path / "run.cih"), bit_depth=bits,
                                 info_dict={"Record Rate(fps)": 20000})
    warnings.simplefilter("ignore", UserWarning)  # 16-bit: pyMRAW's header says 12 bits
    for path in (mraw, cih):
        n, it = iter_frames(path)
        assert n == N
        for k, (label, img) in enumerate(it):
            assert label.endswith(f".mraw#{k}")
            np.testing.assert_array_equal(img, frames[k].astype(np.float32))
    assert open_frames(cih).frame_rate == 20000.0


def test_mraw_bad_files(tmp_path):
    import pyMRAW

    mraw, cih = pyMRAW.save_mraw(_frames(bits=16), str(tmp_path / "run.cih"), bit_depth=16)
    data = open(mraw, "rb").read()
    open(mraw, "wb").write(data[:-100])
    with pytest.raises(InputError, match="truncated"):
        open_frames(mraw)
    lone = tmp_path / "lone.mraw"
    lone.write_bytes(data)
    with pytest.raises(InputError, match=r"no \.cih"):
        open_frames(lone)


def test_tiff_stack_and_npy_stack_and_file_list(tmp_path):
    frames = _frames(bits=16)
    tifffile.imwrite(tmp_path / "stack.tif", frames, photometric="minisblack")
    np.save(tmp_path / "stack.npy", frames.astype(np.float32))
    files = []
    for k in range(N):
        files.append(tmp_path / f"f{k}.png")
        write_image(files[-1], frames[k], dtype=np.uint16)
    for src in (tmp_path / "stack.tif", tmp_path / "stack.npy", files):
        n, it = iter_frames(src)
        assert n == N
        got = np.stack([img for _, img in it])
        np.testing.assert_array_equal(got, frames.astype(np.float32))


def test_frames_are_read_lazily(tmp_path):
    """Only the frames asked for are read: a frame damaged after opening fails when (and
    only when) it is reached."""
    frames = _frames()
    p = tmp_path / "run.cine"
    _write_cine(p, frames, bottom_up=False)
    n, it = iter_frames(p)
    label, first = next(it)
    np.testing.assert_array_equal(first, frames[0])
    with open(p, "r+b") as fh:  # overwrite frame 3's pixels after the file was opened
        fh.seek(-(N - 3) * (8 + H * W * 2) + 8, 2)
        fh.write(np.full(H * W, 7, "<u2").tobytes())
    rest = [img for _, img in it]
    np.testing.assert_array_equal(rest[0], frames[1])
    assert np.all(rest[2] == 7)


def test_mraw_16bit_from_pymraw_contradicting_header(tmp_path):
    """pyMRAW's save_mraw(bit_depth=16) declares 'EffectiveBit Depth : 12': counts above
    4095 contradict the header. A warning names it, the counts are kept, and only the
    16-bit full scale counts as saturated."""
    import pyMRAW

    frames = (_frames(bits=12).astype(np.uint32) * 16).astype(np.uint16)  # up to 65520
    frames[:, 0, 0] = 65535
    mraw, cih = pyMRAW.save_mraw(frames, str(tmp_path / "run.cih"), bit_depth=16)
    assert "12" in str(pyMRAW.get_cih(cih).get("EffectiveBit Depth"))  # the trap itself
    with pytest.warns(UserWarning, match=r"run\.cih: header 'EffectiveBit Depth : 12' is "
                                         r"contradicted by the data") as rec:
        src = open_frames(mraw, mask_saturated=True)
    assert "\n" not in str(rec[0].message)
    got = np.stack([src[k] for k in range(N)])
    assert src.bits == 16
    assert np.isnan(got[:, 0, 0]).all()
    np.testing.assert_array_equal(got[:, 1:], frames[:, 1:].astype(np.float32))


def test_mraw_within_its_bit_depth_no_warning(tmp_path, recwarn):
    import pyMRAW

    frames = _frames(bits=12)  # 12-bit counts in a 16-bit container: the header holds
    mraw, _ = pyMRAW.save_mraw(frames, str(tmp_path / "run.cih"), bit_depth=16)
    src = open_frames(mraw, mask_saturated=True)
    got = np.stack([src[k] for k in range(N)])
    assert src.bits == 12 and np.isnan(got[:, 0, 0]).all()
    assert not [w for w in recwarn if "EffectiveBit" in str(w.message)]


def test_track_on_a_pymraw_16bit_video(tmp_path, capsys):
    """A 16-bit video written by pyMRAW (header: 12 effective bits), counts up to 16,000:
    `track` solves every frame (on today's main every frame failed with 'image has no
    finite pixel')."""
    import csv

    import pyMRAW

    from resection.cli import main
    from scenes.moving_model import pitch_oscillation, write_sequence

    model = pitch_oscillation(4, amplitude_deg=1.0, frequency_hz=3.0)
    files = write_sequence(model, tmp_path / "f")
    stack = np.stack([np.load(f) for f in files["frames"]]) * 16.0  # background ~16,000
    assert stack.max() > 4095
    mraw, _ = pyMRAW.save_mraw(np.clip(np.rint(stack), 0, 65535).astype(np.uint16),
                               str(tmp_path / "run.cih"), bit_depth=16)
    out = tmp_path / "track"
    with pytest.warns(UserWarning, match="EffectiveBit Depth"):
        rc = main(["track", mraw, "--camera", files["camera"], "--markers", files["markers"],
                   "--diameter", "5", "--out", str(out), "--workers", "1", "--no-progress"])
    assert rc == 0, capsys.readouterr().err
    with open(out / "poses.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 4 and all(r["status"] == "ok" for r in rows)


def test_mraw_later_frame_contradicting_header(tmp_path):
    """The first frame within 12 bits, a later one above: the warning comes when that frame
    is read (with the saturation mask, where the full scale matters) and its counts stay."""
    import pyMRAW

    frames = _frames(bits=12)
    frames[3, 5, 5] = 9000
    mraw, _ = pyMRAW.save_mraw(frames, str(tmp_path / "run.cih"), bit_depth=16)
    src = open_frames(mraw, mask_saturated=True)
    assert src.bits == 12
    with pytest.warns(UserWarning, match=r"run\.mraw#3 holds counts up to 9000"):
        img = src[3]
    assert img[5, 5] == 9000 and src.bits == 16


def test_unsteady_blames_a_cih_rate_of_nan_on_the_video_not_fps(tmp_path):
    """Issue 34 item 19: a .cih whose 'Record Rate(fps)' is nan was refused as '--fps must
    be positive, got nan' although --fps was not given. The video is named; --fps, when
    given, is used instead of the header."""
    import types

    import pyMRAW

    from selfillum.unsteady.inputs import open_videos

    frames = np.concatenate([_frames(bits=16)] * 2).astype(np.uint16)  # the run needs 8
    _, cih = pyMRAW.save_mraw(frames, str(tmp_path / "cam01.cih"), bit_depth=16,
                              info_dict={"Record Rate(fps)": "nan"})
    warnings.simplefilter("ignore", UserWarning)
    cam = types.SimpleNamespace(video=Path(cih), number=1)
    cfg = types.SimpleNamespace(cameras=[cam], number_frames=-1, fps=None,
                                source=str(tmp_path / "deck"), filter="none", filter_size=3)
    with pytest.raises(InputError) as exc:
        open_videos(cfg)
    msg = str(exc.value)
    assert msg.startswith(f"{cih}: its header's frame rate nan") and "give --fps" in msg
    cfg.fps = 500.0
    srcs, T, fps = open_videos(cfg)
    assert (T, fps) == (2 * N, 500.0)
