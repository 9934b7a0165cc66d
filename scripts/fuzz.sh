#!/usr/bin/env bash
# Fuzzes one target of fuzz/ (or all) with libFuzzer for SECONDS each, starting from the seed
# corpus fuzz/corpus/<target>/ and keeping what it finds in out/fuzz/<target>/ (crash files too).
# Prints executions and crashes per target; exits 1 if any target crashed.
# By default it builds build-fuzz/ with clang: every library instrumented for the fuzzer's full
# coverage (comparisons traced too), with ASan and UBSan. FUZZ_BUILD=DIR uses the fuzz targets of
# a tree already configured with GONIO_FUZZ=ON instead (scripts/sanitize.sh passes build-asan/,
# whose libraries count edges only, so that the test suite runs at its speed).
# Usage: [FUZZ_BUILD=DIR] scripts/fuzz.sh TARGET|all [SECONDS=60]
#   targets: plan_fuzz schedule_fuzz samples_csv_fuzz instrument_config_fuzz sim_config_fuzz
#            usbtmc_fuzz http_api_fuzz modbus_reply_fuzz
set -euo pipefail
cd "$(dirname "$0")/.."
all=(plan_fuzz schedule_fuzz samples_csv_fuzz instrument_config_fuzz sim_config_fuzz usbtmc_fuzz
     http_api_fuzz modbus_reply_fuzz)
what=${1:?"usage: scripts/fuzz.sh TARGET|all [SECONDS]"} seconds=${2:-60}
if [[ "$what" == all ]]; then
  targets=("${all[@]}")
else
  [[ " ${all[*]} " == *" $what "* ]] || { echo "fuzz.sh: unknown target '$what' (${all[*]})" >&2; exit 2; }
  targets=("$what")
fi
build=${FUZZ_BUILD:-build-fuzz}
if [[ -z "${FUZZ_BUILD:-}" ]]; then
  scripts/install-deps.sh
  cmake -S . -B build-fuzz -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ -DGONIO_FUZZ=ON \
    -DGONIO_BUILD_TESTS=OFF -DGONIO_BUILD_BENCH=OFF -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
elif ! grep -q '^GONIO_FUZZ:BOOL=ON' "$build/CMakeCache.txt" 2>/dev/null; then
  echo "fuzz.sh: $build is not a tree configured with GONIO_FUZZ=ON" >&2
  exit 2
fi
cmake --build "$build" -j "$(nproc)" --target "${targets[@]}"
# Leaks in third-party libraries (GLib's type system) are suppressed as in sanitize.sh.
export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1
export LSAN_OPTIONS="suppressions=$PWD/scripts/lsan.supp:print_suppressions=0"
export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
failed=0
printf '| target | seconds | executions | crashes |\n|---|---|---|---|\n' > "$build/fuzz/summary.md"
for t in "${targets[@]}"; do
  mkdir -p "out/fuzz/$t"
  log="$build/fuzz/$t.log"
  rc=0
  "$build/fuzz/$t" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 \
    -print_final_stats=1 -artifact_prefix="out/fuzz/$t/" "out/fuzz/$t" "fuzz/corpus/$t" \
    > "$log" 2>&1 || rc=$?
  execs=$(awk '/stat::number_of_executed_units/ {print $2}' "$log")
  crashes=0
  if [[ $rc -ne 0 ]]; then
    crashes=1
    failed=1
    echo "fuzz.sh: $t crashed (exit $rc); the input is in out/fuzz/$t/:" >&2
    grep -E "ERROR|SUMMARY|==[0-9]+==" "$log" | head -20 >&2
  fi
  printf '| %s | %s | %s | %s |\n' "$t" "$seconds" "${execs:-?}" "$crashes" >> "$build/fuzz/summary.md"
done
cat "$build/fuzz/summary.md"
exit $failed
