#!/usr/bin/env bash
# The README's first command: the simulated instrument end to end.
#   1. installs what the machine lacks and builds what the demo runs (build/);
#   2. starts gonio-sim (stages over Modbus TCP, the cooled CCD over GigE Vision, the source
#      monitor) on 127.0.0.1 with an accelerated clock;
#   3. starts goniod (the daemon, its API on 127.0.0.1) on that instrument and, with gonioctl,
#      runs the default schedule (config/schedule_demo.toml): cool the CCD, measure the simulated
#      ground glass at theta_i = 0, 30, 60, 80 degrees, fit Beckmann and GGX after the run (stored
#      with it); then exports the run (SQLite: out/demo/runs.sqlite);
#   4. fits Beckmann and GGX at normal incidence with gonio-fit, prints the table like Walter
#      2007's Figure 12 beside the simulator's true values, and writes the plot;
#   5. stops everything it started.
# Usage: scripts/demo.sh [--real-time] [--speed N]     (default: x50 simulated time)
set -euo pipefail
cd "$(dirname "$0")/.."

speed=50
while [[ $# -gt 0 ]]; do
  case "$1" in
    --real-time) speed=1 ;;
    --speed) speed=$2; shift ;;
    *) echo "demo.sh: unknown argument '$1' (known: --real-time, --speed N)" >&2; exit 2 ;;
  esac
  shift
done

scripts/install-deps.sh
work=out/demo
mkdir -p "$work"
echo "== building gonio-sim, goniod, gonioctl, gonio-fit (log: $work/build.log) =="
if ! { cmake -S . -B build -DGONIO_WERROR=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo &&
       cmake --build build -j "$(nproc)" --target gonio-sim goniod gonioctl gonio-fit; } \
     > "$work/build.log" 2>&1; then
  tail -30 "$work/build.log"
  echo "demo.sh: the build failed (log: $work/build.log)" >&2
  exit 1
fi
rm -f "$work"/runs.sqlite* "$work"/*.csv "$work"/port "$work"/mport "$work"/apiport
if pgrep -x gonio-sim >/dev/null; then
  echo "demo.sh: a gonio-sim is already running; the simulated camera's GigE port is taken" >&2
  exit 1
fi

echo "== starting the simulated instrument (clock x$speed) =="
build/sim/gonio-sim --config config/sim.toml --speed "$speed" --port 0 --port-file "$work/port" \
  --monitor-port 0 --monitor-port-file "$work/mport" > "$work/gonio-sim.log" 2>&1 &
sim=$!
daemon=""
stop_all() {
  [[ -n "$daemon" ]] && { kill -TERM "$daemon" 2>/dev/null || true; wait "$daemon" 2>/dev/null || true; }
  kill "$sim" 2>/dev/null || true
  wait "$sim" 2>/dev/null || true
}
trap stop_all EXIT
for _ in $(seq 200); do [[ -s "$work/port" ]] && break; sleep 0.05; done
[[ -s "$work/port" ]] || { echo "gonio-sim did not start:"; cat "$work/gonio-sim.log"; exit 1; }
head -1 "$work/gonio-sim.log"
sed -e "s/^port = 5020/port = $(cat "$work/port")/" -e "s/^port = 5021/port = $(cat "$work/mport")/" \
  config/instrument.toml > "$work/instrument.toml"

echo "== starting the daemon (goniod; log in $work/goniod.log) =="
# The instrument's plans, which the console offers: the example plans.
mkdir -p "$work/plans"
cp config/plan_*.toml "$work/plans/"
build/daemon/goniod -c "$work/instrument.toml" --samples config/samples.toml \
  --plans "$work/plans" --db "$work/runs.sqlite" --port 0 --port-file "$work/apiport" > "$work/goniod.log" 2>&1 &
daemon=$!
for _ in $(seq 300); do [[ -s "$work/apiport" ]] && break; sleep 0.05; done
[[ -s "$work/apiport" ]] || { echo "goniod did not start:"; cat "$work/goniod.log"; exit 1; }
echo "the console: http://127.0.0.1:$(cat "$work/apiport")/console/ (open it in a browser to watch the run)"
ctl() {
  build/daemon/gonioctl --url "http://127.0.0.1:$(cat "$work/apiport")" \
    --token-file "$work/runs.sqlite.token" "$@"
}

echo "== the default schedule (gonioctl schedule config/schedule_demo.toml) =="
ctl schedule config/schedule_demo.toml --dry-run
start=$(date +%s)
ctl schedule config/schedule_demo.toml --wait
took=$(($(date +%s) - start))
# What run 1 exposed beside what the first dry run priced it at (on a new database: from the
# instrument config's [throughput]).
ctl show 1 | sed -n '1,/^theta_l/p' | sed '$d'
echo "== the same schedule priced again, now from run 1's exposures =="
ctl schedule config/schedule_demo.toml --dry-run
echo "(run 1 took ${took} s of wall time at the simulator's x$speed clock:" \
  "about $((took * speed)) s of bench time, cooling included)"
ctl export 1 --out "$work/run1.csv" > /dev/null  # named in the last line

echo "== fitting (gonio-fit): normal incidence, then the other incidences predicted =="
# Huber: the bench's stray-light floor flattens the far tails; a robust loss keeps it from
# pulling the width (docs/fitting.md).
build/fitting/gonio-fit "$work/run1.csv" --model beckmann,ggx --loss huber --out "$work/fit" |
  tee "$work/fit.txt"
model=$(sed -n 's/^model *= *"\(.*\)".*/\1/p' config/sim.toml | head -1)
alpha=$(sed -n 's/^alpha *= *\([0-9.]*\).*/\1/p' config/sim.toml | head -1)
eta=$(sed -n 's/^eta *= *\([0-9.]*\).*/\1/p' config/sim.toml | head -1)
echo "== the simulator's true sample: $model, alpha = $alpha, eta = $eta (config/sim.toml) =="

/usr/bin/python3 fitting/tools/plot_fit.py "$work/fit" "$work/fit.png"
echo "demo: data in $work/runs.sqlite (the schedule's fits: gonioctl fits 1), samples in" \
  "$work/run1.csv, fits in $work/fit/, plot $work/fit.png"
