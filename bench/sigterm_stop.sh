#!/usr/bin/env bash
# How long goniod takes to stop on SIGTERM (issue #18): N times, a run in the middle of its
# exposures (gonio-sim at x5, so a point's frames take about a second), then N/4 times with the
# instrument gone (gonio-sim killed mid-run). Prints the median and the maximum in ms, as a
# Markdown table. Holds the GigE Vision port: nothing else may run a simulated camera meanwhile.
#   bench/sigterm_stop.sh BUILD_DIR [N=20]
set -euo pipefail
build=$1 n=${2:-20}
src=$(cd "$(dirname "$0")/.." && pwd)
work=$(mktemp -d)
source "$src/tests/support/gonio_sim.sh"
daemon=""
trap '[[ -n "$daemon" ]] && kill -KILL $daemon 2>/dev/null; stop_gonio_sim; rm -rf "$work"' EXIT
cat > "$work/plan.toml" <<'PLAN'
sample = "ground-glass-G1"
[geometry]
incidence_deg = [0, 30]
view_about = "refracted"
view_from_deg = -12
view_to_deg = 12
view_step_deg = 3
[exposure]
frames = 4
initial_s = 0.2
[rectangle]
x = 253
y = 246
width = 6
height = 19
PLAN
one_stop() {  # $1: "gone" kills gonio-sim before the signal
  rm -f "$work"/runs.sqlite* "$work/goniod.log" "$work/port" "$work/mport"
  start_gonio_sim "$build/sim/gonio-sim" 5 "$work" "$src"
  start_goniod "$build/daemon/goniod" "$work" "$src" "$work/runs.sqlite" ||
    { echo "goniod did not start:" >&2; cat "$work/goniod.log" >&2; exit 1; }
  "$build/daemon/gonioctl" --url "$url" \
    --token-file "$work/runs.sqlite.token" submit "$work/plan.toml" > /dev/null
  for _ in $(seq 600); do
    [[ $(sqlite3 "$work/runs.sqlite" "select count(*) from measurements" 2>/dev/null || echo 0) -ge 2 ]] && break
    sleep 0.05
  done
  # A random moment within the next point's second of frames.
  sleep "0.$((RANDOM % 9 + 1))"
  if [[ "$1" == gone ]]; then stop_gonio_sim; sleep 1; fi
  local t0 t1
  t0=$(date +%s%N)
  kill -TERM $daemon
  wait $daemon || true
  t1=$(date +%s%N)
  daemon=""
  stop_gonio_sim
  echo $(((t1 - t0) / 1000000))
}
stats() { sort -n | awk '{a[NR]=$1} END {printf "%d | %d | %d", NR, a[int((NR+1)/2)], a[NR]}'; }
mid=$(for _ in $(seq "$n"); do one_stop running; done | stats)
gone=$(for _ in $(seq $(((n + 3) / 4))); do one_stop gone; done | stats)
echo "| SIGTERM | stops | median ms | max ms |"
echo "|---|---|---|---|"
echo "| mid-run | $mid |"
echo "| instrument gone | $gone |"
