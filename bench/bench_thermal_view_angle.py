"""How far the thermal run's emissivity, taken at each node's view angle, is from the one
taken at each pixel's view angle on the map (issue 37 item 2).

A node's value is the area-weighted mean of the faces around it that the camera sees, each
face's the mean of the pixels on it. The pixels on a face see it along nearly one line of
sight (the face is small against the camera's distance), so the per-pixel emissivity a
node's value carries is the area-weighted mean, over those faces, of the emissivity at each
face's view angle. This script compares that with the emissivity at the node's own view
angle (its area-weighted normal), at frame 0's pose, on the grid of an IR run made by
``bench_thermal.py`` (``--folder``), and prints the relative difference for the nodes seen
at under 60 degrees and at 60-70 degrees (the run's cut-off).

    python bench/bench_thermal_view_angle.py --folder DIR
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    import scipy.sparse as sp

    from resection.io.cameras import read_camera
    from selfillum.thermal.balance import NodeGeometry
    from selfillum.thermal.radiometry import read_radiometry
    from selfillum.unsteady.grid import load_run_grid

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--folder", required=True, help="an IR run's inputs (bench_thermal.py)")
    ap.add_argument("--oblique-angle", type=float, default=70.0)
    args = ap.parse_args()
    d = Path(args.folder)
    grid = load_run_grid(d / "model.grid")
    cam = read_camera(d / "cam01.json")
    rad = read_radiometry(d / "R.json")
    geom = NodeGeometry.from_grid(grid)
    centre = -cam.R.T @ np.asarray(cam.t, float)
    mesh = grid.mesh
    faces = np.asarray(mesh.faces)
    fn, fc = np.asarray(mesh.face_normals), np.asarray(mesh.triangles_center)
    area = np.asarray(mesh.area_faces)

    def cosine(p, n):
        v = centre - p
        return np.abs(np.einsum("ij,ij->i", n, v)) / np.linalg.norm(v, axis=1)

    cf = cosine(fc, fn)
    seen = ((np.einsum("ij,ij->i", fn, centre - fc) > 0)
            & (cf > np.cos(np.radians(args.oblique_angle))))
    nf, nv = len(faces), len(mesh.vertices)
    W = sp.csr_matrix((np.repeat(area * seen, 3), (faces.ravel(), np.repeat(np.arange(nf), 3))),
                      shape=(nv, nf))
    with np.errstate(invalid="ignore", divide="ignore"):
        per_face = (W @ rad.emissivity.of_cosine(cf)) / np.asarray(W.sum(axis=1)).ravel()
    per_face = grid.to_nodes(per_face[None, :])[0]
    cn = cosine(geom.points, geom.normals)
    per_node = rad.emissivity.of_cosine(cn)
    angle = np.degrees(np.arccos(np.clip(cn, 0.0, 1.0)))
    print(f"grid: {grid.n_nodes} nodes; emissivity {rad.emissivity}")
    for lo, hi in ((0.0, 60.0), (60.0, args.oblique_angle)):
        sel = np.isfinite(per_face) & (angle >= lo) & (angle < hi)
        rel = np.abs(per_face - per_node)[sel] / per_node[sel]
        p50, p95, mx = np.percentile(rel, [50, 95, 100])
        print(f"view angle {lo:.0f}-{hi:.0f} deg: {sel.sum()} nodes, relative difference "
              f"median {p50:.1e}, p95 {p95:.1e}, max {mx:.1e}")


if __name__ == "__main__":
    main()
