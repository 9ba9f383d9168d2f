"""Kulite time histories, read as uPSP reads them or from a plain table.

uPSP's files (``python/upsp/processing/kulite_utilities.py``): in the datapoint's Kulite
folder, one or more ``*.info`` headers named ``T<run>p<seq>t<n>.info`` or
``r<run>s<seq>t<n>_S<k>C<l>.info``, each beside its binary ``.fast`` / ``.slow`` data:

* the ``.info`` is tab-separated, in four blocks (file paths, statistics, DAQ
  configuration, channel configuration); each block's first line holds its number of rows
  in its second field, and every line's first two fields are line numbers (dropped);
* the statistics block's rows are the fast (row 0) and slow (row 1) streams, with
  ``Sampling Rate``, ``Number Channels`` and ``Samples Acquired``; the file paths block's
  ``File Name`` of rows 1 (fast) and 2 (slow) names the data files (else
  ``<info stem>.fast`` / ``.slow``);
* the channel block has a ``User Name`` column (the Kulite's name; without it, ``K01``,
  ``K02``, ... from ``User Channel``), the channel's ``Coeff k1``, ``Coeff k0``,
  ``EU C1``, ``EU Gain (dB)``, ``EU C0``; its layout versions 1 (second column
  ``Physical Channel``) and 4 (18 columns) are read, others refused as uPSP does;
* the data are little-endian int32, one row per sample, one column per channel:
  ``volts = counts k1 + k0``, ``psi = volts EU_C1 / 10^(EU_Gain / 20) + EU_C0`` (or
  ``volts / calibrationmatrix[channel, 2]`` when a ``.zPXImat`` sits beside the data);
* the channels whose name holds a ``K`` are Kulites.

The fast stream is read when its file exists, else the slow one.

Plain tables (psi, time in seconds from the first frame): a CSV with a header ``time`` then
one column per Kulite; an NPY structured array with a ``time`` field and one per Kulite;
an HDF5 file with a ``time`` dataset and one dataset per Kulite (at the root or under
``kulites``).
"""

from __future__ import annotations

import csv
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from resection.errors import InputError

__all__ = ["KuliteSeries", "read_kulites", "read_upsp_kulites", "read_kulite_table",
           "upsp_info_files"]

_PATTERNS = (r"T(?P<run>\d+)p(?P<seq>\d+)t\d+$", r"r(?P<run>\d{4})s(?P<seq>\d{3})t\d+_S\dC\d$")


@dataclass(frozen=True)
class KuliteSeries:
    """Kulites of a datapoint: ``names``, ``data`` (K, n) psi, ``rate`` (Hz), ``t0``
    (seconds of the first sample from the first frame), ``source``."""

    names: tuple
    data: np.ndarray
    rate: float
    t0: float = 0.0
    source: str = ""


def _blocks(rows, path):
    out = []
    for _ in range(4):
        if not rows:
            raise InputError(f"{path}: {len(out)} blocks, an .info file has 4")
        try:
            n = int(rows[0][1])
        except (IndexError, ValueError):
            raise InputError(f"{path}: a block's first line must give its row count in "
                             f"its second field, got {rows[0][:3]!r}") from None
        if len(rows) < n + 1:
            raise InputError(f"{path}: a block of {n} rows, the file ends before")
        blk = [r[2:] for r in rows[:n + 1]]
        del rows[:n + 1]
        out.append(blk)
    return out


def _table(blk):
    head = blk[0]
    return [dict(zip(head, r, strict=False)) for r in blk[1:]], head


def _num(v, path, what):
    try:
        return float(v)
    except (TypeError, ValueError):
        raise InputError(f"{path}: {what} is not a number ({v!r})") from None


def _read_info(path: Path, prefer: str):
    with open(path, newline="", encoding="utf-8-sig", errors="replace") as fh:
        rows = [r for r in csv.reader(fh, delimiter="\t")]
    files, stats, _, chans = _blocks(rows, path)
    files, _ = _table(files)
    stats, _ = _table(stats)
    chans, chead = _table(chans)
    if "User Name" not in chead:
        if "User Channel" not in chead:
            raise InputError(f"{path}: channel block without 'User Name' or 'User Channel'")
        for c in chans:
            c["User Name"] = f"K{int(_num(c['User Channel'], path, 'User Channel')):02d}"
        cols = [h for h in chead]
    else:
        cols = [h for h in chead if h != "User Name"]
    version = 4 if len(cols) == 18 else 3 if len(cols) == 17 else \
        2 if len(cols) > 1 and cols[1] == "User Channel" else \
        1 if len(cols) > 1 and cols[1] == "Physical Channel" else None
    if version not in (1, 4):
        raise InputError(f"{path}: channel block layout version {version or 'unknown'}; "
                         "uPSP reads versions 1 and 4")
    for k in ("Coeff k1", "Coeff k0", "EU C1", "EU Gain (dB)", "EU C0"):
        if k not in chead:
            raise InputError(f"{path}: channel block has no {k!r} column")
    if len(stats) < 2 or len(files) < 3:
        raise InputError(f"{path}: the statistics block needs the fast and slow rows and "
                         "the file block three rows")
    order = ("fast", "slow") if prefer == "fast" else ("slow", "fast")
    for kind in order:
        row = 1 if kind == "fast" else 2
        f = path.parent / files[row].get("File Name", "")
        if not f.is_file():
            f = path.with_suffix("." + kind)
        if f.is_file():
            st = stats[0 if kind == "fast" else 1]
            return f, kind, st, chans
    raise InputError(f"{path}: neither its .fast nor its .slow data file exists")


def _read_data(info: Path, prefer: str):
    f, kind, st, chans = _read_info(info, prefer)
    rate = _num(st.get("Sampling Rate"), info, "Sampling Rate")
    nch = int(_num(st.get("Number Channels"), info, "Number Channels"))
    ns = int(_num(st.get("Samples Acquired"), info, "Samples Acquired"))
    size = f.stat().st_size
    if size != 4 * nch * ns:
        raise InputError(f"{f}: {size} bytes, the .info says {ns} samples x {nch} channels "
                         f"of 4 bytes ({4 * nch * ns})")
    raw = np.fromfile(f, dtype="<i4").reshape(ns, nch)
    cal = None
    mat = f.with_suffix(".zPXImat")
    if mat.is_file():
        import scipy.io

        cal = np.asarray(scipy.io.loadmat(str(mat))["calibrationmatrix"], float)
    names, data = [], []
    for i, c in enumerate(chans):
        name = str(c["User Name"]).strip()
        if "K" not in name:
            continue
        if i >= nch:
            raise InputError(f"{info}: channel {i + 1} ({name}) beyond the {nch} channels")
        volts = raw[:, i] * _num(c["Coeff k1"], info, "Coeff k1") + \
            _num(c["Coeff k0"], info, "Coeff k0")
        if cal is not None:
            psi = volts / cal[i, 2]
        else:
            psi = volts * _num(c["EU C1"], info, "EU C1") / \
                10 ** (_num(c["EU Gain (dB)"], info, "EU Gain (dB)") / 20) + \
                _num(c["EU C0"], info, "EU C0")
        names.append(name)
        data.append(psi)
    return names, data, rate


def upsp_info_files(folder, run: int, seq: int) -> list:
    """The ``.info`` files of run ``run`` point ``seq`` in ``folder``, found as uPSP finds
    them (the first file's name decides which of the two patterns the folder uses)."""
    infos = sorted(Path(folder).glob("*.info"))
    for pat in _PATTERNS:
        if infos and re.search(pat, infos[0].stem):
            return [p for p in infos if (m := re.search(pat, p.stem))
                    and (int(m["run"]), int(m["seq"])) == (run, seq)]
    return []


def read_upsp_kulites(folder, run: int, seq: int, prefer: str = "fast") -> KuliteSeries:
    """uPSP's ``.info`` + ``.fast``/``.slow`` files of run ``run`` point ``seq`` in
    ``folder`` (module notes)."""
    d = Path(folder)
    if not any(d.glob("*.info")):
        raise InputError(f"{d}: no Kulite .info file")
    picked = upsp_info_files(d, run, seq)
    if not picked:
        raise InputError(f"{d}: no Kulite .info file of run {run} point {seq} "
                         "(T<run>p<seq>t<n>.info or r<run>s<seq>t<n>_S<k>C<l>.info)")
    names, data, rates = [], [], set()
    for p in picked:
        n, x, r = _read_data(p, prefer)
        names += n
        data += x
        rates.add(r)
    if not names:
        raise InputError(f"{d}: no Kulite channel (a name holding 'K') in "
                         f"{', '.join(p.name for p in picked)}")
    if len(rates) > 1 or len({len(x) for x in data}) > 1:
        raise InputError(f"{d}: the .info files of run {run} point {seq} differ in rate or "
                         "length")
    order = np.argsort(names)
    return KuliteSeries(tuple(names[i] for i in order), np.array([data[i] for i in order]),
                        float(rates.pop()), 0.0, str(d))


def _from_columns(cols: dict, path: str) -> KuliteSeries:
    if "time" not in cols:
        raise InputError(f"{path}: no 'time' column (seconds)")
    t = np.asarray(cols.pop("time"), float)
    if t.ndim != 1 or len(t) < 2 or not np.all(np.diff(t) > 0):
        raise InputError(f"{path}: 'time' must increase")
    dt = np.diff(t)
    if np.ptp(dt) > 1e-6 * np.mean(dt):
        raise InputError(f"{path}: 'time' is not evenly sampled")
    if not cols:
        raise InputError(f"{path}: no Kulite column beside 'time'")
    data = np.array([np.asarray(v, float) for v in cols.values()])
    if data.shape[1] != len(t) or not np.all(np.isfinite(data)):
        raise InputError(f"{path}: Kulite columns must be numbers, as long as 'time'")
    return KuliteSeries(tuple(cols), data, float(1.0 / np.mean(dt)), float(t[0]), path)


def read_kulite_table(path) -> KuliteSeries:
    """A plain CSV, NPY or HDF5 table of Kulites (module notes)."""
    p = os.fspath(path)
    suf = Path(p).suffix.lower()
    if suf == ".csv":
        with open(p, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
        if not rows:
            raise InputError(f"{p}: empty")
        head = [h.strip() for h in rows[0]]
        try:
            vals = np.array([[float(x) for x in r] for r in rows[1:] if r], float)
        except ValueError:
            raise InputError(f"{p}: a value is not a number") from None
        if vals.ndim != 2 or vals.shape[1] != len(head):
            raise InputError(f"{p}: every row needs {len(head)} values")
        return _from_columns({h: vals[:, i] for i, h in enumerate(head)}, p)
    if suf == ".npy":
        a = np.load(p, allow_pickle=False)
        if a.dtype.names is None:
            raise InputError(f"{p}: a structured array with a 'time' field is expected")
        return _from_columns({k: a[k] for k in a.dtype.names}, p)
    if suf in (".h5", ".hdf5"):
        import h5py

        with h5py.File(p, "r") as f:
            g = f["kulites"] if "kulites" in f else f
            cols = {k: g[k][()] for k in g if isinstance(g[k], h5py.Dataset)}
            if "time" not in cols and "time" in f:
                cols["time"] = f["time"][()]
        return _from_columns(cols, p)
    raise InputError(f"{p}: a Kulite table is .csv, .npy or .h5")


def read_kulites(path, run: int, seq: int) -> KuliteSeries:
    """A folder of uPSP files, or a plain table."""
    p = Path(path)
    if p.is_dir():
        return read_upsp_kulites(p, run, seq)
    if not p.is_file():
        raise InputError(f"{p}: Kulite file or folder not found")
    return read_kulite_table(p)
