#!/usr/bin/env bash
# Installs Mesa's Vulkan CPU driver (lavapipe, Debian's mesa-vulkan-drivers) where it is not
# installed, so that the GPU device's tests (crates/gpu) run on a machine without a
# GPU. Needs root and apt-get; prints what it found either way.
set -euo pipefail
if ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1; then
  echo "gpu-driver: lavapipe present"
  exit 0
fi
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  if apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null 2>&1 ||
    { apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null 2>&1; }; then
    echo "gpu-driver: installed mesa-vulkan-drivers (lavapipe)"
  else
    echo "gpu-driver: apt-get could not install mesa-vulkan-drivers: the GPU tests will say what is missing" >&2
  fi
else
  echo "gpu-driver: no lavapipe and no root apt-get: the GPU tests will say what is missing" >&2
fi
