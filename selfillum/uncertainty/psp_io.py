"""``selfillum psp --uncertainty``'s inputs and outputs: several frames per condition
(:func:`read_condition`), the per-face and per-node tables, the budget's JSON and the
pictures (:func:`write_uncertainty`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from resection.errors import InputError
from selfillum.uncertainty.noise import frame_mean

__all__ = ["read_condition", "node_values", "node_operator", "write_uncertainty", "write_table",
           "face_columns", "node_columns"]


def read_condition(paths, n_cameras: int, option: str) -> tuple[list, list, list]:
    """Per camera: the mean image, its number of frames and the temporal variance (None
    for one frame). ``paths``: one file per camera (an image, or a multi-page TIFF / NPY
    stack), or ``k`` files per camera, camera by camera (the first ``k`` for camera 1)."""
    from resection.io.video import open_frames

    paths = list(paths)
    if not paths or len(paths) % n_cameras:
        raise InputError(f"{option}: {len(paths)} files for {n_cameras} cameras (give one, "
                         "or the same number, per camera, camera by camera)")
    k = len(paths) // n_cameras
    means, counts, variances = [], [], []
    for c in range(n_cameras):
        frames = []
        for p in paths[c * k:(c + 1) * k]:
            with open_frames(p) as src:
                frames += [np.asarray(src[i], np.float64) for i in range(len(src))]
        shapes = {f.shape for f in frames}
        if len(shapes) > 1:
            raise InputError(f"{paths[c * k]}: {option} frames of camera {c + 1} differ in "
                             f"size ({sorted(shapes)})")
        m, n, v = frame_mean(np.stack(frames), str(paths[c * k]))
        means.append(m)
        counts.append(n)
        variances.append(v)
    return means, counts, variances


def node_values(mesh, face_values, operator=None) -> np.ndarray:
    """Area-weighted mean of the finite face values around each vertex (NaN if none);
    ``operator``: :func:`node_operator` of the mesh, when the caller has it."""
    A = node_operator(mesh) if operator is None else operator
    v = np.asarray(face_values, np.float64)
    ok = np.isfinite(v)
    s = A @ np.where(ok, v, 0.0)
    t = A @ ok.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(t > 0, s / t, np.nan)


def node_operator(mesh):
    """(V, F) sparse: each face's area at its three vertices."""
    import scipy.sparse as sp

    f = np.asarray(mesh.faces)
    a = np.asarray(mesh.area_faces, np.float64)
    nf = len(f)
    return sp.csr_matrix((np.repeat(a, 3), (f.ravel(), np.repeat(np.arange(nf), 3))),
                         shape=(len(mesh.vertices), nf))


def write_table(path, columns: dict) -> None:
    """A CSV of ``columns`` (name -> (n,) values): a header line, then one row per item,
    the first column as integers, the others with 9 significant digits (``nan`` where
    NaN)."""
    names = list(columns)
    fmt = ",".join(["%d"] + ["%.9g"] * (len(names) - 1))
    rows = np.column_stack([np.asarray(columns[k], np.float64) for k in names]).tolist()
    Path(path).write_text(",".join(names) + "\n"
                          + "".join([fmt % tuple(r) + "\n" for r in rows]))


def write_uncertainty(out: Path, mesh, maps, state, budgets, stated, atomic_write,
                      plots: bool = True) -> list:
    """Write ``pressure_faces.csv`` (replacing the plain one), ``pressure_nodes.csv``,
    ``uncertainty.json``, ``<q>_u.png`` and ``budget.png``; returns the names written.

    The node value of an uncertainty is the area-weighted mean of its faces' (their
    errors taken as fully correlated: an upper bound for the independent parts)."""
    res = state.result
    cols = face_columns(state, budgets)
    atomic_write(out / "pressure_faces.csv", write_table, cols)
    ncols = {"node": np.arange(len(mesh.vertices))}
    ncols.update(node_columns(mesh, cols))
    atomic_write(out / "pressure_nodes.csv", write_table, ncols)
    area = np.asarray(mesh.area_faces)
    painted = np.isfinite(res.pressure)
    doc = {"stated": stated.to_dict(), "not_stated": [k for k in _all_keys()
                                                      if k not in stated.given],
           **{k: b.summary(area, painted) for k, b in budgets.items()}}
    atomic_write(out / "uncertainty.json", Path.write_text,
                 json.dumps(doc, indent=2, default=float) + "\n")
    written = ["pressure_faces.csv", "pressure_nodes.csv", "uncertainty.json"]
    if not plots:
        return written
    from selfillum.uncertainty.pictures import budget_chart, map_picture

    q = "cp" if "cp" in budgets else "p"
    b = budgets[q]
    atomic_write(out / f"{q}_u.png", lambda p: map_picture(
        maps[0], b.combined, p, f"standard uncertainty of {q} ({b.method}, k = 1)",
        f"{q}_u"))
    atomic_write(out / "budget.png", lambda p: budget_chart(b, p, area, painted))
    return written + [f"{q}_u.png", "budget.png"]


def face_columns(state, budgets) -> dict:
    """The per-face fields: ``face``, ``pressure``, ``ratio``, then per budget (``cp``
    with its value first) the combined ``<q>_u`` and each source's ``<q>_u_<source>``."""
    res = state.result
    cols = {"face": np.arange(len(res.pressure)), "pressure": res.pressure,
            "ratio": res.ratio}
    for name, b in budgets.items():
        if name == "cp":
            cols["cp"] = state.cp
        cols[f"{name}_u"] = b.combined
        for src, u in b.parts.items():
            cols[f"{name}_u_{src}"] = u
    return cols


def node_columns(mesh, face_cols: dict) -> dict:
    """:func:`node_values` of every face field but ``face``."""
    A = node_operator(mesh)
    return {k: node_values(mesh, v, A) for k, v in face_cols.items() if k != "face"}


def _all_keys():
    from selfillum.uncertainty.stated import KEYS

    return list(KEYS)
