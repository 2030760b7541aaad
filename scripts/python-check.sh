#!/usr/bin/env bash
# The Python module and the Blender extension, checked as users get them: builds the wheel
# with maturin (python/), runs its pytest suite against the CLI built from the same tree, then
# builds the Blender extension around the wheel and runs it in headless Blender 4.5 (bpy, the
# client check's venv): install from the zip, morph a UV sphere into a cube, check the
# imported result. Venvs are cached outside the repo; a registry that cannot be reached is a
# loud skip, not a failure. Usage: scripts/python-check.sh (after `cargo build --release`).
set -euo pipefail
cd "$(dirname "$0")/.."
cache="${XDG_CACHE_HOME:-$HOME/.cache}"
venv="${MORPH_PYTHON_VENV:-$cache/morph-python-venv}"
if ! { [ -x "$venv/bin/maturin" ] && "$venv/bin/python" -c 'import pytest, numpy' >/dev/null 2>&1; }; then
  if ! { python3 -m venv "$venv" &&
    "$venv/bin/pip" install --quiet --disable-pip-version-check "maturin>=1.9,<2" pytest numpy; }; then
    echo "python check skipped: could not install maturin, pytest and numpy into $venv" >&2
    exit 0
  fi
fi
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
"$venv/bin/maturin" build --release --quiet -m python/Cargo.toml -o "$work/wheels"
wheel="$(ls "$work"/wheels/*.whl)"
echo "python check: built $(basename "$wheel") ($(du -h "$wheel" | cut -f1))"
"$venv/bin/pip" install --quiet --disable-pip-version-check --force-reinstall --no-deps "$wheel"
MORPH_BIN="$PWD/target/release/morph" "$venv/bin/python" -m pytest -q -p no:cacheprovider python/tests

# The Blender extension, in the client check's Blender (installed by scripts/client-check.sh).
blender="${MORPH_CLIENT_VENV:-$cache/morph-client-venv}/bin/python"
if ! "$blender" -c 'import bpy' >/dev/null 2>&1; then
  echo "blender extension check skipped: no bpy in $blender (scripts/client-check.sh installs it)" >&2
  exit 0
fi
python3 scripts/build-blender-extension.py "$wheel" "$work/morph-blender.zip"
# A fresh Blender user folder: the extension is installed into it, never into the user's own.
BLENDER_USER_RESOURCES="$work/blender-user" "$blender" scripts/blender_extension_check.py \
  "$work/morph-blender.zip" "$work"
