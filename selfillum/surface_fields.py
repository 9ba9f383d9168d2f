"""``--surface FILE`` of ``selfillum psp`` and ``selfillum unsteady``: the results as
fields on the model, in the formats :func:`resection.io.fields.write_fields` writes (VTU,
VTK, XDMF + HDF5, PLY, CSV; a Plot3D function file ``.f`` with its ``.nam``), so that
ParaView, Tecplot or FAST open the pressure and its uncertainty with the grid.

* :func:`check_surface_paths`: the paths checked before any heavy step (format known, not
  an input, not another output, not there already, ``.f`` only on a Plot3D grid);
* :func:`write_mesh_fields`: per-face and per-node fields of a mesh (``psp``);
* :func:`write_grid_fields`: per-node fields of an unsteady run's grid, nodes in the grid
  file's order (``unsteady``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from resection.errors import InputError

__all__ = ["SURFACE_SUFFIXES", "check_surface_paths", "write_mesh_fields",
           "write_grid_fields"]

#: Formats of ``--surface`` (``.npy`` holds one field only: not offered).
SURFACE_SUFFIXES = (".vtu", ".vtk", ".xdmf", ".ply", ".csv", ".f")


def check_surface_paths(paths, *, inputs=(), outputs=(), plot3d: bool = True) -> list:
    """``--surface`` paths as :class:`~pathlib.Path`, checked; ``plot3d``: the grid is a
    Plot3D grid (a ``.f`` needs one)."""
    from resection.io.fields import nam_path, xdmf_data_path

    out = [Path(p) for p in (paths or [])]
    taken = {Path(p).resolve() for p in outputs}
    ins = {Path(p).resolve() for p in inputs if p is not None}
    for p in out:
        suf = p.suffix.lower()
        if suf not in SURFACE_SUFFIXES:
            raise InputError(f"--surface {p}: unknown format {suf or '(none)'!r} (use "
                             f"{', '.join(SURFACE_SUFFIXES)})")
        if suf == ".f" and not plot3d:
            raise InputError(f"--surface {p}: a Plot3D function file needs a Plot3D grid")
        if not p.parent.exists():
            raise InputError(f"--surface {p}: folder {p.parent} does not exist")
        side = [Path(nam_path(p))] if suf == ".f" else \
            [xdmf_data_path(p)] if suf == ".xdmf" else []
        for q in [p, *side]:
            r = q.resolve()
            if r in ins:
                raise InputError(f"--surface {p}: {q} is an input; choose another name")
            if r in taken:
                raise InputError(f"--surface {p}: {q} is another output of the run")
            if q.exists():
                raise InputError(f"--surface {p}: {q} exists; remove it or choose another "
                                 "name")
            taken.add(r)
    return out


def write_mesh_fields(path, mesh, face_fields: dict, node_fields: dict) -> None:
    """Write the fields of ``mesh``: both kinds, except to a Plot3D function file, which
    holds the node fields (on the grid's own nodes)."""
    from resection.io.fields import write_fields

    if Path(path).suffix.lower() == ".f":
        write_fields(path, mesh, None, node_fields)
    else:
        write_fields(path, mesh, face_fields, node_fields, include_attributes=False)


def write_grid_fields(path, grid, node_fields: dict) -> None:
    """Write per-node fields of ``grid`` (a :class:`selfillum.unsteady.grid.RunGrid`;
    values in the grid file's node order): a Plot3D function file with one block per grid
    block (``i`` fastest, the file's order) and its ``.nam``, or the grid's nodes and
    triangles with the fields as point data."""
    import trimesh

    from resection.io._write import atomic_text
    from resection.io.fields import nam_path, write_fields
    from resection.io.plot3d import write_plot3d_function

    names = list(node_fields)
    if Path(path).suffix.lower() == ".f":
        vals = np.column_stack([np.asarray(node_fields[k], np.float64) for k in names])
        blocks, a = [], 0
        for d in grid.dims:  # a few blocks
            n = int(np.prod(d))
            blocks.append(vals[a:a + n].reshape(tuple(d) + (len(names),), order="F"))
            a += n
        write_plot3d_function(path, blocks)
        atomic_text(nam_path(path), "".join(f"{k}\n" for k in names))
        return
    mesh = trimesh.Trimesh(np.asarray(grid.points), np.asarray(grid.triangles),
                           process=False)
    write_fields(path, mesh, None, node_fields, include_attributes=False)
