#!/usr/bin/env bash
# Checks a morph's output with the clients studios use: Pixar's USD library (usd-core, and the
# validators usdchecker runs; and the older usd-core 24.3) and Blender 4.5 as a Python module
# (bpy), installed into cached venvs outside the repo; then renders OUT/contact.png (scripts/contact_sheet.py). Usage:
# scripts/client-check.sh [OUT]; without OUT it makes a small morph of the built-in assets
# first (numbered from 1001, as a shot is, with its volumes). Needs python3.11 (bpy 4.5's).
set -euo pipefail
cd "$(dirname "$0")/.."
venv="${MORPH_CLIENT_VENV:-${XDG_CACHE_HOME:-$HOME/.cache}/morph-client-venv}"
if ! "$venv/bin/python" -c 'import pxr, bpy' >/dev/null 2>&1; then
  # A registry that cannot be reached is not a failure of morph's output: say so and skip.
  if ! { python3 -m venv "$venv" &&
    "$venv/bin/pip" install --quiet --disable-pip-version-check usd-core "bpy==4.5.*"; }; then
    echo "client check skipped: could not install usd-core and bpy 4.5 into $venv" >&2
    exit 0
  fi
fi
out="${1:-}"
if [ -z "$out" ]; then
  out="$(mktemp -d)/small"
  cargo run --release --quiet -- assets/sphere.obj assets/two-lobes.obj -o "$out" \
    --preset draft --resolution 16 --start-frame 1001 --volume --quiet
fi
"$venv/bin/python" scripts/check_clients.py "$out"
# The USD file with the oldest usd-core on PyPI (24.3: the USD generation of Houdini 20 and
# Maya 2025), in a venv of its own; a loud skip when it cannot be installed.
old="${MORPH_OLD_USD_VENV:-${XDG_CACHE_HOME:-$HOME/.cache}/morph-usd24-venv}"
if ! "$old/bin/python" -c 'import pxr' >/dev/null 2>&1; then
  python3 -m venv "$old" && "$old/bin/pip" install --quiet --disable-pip-version-check "usd-core==24.3" ||
    true
fi
if "$old/bin/python" -c 'import pxr' >/dev/null 2>&1; then
  "$old/bin/python" scripts/check_usd_compat.py "$out"
else
  echo "older USD check skipped: could not install usd-core 24.3 into $old" >&2
fi
# The OpenVDB file with OpenVDB's own library (Debian's python3-openvdb, for the system
# python), installed when missing and allowed; a loud skip otherwise.
if ! /usr/bin/python3 -c 'import pyopenvdb' >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    apt-get install -y -qq python3-openvdb >/dev/null 2>&1 ||
      { apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq python3-openvdb >/dev/null 2>&1; } || true
  fi
fi
if /usr/bin/python3 -c 'import pyopenvdb' >/dev/null 2>&1; then
  /usr/bin/python3 scripts/check_vdb.py "$out"
else
  echo "VDB check skipped: python3-openvdb (Debian) could not be installed" >&2
fi
# What a person looks at: frame 1, halfway, arrival and the last frame of the carried and the
# rebuilt surface next to the target, rendered by Blender (Cycles, CPU) into OUT/contact.png.
# (morph --overwrite/--resume then refuse OUT until contact.png is moved: not morph's file.)
"$venv/bin/python" scripts/contact_sheet.py "$out" --width 1000 --samples 16
