#!/usr/bin/env bash
# The README's test command (within 20 minutes on 2 cores from a clean clone with the packages
# present):
#   1. installs what a fresh Debian 12 machine lacks (scripts/install-deps.sh)
#   2. checks formatting against the committed .clang-format, the layers (cmake/layers.txt) and
#      the functions' length (scripts/check-functions.sh)
#   3. builds everything, the benchmarks too, with warnings as errors, and runs the whole suite
#      (build/), then the README's demo
# Each part's time is printed. CI (.ci/run) runs this, then scripts/sanitize.sh: the unit tests
# and a selection of the simulated instrument's under AddressSanitizer and
# UndefinedBehaviorSanitizer in a second build directory, and the fuzz targets.
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
part() { echo "test: $1 took $((SECONDS - part_start)) s"; part_start=$SECONDS; }
part_start=$SECONDS
scripts/install-deps.sh
scripts/check-format.sh
scripts/check-layers.sh
scripts/check-functions.sh
part "installing and the checks"

echo "== build (warnings are errors) =="
# Without debug information (it nearly doubles the compile time); the benchmarks are compiled
# here so that their warnings fail too, and run only by scripts/bench.sh.
cmake -S . -B build -DGONIO_WERROR=ON -DGONIO_BUILD_BENCH=ON -DGONIO_DEBUG_INFO=OFF \
  -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build build -j "$jobs"
part "the build"
echo "== tests =="
ctest --test-dir build --output-on-failure -j "$jobs" --timeout 900
part "the tests"

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
# What a person sees of it (under about 60 lines after the build), and its fits.
lines=$(sed -n '/^== starting the simulated instrument/,$p' build/demo.log | wc -l)
echo "the demo printed $lines lines after its build (build/demo.log)"
grep -E "^(beckmann|ggx) |^== the simulator|plot_fit: wrote" build/demo.log | head -8
# A new database's first estimate (the instrument config's [throughput]) against what its run
# exposed, through the whole instrument: within 30 % (docs/operator.md).
cost=$(grep -E "^exposure [0-9]+ s, estimated [0-9]+ s \([+-][0-9]+ %\)" build/demo.log | head -1)
echo "run 1: ${cost:0:80}"
pct=$(sed -E 's/.*\(([+-][0-9]+) %\).*/\1/' <<< "$cost")
[[ -n "$cost" && ${pct#[+-]} -le 30 ]] ||
  { echo "test.sh: the demo's first estimate is off by more than 30 %: '$cost'" >&2; exit 1; }
part "the demo"

if [[ $sanitize == 1 ]]; then
  scripts/sanitize.sh
fi
