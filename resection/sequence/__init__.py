"""Sequences: markers tracked and the Point of View solved in every frame of a run.

:func:`track` follows the markers through every frame of a sequence (the paper: 500 frames
at 50 fps) and solves the pose of each, and writes

* ``poses.csv``: one row per frame: ``frame, file, status, reason, roll_deg, pitch_deg,
  yaw_deg, dx, dy, dz, rms_px, n_markers, rvec_x, rvec_y, rvec_z, tvec_x, tvec_y, tvec_z``;
* ``markers.csv``: one row per matched marker and frame: ``frame, id, u, v, residual,
  residual_u, residual_v`` (pixels; residual = observed minus reprojected, and its length).

Motion convention (``fixed_camera=True``: the camera is fixed in the tunnel, the model
moves): the laboratory frame is the model frame at the reference frame (the first frame that
succeeded). At frame ``k`` a model point ``X`` lies at ``Y = M_k X + d_k`` in that frame, with

``M_k = R_0^T R_k``,  ``d_k = R_0^T (t_k - t_0)``

(``R_k, t_k`` the solved camera pose, ``x_cam = R_k X + t_k``). The attitude is reported as
``M_k = Rz(yaw) Ry(pitch) Rx(roll)`` (intrinsic z-y'-x'' sequence, right-handed rotations
about the model's axes; degrees in the files) and ``(dx, dy, dz) = d_k`` is the displacement
of the model origin (model units). With ``fixed_camera=False`` (the model is fixed, the
camera moves) the same columns give the camera's attitude change ``R_k^T R_0`` (same Euler
convention) and the displacement of its perspective centre ``C_k - C_0``, model frame.

Tracking
--------
A frame is tracked *by prediction* (:mod:`resection.sequence.predict`): the pose is
extrapolated from the two previous good frames, every marker is fitted in a small window
around its predicted position, the pose is solved once from there and judged by the
package's acceptance rule. When that gate fails (a jump, lost or hidden markers, the first
frame of a run or of a chunk) the frame goes the long way: marker detection
(:func:`resection.markers.detect.detect_markers`) in the region where the markers can be, matching
to the 3-D markers from the previous good frame (:func:`resection.markers.match.match_markers`)
and the pose (:func:`resection.pose.solve.solve_pose`). Either way a frame is right or refused.

The package is split by step: :mod:`~resection.sequence.frames` (reading frames, their
fingerprints), :mod:`~resection.sequence.predict` (motion model, gated association, pose),
:mod:`~resection.sequence.process` (one frame, a chunk of frames, the repair pass),
:mod:`~resection.sequence.execute` (in this process, on local workers or on Dask),
:mod:`~resection.sequence.pool` (the local worker processes),
:mod:`~resection.sequence.chain` (a deferred chunk started again from the one before it),
:mod:`~resection.sequence.outputs` (per-frame files, CSVs, :func:`read_track`),
:mod:`~resection.sequence.inputs` (checks), :mod:`~resection.sequence.run` (:func:`track`),
:mod:`~resection.sequence.motion_plots` (the motion plot) and
:mod:`~resection.sequence.plot_worker` (the plot drawn by a second process, beside the run).

Parallelism and resume
----------------------
Frames are split into chunks of ``chunk_size`` consecutive frames. Within a chunk every frame
is matched from the previous successful frame; each chunk starts from the reference frame
(frame 0, linked through ``link`` or matched from the approximate ``camera``), so chunks are
independent and run in parallel: on local worker processes forked from a server that has
loaded the package (:mod:`~resection.sequence.pool`; one per CPU core, or ``workers`` of
them; ``workers=1`` runs in this process), or on the Dask cluster at ``scheduler``. A
chunk's first frame is predicted from frame 0. When that fails (the model moved too far
since, e.g. in a roll sweep) the chunk computes nothing and is started again, on a worker,
from the last good frames of the chunk before it as soon as that one is done
(:mod:`~resection.sequence.chain`), as the chunks run in this process are. What still fails
from an older frame goes to a second, sequential pass, which processes those frames again
from the last good frame before them (corrupt frames, which failed although matched from
the previous good frame, are not redone). The chunking does not depend on the number of
workers, so 1 and N workers give the same results, to the solver's convergence where they
match the same markers (in fast motion the frame after a chunk start tracked from frame 0,
predicted with the mean velocity since frame 0, may miss a marker that one process keeps).

Every finished frame is written at once to ``out_dir/frames/frame_NNNNNN.json`` (written to
a temporary file and renamed, so a file is either complete or absent; not fsync'ed: after a
crash of the machine a truncated file reads as missing and the frame is computed again).
A run that is interrupted and started again with ``resume=True`` loads these files and
computes only the missing frames, and the frames whose file has changed since (its size,
modification and status-change times or inode differ from those recorded:
:func:`~resection.sequence.frames.fingerprint`); ``poses.csv`` and ``markers.csv`` are
merged from them at the end. On workers the file is written by the worker, inside the
task, as soon as the frame is finished (local workers share the filesystem); on Ctrl-C the
local workers finish the chunks they run and no other starts, so an interruption loses no
finished frame; the progress bar follows these files. A worker that cannot write there
(a remote cluster without a shared filesystem) leaves the file to the client, which writes
it when the chunk comes back. A failed frame is recorded (status ``failed`` and the
reason, which names its file) and the run goes on; the next frame is then matched from the
last good one.

While a run writes into ``out_dir`` it holds the folder's lock
(:func:`resection.io.lock.lock_folder`): a second run into the same folder is refused with
the holder's process id, host and start time; the lock of a process that died is taken
over. Memory does not grow with the length of the run: frames are read one at a time where
they are processed, a finished frame is kept as its file (and two numbers), and the result
is assembled from the files and the CSVs streamed at the end; only the returned
:class:`TrackResult` (poses and matched markers, about 1.6 kB a frame with 34 markers) grows
with the frames.
"""

from __future__ import annotations

from resection._lazy import attach

#: Public name -> the submodule that defines it, imported on first use (PEP 562): a
#: process that needs only one module of the package (the plot process of ``resection
#: track``, :mod:`~resection.sequence.plot_worker`) does not load the tracker's imports.
_EXPORTS: dict[str, str] = {
    "FrameResult": ".results",
    "TrackResult": ".results",
    "POSE_COLUMNS": ".results",
    "MARKER_COLUMNS": ".results",
    "track": ".run",
    "read_track": ".outputs",
    "relative_motion": ".motion",
}

__all__ = [
    "FrameResult",
    "TrackResult",
    "track",
    "read_track",
    "relative_motion",
    "POSE_COLUMNS",
    "MARKER_COLUMNS",
]

__getattr__, __dir__ = attach(__name__, _EXPORTS)
