#!/usr/bin/env bash
# Checks (and, as root, installs) the system packages the Python wheels need:
#   - python3 >= 3.10 with the venv module
#   - libusb-1.0-0, which Open3D's Linux wheel links against
# Prints nothing when everything is already there, so repeated runs stay quiet.
set -euo pipefail
python=${1:-python3}

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
[ ${#need_apt[@]} -eq 0 ] && exit 0

if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "lidar3d: installing system packages: ${need_apt[*]}" >&2
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >/dev/null
    apt-get install -y -qq "${need_apt[@]}" >/dev/null
else
    echo "lidar3d: missing system package(s) ${need_apt[*]}; run: sudo apt-get install ${need_apt[*]}" >&2
    exit 1
fi
