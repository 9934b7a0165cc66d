#!/usr/bin/env bash
# Builds the benchmarks (Release) and runs them; writes JSON and charts to out/bench/.
# Not part of the test suite: figures depend on the machine, so report them as ratios.
#   optics_bench     D, G1, BTDF evaluation rates  -> optics.json, g1_tradeoff.png
#   fit_bench        time per fit, per model       -> fit.json
#   fit_tradeoff     fitter variants               -> fit_tradeoff.json, fit_tradeoff.png
#   scipy_peer.py    scipy least_squares vs gonio  -> scipy_peer.json
#   truth_bench      ground-truth cost/accuracy and the single-scattering failure map
#                                                  -> truth.json, truth_cost.png, truth_failure.png
#   acquisition_sweep  the engine's efficiency on the simulated instrument -> acquisition_sweep.md
#   api_latency      goniod's /status latency under load during a sweep, and the sweep's slowdown
#                                                  -> api_latency.md
#   sigterm_stop.sh  goniod's stop time on SIGTERM mid-run and with the instrument gone
#                                                  -> sigterm_stop.md
#   rtu_polling      stage polling on a 115200-baud RTU line: sweep time and line load per poll
#                    interval                      -> rtu_polling.md
#   measurement_tradeoff  fit time against alpha bias and coverage: point model, rectangle,
#                    rectangle + apertures, on Figure 12's samples; where the ray budget holds
#                    a sample also with the held error's conservative way and without the budget
#                                                  -> measurement_tradeoff.md, .png
#   instrument_coverage.sh  alpha's 2-sigma coverage, bias and pull spread through the whole
#                    simulated instrument (gonio-sim, drivers, engine, SQLite, gonio-fit): ground
#                    glass (the demo's plan), frosted, etched and antiglare (its auto rectangle),
#                    each with a Beckmann and a GGX truth on 3, 6 and 9 mm plates (24 cases), and
#                    antiglare under a fixed 3 x 10 mm rectangle with either truth (26 cases); not
#                    in the default set:
#                    COVERAGE_RUNS (default 20) runs of 2-5 minutes per case (antiglare_3x10
#                    and antiglare_ggx_3x10: about 10-11, of which 6-7 the fit, its samples held
#                    to the ray budget, docs/measurement.md), about a day for all; COVERAGE_CASES
#                    picks some, SIM_SEED adds fresh runs to a case's earlier series
#                                  -> coverage_<case>.md, coverage/<case>/seed<N>/ (each run kept)
#   acquire_strategies  bench time against alpha error for uniform, lobe and adaptive runs on a
#                    point-level bench, ground, etched and antiglare glass
#                                                  -> acquire.md, acquire.json, acquire.png
#   verdicts.sh      each fit's status word over VERDICT_RUNS (default 20) runs of the demo's plan
#                    at normal incidence through the instrument, and the new database's first
#                    estimate beside its run's exposure           -> verdicts.md
#   forecast_spread  the adaptive forecast made before a first run against FORECAST_RUNS (default
#                    8) real adaptive runs of the ground glass on the simulated instrument, one per
#                    noise seed                    -> forecast_spread.md
# Usage: scripts/bench.sh [optics|fit|tradeoff|peer|truth|scene|measure|coverage|acquire|forecast|sweep|api|stop|verdicts|rtu|soak ...]
#        MEASURE_REPEATS=N sets measure's noise draws per case (default 20); MEASURE_SAMPLE=text
#        runs the cases whose "sample family mm WxH" holds it alone (ground, frosted, etched,
#        antiglare; 2x2 for antiglare's small rectangle, 19x62 for its 3 x 10 mm one);
#        MEASURE_NOISE=x scales its noise (a bias of order sigma^2 grows in sigma with it, chance
#        does not), MEASURE_SEED=N draws other noise, MEASURE_WAYS="full ..." runs those ways
#        COVERAGE_RUNS=N sets coverage's whole-instrument runs per case (default 20);
#        COVERAGE_CASES="ground antiglare_3x10 ..." runs those cases alone: sample[_ggx][_3mm|_9mm]
#        for sample ground, frosted, etched or antiglare (a Beckmann truth on a 6 mm plate unless
#        named), antiglare_3x10 and antiglare_ggx_3x10; SIM_SEED=N adds a series of fresh runs to
#        a case's earlier ones (out/bench/coverage/CASE/seedN), tabulated together in
#        out/bench/coverage_CASE.md
#        ACQUIRE_REPEATS=N sets acquire's simulated runs per row (default 100)
#        FORECAST_RUNS=N sets forecast's real adaptive runs (default 8)
#        (default: all but coverage and soak)
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
cmake -S . -B build-release -DCMAKE_BUILD_TYPE=Release -DGONIO_BUILD_TESTS=OFF >/dev/null
cmake --build build-release -j "$(nproc)"
mkdir -p out/bench
parts=("$@")
[[ ${#parts[@]} -eq 0 ]] && parts=(optics fit tradeoff peer truth scene measure acquire forecast sweep api stop verdicts rtu)
# Debian's matplotlib/scipy are installed for the system interpreter (docs/design.md, Python helpers).
py=/usr/bin/python3
for part in "${parts[@]}"; do
  case "$part" in
    optics)
      build-release/bench/optics_bench --benchmark_repetitions=5 \
        --benchmark_report_aggregates_only=true \
        --benchmark_out=out/bench/optics.json --benchmark_out_format=json
      $py bench/plot_g1_tradeoff.py out/bench/optics.json out/bench/g1_tradeoff.png ;;
    fit)
      build-release/bench/fit_bench --benchmark_repetitions=5 \
        --benchmark_report_aggregates_only=true \
        --benchmark_out=out/bench/fit.json --benchmark_out_format=json ;;
    tradeoff)
      build-release/bench/fit_tradeoff out/bench/fit_tradeoff.json 40
      $py bench/plot_fit_tradeoff.py out/bench/fit_tradeoff.json out/bench/fit_tradeoff.png ;;
    peer)
      $py bench/scipy_peer.py build-release out/bench/scipy_peer.json ;;
    truth)
      build-release/bench/truth_bench out/bench/truth.json
      $py bench/plot_truth.py out/bench/truth.json out/bench/truth_cost.png \
        out/bench/truth_failure.png ;;
    scene)
      build-release/bench/scene_rectangle | tee out/bench/scene_rectangle.md ;;
    measure)
      build-release/bench/measurement_tradeoff "${MEASURE_REPEATS:-20}" ${MEASURE_SAMPLE:+"$MEASURE_SAMPLE"} \
        | tee out/bench/measurement_tradeoff.md
      $py bench/plot_measure.py out/bench/measurement_tradeoff.png out/bench/measurement_tradeoff.md ;;
    coverage)  # holds the GigE Vision port: no other simulated camera may run meanwhile
      # The cross of issue #16: each Figure 12 sample (its plan, then Walter's Beckmann and GGX
      # widths, docs/reference.md) with both truths on 6, 3 and 9 mm plates, named
      # sample[_ggx][_3mm|_9mm]; and antiglare under a fixed 3 x 10 mm rectangle.
      cases=()
      for s in "ground|config/plan_demo.toml|0.344|0.394" \
        "frosted|bench/coverage/plan_frosted.toml|0.400|0.454" \
        "etched|bench/coverage/plan_etched.toml|0.493|0.553" \
        "antiglare|bench/coverage/plan_antiglare.toml|0.023|0.027"; do
        IFS='|' read -r sample plan beckmann ggx <<< "$s"
        for family in beckmann ggx; do
          alpha=$beckmann suffix=""
          [[ $family == beckmann ]] || { alpha=$ggx suffix=_ggx; }
          for mm in 6 3 9; do
            name=$sample$suffix
            [[ $mm == 6 ]] || name=${name}_${mm}mm
            cases+=("$name|SIM_MODEL=$family SIM_ALPHA=$alpha SIM_THICKNESS=$mm.0|$plan")
          done
        done
      done
      cases+=("antiglare_3x10|SIM_ALPHA=0.023|bench/coverage/plan_antiglare_3x10.toml")
      cases+=("antiglare_ggx_3x10|SIM_MODEL=ggx SIM_ALPHA=0.027|bench/coverage/plan_antiglare_3x10.toml")
      names=" ${cases[*]%%|*} "
      wanted=" ${COVERAGE_CASES:-$names} "
      # Each series is kept under its seed, so a case run as several series (a stopped one
      # continued under another SIM_SEED) is tabulated whole; the same seed again would repeat
      # the same noise, so it is refused (before any case runs) rather than counted twice.
      for w in $wanted; do
        [[ "$names" == *" $w "* ]] ||
          { echo "bench.sh: unknown coverage case '$w' (${cases[*]%%|*})" >&2; exit 2; }
        ! compgen -G "out/bench/coverage/$w/seed${SIM_SEED:-1}/fit*" > /dev/null ||
          { echo "bench.sh: out/bench/coverage/$w/seed${SIM_SEED:-1} holds a series of case" \
              "$w already: set SIM_SEED to another seed to add fresh runs, or remove it" >&2
            exit 2; }
      done
      for c in "${cases[@]}"; do
        IFS='|' read -r name sample plan <<< "$c"
        [[ "$wanted" == *" $name "* ]] || continue
        truth=${sample#*SIM_ALPHA=} truth=${truth%% *}  # the simulated width, from the case
        keep=out/bench/coverage/$name/seed${SIM_SEED:-1}
        mkdir -p "$keep"
        env $sample COVERAGE_KEEP="$keep" bench/instrument_coverage.sh build-release \
          "${COVERAGE_RUNS:-20}" "$plan" | tee "out/bench/coverage/$name/seed${SIM_SEED:-1}.md"
        { echo "# $name: every series in out/bench/coverage/$name"; echo
          $py bench/coverage/coverage_table.py "$truth" out/bench/coverage/"$name"/seed*/; } \
          | tee "out/bench/coverage_$name.md"
      done ;;
    acquire)
      build-release/bench/acquire_strategies "${ACQUIRE_REPEATS:-100}" out/bench/acquire.json \
        | tee out/bench/acquire.md
      $py bench/plot_acquire.py out/bench/acquire.json out/bench/acquire.png ;;
    forecast)  # holds the GigE Vision port: no other simulated camera may run meanwhile
      build-release/bench/forecast_spread "${FORECAST_RUNS:-8}" | tee out/bench/forecast_spread.md ;;
    sweep)  # holds the GigE Vision port: no other simulated camera may run meanwhile
      build-release/bench/acquisition_sweep 5 10 | tee out/bench/acquisition_sweep.md ;;
    api)    # goniod's API under load during a sweep; holds the GigE Vision port too
      build-release/bench/api_latency 50 2 100 | tee out/bench/api_latency.md ;;
    stop)   # goniod SIGTERM'd 20 times mid-run and 5 times with gonio-sim gone; GigE port too
      bench/sigterm_stop.sh build-release 20 | tee out/bench/sigterm_stop.md ;;
    verdicts)  # VERDICT_RUNS (default 20) runs through the instrument, about 40 s each; GigE port
      bench/verdicts.sh build-release "${VERDICT_RUNS:-20}" | tee out/bench/verdicts.md ;;
    rtu)    # three axes on a simulated 115200-baud RS-485 line, real time (about 40 s)
      build-release/bench/rtu_polling 115200 10 | tee out/bench/rtu_polling.md ;;
    soak)   # not in the default set: 10,000 points, several minutes
      build-release/bench/acquisition_sweep soak 10000 100 | tee out/bench/acquisition_soak.md ;;
    *) echo "bench.sh: unknown part '$part' (optics, fit, tradeoff, peer, truth, scene, measure, coverage, acquire, forecast, sweep, api, stop, verdicts, rtu, soak)" >&2
       exit 2 ;;
  esac
done
