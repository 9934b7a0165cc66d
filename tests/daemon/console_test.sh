#!/usr/bin/env bash
# The operator's console in headless Chromium against goniod on gonio-sim (issue #20):
# console_test.py says what it checks. Skips (exit 77) with a clear message only when no browser
# is installed; scripts/install-deps.sh installs it, so CI always runs it.
# Usage: console_test.sh GONIO_SIM GONIOD SOURCE_DIR WORKDIR
set -euo pipefail
sim=$1 goniod=$2 src=$3 work=$4
for need in /usr/bin/chromium /usr/bin/chromedriver; do
  [[ -x $need ]] || { echo "SKIP: $need is missing (scripts/install-deps.sh installs it)"; exit 77; }
done
/usr/bin/python3 -c "import selenium" 2>/dev/null ||
  { echo "SKIP: python3-selenium is missing (scripts/install-deps.sh installs it)"; exit 77; }
mkdir -p "$work"
rm -rf "${work:?}"/*
source "$src/tests/support/gonio_sim.sh"
daemon=""
fail() { echo "FAIL: $*" >&2; echo "--- goniod.log (its end)" >&2; tail -30 "$work/goniod.log" >&2 || true; exit 1; }
trap '[[ -n "$daemon" ]] && { kill -KILL $daemon 2>/dev/null || true; }; stop_gonio_sim' EXIT
# x10: a point takes about half a second, so the page sees points arrive and can pause between them.
start_gonio_sim "$sim" 10 "$work" "$src"
cat > "$work/console_plan.toml" <<'PLAN'
sample = "ground-glass-G1"
[geometry]
incidence_deg = [0, 30]
view_about = "refracted"
view_from_deg = -9
view_to_deg = 9
view_step_deg = 3
[exposure]
frames = 3
initial_s = 0.2
[rectangle]
x = 253
y = 246
width = 6
height = 19
PLAN
# The instrument's plans (goniod --plans): the same plan, and a schedule that names it without
# carrying it (the page takes it from there).
mkdir -p "$work/plans"
{ echo "# The console test's plan: two incidences, 14 points"; cat "$work/console_plan.toml"; } \
  > "$work/plans/console_plan.toml"
cat > "$work/console_schedule.toml" <<'SCHEDULE'
[[job]]
plan = "console_plan.toml"
repeat = 2
fit = ["beckmann"]
SCHEDULE
db="$work/runs.sqlite"
start_goniod "$goniod" "$work" "$src" "$db" --plans "$work/plans" || fail "goniod did not start"
/usr/bin/python3 "$src/tests/daemon/console_test.py" "$url" "$(cat "$db.token")" \
  "$work/console_plan.toml" "$work" "$work/console_schedule.toml" || fail "console_test.py"
kill -TERM "$daemon"
wait "$daemon" || fail "goniod did not exit cleanly"
daemon=""
echo "screenshots: $work/console_running.png $work/console_done.png"
