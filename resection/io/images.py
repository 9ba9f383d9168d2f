"""Reading and writing single-channel images (TIFF, PNG, NPY).

Images are 2-D ``float32`` arrays in memory, indexed ``img[v, u]`` (row = v down,
column = u right, the centre of the top-left pixel at ``(0, 0)``). Integer files keep their
counts: an 8-bit pixel of 255 reads as 255.0, a 16-bit pixel of 4095 as 4095.0. Use
:func:`image_info` to learn the file's bit depth (e.g. to mask saturated pixels).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from resection.errors import InputError
from resection.io._write import atomic_write

__all__ = ["read_image", "read_native", "load_npy", "write_image", "image_info", "saturation_level"]

_TIFF = {".tif", ".tiff"}
_PNG = {".png"}
_NPY = {".npy"}
_KNOWN = _TIFF | _PNG | _NPY


def _suffix(path: Path) -> str:
    suf = path.suffix.lower()
    if suf not in _KNOWN:
        raise InputError(
            f"{path}: unknown image extension {suf!r} (expected one of {sorted(_KNOWN)})"
        )
    return suf


def _read_raw(path: str | os.PathLike, *, allow_stack: bool = False) -> np.ndarray:
    path = Path(path)
    suf = _suffix(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such image file")
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a directory, not an image")
    try:
        if suf in _TIFF:
            import tifffile

            arr = tifffile.imread(path)
        elif suf in _PNG:
            import imageio.v3 as iio

            arr = iio.imread(path)
        else:
            arr = load_npy(path)
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 - PIL/tifffile raise many kinds (even SyntaxError)
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"{path}: cannot read image ({msg})") from None
    arr = np.asarray(arr)
    if arr.ndim == 3 and arr.shape[-1] in (2, 3, 4) and suf in _PNG | _TIFF:
        kind = {2: "grey + alpha", 3: "colour (RGB)", 4: "colour + alpha (RGBA)"}[arr.shape[-1]]
        raise InputError(
            f"{path}: {kind} image with {arr.shape[-1]} channels; expected a single-channel "
            "(grey) image without alpha"
        )
    if arr.ndim == 3 and arr.shape[0] == 1:
        arr = arr[0]
    if arr.ndim == 3 and suf in _TIFF | _NPY and allow_stack:
        pass
    elif arr.ndim == 3 and suf in _TIFF | _NPY:
        raise InputError(f"{path}: a stack of {arr.shape[0]} frames, not one image; read it "
                         "as a sequence (resection.io.video.iter_frames)")
    if arr.ndim != 2 and not (allow_stack and arr.ndim == 3):
        raise InputError(f"{path}: expected a 2-D single-channel image, got shape {arr.shape}")
    if arr.dtype.kind not in "uif" and arr.dtype != np.bool_:
        raise InputError(f"{path}: unsupported pixel type {arr.dtype}")
    return arr


def load_npy(path, mmap_mode=None) -> np.ndarray:
    """``numpy.load`` of a numeric ``.npy`` file, with one-line errors.

    Object arrays are refused; the message never advises ``allow_pickle`` (loading pickles
    runs arbitrary code). An empty or truncated file is named as such.
    """
    path = Path(path)
    size = path.stat().st_size
    if size == 0:
        raise InputError(f"{path}: empty file (0 bytes), not a .npy array")
    try:
        arr = np.load(path, allow_pickle=False, mmap_mode=mmap_mode)
    except EOFError:
        raise InputError(f"{path}: truncated .npy file ({size} bytes)") from None
    except ValueError as exc:
        msg = str(exc)
        if "pickle" in msg.lower() or "object" in msg.lower():
            raise InputError(f"{path}: holds Python objects, not a numeric array; refused "
                             "(save a numeric array)") from None
        if "size" in msg.lower() or "reshape" in msg.lower() or "truncat" in msg.lower():
            raise InputError(f"{path}: truncated or corrupt .npy file ({size} bytes)") from None
        raise InputError(f"{path}: not a valid .npy file ({msg.splitlines()[0]})") from None
    except (OSError, TypeError) as exc:
        raise InputError(f"{path}: not a valid .npy file ({exc})") from None
    if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "uifb":
        raise InputError(f"{path}: not a numeric array")
    return arr


def read_image(path: str | os.PathLike, *, mask_saturated: bool = False) -> np.ndarray:
    """Read a single-channel image as a 2-D ``float32`` array.

    Parameters
    ----------
    path : path-like
        ``.tif``/``.tiff`` (8/16/32-bit integer or float, via tifffile), ``.png`` (8/16-bit,
        via imageio) or ``.npy`` (any numeric 2-D array).
    mask_saturated : bool
        Return the saturated pixels of an integer file (those at the type's maximum, e.g.
        255 or 65535) as NaN, so that the float image still knows them (the marker detector
        and the enhancement functions mask NaN). No effect on float files.

    Returns
    -------
    (H, W) float32 ndarray
        Pixel values in the file's own units (counts for integer files).

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    InputError
        Unknown extension, unreadable file, colour or multi-page image.
    """
    raw = _read_raw(path)
    img = raw.astype(np.float32)
    sat = saturation_level(raw.dtype) if mask_saturated else None
    if sat is not None:
        img[raw >= sat] = np.nan
    return img


def read_native(path: str | os.PathLike) -> np.ndarray:
    """Read an image with its own pixel type (not converted to float): a 2-D image (PNG,
    TIFF, NPY) or a ``(T, H, W)`` stack (multi-page TIFF, 3-D NPY). Same checks and
    messages as :func:`read_image`; for commands that write their result in the input's
    type (``selfillum correct``)."""
    return _read_raw(path, allow_stack=True)


def image_info(path: str | os.PathLike) -> dict:
    """Shape, file dtype and saturation level (max of the integer type, or None for float)."""
    arr = _read_raw(path)
    return {"shape": arr.shape, "dtype": str(arr.dtype), "saturation": saturation_level(arr.dtype)}


def saturation_level(dtype) -> float | None:
    """The largest value of an integer pixel type (the saturated count), None for floats."""
    dtype = np.dtype(dtype)
    if dtype.kind in "ui":
        return float(np.iinfo(dtype).max)
    return None


def write_image(path: str | os.PathLike, array, *, dtype=None) -> None:
    """Write a 2-D image.

    Parameters
    ----------
    path : path-like
        ``.tif``/``.tiff``, ``.png`` or ``.npy``.
    array : (H, W) array_like
        The image. NaN is allowed in float TIFF/NPY files only.
    dtype : numpy dtype, optional
        Pixel type on disk (e.g. ``np.uint16``); default: the array's own type (PNG: uint8 if
        the values fit in 0..255, otherwise uint16). Values are rounded and must fit the type.
    """
    path = Path(path)
    suf = _suffix(path)
    arr = np.asarray(array)
    if arr.ndim != 2:
        raise InputError(f"{path}: can only write 2-D images, got shape {arr.shape}")
    if arr.dtype.kind not in "uifb":
        raise InputError(f"{path}: unsupported pixel type {arr.dtype}")
    if suf in _PNG and dtype is None:
        if arr.dtype in (np.uint8, np.uint16):
            dtype = arr.dtype
        else:
            finite = arr[np.isfinite(arr)] if arr.dtype.kind == "f" else arr
            dtype = np.uint8 if finite.size and finite.min() >= 0 and finite.max() <= 255 \
                else np.uint16
    if dtype is not None:
        dtype = np.dtype(dtype)
        if suf in _PNG and dtype not in (np.uint8, np.uint16):
            raise InputError(f"{path}: PNG holds only uint8 or uint16 pixels, not {dtype}")
        if dtype.kind in "ui":
            if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
                raise InputError(f"{path}: NaN or infinite pixels cannot be written as {dtype}")
            info = np.iinfo(dtype)
            if arr.size and (arr.min() < info.min or arr.max() > info.max):
                raise InputError(
                    f"{path}: values {arr.min()}..{arr.max()} do not fit in {dtype}"
                )
            arr = np.rint(arr).astype(dtype) if arr.dtype.kind == "f" else arr.astype(dtype)
        else:
            arr = arr.astype(dtype)
    def write(tmp):
        if suf in _TIFF:
            import tifffile

            tifffile.imwrite(tmp, arr)
        elif suf in _PNG:
            import imageio.v3 as iio

            iio.imwrite(tmp, arr, extension=".png")
        else:
            with open(tmp, "wb") as fh:
                np.save(fh, arr, allow_pickle=False)

    # a temporary name in the same folder, renamed into place: a crash never leaves half a
    # file; a missing folder is an InputError naming it
    atomic_write(path, write)
