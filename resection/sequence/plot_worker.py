"""The motion plot drawn in a second process, whose imports overlap the run.

Importing matplotlib and drawing the figure of :func:`~resection.sequence.motion_plots.
plot_motion` takes about 0.8 s, a third of a 200-frame ``resection track``, and none of it
needs the run until its last step. :class:`MotionPlotter` therefore starts a Python process
(``python -m resection.sequence.plot_worker``) when the command starts: it imports NumPy and
matplotlib (only: the package's modules are loaded lazily) on another core while this
process imports the tracker and tracks the frames, then waits. :meth:`MotionPlotter.plot`
sends it the arrays to draw (pickled through its standard input), and it draws the figure
and writes the file (through a temporary name renamed into place). Should the process fail
to start, to answer or to draw, the figure is drawn in this process instead, by
:func:`~resection.sequence.motion_plots.plot_motion`, which then raises the error a bad
path or frame rate deserves: the file written, and the errors, are those of
``plot_motion``.

The process ignores Ctrl-C (the terminal sends it to the whole process group: the
command reports the interruption) and ends when its standard input closes, so it never
outlives the command, even one that was killed.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys

__all__ = ["MotionPlotter"]

#: longest wait (s) for the drawing process to draw and write the figure
PLOT_TIMEOUT_S = 120.0


class MotionPlotter:
    """Context manager: a process ready to draw a motion plot (see the module docstring).

    >>> with MotionPlotter() as plotter:        # starts the process
    ...     result = track(...)
    ...     plotter.plot(result, "out/pose_vs_time.png", fps=50)
    """

    def __init__(self) -> None:
        self._proc: subprocess.Popen | None = None

    def __enter__(self) -> MotionPlotter:
        self._proc = _start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def plot(self, result, path: str | os.PathLike, *, fps: float | None = None) -> None:
        """Write the motion plot of ``result`` (a ``TrackResult``) to ``path``: drawn by
        the process when it is running and succeeds, else here by
        :func:`~resection.sequence.motion_plots.plot_motion`."""
        from resection.sequence.motion_plots import motion_data, plot_motion

        proc, self._proc = self._proc, None
        request = {"data": motion_data(result), "path": os.fspath(path), "fps": fps}
        if proc is not None and _draw_there(proc, request):
            return
        plot_motion(result, path, fps=fps)

    def close(self) -> None:
        """End the process if it was not used (its standard input closed: it exits)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        try:
            proc.stdin.close()
            proc.wait(timeout=5.0)
        except (OSError, subprocess.TimeoutExpired):
            proc.kill()
            proc.wait()
        finally:
            for stream in (proc.stdout, proc.stderr):
                stream.close()


def _start() -> subprocess.Popen | None:
    """The drawing process, importing what it needs; None when it cannot be started."""
    if not sys.executable:
        return None
    import resection

    # the process imports this copy of the package, wherever it came from
    root = os.path.dirname(os.path.dirname(os.path.abspath(resection.__file__)))
    path = os.environ.get("PYTHONPATH")
    env = {**os.environ, "PYTHONPATH": root + (os.pathsep + path if path else "")}
    try:
        return subprocess.Popen([sys.executable, "-m", "resection.sequence.plot_worker"],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, env=env)
    except OSError:
        return None


def _draw_there(proc: subprocess.Popen, request: dict) -> bool:
    """Send ``request`` to the process and wait for it; whether it wrote the figure."""
    try:
        out, _ = proc.communicate(pickle.dumps(request, protocol=pickle.HIGHEST_PROTOCOL),
                                  timeout=PLOT_TIMEOUT_S)
    except (OSError, ValueError, subprocess.TimeoutExpired):
        proc.kill()
        proc.communicate()
        return False
    except BaseException:  # Ctrl-C while waiting: the process goes with the command
        proc.kill()
        proc.communicate()
        raise
    return proc.returncode == 0 and out.strip() == b"ok"


def serve() -> int:
    """The drawing process: import, wait for one request on standard input, draw it, say
    ``ok`` (exit 0) or give the error's line (exit 1). Exit 0 without a request."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # what takes the time, before the request comes: the imports, and a first figure
    # drawn and encoded (fonts, glyphs, text layouts, markers, PIL's PNG plugin: the real
    # figure then takes half the time)
    import io

    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from resection.sequence.motion_plots import PNG_COMPRESS_LEVEL, motion_figure, save_figure

    k = np.arange(3)
    FigureCanvasAgg(motion_figure(k, np.ones((3, 3)), np.ones((3, 3)), np.ones(3),
                                  k > 0, reference=0)).print_png(
        io.BytesIO(), pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
    try:
        request = pickle.load(sys.stdin.buffer)
    except (EOFError, pickle.UnpicklingError):
        return 0  # closed unused
    try:
        fig = motion_figure(**request["data"], fps=request["fps"])
        save_figure(fig, request["path"])
    except Exception as exc:  # noqa: BLE001 - reported; the command draws it again itself
        print(f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}",
              file=sys.stderr)
        return 1
    print("ok", flush=True)
    return 0


if __name__ == "__main__":
    status = serve()
    sys.stdout.flush()
    sys.stderr.flush()
    # the figure is written and renamed into place: no need to tear the interpreter down
    # (0.1 s that the command would wait for)
    os._exit(status)
