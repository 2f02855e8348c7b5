#!/usr/bin/env bash
# Idempotent set-up on a fresh Debian machine: system packages (lavapipe, Vulkan loader,
# shader compiler, validation layers), a virtual environment in .venv, and the package.
set -euo pipefail
cd "$(dirname "$0")/.."
pkgs="python3 python3-venv mesa-vulkan-drivers libvulkan1 vulkan-tools glslc spirv-tools vulkan-validationlayers"
# Opt-in: Chromium for the test that opens `mgpusim advise`'s report in a headless browser
# (tests/test_advise.py; skipped without it). About 155 MB and two minutes on a fresh Debian
# machine, so CI does not install it unless asked: MGPUSIM_BROWSER=1 bash scripts/test.sh
if [ "${MGPUSIM_BROWSER:-0}" = 1 ]; then pkgs="$pkgs chromium"; fi
missing=""
for p in $pkgs; do dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"; done
if [ -n "$missing" ]; then
  echo "setup: installing Debian packages:$missing" >&2
  sudo_cmd=""
  if [ "$(id -u)" != 0 ]; then
    command -v sudo >/dev/null || { echo "setup: run as root or install sudo to get:$missing" >&2; exit 1; }
    sudo_cmd="sudo"
  fi
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq $missing >/dev/null
fi
if [ ! -x .venv/bin/python ]; then
  python3 -m venv .venv
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null
fi
.venv/bin/python -m pip install -q -e '.[test,vulkan]'
