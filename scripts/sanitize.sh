#!/usr/bin/env bash
# The whole test suite under AddressSanitizer and UndefinedBehaviorSanitizer, in a second build
# directory (build-asan/). CI (.ci/run) runs it after the README's test command; it takes about
# 15 minutes on 2 cores, then a short libFuzzer run of every fuzz/ target (about 8 minutes with
# its clang build). Every library's tests run here, the simulated instrument included.
# Usage: scripts/sanitize.sh
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=$(nproc)
scripts/install-deps.sh

# The benchmarks are compiled here (warnings as errors), not in test.sh's build; not run. The GigE
# tests stay one at a time here (GONIO_TEST_OWN_LOOPBACK=OFF): under the sanitizers' slowdown two
# side by side would spend timing margin that test.sh's build can afford.
echo "== build with ASan + UBSan =="
cmake -S . -B build-asan -DGONIO_WERROR=ON -DGONIO_SANITIZE=ON -DGONIO_BUILD_BENCH=ON \
  -DCMAKE_BUILD_TYPE=RelWithDebInfo -DGONIO_TEST_OWN_LOOPBACK=OFF >/dev/null
cmake --build build-asan -j "$jobs"
echo "== tests under ASan + UBSan =="
# Leak suppressions cover third-party libraries only (scripts/lsan.supp says which and why).
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:strict_string_checks=1 \
LSAN_OPTIONS="suppressions=$PWD/scripts/lsan.supp:print_suppressions=0" \
UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --test-dir build-asan --output-on-failure -j "$jobs" --timeout 1800

# libFuzzer on every parser target for a few seconds each (clang, build-fuzz/; fuzz/README.md):
# a crash regression fails CI here too, beyond the seed replays the suites above ran.
echo "== fuzzing: 10 s per target =="
scripts/fuzz.sh all 10
