#!/usr/bin/env bash
# alpha's coverage through the whole simulated instrument (issue #16): gonio-sim (the stages over
# Modbus, the camera through GigE Vision, the lamp monitor), the drivers, the engine, SQLite, the
# export and gonio-fit, RUNS times over one plan on one simulated bench. Each run is fitted at
# normal incidence and jointly; the table gives, per fit, how often alpha's 2-sigma interval
# covers the simulator's truth (config/sim.toml's alpha, or SIM_ALPHA), the mean bias in units of the
# mean sigma, and the spread of the pulls (alpha - truth) / sigma.
# Usage: [SIM_ALPHA=a] bench/instrument_coverage.sh BUILD_DIR RUNS [PLAN] [SPEED]
#   BUILD_DIR  where gonio-sim, gonio-acquire and gonio-fit were built (build-release from bench.sh)
#   PLAN       default config/plan_demo.toml;  SPEED  simulated seconds per real second, default 50
#   SIM_ALPHA  the simulated sample's width instead of config/sim.toml's (e.g. 0.023 for
#              bench/coverage/plan_antiglare.toml)
#   SIM_MODEL  the simulated sample's family, beckmann (default) or ggx; each run is fitted with
#              the same family (gonio-fit --model)
#   SIM_THICKNESS  the plate's thickness in mm, for the simulated sample and the catalogue's
#              specimens alike (the sphere centre then lies off the rough face unless 6)
#   SIM_SEED   the simulator's noise seed instead of config/sim.toml's 1: continue a stopped
#              series under another, since a fresh bench under the same seed draws from the same
#              sequence (frames that fall alike then repeat their noise)
#   COVERAGE_KEEP  a directory to keep each run's export and fit in (to refit them later), and
#              gonio-sim's truth.csv (what each frame saw: bench/coverage/truth_angles.py,
#              value_check.py, lamp_check.py, norm_check.py); one per series: a case run as
#              several series (a SIM_SEED each) is tabulated whole by
#              bench/coverage/coverage_table.py TRUTH KEEP1 KEEP2 ...
#   COVERAGE_COOL  the CCD's setpoint (C) before the first run, as config/schedule_demo.toml cools
#              it: default -10; "off" runs at ambient (20 C: dark current 2^(30/6) = 32 times,
#              whose error each exposure's dark set shares among its points; docs/measurement.md)
# Holds the GigE Vision port while it runs: no other simulated camera may run meanwhile.
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:?usage: bench/instrument_coverage.sh BUILD_DIR RUNS [PLAN] [SPEED]}
runs=${2:?usage: bench/instrument_coverage.sh BUILD_DIR RUNS [PLAN] [SPEED]}
plan=${3:-config/plan_demo.toml}
speed=${4:-50}
[[ "$runs" =~ ^[1-9][0-9]*$ ]] || { echo "instrument_coverage: RUNS must be a positive integer" >&2; exit 2; }
[[ -f "$plan" ]] || { echo "instrument_coverage: no plan file $plan" >&2; exit 2; }
work=$(mktemp -d)
sim_config=$work/sim.toml samples=$work/samples.toml
thickness="s/^thickness_mm = [0-9.]*/thickness_mm = ${SIM_THICKNESS:-6.0}/"
alpha=""
[[ -n "${SIM_ALPHA:-}" ]] && alpha="s/^alpha = [0-9.]*/alpha = $SIM_ALPHA/"
seed=""
[[ -z "${SIM_SEED:-}" ]] || [[ "$SIM_SEED" =~ ^[0-9]+$ ]] ||
  { echo "instrument_coverage: SIM_SEED must be a non-negative integer, not '$SIM_SEED'" >&2; exit 2; }
[[ -n "${SIM_SEED:-}" ]] && seed="0,/^seed = [0-9]*/s//seed = $SIM_SEED/"
family=${SIM_MODEL:-beckmann}
[[ "$family" == beckmann || "$family" == ggx ]] ||
  { echo "instrument_coverage: SIM_MODEL must be beckmann or ggx, not '$family'" >&2; exit 2; }
sed -e "$thickness" -e "s/^model = \"[a-z]*\"/model = \"$family\"/" ${alpha:+-e "$alpha"} \
  ${seed:+-e "$seed"} config/sim.toml > "$sim_config"
sed -e "$thickness" config/samples.toml > "$samples"
source tests/support/gonio_sim.sh
trap 'stop_gonio_sim; rm -rf "$work"' EXIT
[[ -z "${COVERAGE_KEEP:-}" ]] || { mkdir -p "$COVERAGE_KEEP"; COVERAGE_KEEP=$(realpath "$COVERAGE_KEEP"); }
start_gonio_sim "$build/sim/gonio-sim" "$speed" "$work" "$PWD" --config "$sim_config" \
  ${COVERAGE_KEEP:+--truth-log "$COVERAGE_KEEP/truth.csv"}
truth=$(sed -n 's/^alpha *= *\([0-9.]*\).*/\1/p' "$sim_config" | head -1)
cool=${COVERAGE_COOL:--10}
cool_label="at $cool C"
[[ "$cool" != off ]] || cool_label="uncooled (ambient)"
if [[ "$cool" != off ]]; then
  "$build/daemon/gonio-hw" -c "$work/instrument.toml" camera cool --setpoint "$cool" \
    --tolerance 0.5 --hold 5 --timeout 300 > "$work/cool.log" 2>&1 ||
    { echo "instrument_coverage: cooling the CCD failed:" >&2; cat "$work/cool.log" >&2; exit 1; }
fi
echo "# alpha's coverage through the whole simulated instrument"
echo
echo "$runs runs of \`$plan\` on gonio-sim at x$speed (config/sim.toml, $family alpha = $truth," \
  "a ${SIM_THICKNESS:-6.0} mm plate, the CCD $cool_label), fitted with \`gonio-fit --model $family\`. Command:" \
  "\`${COVERAGE_COOL:+COVERAGE_COOL=$COVERAGE_COOL }${SIM_MODEL:+SIM_MODEL=$SIM_MODEL }${SIM_ALPHA:+SIM_ALPHA=$SIM_ALPHA }${SIM_THICKNESS:+SIM_THICKNESS=$SIM_THICKNESS }${SIM_SEED:+SIM_SEED=$SIM_SEED }bench/instrument_coverage.sh $build $runs $plan $speed\`."
echo
for i in $(seq "$runs"); do
  "$build/daemon/gonio-acquire" -c "$work/instrument.toml" --samples "$samples" \
    --db "$work/runs.sqlite" run "$plan" > "$work/acquire.log" 2>&1 ||
    { echo "instrument_coverage: run $i failed:" >&2; tail -20 "$work/acquire.log" >&2; exit 1; }
  "$build/daemon/gonio-acquire" --db "$work/runs.sqlite" export "$i" --out "$work/run$i.csv" \
    > /dev/null
  "$build/fitting/gonio-fit" "$work/run$i.csv" --model "$family" --out "$work/fit$i" \
    > "$work/fit$i.txt" 2>&1 ||
    { echo "instrument_coverage: fit of run $i failed:" >&2; tail -20 "$work/fit$i.txt" >&2; exit 1; }
  if [[ -n "${COVERAGE_KEEP:-}" ]]; then
    mkdir -p "$COVERAGE_KEEP"
    cp -r "$work/run$i.csv" "$work/fit$i" "$work/fit$i.txt" "$COVERAGE_KEEP/"
  fi
  echo "run $i of $runs fitted" >&2
done
/usr/bin/python3 bench/coverage/coverage_table.py "$truth" "$work"
