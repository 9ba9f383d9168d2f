"""The markers tracked in a child process started at the beginning of the run
(:class:`EarlyTracking`), so that the tracking, which needs only the videos, the cameras'
calibrations and the targets, runs on one core while this process reads the grid, checks
the inputs and computes the view factors on the other.

The child is ``python -m selfillum.thermal.early FOLDER POLARITY TARGETS N VIDEO CAL [N VIDEO
CAL ...]``: it runs :func:`selfillum.thermal.inputs.run_tracking` for each camera in turn
into ``FOLDER/track<n>`` (the same call, with the same arguments, as the run makes in its
own process), one camera after the other. The folder is a temporary one next to the
output; when the run has created its work folder the finished tracks are moved into it,
where an interrupted run's ``--resume`` finds them.

A child that fails for any reason (a bad video, a crash) leaves the run to track in its own
process as before, which then raises the error itself; a run that stops (bad input found
later, an interruption) kills the child and removes its folder.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

__all__ = ["EarlyTracking"]


class EarlyTracking:
    """The child process tracking every camera of a run (module notes).

    Parameters
    ----------
    out : path
        The run's output file; the temporary folder is made next to it.
    cameras : list of CameraInput
        Each camera's ``number``, ``video`` and ``calibration``.
    targets : path
        The markers' file.
    polarity : str
        ``bright`` or ``dark``.
    """

    def __init__(self, out, cameras, targets, polarity: str):
        out = Path(out)
        self.folder = Path(tempfile.mkdtemp(prefix=f".{out.name}.track-", dir=out.parent))
        self.numbers = [c.number for c in cameras]
        args = [str(self.folder), polarity, str(targets)]
        for c in cameras:
            args += [str(c.number), str(c.video), str(c.calibration)]
        root = str(Path(__file__).resolve().parents[2])  # this copy of the package
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            [root, *filter(None, [os.environ.get("PYTHONPATH")])]))
        self._log = self.folder / "stderr.txt"  # a file: a pipe could fill and stall it
        try:
            with open(self._log, "wb") as log:
                self.proc = subprocess.Popen([sys.executable, "-m",
                                              "selfillum.thermal.early", *args],
                                             stdin=subprocess.DEVNULL,
                                             stdout=subprocess.DEVNULL, stderr=log, env=env)
        except BaseException:
            shutil.rmtree(self.folder, ignore_errors=True)
            raise
        self._ok: bool | None = None
        self.error = ""

    def wait(self) -> bool:
        """Wait for the child: True when every camera was tracked."""
        if self._ok is None:
            self.proc.wait()
            self._ok = self.proc.returncode == 0 and all(
                (self.track_dir(n) / "poses.csv").is_file() for n in self.numbers)
            self.error = self._log.read_text(errors="replace").strip()
        return self._ok

    def track_dir(self, number: int) -> Path:
        """The folder of camera ``number``'s track."""
        return self.folder / f"track{number}"

    def adopt(self, work: Path) -> dict:
        """Move the finished tracks into the work folder ``work`` (``work/track<n>``, where
        the run's own tracking would have written them); returns number -> folder."""
        got = {}
        for n in self.numbers:
            dest = Path(work) / f"track{n}"
            if dest.exists():  # a track of an interrupted run: left to the run's resume
                continue
            os.replace(self.track_dir(n), dest)
            got[n] = dest
        return got

    def close(self) -> None:
        """Stop the child if it still runs and remove its folder."""
        if self.proc.poll() is None:
            self.proc.kill()
            with contextlib.suppress(Exception):
                self.proc.wait(timeout=30)
        shutil.rmtree(self.folder, ignore_errors=True)


def _main(argv: list[str]) -> int:
    """The child: ``FOLDER POLARITY TARGETS (NUMBER VIDEO CAL)...``; exit 0 when every camera
    was tracked, else the error's one line on stderr and exit 2 (an input error) or 1."""
    from resection.errors import InputError

    folder, polarity, targets, rest = Path(argv[0]), argv[1], Path(argv[2]), argv[3:]
    try:
        from resection.io.cameras import read_camera
        from selfillum.thermal.inputs import run_tracking

        for k in range(0, len(rest), 3):
            number, video, calibration = rest[k:k + 3]
            run_tracking(video, read_camera(calibration), targets, polarity,
                         folder / f"track{int(number)}", progress=False, resume=False)
    except InputError as exc:
        print(str(exc).splitlines()[0] if str(exc) else "input error", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
