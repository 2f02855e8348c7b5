#!/usr/bin/env bash
# Idempotent set-up on a fresh Debian machine: system packages (lavapipe, Vulkan loader,
# shader compiler, validation layers; Xvfb for the vmgpu tool's tests; RenderDoc's Python module
# for the frame import's replay of .rdc captures), a virtual environment
# in .venv, and the package.
set -euo pipefail
cd "$(dirname "$0")/.."
pkgs="python3 python3-venv mesa-vulkan-drivers libvulkan1 vulkan-tools glslc spirv-tools vulkan-validationlayers xvfb python3-renderdoc"
sudo_cmd=""
[ "$(id -u)" != 0 ] && command -v sudo >/dev/null && sudo_cmd="sudo"
apt_install() {  # apt_install PKG...: update the lists, then install (exit status of apt)
  [ "$(id -u)" = 0 ] || [ -n "$sudo_cmd" ] || return 1
  $sudo_cmd apt-get update -qq && DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq "$@" >/dev/null
}
missing=""
for p in $pkgs; do dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"; done
if [ -n "$missing" ]; then
  echo "setup: installing Debian packages:$missing" >&2
  if [ "$(id -u)" != 0 ] && [ -z "$sudo_cmd" ]; then
    echo "setup: run as root or install sudo to get:$missing" >&2; exit 1
  fi
  apt_install $missing
fi
# Chromium, for the tests that open the HTML reports (`mgpusim advise`, `mgpusim study
# validate`) in a headless browser (tests/headless_browser.py). Installed by default but never
# fatal: where apt cannot install it, one warning line, and those tests are skipped with a
# reason. MGPUSIM_BROWSER=0 opts out. About 35 s for chromium itself (113 MB) on the 2-core
# development machine, more on a fresh one that also lacks its libraries.
if [ "${MGPUSIM_BROWSER:-1}" != 0 ] && ! dpkg -s chromium >/dev/null 2>&1 \
   && ! command -v chromium >/dev/null && ! command -v chromium-browser >/dev/null; then
  echo "setup: installing Debian package chromium (for the headless-browser tests; MGPUSIM_BROWSER=0 skips it)" >&2
  apt_install chromium 2>/dev/null \
    || echo "setup: warning: could not install chromium; the headless-browser tests will be skipped" >&2
fi
if [ ! -x .venv/bin/python ]; then
  python3 -m venv .venv
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null
fi
.venv/bin/python -m pip install -q -e '.[test,vulkan]'
