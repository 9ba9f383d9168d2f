"""What faces no camera sees are taken to emit, stated by the user and written with results.

The correction of a seen face depends on the radiosity of the hidden faces it sees
(:func:`selfillum.correct`). That radiosity is not measured: it follows from an
assumption on what the hidden faces *emit*:

* ``"continue"``: the smoothest continuation of the seen emission (the default);
* ``"none"``: nothing;
* given per-face values (a file);

and from which parts of the model are *unpainted*: those emit nothing, seen or not (a
black block, a sting, a bare metal insert), while they still reflect with their
reflectance. This module reads these choices from files, describes them in one line for
the printout and the result files, and judges how much a result rests on them: the
``unseen_share`` of :class:`selfillum.SolveInfo` is, for each seen face, the share of its
correction that comes from hidden faces; :func:`unseen_warning` turns it into a warning
when the light attributed to hidden faces is a sizeable part of the signal over a
meaningful area.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from resection.errors import InputError

if TYPE_CHECKING:
    import trimesh

__all__ = ["read_unpainted", "read_unseen", "describe_unseen", "unseen_warning",
           "WARN_LEVEL", "WARN_AREA"]

#: Part of a seen face's signal attributed to hidden faces above which it counts as
#: resting on the assumption (5 % of the signal).
WARN_LEVEL = 0.05
#: Share of the seen area over which that must happen for a warning (1 %).
WARN_AREA = 0.01

_BLOCKS = re.compile(r"^\s*(?:blocks?:)?\s*\d+(\s*[,-]\s*\d+)*\s*$", re.IGNORECASE)


def _per_face_file(path: Path, n_faces: int, what: str) -> np.ndarray:
    """One number per face from a ``.npy`` array or a one-column ``.csv``/``.txt``."""
    suffix = path.suffix.lower()
    if suffix == ".npy":
        from resection.io.images import load_npy

        values = load_npy(path)  # one-line errors, never advising allow_pickle
    elif suffix in (".csv", ".txt"):
        try:
            values = np.loadtxt(path, delimiter=",", ndmin=1, comments="#")
        except ValueError:
            try:  # a one-word header line
                values = np.loadtxt(path, delimiter=",", ndmin=1, comments="#", skiprows=1)
            except ValueError as exc:
                raise InputError(f"{path}: non-numeric {what} values ({exc})") from None
    else:
        raise InputError(f"{path}: unknown {what} file type {suffix!r} (use .npy or .csv)")
    values = np.asarray(values)
    if values.dtype.kind not in "biuf":
        raise InputError(f"{path}: non-numeric {what} values")
    values = values.astype(np.float64).reshape(-1)
    if values.size != n_faces:
        raise InputError(f"{path}: {values.size} {what} values for {n_faces} faces")
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise InputError(f"{path}: NaN or infinite {what} value at face {int(bad[0])}")
    return values


def _block_numbers(text: str) -> np.ndarray:
    """``"3,5-7"`` -> ``[3, 5, 6, 7]``."""
    body = text.split(":", 1)[1] if ":" in text else text
    out = []
    for part in body.split(","):
        if "-" in part:
            a, b = (int(v) for v in part.split("-"))
            out.extend(range(a, b + 1))
        else:
            out.append(int(part))
    return np.array(out, dtype=np.int64)


def read_unpainted(spec, mesh: trimesh.Trimesh) -> tuple[np.ndarray, str]:
    """Unpainted faces from a per-face file or Plot3D block numbers.

    Parameters
    ----------
    spec : str, path-like or (N,) array_like
        A ``.npy`` or ``.csv`` file with one 0/1 value per face in face order (1:
        unpainted), block numbers of a Plot3D grid (``"3,5-7"`` or ``"blocks:3,5-7"``,
        counted from 1 in file order), or a per-face boolean array.
    mesh : trimesh.Trimesh
        The model; for block numbers it must come from a Plot3D grid
        (``face_attributes["block"]``, counted from 1, as
        :func:`resection.io.meshes.plot3d_to_mesh` writes it).

    Returns
    -------
    mask : (N,) bool ndarray
        ``True`` on unpainted faces.
    source : str
        Where the mask came from, for the printout.
    """
    n = len(mesh.faces)
    if not isinstance(spec, str | os.PathLike):
        mask = np.asarray(spec)
        if mask.shape != (n,) or mask.dtype != bool:
            raise InputError(f"unpainted: expected a boolean array of shape ({n},), got "
                             f"{mask.dtype} {mask.shape}")
        return mask, "a per-face mask"
    text = os.fspath(spec)
    path = Path(text)
    if not path.exists() and _BLOCKS.match(text):
        numbers = _block_numbers(text)
        block = mesh.face_attributes.get("block") if hasattr(mesh, "face_attributes") else None
        if block is None:
            raise InputError(f"--unpainted {text}: block numbers need a Plot3D grid (this "
                             "mesh has no blocks); give a per-face 0/1 file instead")
        block = np.asarray(block, dtype=np.int64)
        count = int(block.max())
        bad = numbers[(numbers < 1) | (numbers > count)]
        if bad.size:
            raise InputError(f"--unpainted {text}: block {int(bad[0])} does not exist (the "
                             f"grid has blocks 1 to {count}, counted from 1)")
        return np.isin(block, numbers), f"Plot3D blocks {text.split(':')[-1].strip()}"
    if not path.exists():
        raise InputError(f"{path}: no such unpainted-face file (nor block numbers like 3,5-7)")
    values = _per_face_file(path, n, "unpainted")
    bad = np.flatnonzero((values != 0) & (values != 1))
    if bad.size:
        raise InputError(f"{path}: unpainted values must be 0 or 1, got {values[bad[0]]:g} "
                         f"at face {int(bad[0])}")
    return values == 1, str(path)


def read_unseen(spec, n_faces: int):
    """What hidden faces emit: ``"continue"``, ``"none"`` or per-face values from a file.

    Returns
    -------
    ``"continue"``, ``"none"`` or an ``(n_faces,)`` float64 array (given emission, units
    of the image).
    """
    if isinstance(spec, str) and spec in ("continue", "none"):
        return spec
    if not isinstance(spec, str | os.PathLike):
        raise InputError(f"unseen: expected 'continue', 'none' or a file, got {spec!r}")
    path = Path(os.fspath(spec))
    if not path.exists():
        raise InputError(f"{path}: no such unseen-emission file (nor 'continue' or 'none')")
    return _per_face_file(path, n_faces, "unseen emission")


def describe_unseen(unseen, unpainted=None, unpainted_source: str = "") -> str:
    """One line stating the assumption, for the printout and the result files."""
    if isinstance(unseen, str) and unseen == "continue":
        text = "continue (smoothest continuation of the seen emission)"
    elif isinstance(unseen, str) and unseen == "none":
        text = "none (hidden faces emit nothing)"
    else:
        text = "given (per-face emission values)"
    if unpainted is not None and np.any(unpainted):
        where = f" from {unpainted_source}" if unpainted_source else ""
        text += f"; {int(np.sum(unpainted))} unpainted faces{where} emit nothing"
    return text


def unseen_warning(share, si, seen, areas, *, level: float = WARN_LEVEL,
                   area: float = WARN_AREA) -> str | None:
    """A warning when the result rests on the hidden faces over a meaningful area.

    Parameters
    ----------
    share : (N,) array_like
        Share of each seen face's correction that comes from hidden faces
        (:attr:`selfillum.SolveInfo.unseen_share`).
    si : (N,) array_like
        Self-illumination part of each seen face's signal, ``(B - E) / B``.
    seen : (N,) array_like of bool
        Seen faces.
    areas : (N,) array_like
        Face areas (model units squared).
    level, area : float
        The warning is given when ``share * si`` (the part of the signal attributed to
        hidden faces) exceeds ``level`` over at least ``area`` of the seen area.

    Returns
    -------
    str or None
        The warning text, or None.
    """
    seen = np.asarray(seen, dtype=bool)
    part = np.asarray(share, dtype=np.float64) * np.asarray(si, dtype=np.float64)
    a = np.asarray(areas, dtype=np.float64)
    total = float(a[seen].sum())
    if total <= 0:
        return None
    big = seen & np.isfinite(part) & (part > level)
    frac = float(a[big].sum()) / total
    if frac < area:
        return None
    return (f"on {100 * frac:.1f} % of the seen area more than {100 * level:.0f} % of the "
            f"signal is light from faces no camera sees (up to "
            f"{100 * float(np.nanmax(part[big])):.0f} %): the correction there rests on "
            "the assumption for unseen faces (--unseen, --unpainted)")
