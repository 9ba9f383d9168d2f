"""The thermal run's file, its XDMF sidecar and its pictures.

Layout (``format = "selfillum-thermal"``, ``version = 1`` in the root attributes)::

    /temperature         (T, N) float32   surface temperature, K; row = frame, column =
                                          grid node (file order); NaN unseen
    /heat_flux           (T, N) float32   heat flux into the model, W/m^2; NaN unseen
    /heat_transfer_coefficient, /stanton  (T, N) float32, with --sds: h (W/m^2/K) and St
    /grid/points, /grid/triangles, /grid/block_dims     as the unsteady run's file
    /frames/time         (T,) float64     seconds from the first frame
    /cameras/camNN/K, dist, R, t          as the unsteady run's file
    /probes/nodes, /probes/temperature, /probes/heat_flux   (P,), (T, P), (T, P)
    root attributes: mode (ir, tsp), radiometry or tsp_calibration, substrate, method,
                     flow (T_aw, recovery factor, ...), options, provenance (JSON text),
                     saturated_pixels, out_of_range, tracked_failed

Chunks as the unsteady run's (:func:`selfillum.unsteady.output.chunk_shape`): a frame of
every node and a node's whole history cost about the same to read.
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

__all__ = ["FORMAT", "VERSION", "write_xdmf", "plot_heat_flux", "plot_probes"]

FORMAT = "selfillum-thermal"
VERSION = 1


def write_xdmf(path, h5_name: str, n_frames: int, n_nodes: int, n_tris: int, times,
               fields=("temperature", "heat_flux")) -> None:
    """The XDMF sidecar: the grid, and one temporal grid per frame whose node fields are
    row ``k`` of each dataset of ``fields`` (hyperslabs)."""
    h5 = escape(h5_name)
    lines = ['<?xml version="1.0"?>',
             '<Xdmf Version="3.0" xmlns:xi="http://www.w3.org/2001/XInclude">', "<Domain>",
             '<Grid Name="grid" GridType="Uniform">',
             f'<Topology TopologyType="Triangle" NumberOfElements="{n_tris}">',
             f'<DataItem Dimensions="{n_tris} 3" NumberType="Int" Precision="8" '
             f'Format="HDF">{h5}:/grid/triangles</DataItem>', "</Topology>",
             '<Geometry GeometryType="XYZ">',
             f'<DataItem Dimensions="{n_nodes} 3" NumberType="Float" Precision="8" '
             f'Format="HDF">{h5}:/grid/points</DataItem>', "</Geometry>", "</Grid>",
             '<Grid Name="thermal" GridType="Collection" CollectionType="Temporal">']
    include = ('<xi:include xpointer="xpointer(//Grid[@Name=&quot;grid&quot;]/*'
               '[self::Topology or self::Geometry])"/>')
    for k in range(n_frames):  # one entry of text per frame
        lines += [f'<Grid Name="frame {k}" GridType="Uniform">', include,
                  f'<Time Value="{float(times[k])!r}"/>']
        for name in fields:  # a few fields
            lines += [
                f'<Attribute Name="{name}" AttributeType="Scalar" Center="Node">',
                f'<DataItem ItemType="HyperSlab" Dimensions="1 {n_nodes}" Type="HyperSlab">',
                f'<DataItem Dimensions="3 2" Format="XML">{k} 0 1 1 1 {n_nodes}</DataItem>',
                f'<DataItem Dimensions="{n_frames} {n_nodes}" NumberType="Float" '
                f'Precision="4" Format="HDF">{h5}:/{name}</DataItem>',
                "</DataItem>", "</Attribute>"]
        lines.append("</Grid>")
    lines += ["</Grid>", "</Domain>", "</Xdmf>", ""]
    Path(path).write_text("\n".join(lines), encoding="utf-8")


def plot_heat_flux(grid, q, time_s: float, path):
    """Heat flux (W/m^2, per node) on the model at one time, as a picture."""
    from resection.surface.plots import plot_surface, virtual_camera
    from selfillum.unsteady.plots import node_to_faces

    fv = node_to_faces(grid.triangles, q)
    fin = fv[np.isfinite(fv)]
    lo = float(np.percentile(fin, 1)) if fin.size else None
    hi = float(np.percentile(fin, 99)) if fin.size else None
    return plot_surface(grid.mesh, fv, virtual_camera(grid.mesh), cmap="inferno", vmin=lo,
                        vmax=hi if hi is not None and lo is not None and hi > lo else None,
                        label="q (W/m^2)", title=f"heat flux at t = {time_s:.3g} s",
                        outline=True, path=path)


def plot_probes(times, temperature, heat_flux, nodes, points, path):
    """T (K) and q (W/m^2) histories at the probe nodes, two panels (a probe no camera
    sees is named in the legend as unseen)."""
    from matplotlib.figure import Figure

    from resection.surface.plots import finish_figure

    fig = Figure(figsize=(7.5, 6.0), dpi=100, layout="constrained")
    a1, a2 = fig.subplots(2, 1, sharex=True)
    for j, n in enumerate(nodes):  # a few probes
        x, y, z = points[int(n)]
        lab = f"node {int(n)} ({x:.3g}, {y:.3g}, {z:.3g})"
        col = f"C{j % 10}"  # one colour a probe in both panels
        if not np.isfinite(temperature[:, j]).any():
            a1.plot([], [], color=col, label=lab + ": unseen")
            continue
        a1.plot(times, temperature[:, j], lw=1.0, color=col, label=lab)
        a2.plot(times, heat_flux[:, j], lw=1.0, color=col, label=lab)
    a1.set_ylabel("T (K)")
    a2.set_ylabel("q (W/m^2)")
    a2.set_xlabel("time (s)")
    a1.set_title("surface temperature and heat flux at the probes")
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
    a1.legend(fontsize=8)
    return finish_figure(fig, path)
