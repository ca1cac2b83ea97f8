#!/usr/bin/env bash
# Runs every test: the C++ unit tests (gtest via ctest) and the Python suite against the installed package.
# Usage: bash scripts/test.sh   (after scripts/setup.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
JOBS=${M3C_JOBS:-2}

cmake -S . -B build/tests -G Ninja -DCMAKE_BUILD_TYPE=Release -DM3C_BUILD_TESTS=ON -DM3C_BUILD_PYTHON=OFF >/dev/null
cmake --build build/tests -j "$JOBS"
ctest --test-dir build/tests --output-on-failure -j "$JOBS"

"$PY" -m pytest -q
