"""Defaults that the library and every command share.

They live here, away from the modules that use them, so that a command line can print
them in its ``--help`` without importing the numerical stacks; each is re-exported by the
module of its concept (:mod:`resection.surface.surface_map`, :mod:`resection.pose.acceptance`,
:mod:`resection.io.meshes`).
"""

from __future__ import annotations

__all__ = ["DEFAULT_MAX_OBLIQUENESS", "DEFAULT_MARKER_ACCURACY", "DEFAULT_MAX_RMS",
           "MESH_FORMATS", "FRAME_RATE_RANGE"]

#: Default obliqueness cut-off (degrees between the line of sight and the face normal), as
#: NASA's uPSP software uses: paint seen more obliquely is not measured reliably.
DEFAULT_MAX_OBLIQUENESS = 70.0

#: Default stated accuracy of a marker's position (survey + detection), px (RMS length).
DEFAULT_MARKER_ACCURACY = 1.0
#: Default upper limit of the RMS residual whatever the accuracy, px (the paper's guide).
DEFAULT_MAX_RMS = 2.0

#: What ``format=`` of :func:`resection.io.meshes.load_mesh` (and the commands'
#: ``--format``) accepts.
MESH_FORMATS = ("plot3d", "cart3d", "stl", "obj", "ply", "off", "glb", "gltf")

#: what ``track`` writes into its output folder, and the producer named in its manifest
#: (``track.json``), which marks the folder as a track output
TRACK_FILES = ("poses.csv", "markers.csv", "track.json", "pose_vs_time.png", "frames")
TRACK_PRODUCER = "resection track"

#: Frame rates a video header or ``--fps`` may give, frames/s: from one frame an hour to a
#: billion a second (the frames' times ``k / fps`` stay finite and distinct).
FRAME_RATE_RANGE = (1.0 / 3600.0, 1e9)
