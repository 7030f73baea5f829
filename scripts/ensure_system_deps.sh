#!/usr/bin/env bash
# Checks (and, as root, installs) the system packages the Python wheels need:
#   - python3 >= 3.10 with the venv module
#   - libusb-1.0-0, which Open3D's Linux wheel links against
#   - with "test" as second argument: chromium, which the batch report's browser test opens
#     (that test is skipped, saying so, where chromium cannot be installed)
# Prints nothing when everything is already there, so repeated runs stay quiet.
set -euo pipefail
python=${1:-python3}
purpose=${2:-run}

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
    apt-get update -qq >/dev/null
    apt-get install -y -qq "${need_apt[@]}" >/dev/null
    if [ ${#optional_apt[@]} -gt 0 ] && ! apt-get install -y -qq "${optional_apt[@]}" >/dev/null; then
        echo "lidar3d: could not install ${optional_apt[*]} (the browser test will be skipped)" >&2
    fi
else
    echo "lidar3d: missing system package(s) ${need_apt[*]}; run: sudo apt-get install ${need_apt[*]}" >&2
    exit 1
fi
