# Installing Debian packages from tools/setup.sh, judged by what ends up installed.
# Sourced, not run. Another apt (unattended upgrades, a second setup) may hold dpkg's lock
# or apt's list lock: apt-get waits for them up to APT_LOCK_WAIT seconds (default 600),
# and whatever apt-get says, the packages count as installed when dpkg says so and the
# command or library that needs them is there. Only then is a failure reported.

APT_LOCK_WAIT=${APT_LOCK_WAIT:-600}

# apt_installed PKG...: 0 when dpkg reports every PKG as "install ok installed".
apt_installed() {
    local pkg status
    for pkg in "$@"; do
        status=$(dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null) || return 1
        [ "$status" = "install ok installed" ] || return 1
    done
}

# apt_install_checked WHAT CHECK PKG...: install PKG... unless CHECK (a shell command)
# already succeeds; warn with WHAT only when, after apt-get has run (waiting for any lock
# held by another apt), CHECK still fails or a PKG is not installed. The last apt-get
# lines are shown with the warning so that the cause is visible.
# APT_EXTRA: more options for apt-get install (e.g. --no-install-recommends).
apt_install_checked() {
    local what=$1 check=$2
    shift 2
    if eval "$check" >/dev/null 2>&1 && apt_installed "$@"; then
        return 0
    fi
    local log
    log=$(mktemp)
    # -o DPkg::Lock::Timeout: wait for dpkg's and apt's locks instead of failing at once
    apt-get -o DPkg::Lock::Timeout="$APT_LOCK_WAIT" update -qq >"$log" 2>&1 || true
    DEBIAN_FRONTEND=noninteractive apt-get -o DPkg::Lock::Timeout="$APT_LOCK_WAIT" \
        install -y -qq ${APT_EXTRA:-} "$@" >>"$log" 2>&1 || true
    if eval "$check" >/dev/null 2>&1 && apt_installed "$@"; then
        rm -f "$log"
        return 0
    fi
    echo "setup: could not install $what ($*): $(grep -E '^(E|W):' "$log" | tail -1)" >&2
    rm -f "$log"
    return 1
}
