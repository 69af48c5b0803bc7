#!/usr/bin/env bash
# Non-Python prerequisites. Installed when run as root (Debian/Ubuntu), named otherwise.
set -euo pipefail
missing=()
# Open3D's wheel links against libusb-1.0 and libgomp.
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || missing+=(libusb-1.0-0)
ldconfig -p 2>/dev/null | grep -q 'libgomp.so.1' || missing+=(libgomp1)
# The operator GUI (PySide6's xcb platform, VTK's OpenGL) and its tests' virtual display.
for pair in libxcb-icccm.so.4:libxcb-icccm4 libxcb-keysyms.so.1:libxcb-keysyms1 libxcb-image.so.0:libxcb-image0 \
            libxcb-render-util.so.0:libxcb-render-util0 libxcb-cursor.so.0:libxcb-cursor0 libxcb-xkb.so.1:libxcb-xkb1 \
            libxkbcommon-x11.so.0:libxkbcommon-x11-0 libxcb-randr.so.0:libxcb-randr0 libxcb-shape.so.0:libxcb-shape0 \
            libEGL.so.1:libegl1 libGL.so.1:libgl1 libXrender.so.1:libxrender1 libfontconfig.so.1:libfontconfig1 \
            libdbus-1.so.3:libdbus-1-3; do
  ldconfig -p 2>/dev/null | grep -q "${pair%%:*}" || missing+=("${pair##*:}")
done
# The banner's verdict icons (check, cross, warning sign) are in DejaVu Sans.
fc-list 2>/dev/null | grep -qi 'DejaVuSans.ttf' || missing+=(fonts-dejavu-core)
command -v Xvfb >/dev/null || missing+=(xvfb)
command -v xauth >/dev/null || missing+=(xauth)
# Optional: installed when root, named otherwise (their tests skip and say why).
# PostgreSQL's server (initdb, pg_ctl): the history plugin's plant-database tests start one.
optional=()
{ command -v initdb >/dev/null || ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1; } || optional+=(postgresql)
if [ ${#missing[@]} -eq 0 ] && [ ${#optional[@]} -eq 0 ]; then exit 0; fi
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
  echo "Installing system packages: ${missing[*]} ${optional[*]}"
  apt-get update -qq >/dev/null
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" "${optional[@]}" >/dev/null
elif [ ${#missing[@]} -eq 0 ]; then
  echo "Optional system packages missing: ${optional[*]} (their tests skip; sudo apt-get install ${optional[*]})." >&2
else
  echo "Missing system packages: ${missing[*]}. Install them (e.g. sudo apt-get install ${missing[*]} ${optional[*]}) and run make again." >&2
  exit 1
fi
