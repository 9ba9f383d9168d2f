"""``--surface FILE`` of ``selfillum psp``: the paths checked, and the fields written
(:mod:`selfillum.surface_fields`). Only parses and calls the library."""

from __future__ import annotations

__all__ = ["surface_paths", "write_surfaces"]


def surface_paths(args, mesh) -> list:
    """``--surface`` paths checked (before the heavy steps)."""
    from selfillum.surface_fields import check_surface_paths

    inputs = [args.mesh, *args.camera, *args.wind_off, *(args.wind_on or []), args.taps,
              args.tap_positions, getattr(args, "markers", None)]
    return check_surface_paths(args.surface, inputs=inputs,
                               plot3d=mesh.metadata.get("plot3d_dims") is not None)


def write_surfaces(paths, mesh, face_fields: dict) -> None:
    """Each ``--surface`` file: the face fields and their node values (area-weighted mean
    of the faces around a vertex, :func:`selfillum.uncertainty.psp_io.node_values`)."""
    if not paths:
        return
    from selfillum.surface_fields import write_mesh_fields
    from selfillum.uncertainty.psp_io import node_operator, node_values

    A = node_operator(mesh)
    nodes = {k: node_values(mesh, v, A) for k, v in face_fields.items()}
    for p in paths:
        write_mesh_fields(p, mesh, face_fields, nodes)
