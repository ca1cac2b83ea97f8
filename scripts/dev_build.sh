#!/usr/bin/env bash
# Developer build: the core, the C++ tests and m3c/_core*.so placed in python/m3c, so that
#   PYTHONPATH=python python3 -m pytest   and   ctest --test-dir build/dev
# run against the working tree without reinstalling.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
cmake -S . -B build/dev -G Ninja -DCMAKE_BUILD_TYPE=Release -DM3C_BUILD_TESTS=ON \
  -DPython_EXECUTABLE="$(command -v "$PY")" -Dpybind11_DIR="$("$PY" -m pybind11 --cmakedir)" >/dev/null
cmake --build build/dev -j "${M3C_JOBS:-2}"
