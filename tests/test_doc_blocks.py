"""Every code block of README.md and docs/*.md runs, with sybil (a maintained tool for it).

Each page is one test: its blocks run in page order in a fresh folder, the Python blocks in
one namespace (as a reader would paste them into one session), the ``bash`` blocks with
``bash -eu -o pipefail`` and ``.venv/bin`` first on the PATH; a ``json`` or ``yaml`` block
(a file's content) must parse. A page may prepare its files in an invisible block
(``<!-- invisible-code-block: python ... -->``, not shown on the site). Any other block
must be ``text``: a diagram, a file's layout, printed output or a command's synopsis
(placeholders in capitals; the command-line reference has them all). A block without a
language, or in one this test cannot run, fails it.

Two commands are run elsewhere, and only checked to be the same here: the README's test
command is what CI (``.ci/run``) runs, and the site build is what ``tests/test_docs.py``
runs.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path

import pytest
import yaml
from sybil import Sybil
from sybil.parsers.markdown import CodeBlockParser, PythonCodeBlockParser

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LANGUAGES = {"python", "bash", "json", "yaml", "text"}

# run by CI itself: running it here would run the suite inside the suite
CI_COMMAND = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
# run by tests/test_docs.py (the site build, with its gallery)
SITE_COMMAND = ".venv/bin/python -m sphinx -W -b html docs docs/_build/html"


def _run_bash(example) -> None:
    lines = []
    for line in example.parsed.splitlines():
        if line.strip() == CI_COMMAND:
            continue  # checked in test_commands_run_elsewhere
        if line.strip() == SITE_COMMAND:
            continue  # built by tests/test_docs.py
        lines.append(line)
    script = "\n".join(lines).strip()
    if not script:
        return
    ns = example.namespace
    cwd = ROOT if "tools/setup.sh" in script else ns["cwd"]
    env = dict(os.environ, PATH=f"{ROOT / '.venv' / 'bin'}:{os.environ['PATH']}",
               PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    done = subprocess.run(["bash", "-eu", "-o", "pipefail", "-c", script], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=900)
    where = f"{example.path}, line {example.line}"
    assert done.returncode == 0, f"{where}: exit {done.returncode}\n{done.stdout[-3000:]}" \
        f"\n{done.stderr[-3000:]}"


def _parse_json(example) -> None:
    """A file's content in JSON: one value, or several shown as alternatives."""
    text, decoder, at = example.parsed, json.JSONDecoder(), 0
    while text[at:].strip():
        at += len(text[at:]) - len(text[at:].lstrip())
        try:
            _, at = decoder.raw_decode(text, at)
        except json.JSONDecodeError as e:
            raise AssertionError(f"{example.path}, line {example.line}: not JSON: {e}") from e


def _parse_yaml(example) -> None:
    """A file's content in YAML."""
    try:
        yaml.safe_load(example.parsed)
    except yaml.YAMLError as e:
        raise AssertionError(f"{example.path}, line {example.line}: not YAML: {e}") from e


SYBIL = Sybil(parsers=[PythonCodeBlockParser(),
                       CodeBlockParser(language="bash", evaluator=_run_bash),
                       CodeBlockParser(language="json", evaluator=_parse_json),
                       CodeBlockParser(language="yaml", evaluator=_parse_yaml)])


def _fence_languages(text: str) -> list[tuple[int, str]]:
    """``(line, language)`` of every fenced block's opening line."""
    found, fence = [], None
    for number, line in enumerate(text.splitlines(), 1):
        m = re.match(r"^(`{3,}|~{3,})\s*([^`\s]*)", line)
        if not m:
            continue
        if fence is None:
            fence = m.group(1)
            found.append((number, m.group(2)))
        elif m.group(1).startswith(fence) and not m.group(2):
            fence = None
    return found


#: Pages whose blocks run a whole command on a generated run (8-13 s each on 2 cores):
#: with the slow tests, so that CI's default run stays under 10 minutes; the commands
#: themselves are tested in their own files (test_entry*, test_thermal*,
#: test_uncertainty*, test_unsteady*, test_cli_*, test_merge*, test_link*)
SLOW_PAGES = {"docs/entry.md", "docs/thermal.md", "docs/uncertainty.md",
              "docs/unsteady.md", "docs/mapping.md", "docs/merge_and_views.md",
              "docs/linking.md"}


@pytest.mark.parametrize("page", [
    pytest.param(p, marks=pytest.mark.slow) if str(p.relative_to(ROOT)) in SLOW_PAGES
    else p for p in PAGES], ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_code_blocks_run(page, tmp_path, monkeypatch):
    (tmp_path / ".venv").symlink_to(ROOT / ".venv")  # the README's .venv/bin/... paths
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(ROOT))  # scenes/, as in a clone
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("PATH", f"{ROOT / '.venv' / 'bin'}:{os.environ['PATH']}")
    for number, language in _fence_languages(page.read_text()):
        if language.startswith("{"):  # a MyST directive (toctree), not code
            continue
        assert language in LANGUAGES, (
            f"{page}, line {number}: a code block in {language or 'no language'}: give it "
            "python or bash (run here), json or yaml (parsed) or text (a diagram, printed "
            "output, a synopsis)")
    document = SYBIL.parse(page)
    document.namespace["cwd"] = tmp_path
    for example in document:
        example.evaluate()


def test_commands_run_elsewhere():
    readme = (ROOT / "README.md").read_text()
    assert f"\n{CI_COMMAND}\n" in readme, "the README's test command is not .ci/run's"
    assert f"\n{SITE_COMMAND}\n" in readme, "the README's site build is not documented"
    docs_test = (ROOT / "tests" / "test_docs.py").read_text()
    assert f'SITE_COMMAND = "{SITE_COMMAND}"' in docs_test, "test_docs builds another way"
