#!/usr/bin/env bash
# Installs everything M3C needs on a Debian/Ubuntu machine: the C++ libraries (apt), PyTorch (CPU wheel,
# pinned so nothing pulls a CUDA build), and M3C itself with its test dependencies.
# Usage: bash scripts/setup.sh        (run as root or with sudo available)
set -euo pipefail
cd "$(dirname "$0")/.."

APT_PACKAGES=(build-essential cmake ninja-build pkg-config libeigen3-dev libceres-dev libopencv-dev
              libgtest-dev nlohmann-json3-dev graphviz)
if command -v apt-get >/dev/null 2>&1; then
  missing=()
  for pkg in "${APT_PACKAGES[@]}"; do
    dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
  done
  if [ ${#missing[@]} -gt 0 ]; then
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    echo "setup: installing ${missing[*]}"
    $SUDO apt-get update -qq
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
  fi
else
  echo "setup: no apt-get; install Eigen 3, Ceres, OpenCV and GoogleTest with your package manager" >&2
fi

PY=${PYTHON:-python3}
# The CPU build of torch 2.13.0; the package's own range (torch>=2.1) is then satisfied and pulls nothing.
"$PY" -m pip install --quiet "torch==2.13.0"
"$PY" -m pip install --quiet ".[test]"
# The optional perception backend (the m3c[perception] extra, same pin): MediaPipe's BlazePose with its models
# inside the wheel. Installed on its own so that a platform without a wheel still gets a working M3C: only the
# MediaPipe tests then skip. M3C_NO_PERCEPTION=1 leaves it out.
if [ "${M3C_NO_PERCEPTION:-0}" != "1" ]; then
  "$PY" -m pip install --quiet "mediapipe==0.10.14" ||
    echo "setup: mediapipe==0.10.14 not installed; the MediaPipe perception tests will skip" >&2
fi
"$PY" -c "import m3c._core; print('setup: m3c', __import__('m3c').__version__, 'installed')"
