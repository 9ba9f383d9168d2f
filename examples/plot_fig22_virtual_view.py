"""
Figure 22: surface data from a virtual point of view
====================================================

Per-face data drawn from any point of view, as ``resection view`` does: a pressure-like
field on a sphere-on-a-plate model seen by :func:`resection.virtual_camera`, once as a
raster through a :class:`resection.SurfaceMap` (exact visibility by Embree) and once as
depth-sorted polygons.
"""

import numpy as np
import trimesh

from resection import plot_surface, virtual_camera

sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.3)
sphere.apply_translation([0, 0, 0.3])
plate = trimesh.creation.box(extents=[2.0, 1.2, 0.02])
plate.apply_translation([0.2, 0, -0.01])
plate = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(plate.vertices, plate.faces, 0.04),
                        process=False)
model = trimesh.util.concatenate([sphere, plate])
model = trimesh.Trimesh(model.vertices, model.faces, process=False)
n = model.face_normals
flow = np.array([1.0, 0.0, 0.0])
cp = 1.0 - 2.25 * (1.0 - (n @ flow) ** 2)  # potential-flow-like Cp on the sphere
cp[len(sphere.faces):] = 0.2 * np.exp(-((model.triangles_center[len(sphere.faces):, 0]
                                          - 0.4) ** 2) / 0.05)
camera = virtual_camera(model, azimuth_deg=-60, elevation_deg=35, width=560, height=400)
raster = plot_surface(model, cp, camera, label="Cp", cmap="jet", title="raster (SurfaceMap)")

# %%
polygons = plot_surface(model, cp, camera, method="polygons", label="Cp", cmap="jet",
                        title="polygons (depth-sorted)")
