"""The pixel type of a corrected image on disk.

A self-illumination correction is often under one count (a flat plate: half a count in an
8-bit image); rounding it back to 8 bits erases it. So ``selfillum correct`` writes:

* ``float32`` to TIFF and NPY for an 8-bit (or any integer type of 8 bits or fewer) image;
* the input's own type for a 16-bit, 32-bit or float image (a 16-bit image keeps its counts
  to a sixtieth of a percent of full scale; float stays float);
* PNG holds integers only: a 16-bit image stays 16-bit, an 8-bit image is refused unless a
  type is asked for (the message gives the choices);
* ``uint8`` only when the user asks for it (``--dtype uint8``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from resection.errors import InputError

__all__ = ["DTYPES", "output_dtype"]

#: the pixel types ``--dtype`` accepts
DTYPES = ("float32", "uint16", "uint8")


def output_dtype(input_dtype, out_path: str | os.PathLike, requested: str | None = None
                 ) -> np.dtype:
    """The pixel type to write the corrected image with (rules in the module docstring).

    Raises
    ------
    InputError
        A type PNG cannot hold, or an 8-bit image to PNG without a type asked for.
    """
    dt = np.dtype(input_dtype)
    png = Path(out_path).suffix.lower() == ".png"
    if requested is not None:
        if requested not in DTYPES:
            raise InputError(f"--dtype: expected one of {', '.join(DTYPES)}, got {requested!r}")
        target = np.dtype(requested)
        if png and target.kind == "f":
            raise InputError(f"{out_path}: PNG holds integers only; write .tif or .npy for "
                             "float32, or ask --dtype uint16 or uint8")
        return target
    small = dt.kind == "b" or (dt.kind in "ui" and dt.itemsize == 1)
    if png:
        if small:
            raise InputError(f"{out_path}: an 8-bit image's correction (often under one "
                             "count) would be rounded away in a PNG; write .tif or .npy "
                             "(float32), or ask --dtype uint16 or --dtype uint8")
        return dt
    return np.dtype(np.float32) if small else dt
