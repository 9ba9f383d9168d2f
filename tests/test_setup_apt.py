"""tools/apt_install.sh (sourced by tools/setup.sh): a package counts as installed by what
dpkg and the system report after apt-get has run, not by apt-get's exit status, so a lock
held by another apt that is installing the same package is no failure; a real failure is
reported with apt's own error line.

apt-get and dpkg-query are replaced by stubs on PATH: the real ones would need root and
would take the machine's dpkg lock from other users."""

from __future__ import annotations

import os
import stat
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "tools" / "apt_install.sh"


def _stub(path: Path, body: str) -> None:
    path.write_text("#!/usr/bin/env bash\n" + body)
    path.chmod(path.stat().st_mode | stat.S_IEXEC)


@pytest.fixture
def fake_apt(tmp_path):
    """A bin folder with apt-get and dpkg-query stubs. dpkg-query reports a package as
    installed when STATE/<pkg> exists; apt-get appends its arguments to STATE/calls and
    behaves as STATE/mode says."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    state = tmp_path / "state"
    state.mkdir()
    _stub(
        bin_dir / "dpkg-query",
        f'pkg="${{@: -1}}"\n'
        f'if [ -f "{state}/$pkg" ]; then printf "install ok installed"; exit 0; fi\n'
        'echo "dpkg-query: no packages found matching $pkg" >&2; exit 1\n',
    )
    _stub(
        bin_dir / "apt-get",
        f'echo "$*" >> "{state}/calls"\n'
        f'mode=$(cat "{state}/mode")\n'
        'case "$mode" in\n'
        # another apt holds the lock, and installs the packages meanwhile
        f'  locked) for p in "$@"; do case "$p" in -*|install|update) ;; *=*) ;; '
        f'*) touch "{state}/$p";; esac; done\n'
        '          echo "E: Could not get lock /var/lib/dpkg/lock-frontend. It is held by '
        'process 4242 (apt-get)" >&2; exit 100;;\n'
        '  missing) [ "${*: -1}" = "-qq" ] && exit 0\n'
        '           echo "E: Unable to locate package ${*: -1}" >&2; exit 100;;\n'
        "esac\n",
    )
    return bin_dir, state


def _run(bin_dir: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}", APT_LOCK_WAIT="7")
    cmd = f'. "{SCRIPT}"; apt_install_checked "$@"'
    return subprocess.run(
        ["bash", "-c", cmd, "apt_install_checked", *args],
        capture_output=True, text=True, env=env, timeout=60,
    )


def test_lock_held_by_an_apt_that_installs_the_package_is_no_failure(fake_apt):
    bin_dir, state = fake_apt
    (state / "mode").write_text("locked")
    done = _run(bin_dir, "pkgA and pkgB", "true", "pkgA", "pkgB")
    assert done.returncode == 0, done.stderr
    assert "could not install" not in done.stderr
    # apt-get was asked to wait for the lock rather than fail at once
    calls = (state / "calls").read_text().splitlines()
    assert calls and all("DPkg::Lock::Timeout=7" in c for c in calls)
    assert any(c.split()[-2:] == ["pkgA", "pkgB"] for c in calls)


def test_a_real_failure_is_reported_with_apts_error(fake_apt):
    bin_dir, state = fake_apt
    (state / "mode").write_text("missing")
    done = _run(bin_dir, "pkgX; the X test will fail", "true", "pkgX")
    assert done.returncode == 1
    line = done.stderr.strip()
    assert line.startswith("setup: could not install pkgX; the X test will fail (pkgX)")
    assert "Unable to locate package pkgX" in line
    assert len(done.stderr.strip().splitlines()) == 1


def test_installed_package_whose_command_is_missing_is_a_failure(fake_apt):
    bin_dir, state = fake_apt
    (state / "mode").write_text("locked")  # dpkg will say installed ...
    done = _run(bin_dir, "pkgC", "command -v no-such-command-here", "pkgC")
    assert done.returncode == 1  # ... but the command the package should bring is absent
    assert "could not install pkgC" in done.stderr


def test_nothing_is_run_when_already_installed(fake_apt):
    bin_dir, state = fake_apt
    (state / "mode").write_text("missing")
    (state / "pkgD").touch()
    done = _run(bin_dir, "pkgD", "true", "pkgD")
    assert done.returncode == 0 and done.stderr == ""
    assert not (state / "calls").exists()


def test_apt_extra_reaches_apt_get_install_only(fake_apt):
    """``APT_EXTRA=--no-install-recommends`` (ParaView's install in tools/setup.sh) is
    given to ``apt-get install``, before the packages, and not to ``apt-get update``."""
    bin_dir, state = fake_apt
    (state / "mode").write_text("locked")
    env_cmd = f'. "{SCRIPT}"; APT_EXTRA=--no-install-recommends apt_install_checked "$@"'
    done = subprocess.run(
        ["bash", "-c", env_cmd, "apt_install_checked", "pkgE", "true", "pkgE"],
        capture_output=True, text=True, timeout=60,
        env=dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}", APT_LOCK_WAIT="7"))
    assert done.returncode == 0, done.stderr
    calls = (state / "calls").read_text().splitlines()
    install = [c for c in calls if " install " in f" {c} "]
    assert len(install) == 1 and install[0].split()[-2:] == ["--no-install-recommends", "pkgE"]
    assert all("--no-install-recommends" not in c for c in calls if c not in install)
