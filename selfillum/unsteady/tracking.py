"""A moving model's poses tracked in a helper thread beside the run's set-up.

Phase 1 of a moving model (``registration = track``) needs frame 0's pose for its first
frame (the full map: a ray cast, the merge, the first self-illumination solve), then each
frame's pose as it comes to that frame (the references are planned piece by piece,
:class:`selfillum.unsteady.references.ReferencePlan`, each piece needing the poses up to its
last frame). The tracker solves frame 0 first (a detection over the whole frame), then the
others by prediction, in order. :class:`TrackingAhead` runs it in one helper thread and
hands each frame's pose over as soon as it is solved, so that the view factors, the first
frame and the frames after it are computed while the tracker goes on. The run gives it a
tracker in a child process
(:class:`selfillum.unsteady.tracking_process.TrackingProcess`, started with the run):
the helper thread then only relays the child's poses, and the tracker's Python no longer
takes turns with the run's on the interpreter's lock. Measured on the 609k run (256
frames, 2 cores) and the options scene, the whole command: see
``docs/benchmark_history.md`` (sessions 16-17, 20).

The poses are those the tracker gives when run before the set-up (the same calls, the same
frames): only the order of the work changes. A frame the tracker solved is handed over as
solved (its final pose: the repair pass redoes only the frames that failed); a frame that
failed, or that a resumed run read back, is given once the tracking is done (a failed
frame then takes its nearest tracked neighbour's pose). An error of the tracker is raised
in the caller when it asks for a pose it does not have.
"""

from __future__ import annotations

import operator
import threading
from collections.abc import Callable, Sequence

__all__ = ["TrackingAhead", "TrackedPoses", "TrackingStopped"]


class TrackingStopped(Exception):
    """Raised in the helper thread at the tracker's next frame once
    :meth:`TrackingAhead.stop` is called."""


class TrackingAhead:
    """The cameras' tracking, one after the other, in a helper thread.

    Parameters
    ----------
    track : callable
        ``track(i, on_frame) -> (poses, failed)``: camera ``i``'s poses (a sequence of
        :class:`resection.Camera`, one a frame) and the number of frames that took a
        neighbour's pose; ``on_frame(k, pose)`` is called as each frame is tracked, frame
        0 first (``pose`` None where it failed), and raises :class:`TrackingStopped` once
        :meth:`stop` is called (:func:`selfillum.unsteady.inputs.track_poses`).
    n_cameras : int
    n_frames : int, optional
        The run's frames (each camera's poses), where known when the tracking starts
        (else given to :meth:`poses`).
    on_stop : callable, optional
        Called first by :meth:`stop`: a tracker in another process
        (:class:`TrackingProcess`) is told to stop without waiting for its next frame's
        hand-over.

    Notes
    -----
    A run that ends in the caller's thread before the tracking (an error, Ctrl-C) calls
    :meth:`stop`: the tracker stops at its next frame, what it finished kept in its folder
    for a resume. The thread is a daemon: an interpreter that exits does not wait for
    it.
    """

    def __init__(self, track: Callable, n_cameras: int, n_frames: int | None = None, *,
                 on_stop: Callable[[], None] | None = None) -> None:
        self._track = track
        self._n = None if n_frames is None else int(n_frames)
        self._on_stop = on_stop
        self._solved: list[dict] = [{} for _ in range(n_cameras)]  # frame -> pose
        self._changed = threading.Condition()
        self._done = threading.Event()
        self._stop = threading.Event()
        self._poses: list = []
        self._failed = 0
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="tracking", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            for i in range(len(self._solved)):
                poses, failed = self._track(i, lambda k, cam, i=i: self._frame(i, k, cam))
                self._poses.append(poses)
                self._failed += int(failed)
        except BaseException as exc:  # raised in the caller's thread (result)
            self._error = exc
        finally:
            with self._changed:  # the waiters for a frame never solved go on to the
                self._done.set()  # result (or its error)
                self._changed.notify_all()

    def _frame(self, i: int, k: int, camera) -> None:
        if self._stop.is_set():
            raise TrackingStopped("the run ended before the tracking")
        if camera is not None:
            with self._changed:
                self._solved[i][int(k)] = camera
                self._changed.notify_all()

    def pose(self, i: int, k: int):
        """Camera ``i``'s pose in frame ``k``: as soon as the tracker has solved it (else
        its :meth:`result`'s, which waits for the whole tracking)."""
        solved = self._solved[i]
        with self._changed:
            self._changed.wait_for(lambda: k in solved or self._done.is_set())
        got = solved.get(k)
        return got if got is not None else self.result()[0][i][k]

    def result(self) -> tuple[list, int]:
        """Every camera's poses and the frames that took a neighbour's, once the
        tracking is done; the tracker's error if it failed."""
        self._done.wait()
        if self._error is not None:
            raise self._error
        return self._poses, self._failed

    def poses(self, i: int, n: int | None = None, make: Callable | None = None
              ) -> TrackedPoses:
        """Camera ``i``'s poses as a sequence of ``n`` frames (default the ``n_frames``
        given) that waits only for what it is asked; each ``make(pose)`` where given (a
        camera made of a :func:`selfillum.unsteady.inputs.tracked_motion` pose)."""
        return TrackedPoses(self, i, self._n if n is None else int(n), make)

    def stop(self) -> None:
        """Stop the tracking at its next frame (nothing if it is done) and wait for the
        helper thread to end; its error, if any, is left to :meth:`result`."""
        self._stop.set()
        if self._on_stop is not None:  # a tracker in another process: told at once
            self._on_stop()
        self._done.wait()
        self._thread.join()


class TrackedPoses(Sequence):
    """One camera's poses from a :class:`TrackingAhead`: each frame's as soon as the
    tracker has solved it (:meth:`TrackingAhead.pose`)."""

    def __init__(self, ahead: TrackingAhead, camera: int, n: int,
                 make: Callable | None = None) -> None:
        self._ahead, self._camera, self._n, self._make = ahead, camera, n, make
        self._made: dict = {}

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(self._n))]
        k = operator.index(k)
        if k < 0:
            k += self._n
        if not 0 <= k < self._n:
            raise IndexError(f"frame {k} of a run of {self._n}")
        pose = self._ahead.pose(self._camera, k)
        if self._make is None:
            return pose
        made = self._made.get(k)
        if made is None or made[0] is not pose:  # one camera a frame, made once
            made = self._made[k] = (pose, self._make(pose))
        return made[1]
