"""How many of this process's cores other work leaves free, measured now.

The 1-minute load average lags: a build or a batch that ended a few seconds ago still
counts as several busy cores, and a run would then refuse its workers for a minute (a
2,000-frame track on 16 cores ran on one, 18 s instead of 9 s, just after a 16-process
job had ended). Here the cores' idle time is read from ``/proc/stat`` at the start and the
end of a window of the run's own work (the reference frame and the first chunk): what
was busy beyond this process's own CPU time (and the worker pool's server, starting in
that window) is other work.

Where ``/proc/stat`` cannot be read (not Linux), the load average is used.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

__all__ = ["LoadWindow", "cpu_ticks", "free_by_load_average"]


def cpu_ticks(cpus, stat: str = "/proc/stat") -> tuple[int, int] | None:
    """``(busy, total)`` clock ticks since boot of the CPUs numbered ``cpus`` (idle and
    I/O wait count as not busy; guest time is inside user time), or ``None`` when
    ``stat`` cannot be read or lacks one of them."""
    want = {f"cpu{c}" for c in cpus}
    busy = total = 0
    try:
        with open(stat, encoding="ascii") as fh:
            for line in fh:
                name, _, rest = line.partition(" ")
                if name not in want:
                    continue
                f = [int(x) for x in rest.split()[:8]]
                idle = f[3] + f[4]
                busy += sum(f) - idle
                total += sum(f)
                want.discard(name)
    except (OSError, ValueError):
        return None
    return None if want or total == 0 else (busy, total)


def free_by_load_average() -> float:
    """Cores this process may use less the 1-minute load average (this process counted
    back), at least 1: where no window was measured."""
    from resection._threads import available_cores

    try:
        load = os.getloadavg()[0]
    except OSError:  # no load average on this platform
        load = 0.0
    return max(1.0, available_cores() - max(load - 1.0, 0.0))


@dataclass
class LoadWindow:
    """A window over which the machine's other work is measured.

    Create it at the window's start; :meth:`free_cores` at its end.
    """

    cpus: list
    ticks: tuple | None
    cpu_s: float
    wall_s: float
    stat: str = "/proc/stat"

    @classmethod
    def start(cls, stat: str = "/proc/stat") -> LoadWindow:
        """The window from now, on the CPUs this process may run on (``stat``: the
        kernel's CPU statistics file)."""
        from resection._threads import core_ids

        cpus = core_ids()
        return cls(cpus, cpu_ticks(cpus, stat), time.process_time(), time.perf_counter(),
                   stat)

    def free_cores(self, helpers: float = 0.0) -> float:
        """Cores this process may use less those other work kept busy during the window,
        at least 1. ``helpers``: cores' worth of this run's other processes in the window
        (the worker pool's server), not counted as other work."""
        from resection._threads import available_cores

        n = available_cores()
        now = cpu_ticks(self.cpus, self.stat)
        wall = time.perf_counter() - self.wall_s
        if self.ticks is None or now is None or now[1] <= self.ticks[1] or wall <= 0:
            return free_by_load_average()
        busy = n * (now[0] - self.ticks[0]) / (now[1] - self.ticks[1])
        own = (time.process_time() - self.cpu_s) / wall + float(helpers)
        return max(1.0, min(float(n), n - max(busy - own, 0.0)))
