"""Where the datapoints run: a Dask local cluster (default), a running scheduler, or a
batch cluster through ``dask-jobqueue`` (PBS, Slurm) from a small YAML/JSON file::

    kind: pbs            # or slurm
    jobs: 10             # batch jobs started (one Dask worker each by default)
    cores: 40            # per job
    memory: 180GB        # per job
    walltime: "01:00:00"
    queue: normal
    account: g1234       # PBS -A / Slurm --account
    processes: 1         # Dask workers per job
    job_extra_directives: ["-l select=1:model=cas_ait"]
    job_script_prologue: ["source /usr/local/lib/global.profile"]
    local_directory: /tmp
    interface: ib0

Every other key of ``dask_jobqueue``'s ``PBSCluster`` / ``SLURMCluster`` is refused by
name (``jobs`` is this file's). The workers must see the entry's files at the same paths.
"""

from __future__ import annotations

import os

from resection.errors import InputError

__all__ = ["read_jobqueue", "make_jobqueue_cluster", "open_client", "JOBQUEUE_KEYS"]

#: keys passed on to the dask-jobqueue cluster.
JOBQUEUE_KEYS = ("cores", "memory", "walltime", "queue", "account", "processes",
                 "job_extra_directives", "job_script_prologue", "local_directory",
                 "interface", "job_name", "log_directory", "resource_spec")
_KINDS = ("pbs", "slurm")


def read_jobqueue(path) -> dict:
    """The batch cluster's file (module notes), checked."""
    from selfillum.entry.index import _load

    p = os.fspath(path)
    d = _load(p)
    if not isinstance(d, dict):
        raise InputError(f"{p}: expected an object (kind, jobs, cores, memory, ...)")
    kind = d.get("kind")
    if kind not in _KINDS:
        raise InputError(f"{p}: kind must be one of {', '.join(_KINDS)}, got {kind!r}")
    for k in d:
        if k not in (*JOBQUEUE_KEYS, "kind", "jobs"):
            raise InputError(f"{p}: unknown key {k!r} (known: kind, jobs, "
                             f"{', '.join(JOBQUEUE_KEYS)})")
    for k in ("cores", "memory"):
        if k not in d:
            raise InputError(f"{p}: missing {k!r} (per job)")
    jobs = d.get("jobs", 1)
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise InputError(f"{p}: jobs must be a positive integer, got {jobs!r}")
    return dict(d, jobs=jobs, source=p)


def make_jobqueue_cluster(conf: dict, *, scheduler_options: dict | None = None):
    """The ``PBSCluster`` / ``SLURMCluster`` of ``conf`` (:func:`read_jobqueue`), not yet
    scaled (its ``job_script()`` shows what would be submitted)."""
    import dask_jobqueue

    cls = dask_jobqueue.PBSCluster if conf["kind"] == "pbs" else dask_jobqueue.SLURMCluster
    kw = {k: conf[k] for k in JOBQUEUE_KEYS if k in conf}
    kw.setdefault("processes", 1)
    try:
        return cls(**kw, scheduler_options=scheduler_options or {"dashboard_address": ":0"})
    except (TypeError, ValueError) as e:
        raise InputError(f"{conf['source']}: {e}") from None


def open_client(*, workers: int = 1, scheduler: str | None = None, jobqueue=None):
    """A Dask client and what to close after: a running scheduler (``scheduler``), a batch
    cluster (``jobqueue`` file), or a local cluster of ``workers`` processes."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        try:
            c = Client(scheduler, timeout="30s")
        except OSError as e:
            raise InputError(f"--scheduler {scheduler}: cannot connect ({e})") from None
        return c, [c]
    if jobqueue is not None:
        conf = read_jobqueue(jobqueue)
        cluster = make_jobqueue_cluster(conf)
        cluster.scale(jobs=conf["jobs"])
        c = Client(cluster)
        return c, [c, cluster]
    cluster = LocalCluster(n_workers=max(1, int(workers)), threads_per_worker=1,
                           processes=True, dashboard_address=":0")
    c = Client(cluster)
    return c, [c, cluster]
