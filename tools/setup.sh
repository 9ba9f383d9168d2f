#!/usr/bin/env bash
# Set up everything this project needs in ./.venv (idempotent, safe to re-run).
# - a Python >= 3.11 virtual environment with the package (editable) and its test peers;
# - on Debian as root: libllvm19, which Mitsuba's CPU `llvm_ad_rgb` variant needs
#   (without it the renders fall back to the slower `scalar_rgb` variant);
# - on Debian as root: chromium and chromium-driver, which the browser test of the linking
#   page (tests/test_link_page.py, selenium) drives headless;
# - on Debian as root: Mesa's EGL, which VTK's offscreen rendering uses without a display;
# - on Debian as root: ParaView (paraview, python3-paraview: 5.11 on Debian 12, without its
#   recommended packages; about 1.3 GB installed, 2 minutes here) and Xvfb, a virtual
#   display it draws in: the tutorial opens the run's XDMF in ParaView and
#   tests/test_paraview.py (slow) checks what ParaView reads (tools/paraview_frame.py).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    "$PY" -m venv .venv
fi
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    # shellcheck source=tools/apt_install.sh
    . tools/apt_install.sh
    # grep without -q: it reads all of ldconfig's output (no SIGPIPE under pipefail)
    apt_install_checked "libllvm19; Mitsuba will use scalar_rgb" \
        "ldconfig -p | grep 'libLLVM-19\\|libLLVM.so.19'" libllvm19 || true
    apt_install_checked "chromium and chromium-driver; the browser test will fail" \
        "command -v chromium && command -v chromedriver" chromium chromium-driver || true
    apt_install_checked "Mesa's EGL; VTK's offscreen pictures (the tutorial) will fail" \
        "ldconfig -p | grep 'libEGL_mesa.so.0'" libegl1 libegl-mesa0 libgl1-mesa-dri || true
    APT_EXTRA=--no-install-recommends apt_install_checked \
        "ParaView and Xvfb; the tutorial reads the XDMF with VTK, tests/test_paraview.py fails" \
        "command -v pvbatch && command -v Xvfb" paraview python3-paraview xvfb || true
fi
stamp=.venv/.installed-$(sha1sum pyproject.toml | cut -c1-12)
if [ ! -f "$stamp" ]; then
    .venv/bin/python -m pip install -q --disable-pip-version-check --upgrade pip 2>/dev/null
    if ! .venv/bin/python -m pip install -q --disable-pip-version-check -e ".[test,docs]" \
            >.venv/pip.log 2>&1; then
        grep -v "is ignored: it is neither" .venv/pip.log | tail -30 >&2
        exit 1
    fi
    .venv/bin/python -c "import resection, selfillum" 
    rm -f .venv/.installed-*
    touch "$stamp"
fi
