"""Cart3D annotated triangulations (``.triq``): a ``.tri`` surface with scalars per vertex.

ASCII layout (Cart3D's ``.triq``, as uPSP reads steady Cp from it)::

    nVerts nTris nScalars
    x y z                      (nVerts lines)
    i j k                      (nTris lines, 1-based vertex indices)
    comp                       (nTris lines, component ids)
    s1 ... s_nScalars          (nVerts lines)

Read by :func:`read_triq`: the triangles (a :class:`trimesh.Trimesh` in file order, as
:func:`resection.io.meshes.read_cart3d_tri`) and the ``(nVerts, nScalars)`` scalars. The
Fortran-unformatted variant is refused by name.
"""

from __future__ import annotations

import os

import numpy as np
import trimesh

from resection.errors import InputError

__all__ = ["read_triq"]


def read_triq(path: str | os.PathLike) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Read an ASCII Cart3D ``.triq``: ``(mesh, scalars)`` with scalars ``(nVerts, nScalars)``.

    Raises
    ------
    InputError
        Missing or binary file, a header that is not ``nVerts nTris nScalars``, too few
        numbers, vertex indices out of range, non-finite values (the file is named).
    """
    p = os.fspath(path)
    try:
        with open(p, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        raise InputError(f"Cart3D .triq file not found: {p}") from None
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        raise InputError(f"{p}: not an ASCII .triq (the Fortran-unformatted .triq is not "
                         "read)") from None
    first, _, body = text.partition("\n")
    try:
        head = [int(x) for x in first.split()]
    except ValueError:
        raise InputError(f"{p}: first line must be 'nVerts nTris nScalars'") from None
    if len(head) != 3 or min(head) < 0 or head[0] == 0 or head[1] == 0:
        raise InputError(f"{p}: first line must be 'nVerts nTris nScalars', got {first!r}")
    nv, nt, ns = head
    try:
        v = np.array(body.replace("D", "E").split(), dtype=np.float64)
    except ValueError as exc:
        raise InputError(f"{p}: non-numeric entry ({exc})") from None
    need = 3 * nv + 3 * nt + nt + ns * nv
    if v.size != need:
        raise InputError(f"{p}: {v.size} numbers, the header ({nv} vertices, {nt} triangles, "
                         f"{ns} scalars) needs {need}")
    V = v[:3 * nv].reshape(nv, 3)
    T = v[3 * nv:3 * nv + 3 * nt].reshape(nt, 3)
    if np.any(T != np.round(T)) or T.min() < 1 or T.max() > nv:
        raise InputError(f"{p}: triangle vertex indices must be integers in [1, {nv}]")
    S = v[3 * nv + 4 * nt:].reshape(nv, ns)
    if not (np.all(np.isfinite(V)) and np.all(np.isfinite(S))):
        raise InputError(f"{p}: NaN or infinite values")
    mesh = trimesh.Trimesh(V, T.astype(np.int64) - 1, process=False)
    mesh.face_attributes["component"] = v[3 * nv + 3 * nt:3 * nv + 4 * nt].astype(np.int64)
    return mesh, S
