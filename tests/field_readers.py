"""Independent readers of the field files the uncertainty tests check: a Plot3D function
file read with plain NumPy following the format, an XDMF attribute through its XML
(standard library) and its HDF5 data (h5py)."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import h5py
import numpy as np


def read_function_file(path) -> list:
    """A multi-block Plot3D function file by hand: (ni, nj, nk, nvar) per block."""
    raw = open(path, "rb").read()  # noqa: SIM115
    recs, pos = [], 0
    while pos < len(raw):
        n = int(np.frombuffer(raw, "<i4", 1, pos)[0])
        recs.append(raw[pos + 4:pos + 4 + n])
        assert np.frombuffer(raw, "<i4", 1, pos + 4 + n)[0] == n
        pos += n + 8
    nb = int(np.frombuffer(recs[0], "<i4")[0])
    dims = np.frombuffer(recs[1], "<i4").reshape(nb, 4)
    out = []
    for r, (ni, nj, nk, nv) in zip(recs[2:], dims, strict=True):
        v = np.frombuffer(r, "<f8").reshape(nv, nk, nj, ni)
        out.append(np.transpose(v, (3, 2, 1, 0)))
    return out


def read_xdmf_attribute(path, name: str, center: str) -> np.ndarray:
    """The named attribute of an XDMF file: its DataItem's ``file:/dataset`` read with
    h5py (the file beside the XDMF)."""
    root = ET.parse(path).getroot()
    for att in root.iter("Attribute"):
        if att.get("Name") == name and att.get("Center") == center:
            fname, ds = att.find("DataItem").text.strip().split(":")
            with h5py.File(path.parent / fname) as f:
                return f[ds][()]
    raise KeyError(name)
