#!/usr/bin/env bash
# The README's test command, and what CI runs (.ci/run).
#   1. installs what a fresh Debian 12 machine lacks (scripts/install-deps.sh)
#   2. checks formatting against the committed .clang-format
#   3. builds with warnings as errors and runs the test suite (build/), then the README's demo
#   4. builds again with AddressSanitizer + UndefinedBehaviorSanitizer and runs the suite (build-asan/)
# Usage: scripts/test.sh [--no-sanitize]    (--no-sanitize skips step 4, for quick local runs)
set -euo pipefail
cd "$(dirname "$0")/.."

sanitize=1
for arg in "$@"; do
  case "$arg" in
    --no-sanitize) sanitize=0 ;;
    *) echo "test.sh: unknown argument '$arg' (known: --no-sanitize)" >&2; exit 2 ;;
  esac
done

jobs=$(nproc)
scripts/install-deps.sh
scripts/check-format.sh

echo "== build (warnings are errors) =="
cmake -S . -B build -DGONIO_WERROR=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build build -j "$jobs"
echo "== tests =="
ctest --test-dir build --output-on-failure -j "$jobs" --timeout 900

# The README's first command, as its text says, after the suite (it needs the GigE port alone).
echo "== the demo: the README's first command =="
demo_cmd=$(awk '/^Run the instrument/ {f = 1; next} f && /^    / {sub(/^    /, ""); print; exit}' README.md)
[[ -n "$demo_cmd" ]] || { echo "test.sh: README.md names no demo command" >&2; exit 1; }
echo "$ $demo_cmd"
if ! bash -c "$demo_cmd" > build/demo.log 2>&1; then
  tail -40 build/demo.log
  echo "test.sh: the demo failed (log: build/demo.log)" >&2
  exit 1
fi
grep -E "^(beckmann|ggx) |^== the simulator|plot_fit: wrote" build/demo.log | head -8

if [[ $sanitize == 1 ]]; then
  echo "== build with ASan + UBSan =="
  cmake -S . -B build-asan -DGONIO_WERROR=ON -DGONIO_SANITIZE=ON -DGONIO_BUILD_BENCH=OFF \
    -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
  cmake --build build-asan -j "$jobs"
  echo "== tests under ASan + UBSan =="
  # Leak suppressions cover third-party libraries only (scripts/lsan.supp says which and why).
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:strict_string_checks=1 \
  LSAN_OPTIONS="suppressions=$PWD/scripts/lsan.supp:print_suppressions=0" \
  UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
    ctest --test-dir build-asan --output-on-failure -j "$jobs" --timeout 1800
fi
