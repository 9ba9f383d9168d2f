"""The asv suite (``asv.conf.json``, ``benchmarks/``) is well formed: asv finds every
benchmark, each kind (``time_``, ``track_``) is what asv expects, and every peer it wraps
is importable. ``asv check`` imports the suite in this environment, as ``asv run
--python=same`` does."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_asv_check_finds_the_suite():
    asv = Path(sys.executable).parent / "asv"
    done = subprocess.run([str(asv), "check", "--python=same"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "No problems found" in done.stdout + done.stderr
    # every benchmark class pairs the package with a peer and tracks their ratio
    sys.path.insert(0, str(ROOT))
    try:
        import importlib

        for path in sorted((ROOT / "benchmarks").glob("bench_*.py")):
            module = importlib.import_module(f"benchmarks.{path.stem}")
            classes = [c for n, c in vars(module).items()
                       if isinstance(c, type) and c.__module__ == module.__name__]
            assert classes, path.name
            for cls in classes:
                names = [n for n in dir(cls) if n.startswith(("time_", "track_"))]
                assert sum(n.startswith("track_ratio") for n in names) == 1, cls
                assert sum(n.startswith("time_") for n in names) >= 2, cls
                # what it measures, on what, and the unit of every tracked value
                assert cls.__doc__ and len(cls.__doc__.split()) > 10, cls
                for n in names:
                    if n.startswith("track_"):
                        assert getattr(getattr(cls, n), "unit", ""), f"{cls.__name__}.{n}"
    finally:
        sys.path.remove(str(ROOT))
