#!/usr/bin/env bash
# System packages for the acquisition drivers (aravis; genicam needs none), idempotent.
#
#   scripts/install-acquisition-deps.sh [--strict] [--python PY]
#
# Debian/Ubuntu packages, installed when run as root, otherwise named with the command:
#   gir1.2-aravis-0.8       Aravis 0.8 library and its GObject introspection data (driver aravis)
#   aravis-tools            arv-fake-gv-camera-0.8, the GigE Vision emulator of the aravis tests
#   iproute2                ip netns, for the emulators' private network (tests, as root)
#   libgirepository1.0-dev, libcairo2-dev, pkg-config, gcc
#                           to build PyGObject < 3.51 and pycairo in a virtualenv
#   python3-dev             only when the interpreter given with --python has no Python.h
# --python PY   also pip-install the pinned Python packages into PY's environment
#               (harvesters, genicam, PyGObject, pycairo), after the system packages.
# --strict      exit 1 when packages are missing and cannot be installed (default: warn, exit
#               0 — the drivers are optional and their tests skip without them).
set -euo pipefail

strict=0
python=""
while [ $# -gt 0 ]; do
  case "$1" in
    --strict) strict=1 ;;
    --python) python="${2:?--python needs an interpreter}"; shift ;;
    -h|--help) sed -n '2,20p' "$0"; exit 0 ;;
    *) echo "install-acquisition-deps: unknown option $1" >&2; exit 2 ;;
  esac
  shift
done

# Exact versions (Python 3.11, x86_64) with which the drivers and their tests were checked.
PIP_PINS=(harvesters==1.4.3 genicam==1.6.0 "PyGObject==3.50.2" pycairo==1.29.2)

want=(gir1.2-aravis-0.8 aravis-tools iproute2 libgirepository1.0-dev libcairo2-dev pkg-config gcc)
if [ -n "$python" ]; then
  inc="$("$python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])' 2>/dev/null || true)"
  if [ -z "$inc" ] || [ ! -f "$inc/Python.h" ]; then want+=(python3-dev); fi
fi

missing=()
if command -v dpkg-query >/dev/null 2>&1; then
  for p in "${want[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
else
  echo "install-acquisition-deps: not a Debian/Ubuntu system; install the equivalents of: ${want[*]}" >&2
  [ "$strict" = 1 ] && exit 1
fi

if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "Installing system packages: ${missing[*]}"
    DEBIAN_FRONTEND=noninteractive apt-get update -qq >/dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  else
    echo "Acquisition drivers: missing system packages: ${missing[*]}." >&2
    echo "  Install them with: sudo apt-get install ${missing[*]}" >&2
    [ "$strict" = 1 ] && exit 1
    exit 0
  fi
fi

if [ -n "$python" ]; then
  # pip is idempotent: pinned versions already installed are left alone.
  "$python" -m pip install -q --disable-pip-version-check "${PIP_PINS[@]}"
fi
exit 0
