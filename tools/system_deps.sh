#!/usr/bin/env bash
# Install the Debian packages the project needs, only when something is missing (idempotent, fast).
set -euo pipefail
PY=${1:-python3}
missing=()
# ldconfig lives in /sbin, which a non-login PATH may lack
LDCONFIG=$(command -v ldconfig || echo /sbin/ldconfig)
LIBS=$("$LDCONFIG" -p 2>/dev/null || true)   # read once: `ldconfig | grep -q` dies of SIGPIPE under pipefail
have_lib() { grep -qF "$1" <<<"$LIBS"; }
command -v cmake >/dev/null || missing+=(cmake)
command -v g++ >/dev/null || missing+=(g++)
command -v make >/dev/null || missing+=(make)
have_lib 'libusb-1.0.so' || missing+=(libusb-1.0-0)   # import open3d needs it
have_lib 'libGL.so.1' || missing+=(libgl1)              # open3d-cpu links libGL
have_lib 'libgomp.so.1' || missing+=(libgomp1)
if [ -z "$PY" ] || ! command -v "$PY" >/dev/null; then
  missing+=(python3 python3-venv python3-dev)
else
  "$PY" -c 'import venv, ensurepip' 2>/dev/null || missing+=(python3-venv)
  inc=$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
  [ -f "$inc/Python.h" ] || missing+=(python3-dev)
  "$PY" -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' \
    || echo "warning: $PY is not Python 3.11; the ROS 2 Kilted wheels need CPython 3.11" >&2
fi
if [ ${#missing[@]} -eq 0 ]; then
  echo "system-deps: all present"
  exit 0
fi
echo "system-deps: installing ${missing[*]}"
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
