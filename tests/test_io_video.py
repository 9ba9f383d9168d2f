"""Frame sequences read lazily: Photron .mraw/.cih (files written by pyMRAW's own writer),
Phantom .cine (files written below from the published file layout, read through the
cine-handler package), multi-page TIFF (tifffile), 3-D NPY and lists of image files."""

from __future__ import annotations

import struct

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


def _write_cine(path, frames, *, bits=12, bottom_up=True, first_no=-3, packed=False):
    """A grey 16-bit-container Phantom .cine laid out as the Vision Research "Cine File
    Format" document describes: CINEFILEHEADER (44 bytes), BITMAPINFOHEADER (40), SETUP
    (16 kB of zeros except RealBPP at byte 896 and dFrameRate at byte 10400 of the setup
    block; recent cameras write a setup of that size), the 64-bit image offset table,
    then per image an annotation block (its size, then the image size) and the pixels."""
    n, h, w = frames.shape
    off_bih = 44
    off_setup = off_bih + 40
    setup = bytearray(16384)
    setup[896:900] = struct.pack("<I", bits)
    setup[10400:10408] = struct.pack("<d", 25000.0)
    setup[142:144] = struct.pack("<H", len(setup))
    off_offsets = off_setup + len(setup)
    data_start = off_offsets + 8 * n
    img_bytes = h * w * 3 // 2 if packed else h * w * 2
    ann = 8
    offsets = [data_start + k * (ann + img_bytes) for k in range(n)]
    header = struct.pack("<2sHHHiIiIIIIQ", b"CI", 44, 0, 1, first_no, n, first_no, n,
                         off_bih, off_setup, off_offsets, 0)
    bih = struct.pack("<IiiHHIIiiII", 40, w, h if bottom_up else -h, 1, 16,
                      1024 if packed else 0, img_bytes, 0, 0, 0, 0)
    with open(path, "wb") as fh:
        fh.write(header + bih + bytes(setup))
        fh.write(np.asarray(offsets, "<u8").tobytes())
        for f in frames:
            rows = f[::-1] if bottom_up else f
            fh.write(struct.pack("<II", ann, img_bytes))
            fh.write(_pack_p12l(rows) if packed else rows.astype("<u2").tobytes())


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


def test_cine_p12l_packed(tmp_path):
    """12-bit packed frames (P12L, uPSP's usual recording) unpack to the written counts."""
    frames = _frames()
    p = tmp_path / "packed.cine"
    _write_cine(p, frames, packed=True)
    n, it = iter_frames(p)
    got = np.stack([img for _, img in it])
    assert n == N
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
def test_mraw_written_by_pymraw(tmp_path, bits):
    import pyMRAW

    frames = _frames(bits=bits).astype(np.uint8 if bits == 8 else np.uint16)
    mraw, cih = pyMRAW.save_mraw(frames, str(tmp_path / "run.cih"), bit_depth=bits,
                                 info_dict={"Record Rate(fps)": 20000})
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
