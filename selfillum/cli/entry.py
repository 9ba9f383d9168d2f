"""``selfillum entry``: a wind-tunnel entry, every datapoint calibrated from the tunnel, run
and checked against its Kulites.

Only parses arguments and calls :func:`selfillum.entry.run.run_entry`.
"""

from __future__ import annotations

from pathlib import Path

from resection.errors import InputError


def _cmd_entry(args) -> int:
    from selfillum.entry.run import EntryConfig, run_entry

    if args.workers is not None and args.workers < 0:
        raise InputError(f"--workers {args.workers}: must be >= 0")
    given = [x for x in (args.scheduler, args.jobqueue) if x]
    if len(given) > 1 or (given and args.workers is not None):
        raise InputError("give one of --workers, --scheduler, --jobqueue")
    unsteady = {"memory_mb": args.memory, "plots": True}
    if args.fps is not None:
        unsteady["fps"] = args.fps
    if args.no_si:
        unsteady["si"] = False
    cfg = EntryConfig(
        index=Path(args.index), out=Path(args.out),
        processing=Path(args.processing) if args.processing else None,
        test_config=Path(args.test_config) if args.test_config else None,
        only=args.only, resume=args.resume,
        workers=1 if args.workers is None else args.workers,
        scheduler=args.scheduler, jobqueue=Path(args.jobqueue) if args.jobqueue else None,
        rays=args.rays, seed=args.seed, unsteady=unsteady,
        calibration={"marker_accuracy": args.marker_accuracy, "max_rms": args.max_rms,
                     "search_radius": args.search_radius},
        progress=not args.quiet)
    res = run_entry(cfg)
    n_ok = sum(r["status"] == "ok" for r in res.rows)
    n_off = sum(r["status"] == "wind-off" for r in res.rows)
    print(f"entry: {len(res.rows)} datapoints, {n_ok} ok, {n_off} wind-off, "
          f"{len(res.failed)} failed ({len(res.skipped)} done before); "
          f"{res.seconds:.1f} s")
    for r in res.failed:
        print(r["status"][len("failed: "):])
    print(f"wrote {res.summary}, {res.html}")
    return 1 if res.failed else 0


def register(sub) -> None:
    """Add the ``entry`` sub-command to ``sub`` (an argparse sub-parsers object)."""
    from selfillum.unsteady.budget import DEFAULT_MEMORY_MB

    p = sub.add_parser(
        "entry",
        help="a wind-tunnel entry: every datapoint's first frame calibrated from the "
        "tunnel, its unsteady run, its Kulites compared (uPSP's processing tree)",
        description="Reads a datapoint index (the project's YAML/JSON or uPSP's JSON), "
        "calibrates each datapoint's cameras from their camera-to-tunnel calibrations "
        "moved by the .wtd's attitude, runs the unsteady PSP, compares with the Kulites, "
        "and writes DIR/<datapoint>/ and DIR/summary.csv, DIR/index.html. Exit 0 when "
        "every datapoint is ok or wind-off, 1 when one failed, 2 on bad input. "
        "See docs/entry.md.",
    )
    p.add_argument("index", metavar="INDEX", help="datapoint index (.yaml/.json)")
    p.add_argument("--out", required=True, metavar="DIR", help="products folder")
    p.add_argument("--processing", metavar="PARAMS.json",
                   help="uPSP's processing parameters file (defaults, parameter sets, "
                   "__overlays__): psp_process and external-calibration")
    p.add_argument("--test-config", metavar="TEST_CONFIG.json",
                   help="uPSP's external-calibration configuration (the tunnel's centre of "
                   "rotation), when neither the index nor --processing gives it")
    p.add_argument("--only", nargs="+", metavar="ID", help="these datapoints only")
    p.add_argument("--resume", action="store_true",
                   help="skip datapoints finished with the same inputs and options, carry "
                   "on half-done ones")
    p.add_argument("--workers", type=int, metavar="N",
                   help="Dask local cluster of N worker processes (default 1; 0: the "
                   "datapoints one after the other in this process, no Dask)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a running Dask scheduler (tcp://host:8786); its workers must see "
                   "the files at the same paths")
    p.add_argument("--jobqueue", metavar="CLUSTER.yaml",
                   help="a PBS or Slurm batch cluster through dask-jobqueue (docs/entry.md)")
    p.add_argument("--rays", type=int, default=1024,
                   help="rays per face of the view factors, computed once for the entry "
                   "(default 1024)")
    p.add_argument("--seed", type=int, default=0, help="view-factor seed")
    p.add_argument("--no-si", action="store_true",
                   help="do not remove the self-illumination")
    p.add_argument("--fps", type=float, help="frame rate, when the videos do not say it")
    p.add_argument("--memory", type=float, default=DEFAULT_MEMORY_MB, metavar="MB",
                   help="memory budget of each datapoint's run, MiB")
    p.add_argument("--marker-accuracy", type=float, default=1.0, metavar="PX",
                   help="the acceptance rule's stated marker accuracy, px (default 1)")
    p.add_argument("--max-rms", type=float, default=2.0, metavar="PX",
                   help="the acceptance rule's largest RMS residual, px (default 2)")
    p.add_argument("--search-radius", type=float, default=25.0, metavar="PX",
                   help="how far a target may lie from its prediction from the tunnel, px "
                   "(default 25)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    from resection.cli.paths import FolderOutput
    from selfillum.entry.run import MANIFEST, OUT_NAMES

    p.set_defaults(func=_cmd_entry, out_folder=FolderOutput(OUT_NAMES, MANIFEST,
                                                            "selfillum entry"))
