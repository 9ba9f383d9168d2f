"""Figures 20 and 22 of the paper on synthetic data.

* Figure 20: the resection check picture (grid outline, detected and reprojected markers,
  magnified residual vectors, RMS in the title) for the synthetic PSP panel, with markers
  "detected" at their true projections plus 0.15 px of noise and a camera whose pose is
  slightly off.
* Figure 22: surface data (a pressure-like field on a sphere-on-a-plate model) from a
  virtual Point of View, as a raster (SurfaceMap) and as depth-sorted polygons.

Run: ``.venv/bin/python examples/figure20_22_pictures.py [OUTDIR]``
"""

import sys
from pathlib import Path

import numpy as np
import trimesh

from resection.surface.plots import plot_resection, plot_surface, virtual_camera
from scenes.psp_pair import HALF_X, HALF_Y, psp_pair, render


def main(outdir: str = ".") -> None:
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    pp = psp_pair(seed=0)
    K = np.array(pp.camera_off.K)
    K[0, 0] = K[1, 1] = 380.0  # wider view than the pair's camera: the panel outline shows
    cam = pp.camera_off.replace(K=K)
    image = render(cam, noise=0.005, rng=rng)
    gx, gy = np.meshgrid(np.linspace(-0.8 * HALF_X, 0.8 * HALF_X, 6),
                         np.linspace(-0.8 * HALF_Y, 0.8 * HALF_Y, 4))
    markers = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    detected = cam.project(markers) + 0.15 * rng.standard_normal((len(markers), 2))
    solved = cam.with_pose(rvec=cam.rvec + [0.0, 0.0, 0.0005])
    plot_resection(np.nan_to_num(image), solved, markers, detected, mesh=pp.mesh,
                   ids=[f"M{k}" for k in range(len(markers))], title="wind-off",
                   path=out / "figure20_resection.png")

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.3)
    sphere.apply_translation([0, 0, 0.3])
    plate = trimesh.creation.box(extents=[2.0, 1.2, 0.02])
    plate.apply_translation([0.2, 0, -0.01])
    plate = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(plate.vertices, plate.faces,
                                                               0.04), process=False)
    model = trimesh.util.concatenate([sphere, plate])
    model = trimesh.Trimesh(model.vertices, model.faces, process=False)
    n = model.face_normals
    flow = np.array([1.0, 0.0, 0.0])
    cp = 1.0 - 2.25 * (1.0 - (n @ flow) ** 2)  # potential-flow-like Cp on the sphere
    cp[len(sphere.faces):] = 0.2 * np.exp(-((model.triangles_center[len(sphere.faces):, 0]
                                              - 0.4) ** 2) / 0.05)
    cam = virtual_camera(model, azimuth_deg=-60, elevation_deg=35, width=560, height=400)
    plot_surface(model, cp, cam, label="Cp", cmap="jet", title="raster (SurfaceMap)",
                 path=out / "figure22_surface_raster.png")
    plot_surface(model, cp, cam, method="polygons", label="Cp", cmap="jet",
                 title="polygons (depth-sorted)", path=out / "figure22_surface_polygons.png")
    print("wrote", *sorted(p.name for p in out.glob("figure2*.png")))


if __name__ == "__main__":
    main(*sys.argv[1:])
