#!/usr/bin/env bash
# Sanitizer check, not part of CI (a run from scratch takes ~16 min on 2 shared cores, mostly the build): builds
# the core, the C++ tests and the extension with AddressSanitizer + UndefinedBehaviorSanitizer (CMake option
# M3C_SANITIZE) in build/sanitize, then runs ctest and the Python robustness suites (the property-based fuzz of
# every bound function and the issue 19 cases) against that extension, with libasan preloaded into Python. Any
# sanitizer report fails the run.
#   bash scripts/sanitize.sh                 # everything
#   M3C_FUZZ_EXAMPLES=300 bash scripts/sanitize.sh   # a deeper fuzz
# The extension goes into build/sanitize/python/m3c (a copy of the package): the developer build is untouched.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
BUILD=build/sanitize
PKG=$BUILD/python

rm -rf "$PKG/m3c" && mkdir -p "$PKG" && cp -r python/m3c "$PKG/"
find "$PKG/m3c" \( -name '_core*.so' -o -name __pycache__ \) -prune -exec rm -rf {} +
# -O1 -g1: the sanitizers' recommended optimisation with line tables for the reports, and a build that fits in a
# session on 2 cores (-O2 -g with ASan takes several times longer on Ceres's templates).
cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_FLAGS_RELEASE="-O1 -g1 -DNDEBUG" \
  -DM3C_BUILD_TESTS=ON -DM3C_SANITIZE=ON \
  -DM3C_EXTENSION_DIR="$PWD/$PKG/m3c" -DPython_EXECUTABLE="$(command -v "$PY")" \
  -Dpybind11_DIR="$("$PY" -m pybind11 --cmakedir)" >/dev/null
cmake --build "$BUILD" -j "${M3C_JOBS:-2}"

# Leaks are not checked: CPython and numpy keep allocations alive until exit by design. allocator_may_return_null:
# an impossible allocation (the fuzz's 2^40-row inputs) returns NULL as glibc's malloc does, so numpy raises
# MemoryError, instead of ASan stopping the process.
export ASAN_OPTIONS=detect_leaks=0:halt_on_error=1:strict_init_order=1:detect_stack_use_after_return=1
export ASAN_OPTIONS=$ASAN_OPTIONS:allocator_may_return_null=1
export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
echo "== ctest (ASan + UBSan)"
ctest --test-dir "$BUILD" --output-on-failure -j "${M3C_JOBS:-2}"

echo "== Python robustness suites against the sanitized extension"
# ASan must be the first library in the process; verify_asan_link_order is off because Python itself is not
# instrumented. OMP/torch threads are kept to one to keep the run reproducible.
LD_PRELOAD="$(gcc -print-file-name=libasan.so) $(gcc -print-file-name=libubsan.so)" \
ASAN_OPTIONS="$ASAN_OPTIONS:verify_asan_link_order=0" OMP_NUM_THREADS=1 PYTHONPATH="$PWD/$PKG" \
  "$PY" -m pytest -q -p no:cacheprovider tests/python/test_bindings_fuzz.py tests/python/test_robust_bindings.py \
  tests/python/test_body_core.py tests/python/test_ground_dbscan.py tests/python/test_ground_planes.py \
  tests/python/test_vo_api.py
echo "sanitize: no ASan/UBSan report"
