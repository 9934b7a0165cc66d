#!/usr/bin/env bash
# The README's test command (about 17½ minutes on 2 cores from a clean clone with the packages
# present; README.md states the measured time):
#   1. installs what a fresh Debian 12 machine lacks (scripts/install-deps.sh)
#   2. checks formatting against the committed .clang-format, and the layers (cmake/layers.txt)
#   3. builds with warnings as errors and runs the whole suite (build/), then the README's demo
# CI (.ci/run) runs this, then scripts/sanitize.sh: the same suite under AddressSanitizer and
# UndefinedBehaviorSanitizer in a second build directory.
# Usage: scripts/test.sh [--sanitize]    (--sanitize: run scripts/sanitize.sh afterwards, as CI)
set -euo pipefail
cd "$(dirname "$0")/.."

sanitize=0
for arg in "$@"; do
  case "$arg" in
    --sanitize) sanitize=1 ;;
    --no-sanitize) ;;  # the default now; accepted so that older habits keep working
    *) echo "test.sh: unknown argument '$arg' (known: --sanitize)" >&2; exit 2 ;;
  esac
done

jobs=$(nproc)
scripts/install-deps.sh
scripts/check-format.sh
scripts/check-layers.sh

echo "== build (warnings are errors) =="
# The benchmarks are not built here (scripts/bench.sh builds its own release tree); CI compiles
# them with warnings as errors in the sanitizer build (scripts/sanitize.sh).
cmake -S . -B build -DGONIO_WERROR=ON -DGONIO_BUILD_BENCH=OFF -DGONIO_DEBUG_INFO=OFF \
  -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
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
  scripts/sanitize.sh
fi
