"""A moving model's tracking in a child process, started with the run.

The tracker (:func:`selfillum.unsteady.inputs.tracked_motion`) is mostly Python: per
frame a prediction, a few small fits and a pose's Gauss-Newton, 11 ms a frame on the
options scene, 25-28 ms on the 609k run (2 cores). Run in a thread beside the run's
set-up and Phase 1, it holds the interpreter's lock most of that time, and the two take
turns on one core's worth of Python. In a child process it runs on the other core from
the run's first step: the run reads its grid, hashes its inputs and builds its view
factors (mostly one core) while the tracker goes on.

:class:`TrackingProcess` starts the child and relays its messages: each frame's pose as it
is solved, then each camera's poses. Its :meth:`~TrackingProcess.track` is the callable
of a :class:`selfillum.unsteady.tracking.TrackingAhead`, whose thread reads them as they
come (the pipe never fills, the child never waits on the run). The child is forked from
the run's process when the run starts, before it opens its grid, its videos or its
Embree scene, where no other thread of Python runs (a POSIX system): it starts at once
with what the run has imported, and at a lower priority (:data:`CHILD_NICENESS`).
Elsewhere (Windows, a caller with threads) it is spawned:
a fresh interpreter that imports the tracker itself, and a script that calls
:func:`selfillum.unsteady.run_unsteady` then needs the usual ``if __name__ ==
"__main__":`` guard. The child ignores Ctrl-C: the run stops it
(:meth:`~TrackingProcess.stop`) at its next frame.

The child reads its inputs itself (the videos' lengths, each camera's calibration, the
targets): the same files with the same functions as the run, so the same poses as the
tracker gives in the run's own process (tested). A bad input it meets is raised in the
run only where the run asks for a pose; the run's own checks, which come first, name it.

A run started fresh (no work folder to resume) starts the child before its inputs are
read: the tracking's files then go to a private temporary folder (the system's), moved
into the run's work folder (``OUT.h5.work/track<number>``) if the run stops before the
end (an interrupt, a failure) so that ``--resume`` keeps them, and removed otherwise. A
resumed run starts it once its work folder is open, and tracks into it. A daemonic
process (a Dask worker's: ``selfillum entry`` on a cluster) may not start one
(:func:`can_start`): the run there tracks in its relaying thread, as before.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import shutil
import signal
import tempfile
import threading
import traceback
from pathlib import Path

from resection.errors import InputError
from selfillum.unsteady.tracking import TrackingAhead

__all__ = ["TrackingProcess", "can_start"]

#: the child's niceness over the run's (POSIX): where both want a core, the run's own work
#: (its first frame's cast and merge, its frames' sampling) goes first, and the tracker
#: takes what the run leaves idle. On the 609k run (2 cores, 3 alternated rounds):
#: ``track`` 17.9-19.3 s against 19.8-20.8 s at the run's own niceness, ``none`` 16.1-17.3 s
CHILD_NICENESS = 10

#: seconds :meth:`TrackingProcess.close` waits for a child told to stop (its next frame)
#: before it ends it
STOP_WAIT_S = 60.0


def can_start() -> bool:
    """Whether this process may start a child: not a daemonic process (a Dask worker's,
    which the run then tracks in a thread of its own)."""
    return not multiprocessing.current_process().daemon


def _context():
    """Forked from this process where that is safe (a POSIX fork, no other thread of
    Python running: the child starts in milliseconds with what this process has
    imported), else spawned (a fresh interpreter: 1-2 s of imports beside the run)."""
    if "fork" in multiprocessing.get_all_start_methods() and threading.active_count() == 1:
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("spawn")


class TrackingProcess:
    """Every camera's tracking (:func:`selfillum.unsteady.inputs.tracked_motion`), one
    after the other, in a child process.

    Parameters
    ----------
    cfg : UnsteadyConfig
        The run's settings (its cameras, videos, targets, ``progress``).
    folder : path, optional
        Where the tracking's files go (``folder / "track<number>"``): the run's work
        folder. None: a temporary folder of its own (see :meth:`close`).
    resume : bool
        Keep the frames an interrupted tracking finished in ``folder``.

    Attributes
    ----------
    ahead : TrackingAhead
        The helper thread relaying the child's poses (:meth:`track` its callable,
        :meth:`stop` its ``on_stop``): ask it for the poses. :meth:`close` once the run
        ends.
    """

    def __init__(self, cfg, folder: str | Path | None = None, *, resume: bool = False
                 ) -> None:
        self._tmp = None
        if folder is None:
            self._tmp = Path(tempfile.mkdtemp(prefix="selfillum-track-"))
        self.folder = Path(folder) if folder is not None else self._tmp
        ctx = _context()
        self._stop = ctx.Event()
        self._conn, send = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_track_cameras, name="selfillum-tracking",
                                 args=(cfg, str(self.folder), bool(resume), send,
                                       self._stop), daemon=True)
        try:
            self._proc.start()
        except BaseException:
            self._conn.close()
            self._remove_tmp()
            raise
        finally:
            send.close()  # the child's end: this process sees its end as the pipe's
        self._ended = False
        try:  # its poses read as they come (the pipe never fills)
            self.ahead = TrackingAhead(self.track, len(cfg.cameras), on_stop=self.stop)
        except BaseException:
            self.close()
            raise

    @property
    def pid(self) -> int | None:
        """The child's process id."""
        return self._proc.pid

    def track(self, i: int, on_frame) -> tuple[list, int]:
        """Camera ``i``'s ``(motion, failed)`` as the child gives it, each frame's pose
        handed to ``on_frame(k, motion)`` as it comes (the cameras in order: ``i`` is
        the next the child tracks). An exception of ``on_frame`` stops the child; the
        child's error is raised here."""
        while True:
            try:
                msg = self._conn.recv()
            except (EOFError, OSError):
                self._proc.join()
                raise RuntimeError(f"the tracking process ended (exit code "
                                   f"{self._proc.exitcode}) before camera {i}'s poses"
                                   ) from None
            kind = msg[0]
            if kind == "frame":
                if msg[1] != i:
                    raise RuntimeError(f"the tracking process sent camera {msg[1]}'s frame "
                                       f"while camera {i}'s were expected")
                try:
                    on_frame(msg[2], msg[3])
                except BaseException:
                    self._stop.set()
                    raise
            elif kind == "done":
                return msg[2], msg[3]
            else:  # "error"
                raise msg[1]

    def stop(self) -> None:
        """Tell the child to stop at its next frame (what it finished kept in its
        folder)."""
        self._stop.set()

    def close(self, keep: str | Path | None = None) -> None:
        """Stop the child if it still tracks (and :attr:`ahead`), wait for it to end, and
        for a run started
        fresh: move its tracking's folders into ``keep`` (the run's work folder, where
        the run stopped before its end) or remove them (``keep`` None). Once."""
        if self._ended:
            return
        self._ended = True
        if hasattr(self, "ahead"):  # its relaying thread first: stopped, joined
            self.ahead.stop()
        self._stop.set()
        with contextlib.suppress(EOFError, OSError):
            while self._conn.poll(STOP_WAIT_S):  # what it still sends, until its end
                self._conn.recv()
        self._conn.close()
        self._proc.join(STOP_WAIT_S)
        if self._proc.is_alive():  # a frame that never ends: its finished ones are kept
            self._proc.terminate()
            self._proc.join()
        if self._tmp is None:
            return
        if keep is not None and Path(keep).is_dir():
            for d in sorted(self._tmp.glob("track*")):
                if any((d / "frames").glob("frame_*.json")) and \
                        not (Path(keep) / d.name).exists():
                    shutil.move(str(d), str(Path(keep) / d.name))
        self._remove_tmp()

    def _remove_tmp(self) -> None:
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)


def _track_cameras(cfg, folder: str, resume: bool, conn, stop) -> None:
    """The child: each camera tracked in turn, its frames and its poses sent on
    ``conn``; stops at the frame after ``stop`` is set. Any error is sent, never
    raised."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the run handles Ctrl-C
    if hasattr(os, "nice"):  # the run's own work first: the tracker fills its idle core
        os.nice(CHILD_NICENESS)
    from resection.io.cameras import read_camera_file
    from resection.io.video import open_frames
    from selfillum.unsteady.inputs import run_length, tracked_motion
    from selfillum.unsteady.tracking import TrackingStopped

    try:
        cams, n = [], []
        for c in cfg.cameras:  # the run's length and each camera's calibration (the
            with open_frames(c.video) as s:  # run checks the rest)
                n.append(len(s))
                cams.append(read_camera_file(c.calibration, image_size=s.shape[::-1]).camera)
        T = run_length(cfg, n)
        for i, (c, cam) in enumerate(zip(cfg.cameras, cams, strict=True)):

            def on_frame(k, motion, i=i):
                if stop.is_set():
                    raise TrackingStopped("the run ended before the tracking")
                conn.send(("frame", i, int(k), motion))

            motion, failed = tracked_motion(cfg, c, cam, T, Path(folder), resume=resume,
                                            on_frame=on_frame, fit_threads=1)
            conn.send(("done", i, motion, failed))
    except BaseException as exc:  # sent to the run, which raises it where it asks
        with contextlib.suppress(OSError):
            conn.send(("error", _portable(exc)))
    finally:
        conn.close()


def _portable(exc: BaseException) -> BaseException:
    """``exc`` as it can cross to the run: an input error or a stop as itself, anything
    else as a RuntimeError holding its traceback (the child's stack, for a report)."""
    import pickle

    from selfillum.unsteady.tracking import TrackingStopped

    if isinstance(exc, InputError | TrackingStopped):
        try:
            pickle.dumps(exc)
            return exc
        except Exception:
            return type(exc)(str(exc))
    text = "".join(traceback.format_exception(exc)).rstrip()
    return RuntimeError(f"the tracking process failed:\n{text}")
