#!/usr/bin/env bash
# Checks (and, as root, installs) the system packages the Python wheels need:
#   - python3 >= 3.10 with the venv module
#   - libusb-1.0-0, which Open3D's Linux wheel links against
#   - with "test" as second argument: chromium, which the batch report's browser test opens
#     (that test is skipped, saying so, where chromium cannot be installed)
# Prints nothing when everything is already there, so repeated runs stay quiet.
#
# Before apt-get runs it waits for the package manager's locks (another apt-get or dpkg, e.g. the
# unattended upgrades a fresh Ubuntu machine runs at first boot), saying once that it waits and why,
# and gives up after LIDAR3D_APT_LOCK_TIMEOUT_S seconds (default 300) with one line. The locks are
# the fcntl locks dpkg and apt take; they are tested with Python's fcntl.lockf (non-blocking), which
# sees them (flock(1) would not: flock and fcntl locks do not conflict on Linux). apt-get itself also
# waits for the dpkg lock (-o DPkg::Lock::Timeout) should another one take it in between.
# Overridable for tests: LIDAR3D_APT_LOCKS (space-separated lock files), LIDAR3D_APT_LOCK_POLL_S.
# Sourcing the script defines its functions without running it.
set -euo pipefail
python=${1:-python3}
purpose=${2:-run}
default_apt_locks="/var/lib/dpkg/lock-frontend /var/lib/dpkg/lock /var/lib/apt/lists/lock /var/cache/apt/archives/lock"
apt_locks=${LIDAR3D_APT_LOCKS:-$default_apt_locks}
apt_lock_timeout_s=${LIDAR3D_APT_LOCK_TIMEOUT_S:-300}
apt_lock_poll_s=${LIDAR3D_APT_LOCK_POLL_S:-5}
apt_deadline=$((SECONDS + apt_lock_timeout_s))
apt_wait_announced=0

# Prints the first of the lock files that another process holds (nothing when all are free).
held_apt_lock() {
    # shellcheck disable=SC2086  # the list is space-separated on purpose
    "$python" - $apt_locks <<'PY'
import fcntl
import os
import sys

for path in sys.argv[1:]:
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:  # absent (nothing holds it) or not ours to open
        continue
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        print(path)
        break
    finally:
        os.close(fd)  # releases the lock we took for the test at once
PY
}

# Returns once no lock is held; exits 1 with one line when the deadline passes first.
wait_for_apt_locks() {
    local lock
    while lock=$(held_apt_lock) && [ -n "$lock" ]; do
        if [ "$SECONDS" -ge "$apt_deadline" ]; then
            echo "lidar3d: gave up after ${apt_lock_timeout_s} s waiting for $lock (another apt-get or dpkg," \
                 "e.g. unattended-upgrades, still holds it); rerun when it has finished" >&2
            exit 1
        fi
        if [ "$apt_wait_announced" -eq 0 ]; then
            echo "lidar3d: waiting up to ${apt_lock_timeout_s} s for the package manager: $lock is held by" \
                 "another apt-get or dpkg (on a fresh machine: unattended upgrades at first boot)" >&2
            apt_wait_announced=1
        fi
        sleep "$apt_lock_poll_s"
    done
}

# apt-get "$@" once the locks are free; retried when another package manager took them in between.
apt_get() {
    while true; do
        wait_for_apt_locks
        local left=$((apt_deadline - SECONDS))
        if apt-get -o DPkg::Lock::Timeout="$((left > 0 ? left : 0))" "$@"; then
            return 0
        fi
        if [ -z "$(held_apt_lock)" ]; then
            return 1  # failed for another reason than a lock
        fi
    done
}

if [ "${BASH_SOURCE[0]}" != "$0" ]; then
    return 0  # sourced (tests): functions only
fi

need_apt=()
if ! command -v "$python" >/dev/null 2>&1; then
    echo "lidar3d: '$python' not found; install Python 3.10 or newer (Debian package python3)" >&2
    exit 1
fi
if ! "$python" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 10) else 1)'; then
    echo "lidar3d: $("$python" --version 2>&1) is too old; Python 3.10 or newer is required" >&2
    exit 1
fi
if ! "$python" -c 'import venv, ensurepip' >/dev/null 2>&1; then
    need_apt+=("python3-venv")
fi
if ! { ldconfig -p 2>/dev/null | grep -q 'libusb-1\.0\.so\.0'; } \
   && ! ls /usr/lib/*/libusb-1.0.so.0 /usr/lib/libusb-1.0.so.0 >/dev/null 2>&1; then
    need_apt+=("libusb-1.0-0")
fi
optional_apt=()
if [ "$purpose" = test ] && ! command -v chromium >/dev/null 2>&1; then
    optional_apt+=("chromium")
fi
if [ ${#need_apt[@]} -eq 0 ] && [ ${#optional_apt[@]} -eq 0 ]; then
    exit 0
fi
if [ ${#need_apt[@]} -eq 0 ] && [ "$(id -u)" -ne 0 ]; then
    echo "lidar3d: optional package ${optional_apt[*]} is missing (the browser test will be skipped)" >&2
    exit 0
fi

if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "lidar3d: installing system packages: ${need_apt[*]} ${optional_apt[*]}" >&2
    export DEBIAN_FRONTEND=noninteractive
    apt_get update -qq >/dev/null
    apt_get install -y -qq "${need_apt[@]}" >/dev/null
    if [ ${#optional_apt[@]} -gt 0 ] && ! apt_get install -y -qq "${optional_apt[@]}" >/dev/null; then
        echo "lidar3d: could not install ${optional_apt[*]} (the browser test will be skipped)" >&2
    fi
else
    echo "lidar3d: missing system package(s) ${need_apt[*]}; run: sudo apt-get install ${need_apt[*]}" >&2
    exit 1
fi
