#!/usr/bin/env bash
# The test suite under AddressSanitizer and UndefinedBehaviorSanitizer, then a short libFuzzer run
# of every fuzz/ target, from one clang build (build-asan/: every library instrumented for the
# sanitizers and for the fuzzers' coverage, line tables for the reports' file:line). CI (.ci/run)
# runs it after the README's test command.
#
# By default it runs every unit test and the selection of simulated-instrument tests labelled
# "sim-sanitize" (tests/CMakeLists.txt lists them with the reason for each); --all runs every
# test.
# Then each fuzz target for 10 s (scripts/fuzz.sh). Each part's time is printed.
# Usage: scripts/sanitize.sh [--all]
set -euo pipefail
cd "$(dirname "$0")/.."

labels='^(unit|sim-sanitize)$'
for arg in "$@"; do
  case "$arg" in
    --all) labels='' ;;
    *) echo "sanitize.sh: unknown argument '$arg' (known: --all)" >&2; exit 2 ;;
  esac
done
jobs=$(nproc)
scripts/install-deps.sh

# A build-asan/ configured earlier with another compiler is started afresh: CMake cannot change
# a tree's compiler in place.
if [[ -f build-asan/CMakeCache.txt ]] &&
   ! grep -q '^CMAKE_CXX_COMPILER:[A-Z]*=.*clang++' build-asan/CMakeCache.txt; then
  echo "sanitize.sh: build-asan/ was configured with another compiler; starting it afresh"
  rm -rf build-asan
fi

# The GigE tests stay one at a time here (GONIO_TEST_OWN_LOOPBACK=OFF): under the sanitizers'
# slowdown two side by side would spend timing margin that test.sh's build can afford.
start=$SECONDS
echo "== build with ASan + UBSan (clang; and the fuzz targets) =="
cmake -S . -B build-asan -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
  -DGONIO_WERROR=ON -DGONIO_SANITIZE=ON -DGONIO_FUZZ=ON -DGONIO_DEBUG_INFO=LINES \
  -DGONIO_BUILD_BENCH=OFF -DCMAKE_BUILD_TYPE=RelWithDebInfo -DGONIO_TEST_OWN_LOOPBACK=OFF \
  >/dev/null
cmake --build build-asan -j "$jobs"
echo "sanitize: the build took $((SECONDS - start)) s"

start=$SECONDS
if [[ -n "$labels" ]]; then
  echo "== tests under ASan + UBSan: every unit test and the selection (label sim-sanitize) =="
else
  echo "== tests under ASan + UBSan: every test =="
fi
# Leak suppressions cover third-party libraries only (scripts/lsan.supp says which and why).
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:strict_string_checks=1 \
LSAN_OPTIONS="suppressions=$PWD/scripts/lsan.supp:print_suppressions=0" \
UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --test-dir build-asan --output-on-failure -j "$jobs" --timeout 1800 \
    ${labels:+-L "$labels"}
echo "sanitize: the tests took $((SECONDS - start)) s"

# libFuzzer on every target for a few seconds each, from the same build: a crash regression
# fails CI here too, beyond the seed replays the suite above ran (fuzz/README.md).
start=$SECONDS
echo "== fuzzing: 10 s per target =="
FUZZ_BUILD=build-asan scripts/fuzz.sh all 10
echo "sanitize: fuzzing took $((SECONDS - start)) s"
