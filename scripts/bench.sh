#!/usr/bin/env bash
# Builds the benchmarks (Release) and runs them; writes JSON and charts to out/bench/.
# Not part of the test suite: figures depend on the machine, so report them as ratios.
# Usage: scripts/bench.sh [extra Google Benchmark flags, e.g. --benchmark_filter=G1]
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
cmake -S . -B build-release -DCMAKE_BUILD_TYPE=Release -DGONIO_BUILD_TESTS=OFF >/dev/null
cmake --build build-release -j "$(nproc)" --target optics_bench
mkdir -p out/bench
build-release/bench/optics_bench --benchmark_repetitions=5 --benchmark_report_aggregates_only=true \
  --benchmark_out=out/bench/optics.json --benchmark_out_format=json "$@"
# Debian's matplotlib is installed for the system interpreter (DESIGN.md, Python helpers).
/usr/bin/python3 bench/plot_g1_tradeoff.py out/bench/optics.json out/bench/g1_tradeoff.png
