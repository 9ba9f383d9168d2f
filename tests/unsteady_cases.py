"""A small unsteady run (two cameras, 12 frames, 800 faces: scenes/unsteady_run.py) built
once per test session, and a copy of it per test to spoil (the deck pointing at the
copies). Used by tests/test_unsteady_faults*.py (imported there: pytest finds the fixture
through the import)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def small_run(tmp_path_factory):
    from scenes.unsteady_run import make_unsteady_run

    return make_unsteady_run(tmp_path_factory.mktemp("unsteady_faults"), frames=12,
                             cameras=2, faces=800)


def copy_run(run, dest: Path) -> Path:
    """The run's inputs copied into ``dest`` (created), its deck rewritten to name the
    copies; returns ``dest``."""
    dest.mkdir(parents=True, exist_ok=True)
    for p in run.folder.iterdir():
        if p.is_file() and p.suffix in (".grid", ".tgts", ".npy", ".json", ".wtd", ".txt",
                                        ".f", ".inp"):
            shutil.copy2(p, dest / p.name)
    (dest / "run.inp").write_text(run.deck.read_text().replace(str(run.folder), str(dest)))
    return dest


def args(case: Path, *extra, out: str = "out.h5") -> list[str]:
    """``selfillum unsteady`` on the copy ``case``: the deck, the paint calibration, the
    steady Cp, 16 rays a face, no pictures, quiet."""
    return ["unsteady", str(case / "run.inp"), "--paint-calibration", str(case / "paint.txt"),
            "--steady", str(case / "steady.f"), "--fps", "1000", "--out", str(case / out),
            "--quiet", "--no-plots", "--rays", "16", *extra]


def run_cli(argv, capsys) -> tuple[int, str, str]:
    """``selfillum`` in this process: ``(status, stdout, stderr)``."""
    from selfillum.cli import main

    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def refused(case: Path, capsys, *extra, out: str = "out.h5") -> str:
    """Run on ``case`` and check the refusal: exit 2, one line without a traceback, no
    output (nor work folder) left. Returns the line."""
    before = sorted(p.name for p in case.iterdir())
    rc, _, err = run_cli(args(case, *extra, out=out), capsys)
    err = err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert sorted(p.name for p in case.iterdir()) == before
    return err
