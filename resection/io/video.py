"""Frame sequences, read lazily one frame at a time: image files, multi-page TIFF stacks,
3-D NPY stacks, Photron ``.mraw`` + ``.cih`` and Phantom ``.cine``.

The one entry point for commands that walk a sequence (``track``, ``map``) is
:func:`iter_frames` (or :func:`open_frames` for random access)::

    n, frames = iter_frames(["f000.tif", "f001.tif"])   # or "run.cine", "run.cih", "stack.tif"
    for label, image in frames:                         # image: (H, W) float32, img[v, u]
        ...

Readers
-------
* Image files (PNG, TIFF, NPY): :func:`resection.io.images.read_image`, one file per frame.
* Multi-page TIFF: ``tifffile.TiffFile`` pages, one page read per frame.
* 3-D NPY ``(n, H, W)``: ``numpy.load(mmap_mode="r")``.
* Photron ``.mraw`` (+ its ``.cih``/``.cihx`` header, found next to it with the same stem):
  ``pyMRAW.get_cih`` for the header, then ``pyMRAW.load_images`` which memory-maps the raw
  file (8/12/16-bit); a frame is read when it is indexed. The sensor's full scale comes
  from ``EffectiveBit Depth``; a frame whose counts exceed it (pyMRAW's own writer declares
  12 for 16-bit data) contradicts the header: a warning names the header, the counts are
  kept, and the full scale becomes the container's (``Color Bit``).
* Phantom ``.cine``: headers, setup and frame offset table parsed by the ``cine-handler``
  package (module ``cine_reader``, numpy only); a frame's payload is read when it is asked
  for and decoded here (grey 8/16-bit; P12L 12-bit packed, uPSP's usual recording) or by
  cine-handler's 10-bit unpacker (P10, which applies Phantom's 10-to-12-bit linearisation
  table, as uPSP's CineReader does: such counts are 12-bit). Orientation follows uPSP's
  ``CineReader.cpp``: unpacked frames are stored bottom-up when the bitmap header's height
  is positive (the DIB convention) and are flipped so that row 0 is the top of the image;
  packed frames (P10, P12L) are stored top-down and are never flipped (uPSP: "Do not flip
  any version, checked against Buffet data and TC3 data"; pims reads them so too). No
  black/white level is applied.
* Telops ``.hcc`` (IR cameras): the ``fasthcc`` package's ``HCCReader`` (header per
  frame, 16-bit pixels memory-mapped); the rate is the header's ``AcquisitionFrameRate``.
  Counts are the file's raw 16-bit values (a calibrated file's ``DataOffset`` and
  ``DataExp`` are not applied).
* FLIR ``.seq`` and ``.csq`` (FFF frames one after another, as FLIR's cameras and
  ResearchIR record them): the ``flirpy`` package's FFF parser on a memory map of the file
  (its frame positions, then one frame's records when the frame is asked for); the rate is
  the first frame's ``FrameRate`` tag. A ``.seq`` frame's raw-data record holds the 16-bit
  counts as they are (flirpy's ``Fff.get_image``). A ``.csq`` (FLIR's compressed
  sequence) holds them as a JPEG-LS stream, which flirpy cannot decode: the record's
  stream is decoded by ``imagecodecs.jpegls_decode`` (CharLS), lossless.
* A TIFF stack's rate comes from its ImageJ metadata (``finterval``, seconds between
  frames) when it has it.

Counts stay counts (a 12-bit pixel of 4095 reads 4095.0); with ``mask_saturated`` the
pixels at the sensor's full scale (``2**bits - 1``) read as NaN, as
:func:`~resection.io.images.read_image` does for single images.
"""

from __future__ import annotations

import os
import struct
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from resection.errors import InputError
from resection.io.images import read_image

__all__ = ["FrameSource", "open_frames", "iter_frames", "frame_rate_of", "VIDEO_SUFFIXES"]

VIDEO_SUFFIXES = (".cine", ".mraw", ".cih", ".cihx", ".hcc", ".seq", ".csq")


class FrameSource:
    """A sequence of frames read on demand.

    Attributes
    ----------
    path : str
        The file (or the first file of a list).
    n : int
        Number of frames; ``len(source)`` too.
    shape : (int, int)
        ``(H, W)`` of every frame.
    bits : int or None
        Bits per pixel of the sensor data (None for float files).
    frame_rate : float or None
        Frames per second when the file says so (``.cine``, ``.mraw``).

    ``source[i]`` is frame ``i`` as a ``(H, W)`` float32 array; ``source.label(i)`` names it
    (``"run.cine#12"`` or the image file's path), for messages and result files.
    """

    def __init__(self, path, n, shape, reader, labeler, *, bits=None, frame_rate=None,
                 mask_saturated=False, closer=None):
        self.path = str(path)
        self.n = int(n)
        self.shape = tuple(int(s) for s in shape)
        self.bits = bits
        self.frame_rate = frame_rate
        self.mask_saturated = mask_saturated
        self._reader = reader
        self._labeler = labeler
        self._closer = closer

    def __len__(self) -> int:
        return self.n

    def label(self, i: int) -> str:
        return self._labeler(i)

    def __getitem__(self, i: int) -> np.ndarray:
        raw = self.native(i)
        img = raw.astype(np.float32)
        if self.mask_saturated and self.bits is not None and raw.dtype.kind in "ui":
            img[raw >= (1 << self.bits) - 1] = np.nan
        return img

    def native(self, i: int) -> np.ndarray:
        """Frame ``i`` as the file stores it (integer counts stay integers: no float32
        copy), without the saturation mask: for callers that read counts in their own
        loop (the unsteady run's sparse products)."""
        i = int(i)
        if i < 0:
            i += self.n
        if not 0 <= i < self.n:
            raise IndexError(f"{self.path}: frame {i} out of range (0..{self.n - 1})")
        raw = np.asarray(self._reader(i))
        if raw.shape != self.shape:
            raise InputError(f"{self.label(i)}: frame of shape {raw.shape}, expected "
                             f"{self.shape} like the others")
        return raw

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(self.n):
            yield self[i]

    def close(self) -> None:
        if self._closer is not None:
            self._closer()
            self._closer = None

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def iter_frames(
    path_or_paths: str | os.PathLike | Sequence[str | os.PathLike],
    *,
    mask_saturated: bool = False,
) -> tuple[int, Iterator[tuple[str, np.ndarray]]]:
    """Count the frames of a sequence and iterate over them lazily.

    Parameters
    ----------
    path_or_paths : path or list of paths
        A list of image files (one frame each, in the given order), or one file holding
        many frames: ``.cine``, ``.mraw`` (or its ``.cih``/``.cihx``), a multi-page TIFF, a
        3-D ``.npy``; a single 2-D image file is a sequence of one frame.
    mask_saturated : bool
        Saturated pixels (full scale of the sensor's bit depth) read as NaN.

    Returns
    -------
    n : int
        Number of frames, known before any frame is read.
    frames : iterator of (label, image)
        ``label`` names the frame (``"run.cine#12"``, or the image file's path);
        ``image`` is a ``(H, W)`` float32 array, ``img[v, u]``. Frames are read one at a time
        as the iterator advances; the file is closed at the end.

    Raises
    ------
    InputError
        Missing, unknown or unreadable file (the message names it).
    """
    src = open_frames(path_or_paths, mask_saturated=mask_saturated)

    def gen():
        try:
            for i in range(src.n):
                yield src.label(i), src[i]
        finally:
            src.close()

    return src.n, gen()


def open_frames(
    path_or_paths: str | os.PathLike | Sequence[str | os.PathLike],
    *,
    mask_saturated: bool = False,
) -> FrameSource:
    """Open a frame sequence for random access (see :func:`iter_frames` for the inputs)."""
    if isinstance(path_or_paths, (str, os.PathLike)):
        paths = [Path(path_or_paths)]
    else:
        paths = [Path(p) for p in path_or_paths]
        if not paths:
            raise InputError("no frames given")
    if len(paths) > 1:
        for p in paths:
            if p.suffix.lower() in VIDEO_SUFFIXES:
                raise InputError(f"{p}: a video file cannot be mixed with other frame files")
        return _image_files(paths, mask_saturated)
    p = paths[0]
    if not p.exists():
        raise InputError(f"{p}: no such frame file")
    if p.is_dir():
        raise InputError(f"{p}: is a folder; give the frame files")
    suf = p.suffix.lower()
    if suf == ".cine":
        return _cine(p, mask_saturated)
    if suf in (".mraw", ".cih", ".cihx"):
        return _mraw(p, mask_saturated)
    if suf in (".tif", ".tiff"):
        return _tiff_stack(p, mask_saturated)
    if suf == ".npy":
        return _npy_stack(p, mask_saturated)
    if suf == ".hcc":
        return _hcc(p, mask_saturated)
    if suf in (".seq", ".csq"):
        return _flir_seq(p, mask_saturated)
    return _image_files(paths, mask_saturated)


# --------------------------------------------------------------------------- readers
def _image_files(paths: list[Path], mask_saturated: bool) -> FrameSource:
    first = read_image(paths[0])
    return FrameSource(paths[0], len(paths), first.shape,
                       lambda i: read_image(paths[i], mask_saturated=mask_saturated),
                       lambda i: str(paths[i]))


def _tiff_stack(p: Path, mask_saturated: bool) -> FrameSource:
    import tifffile

    try:
        tf = tifffile.TiffFile(p)
        series = tf.series[0]
        shape = series.shape
        dtype = series.dtype
    except (OSError, ValueError, IndexError, tifffile.TiffFileError) as exc:
        raise InputError(f"{p}: cannot read TIFF ({str(exc).splitlines()[0]})") from None
    if len(shape) == 2:
        tf.close()
        return _image_files([p], mask_saturated)
    if len(shape) != 3 or shape[-1] in (3, 4) and len(tf.pages) == 1:
        tf.close()
        raise InputError(f"{p}: expected a stack of single-channel pages, got shape {shape}")
    pages = tf.pages

    def read(i):
        try:
            return pages[i].asarray()
        except (OSError, ValueError, tifffile.TiffFileError) as exc:
            raise InputError(f"{p}#{i}: cannot read page ({exc})") from None

    bits = np.iinfo(dtype).bits if dtype.kind in "ui" else None
    fi = (tf.imagej_metadata or {}).get("finterval")
    try:
        rate = 1.0 / float(fi) if fi is not None and float(fi) > 0 else None
    except (TypeError, ValueError):
        rate = None
    return FrameSource(p, shape[0], shape[1:], read, lambda i: f"{p}#{i}", bits=bits,
                       frame_rate=rate, mask_saturated=mask_saturated, closer=tf.close)


#: The start of a JPEG-LS stream (SOI, then SOF55): a ``.csq`` frame's raw data.
_JPEG_LS = b"\xff\xd8\xff\xf7"


def _flir_image(p: Path, i: int, frame: bytes):
    """Frame ``i``'s counts (uint16) from its FFF bytes: flirpy's ``Fff`` for the records;
    a raw-data record holding a JPEG-LS stream (a ``.csq``) decoded by ``imagecodecs``."""
    from flirpy.io.fff import Fff

    f = Fff(frame)
    raw = next((r for r in f.records if r.record_type == 1), None)
    if raw is None:
        raise InputError(f"{p}#{i}: a FLIR frame without raw data")
    start, end = f.image_offset, raw.record_offset + raw.record_length
    if frame[start:start + 4] != _JPEG_LS:
        return f, f.get_image()
    try:
        import imagecodecs
    except ImportError:
        raise InputError(f"{p}: reading FLIR .csq (JPEG-LS frames) needs the imagecodecs "
                         "package (pip install imagecodecs)") from None
    try:
        img = imagecodecs.jpegls_decode(frame[start:end])
    except Exception as exc:  # imagecodecs raises its own JpeglsError
        raise InputError(f"{p}#{i}: cannot decode the frame's JPEG-LS data "
                         f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"
                         ) from None
    if img.shape != (f.height, f.width):
        raise InputError(f"{p}#{i}: JPEG-LS frame {img.shape[1]}x{img.shape[0]}, its "
                         f"header {f.width}x{f.height}")
    return f, img


def _flir_seq(p: Path, mask_saturated: bool) -> FrameSource:
    """A FLIR ``.seq`` or ``.csq`` through ``flirpy``'s FFF parser, on a memory map of the
    file (``.csq`` frames decoded by :func:`_flir_image`)."""
    import mmap

    try:
        from flirpy.io.seq import Seq
    except ImportError:
        raise InputError(f"{p}: reading FLIR {p.suffix.lower()} needs the flirpy package "
                         "(pip install flirpy)") from None
    fh = open(p, "rb")  # noqa: SIM115 - closed by the source's closer
    try:
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        pos = Seq._get_frame_positions(mm)  # flirpy's walk of the FFF headers
        if not pos:
            raise ValueError("no FFF frame")
        first, img0 = _flir_image(p, 0, bytes(mm[pos[0][0]:pos[0][0] + pos[0][1]]))
        shape = img0.shape
        rate = float(first.meta.get("FrameRate") or 0) or None
    except InputError:
        fh.close()
        raise
    except (OSError, ValueError, struct.error, AttributeError, IndexError) as exc:
        fh.close()
        raise InputError(f"{p}: cannot read FLIR {p.suffix.lower()[1:].upper()} "
                         f"({str(exc).splitlines()[0]})") from None

    def read(i):
        a, n = pos[int(i)]
        img = _flir_image(p, int(i), bytes(mm[a:a + n]))[1]
        if img.shape != shape:
            raise InputError(f"{p}#{i}: a {img.shape[1]}x{img.shape[0]} frame in a "
                             f"{shape[1]}x{shape[0]} sequence")
        return img

    def close():
        mm.close()
        fh.close()

    return FrameSource(p, len(pos), shape, read, lambda i: f"{p}#{i}", bits=16,
                       frame_rate=rate, mask_saturated=mask_saturated, closer=close)


def _hcc(p: Path, mask_saturated: bool) -> FrameSource:
    """A Telops ``.hcc`` through ``fasthcc``'s memory-mapped reader."""
    import warnings

    try:
        from fasthcc import HCCReader
    except ImportError:
        raise InputError(f"{p}: reading Telops .hcc needs the fasthcc package "
                         "(pip install fasthcc)") from None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # trailing bytes: a truncated file
            r = HCCReader(p)
    except (OSError, ValueError, KeyError, UserWarning) as exc:
        raise InputError(f"{p}: cannot read Telops HCC ({str(exc).splitlines()[0]})") \
            from None

    def read(i):
        return r.read_frames(int(i), int(i) + 1)[0]

    rate = float(r.frame_rate) if r.frame_rate and r.frame_rate > 0 else None
    return FrameSource(p, r.n_frames, (r.height, r.width), read, lambda i: f"{p}#{i}",
                       bits=16, frame_rate=rate, mask_saturated=mask_saturated,
                       closer=r.close)


def _npy_stack(p: Path, mask_saturated: bool) -> FrameSource:
    from resection.io.images import load_npy

    arr = load_npy(p, mmap_mode="r")
    if arr.ndim == 2:
        return _image_files([p], mask_saturated)
    if arr.ndim != 3:
        raise InputError(f"{p}: expected a 2-D frame or a 3-D (n, H, W) stack, got "
                         f"shape {arr.shape}")
    if arr.shape[0] == 0:
        raise InputError(f"{p}: a stack of 0 frames (shape {arr.shape})")
    bits = np.iinfo(arr.dtype).bits if arr.dtype.kind in "ui" else None
    read = lambda i: np.array(arr[i])  # noqa: E731
    if isinstance(arr, np.memmap) and arr.flags.c_contiguous:
        # frames read from the file, not through the map: the pages of a mapped video
        # stay in the process's resident memory as it is read (a 4 GB video, 4 GB RSS)
        fh = open(p, "rb")  # noqa: SIM115 - closed by the source's closer
        dtype, shape, offset = arr.dtype, arr.shape, int(arr.offset)
        size = int(np.prod(shape[1:]))
        del arr

        def read(i):  # pread: no shared file position (threads may read frames)
            n = size * dtype.itemsize
            buf = bytearray(n)
            if os.preadv(fh.fileno(), [buf], offset + int(i) * n) != n:
                raise InputError(f"{p}#{i}: the file is shorter than its header says")
            return np.frombuffer(buf, dtype=dtype).reshape(shape[1:])

        return FrameSource(p, shape[0], shape[1:], read, lambda i: f"{p}#{i}", bits=bits,
                           mask_saturated=mask_saturated, closer=fh.close)
    return FrameSource(p, arr.shape[0], arr.shape[1:], read,
                       lambda i: f"{p}#{i}", bits=bits, mask_saturated=mask_saturated)


def _mraw(p: Path, mask_saturated: bool) -> FrameSource:
    import pyMRAW

    if p.suffix.lower() == ".mraw":
        cands = [p.with_suffix(s) for s in (".cihx", ".cih")]
        cih = next((c for c in cands if c.exists()), None)
        if cih is None:
            raise InputError(f"{p}: no .cih/.cihx header next to it (same name)")
        mraw = p
    else:
        cih, mraw = p, p.with_suffix(".mraw")
        if not mraw.exists():
            raise InputError(f"{p}: no .mraw file next to it ({mraw.name})")
    try:
        info = pyMRAW.get_cih(str(cih))
        w = int(info["Image Width"])
        h = int(info["Image Height"])
        n = int(info["Total Frame"])
        bits = int(info["Color Bit"])
        eff = int(info.get("EffectiveBit Depth", bits))
    except Exception as exc:  # noqa: BLE001 - pyMRAW raises many kinds on a bad header
        raise InputError(f"{cih}: not a readable Photron header "
                         f"({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})"
                         ) from None
    if bits not in (8, 12, 16):
        raise InputError(f"{cih}: {bits}-bit frames are not supported (8, 12 or 16)")
    if w <= 0 or h <= 0 or n <= 0:  # header values checked where they enter
        raise InputError(f"{cih}: the header says {n} frames of {w}x{h} pixels; expected "
                         "positive numbers")
    need = n * w * h * bits // 8
    have = mraw.stat().st_size
    if have < need:
        raise InputError(f"{mraw}: truncated ({have} bytes, the header says {n} frames of "
                         f"{w}x{h} at {bits} bit = {need} bytes)")
    try:
        images = pyMRAW.load_images(str(mraw), h, w, n, bit=bits, roll_axis=False)
    except (ValueError, OSError) as exc:
        raise InputError(f"{mraw}: cannot read frames ({exc})") from None
    rate = frame_rate_of(info.get("Record Rate(fps)"))
    declared = eff if 0 < eff <= bits else bits

    def check(i, img):
        if src.bits < bits:  # the data may contradict the header's effective bit depth
            top = int(img.max())
            if top > (1 << src.bits) - 1:
                warnings.warn(
                    f"{cih}: header 'EffectiveBit Depth : {declared}' is contradicted by the "
                    f"data ({mraw.name}#{i} holds counts up to {top} > {(1 << declared) - 1}); "
                    f"the counts are kept and read as {bits}-bit ('Color Bit'), saturated at "
                    f"{(1 << bits) - 1}", UserWarning, stacklevel=3)
                src.bits = bits

    closer = None
    if isinstance(images, np.memmap) and images.flags.c_contiguous:
        # 8- and 16-bit words: frames read from the file, not through the map (a mapped
        # video's pages stay in the process's resident memory as it is read: a 500 MB
        # video, 500 MB more RSS), as the NPY stack's
        fh = open(mraw, "rb")  # noqa: SIM115 - closed by the source's closer
        dtype, offset, size = images.dtype, int(images.offset), h * w
        del images
        images = _PreadFrames(fh, dtype, offset, (h, w), size)
        closer = fh.close

    def read(i):
        img = images[i]
        if mask_saturated:  # where the full scale matters: every frame is checked
            check(i, img)
        return img

    src = FrameSource(mraw, n, (h, w), read, lambda i: f"{mraw}#{i}", bits=declared,
                      frame_rate=rate, mask_saturated=mask_saturated, closer=closer)
    if n:
        check(0, images[0])  # the first frame says at once whether the header holds
    return src


class _PreadFrames:
    """Frames of a raw stack read by ``os.pread`` (no shared file position: threads may
    read frames), each a fresh array."""

    def __init__(self, fh, dtype, offset: int, shape: tuple, size: int):
        self.fh, self.dtype, self.offset, self.shape, self.size = fh, dtype, offset, shape, \
            size

    def __getitem__(self, i):
        out = np.empty(self.shape, dtype=self.dtype)
        nb = out.nbytes
        got = os.preadv(self.fh.fileno(), [memoryview(out).cast("B")],
                        self.offset + int(i) * nb)
        if got != nb:
            raise InputError(f"{self.fh.name}: frame {int(i)} is truncated")
        return out


def _cine(p: Path, mask_saturated: bool) -> FrameSource:
    """Phantom .cine: headers, setup and the frame offset table parsed by cine-handler's
    ``cine_reader.headers``; each frame's payload read on demand and decoded here
    (uncompressed 8/16-bit; ``P12L`` 12-bit packed, ``biCompression`` 1024, uPSP's usual
    format) or by cine-handler's 10-bit unpacker (``P10``, ``biCompression`` 256, counts
    linearised to 12 bits). Packed frames are never flipped, unpacked ones are when stored
    bottom-up (uPSP's rule, module docstring). No black/white level is applied."""
    try:
        from cine_reader.headers import (
            read_bitmap_header,
            read_cine_header,
            read_image_offsets,
            read_setup,
        )
        from cine_reader.unpack import unpack_10bit_data
    except ImportError:  # pragma: no cover - a runtime dependency
        raise InputError(f"{p}: reading .cine needs the 'cine-handler' package") from None
    fh = open(p, "rb")  # noqa: SIM115 - kept open for the frames, closed by FrameSource.close
    try:
        head = read_cine_header(fh)
        if head.Type != b"CI":
            raise ValueError(f"signature {head.Type!r}, expected b'CI'")
        bmp = read_bitmap_header(fh, off_image_header=int(head.OffImageHeader))
        setup = read_setup(fh, off_setup=int(head.OffSetup),
                           off_image_offsets=int(head.OffImageOffsets))
        n = int(head.ImageCount)
        size = os.fstat(fh.fileno()).st_size
        table = int(head.OffImageOffsets)
        # header values checked before they size anything: a table of n offsets (4 or 8
        # bytes each) must lie inside the file
        if n < 1 or table < 0 or table + 4 * n > size:
            raise ValueError(f"the header says {n} frames with their offset table at byte "
                             f"{table}, the file has {size} bytes")
        offsets = read_image_offsets(fh, off_image_offsets=table, image_count=n,
                                     version=int(head.Version)).pImage[:n]  # + a sentinel
        offsets = np.asarray(offsets, np.uint64).astype(np.int64)  # > 2**63: negative
    except (OSError, ValueError, EOFError, IndexError, struct.error) as exc:
        fh.close()
        raise InputError(f"{p}: not a readable Phantom .cine file ({exc})") from None
    w, h_signed = int(bmp.biWidth), int(bmp.biHeight)
    h, comp, bitcount = abs(h_signed), int(bmp.biCompression), int(bmp.biBitCount)
    if bitcount not in (8, 16) or comp not in (0, 256, 1024) or w <= 0 or h <= 0:
        fh.close()
        raise InputError(f"{p}: unsupported .cine image layout ({bitcount} bits a pixel, "
                         f"compression {comp}, {w}x{h}); grey 8/16-bit, P10 or P12L are read")
    bits = int(setup.RealBPP) or (12 if comp == 1024 else bitcount)
    if comp == 256:
        bits = 12  # P10 is linearised to 12-bit counts (Phantom's table, as uPSP reads it)
    need = {0: w * h * bitcount // 8, 256: w * h * 10 // 8, 1024: w * h * 3 // 2}[comp]
    bad = np.flatnonzero((offsets < 0) | (offsets >= size))  # a short last frame: when read
    if bad.size:
        fh.close()
        raise InputError(f"{p}: frame {int(bad[0])}'s offset {int(offsets[bad[0]])} lies "
                         f"outside the file ({size} bytes): damaged offset table")
    # DIB convention: positive height = rows stored bottom-up, for unpacked frames only;
    # packed frames are top-down whatever the sign (uPSP's CineReader, pims)
    flip = h_signed > 0 and comp == 0

    def read(i):
        try:
            fh.seek(int(offsets[i]))
            ann = struct.unpack("<I", fh.read(4))[0]
            fh.seek(int(offsets[i]) + ann)
            data = fh.read(need)
        except (OSError, struct.error) as exc:
            raise InputError(f"{p}#{i}: cannot read frame ({exc})") from None
        if len(data) != need:
            raise InputError(f"{p}#{i}: truncated frame ({len(data)} of {need} bytes)")
        if comp == 0:
            img = np.frombuffer(data, "<u2" if bitcount == 16 else "u1").reshape(h, w)
        elif comp == 1024:
            img = _unpack_p12l(data, h, w)
        else:
            img = np.asarray(unpack_10bit_data(data))[: w * h].reshape(h, w)
        return img[::-1] if flip else img

    rate = frame_rate_of(setup.frame_rate_hz)
    return FrameSource(p, n, (h, w), read, lambda i: f"{p}#{i}", bits=bits,
                       frame_rate=rate, mask_saturated=mask_saturated,
                       closer=fh.close)


def frame_rate_of(value) -> float | None:
    """A header's frame rate as a number of frames/s, as the header says it: None when it
    is absent or 0 (not recorded), NaN when it is not a number. Whether it can be used is
    the caller's to judge (:data:`resection.defaults.FRAME_RATE_RANGE`): a command given
    the rate by the user does not need the header's."""
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    try:
        r = float(value)
    except (TypeError, ValueError, OverflowError):
        return float("nan")
    return None if r == 0 else r


def _unpack_p12l(data: bytes, h: int, w: int) -> np.ndarray:
    """Phantom P12L: two 12-bit pixels in three bytes, most significant bits first
    (``b0 b1_hi | b1_lo b2``)."""
    b = np.frombuffer(data, np.uint8).reshape(-1, 3).astype(np.uint16)
    out = np.empty((b.shape[0], 2), np.uint16)
    out[:, 0] = (b[:, 0] << 4) | (b[:, 1] >> 4)
    out[:, 1] = ((b[:, 1] & 0x0F) << 8) | b[:, 2]
    return out.reshape(h, w)
