#!/usr/bin/env bash
# A run killed with SIGKILL at random moments, again and again, then resumed, ends with the same
# points as an uninterrupted run: none twice, none missing, each value within its uncertainty of
# the uninterrupted run's (the noise differs, the data must not). Then SIGINT pauses cleanly and a
# second one stops the point in hand, a power cycle of the instrument mid-run is waited out (the
# run measures again by itself), and signals with the instrument gone stop it within seconds.
# Usage: kill_resume_test.sh GONIO_SIM GONIO_ACQUIRE SOURCE_DIR WORKDIR
set -euo pipefail
sim=$1 acq=$2 src=$3 work=$4
mkdir -p "$work"
rm -f "$work"/*
source "$src/tests/support/gonio_sim.sh"
trap stop_gonio_sim EXIT
start_gonio_sim "$sim" 40 "$work" "$src"
# Each resume waits out the killed process's hold on the camera (its heartbeat timeout + 3 s):
# 5 s instead of the example's 10 keeps four kills 20 s shorter. Aravis sends a heartbeat every
# second, so five may be missed before the camera drops a live controller.
sed -i 's/^heartbeat_timeout_s = 10 /heartbeat_timeout_s = 5 /' "$work/instrument.toml"
grep -q '^heartbeat_timeout_s = 5 ' "$work/instrument.toml" ||
  { echo "the example config's heartbeat_timeout_s line changed; update this test"; exit 1; }
cat > "$work/plan.toml" <<'PLAN'
sample = "ground-glass-G1"
[geometry]
incidence_deg = [0, 30, 60]
view_about = "refracted"
view_from_deg = -6
view_to_deg = 6
view_step_deg = 3
[exposure]
frames = 3
initial_s = 0.05
[rectangle]
x = 253
y = 246
width = 6
height = 19
PLAN
acq() { "$acq" -c "$work/instrument.toml" --samples "$src/config/samples.toml" "$@"; }
# In the background, the program itself (not a subshell running a function) must get the
# signals: start it directly and keep its pid.
start() {
  local log=$1
  shift
  "$acq" -c "$work/instrument.toml" --samples "$src/config/samples.toml" "$@" >> "$log" 2>&1 &
  victim=$!
}
q() { sqlite3 "$1" "$2"; }

# The reference: one uninterrupted run, with the CCD cooled first (--cool) as a lab measures.
acq --db "$work/ref.sqlite" --cool -10 --cool-hold 1 run "$work/plan.toml" > "$work/ref.log"
total=$(q "$work/ref.sqlite" "select count(*) from plan_points")
[[ $(q "$work/ref.sqlite" "select count(*) from measurements where abs(temperature_c + 10) > 0.5") == 0 ]] ||
  { echo "--cool -10: points measured away from -10 C"; cat "$work/ref.log"; exit 1; }
[[ $(q "$work/ref.sqlite" "select detail from run_events where kind = 'cooled'") == "sensor held at -10 C" ]] ||
  { echo "--cool: the run does not say it was cooled"; exit 1; }
# A cooling that cannot hold in time fails (exit 1), naming the temperature, and creates no run.
set +e
acq --db "$work/cool.sqlite" --cool -10 --cool-hold 30 --cool-timeout 1 run "$work/plan.toml" \
  > "$work/cool.log" 2>&1
rc=$?
set -e
[[ $rc == 1 ]] || { echo "--cool timing out gave exit $rc, expected 1"; cat "$work/cool.log"; exit 1; }
grep -q "not held for 30" "$work/cool.log" || { echo "the timeout was not named:"; cat "$work/cool.log"; exit 1; }
[[ $(q "$work/cool.sqlite" "select count(*) from runs") == 0 ]] ||
  { echo "--cool timing out left a run behind"; exit 1; }

# The victim: killed at random moments, resumed each time. A resume first waits out the dead
# process's hold on the camera (the GigE Vision heartbeat timeout it set, 10 s), then measures.
# Kills the victim after each delay while it lives, resuming it each time, then waits for the
# last resume; sets landed to the number of kills.
# Usage: kill_and_resume LOG DB DELAY...
kill_and_resume() {
  local log=$1 db=$2
  shift 2
  landed=0
  for delay in "$@"; do
    sleep "$delay"
    kill -0 $victim 2>/dev/null || break
    kill -KILL $victim
    wait $victim 2>/dev/null || true
    landed=$((landed + 1))
    start "$log" --db "$db" resume
  done
  wait $victim || { echo "the last resume failed:"; tail -5 "$log"; exit 1; }
}
# The kills' delays count from the run's creation: a kill before it leaves nothing to resume,
# which is right, and the test would count no points (the CI's ASan build on a loaded host was
# killed 1.3 s after its start with no run stored yet). Waits up to 30 s for the run's row.
# Usage: wait_for_run LOG DB
wait_for_run() {
  local log=$1 db=$2
  for _ in $(seq 300); do
    # (-s first: sqlite3 must not create the file the run is about to)
    [[ -s "$db" && $(q "$db" "select count(*) from runs" 2>/dev/null || echo 0) == 1 ]] && return 0
    kill -0 $victim 2>/dev/null || { echo "the run ended before it was stored:"; cat "$log"; exit 1; }
    sleep 0.1
  done
  echo "no run stored 30 s after its start:"
  cat "$log"
  exit 1
}
# Waits until DB has stored N points (up to 30 s); as wait_for_run, never creates DB.
# Usage: wait_points DB N
wait_points() {
  local db=$1 n=$2
  for _ in $(seq 600); do
    [[ -s "$db" && $(q "$db" "select count(*) from measurements" 2>/dev/null || echo 0) -ge $n ]] &&
      return 0
    sleep 0.05
  done
  echo "$db: fewer than $n points after 30 s"; exit 1
}
start "$work/kill.log" --db "$work/kill.sqlite" run "$work/plan.toml"
wait_for_run "$work/kill.log" "$work/kill.sqlite"
kill_and_resume "$work/kill.log" "$work/kill.sqlite" 1.3 4.4 3.9 4.8
kills=$landed
done_points=$(q "$work/kill.sqlite" "select count(*) from measurements")
[[ $done_points == "$total" ]] || { echo "kill.sqlite has $done_points of $total"; exit 1; }
[[ $(q "$work/kill.sqlite" "select count(*) from plan_points where status <> 'done'") == 0 ]]
[[ $(q "$work/kill.sqlite" "select status from runs") == done ]]
(( kills >= 2 )) || { echo "only $kills kills landed: the run was too fast to interrupt"; exit 1; }
# Point for point: the same geometry, values within 5 combined sigma.
differ=$(q "$work/kill.sqlite" "attach '$work/ref.sqlite' as ref;
  select count(*) from measurements k join ref.measurements r using (idx)
  where abs(k.value - r.value) > 5 * sqrt(k.sigma * k.sigma + r.sigma * r.sigma)
     or abs(k.arm_read_deg - r.arm_read_deg) > 0.01")
[[ $differ == 0 ]] || { echo "$differ points differ from the uninterrupted run"; exit 1; }
resumes=$(q "$work/kill.sqlite" "select count(*) from run_events where kind = 'resumed'")

# SIGINT pauses after the current point; resume finishes; exit codes tell scripts which.
start "$work/int.log" --db "$work/int.sqlite" run "$work/plan.toml"
sleep 3
kill -INT $victim
set +e
wait $victim
rc=$?
set -e
[[ $rc == 3 ]] || { echo "SIGINT gave exit $rc, expected 3 (paused)"; cat "$work/int.log"; exit 1; }
[[ $(q "$work/int.sqlite" "select status from runs") == paused ]]
acq --db "$work/int.sqlite" resume 1 >> "$work/int.log"
[[ $(q "$work/int.sqlite" "select count(*) from measurements") == "$total" ]]

# A second SIGINT does not wait for the point in hand: on the flank, where each of its frames is
# a 20 s exposure (0.5 s here), the signals land just after a point is stored, and the next one is
# abandoned (its event says so), the run paused within a second or two.
# The test's plan moved to the flank of one incidence, at the longest exposure from the start.
sed -e 's/^incidence_deg = .*/incidence_deg = [0]/' -e 's/^view_from_deg = .*/view_from_deg = -20/' \
  -e 's/^view_to_deg = .*/view_to_deg = -15/' -e 's/^view_step_deg = .*/view_step_deg = 2.5/' \
  -e 's/^frames = .*/frames = 4/' -e 's/^initial_s = .*/initial_s = 20\nmax_s = 20/' \
  "$work/plan.toml" > "$work/long.toml"
grep -q '^max_s = 20$' "$work/long.toml" || { echo "the test's plan changed; update this test"; exit 1; }
start "$work/long.log" --db "$work/long.sqlite" run "$work/long.toml"
wait_points "$work/long.sqlite" 1
kill -INT $victim
sleep 0.2
t0=$(date +%s%N)
kill -INT $victim
rc=0
wait $victim || rc=$?
twice_live_ms=$((($(date +%s%N) - t0) / 1000000))
[[ $rc == 3 ]] || { echo "two SIGINTs gave exit $rc, expected 3"; cat "$work/long.log"; exit 1; }
[[ $(q "$work/long.sqlite" "select status from runs") == paused ]]
[[ $(q "$work/long.sqlite" "select count(*) from run_events where detail like 'interrupted during point%'") == 1 ]] ||
  { echo "the second SIGINT did not interrupt the point in hand"; cat "$work/long.log"; exit 1; }
((twice_live_ms < 2000)) ||
  { echo "the second SIGINT took $twice_live_ms ms to stop the point in hand"; exit 1; }

# The instrument power-cycled mid-run (gonio-sim stopped, gone 2 s, started again on its ports):
# gonio-acquire waits for it and measures again by itself, as goniod does, saying so once each
# way; its points agree with the uninterrupted run's. Once it measures again, a signal pauses it
# after the point in hand as usual (not at once, as during the outage); a resume finishes it.
start "$work/cycle.log" --db "$work/cycle.sqlite" --retry-s 0.5 run "$work/plan.toml"
wait_points "$work/cycle.sqlite" 2
stop_gonio_sim
sleep 2
restart_gonio_sim "$sim" 40 "$work"
for _ in $(seq 1200); do grep -q "^measuring again" "$work/cycle.log" && break; sleep 0.05; done
kill -INT $victim
set +e
wait $victim
rc=$?
set -e
[[ $rc == 3 ]] || { echo "after a power cycle, SIGINT: exit $rc"; tail -5 "$work/cycle.log"; exit 1; }
[[ $(q "$work/cycle.sqlite" "select count(*) from run_events where detail like 'stopped at once%'
      or detail like 'interrupted during point%'") == 0 ]] ||
  { echo "a signal after the outage stopped the point in hand"; cat "$work/cycle.log"; exit 1; }
acq --db "$work/cycle.sqlite" resume >> "$work/cycle.log" ||
  { echo "the resume after the power cycle failed"; tail -5 "$work/cycle.log"; exit 1; }
[[ $(grep -c "^device fault, run 1 paused " "$work/cycle.log") -ge 1 ]] ||
  { echo "the outage was not reported:"; cat "$work/cycle.log"; exit 1; }
[[ $(grep -c "^measuring again after " "$work/cycle.log") == 1 ]] ||
  { echo "the outage's end was not reported once:"; cat "$work/cycle.log"; exit 1; }
[[ $(q "$work/cycle.sqlite" "select count(*), count(distinct idx) from measurements") == "$total|$total" ]]
differ=$(q "$work/cycle.sqlite" "attach '$work/ref.sqlite' as ref;
  select count(*) from measurements k join ref.measurements r using (idx)
  where abs(k.value - r.value) > 5 * sqrt(k.sigma * k.sigma + r.sigma * r.sigma)")
[[ $differ == 0 ]] || { echo "$differ points measured across the power cycle differ"; exit 1; }

# An adaptive run (issue #17) killed at random moments resumes to a complete run: its decisions
# are stored with the points they chose, so none is made twice or lost, and each chosen point is
# logged once, with its reason; the run says why it stopped, once.
cat > "$work/adaptive.toml" <<'PLAN'
sample = "ground-glass-G1"
[geometry]
incidence_deg = [0]
view_about = "refracted"
view_from_deg = -30
view_to_deg = 30
view_step_deg = 3
[exposure]
frames = 2
initial_s = 0.05
max_s = 2
[strategy]
kind = "adaptive"
coarse_every = 3
batch = 3
budget_s = 60
[rectangle]
x = 253
y = 246
width = 6
height = 19
PLAN
ad=$work/adaptive.sqlite
start "$work/adaptive.log" --db "$ad" run "$work/adaptive.toml"
wait_for_run "$work/adaptive.log" "$ad"
kill_and_resume "$work/adaptive.log" "$ad" 2.1 3.7 5.3
akills=$landed
[[ $(q "$ad" "select status from runs") == done ]]
[[ $(q "$ad" "select count(*) from plan_points where status = 'pending'") == 0 ]]
chosen=$(q "$ad" "select count(*) from plan_points where predicted_s is not null")
(( chosen >= 3 )) || { echo "the adaptive run chose $chosen points"; cat "$work/adaptive.log"; exit 1; }
# Every chosen point measured, and named by exactly one 'chosen' event; no event without a point.
[[ $(q "$ad" "select count(*) from plan_points p where predicted_s is not null and status = 'done'
  and (select count(*) from run_events e where e.kind = 'chosen'
       and e.detail like 'point ' || p.idx || ': %') = 1") == "$chosen" ]] ||
  { echo "chosen points and their events do not match one to one"; exit 1; }
[[ $(q "$ad" "select count(*) from run_events where kind = 'chosen'") == "$chosen" ]]
[[ $(q "$ad" "select count(*) from run_events where kind = 'adaptive'") == 1 ]] ||
  { echo "the adaptive run's stop was not logged once"; exit 1; }
(( akills >= 1 )) || { echo "no kill landed in the adaptive run"; exit 1; }
why=$(q "$ad" "select detail from run_events where kind = 'adaptive'")

# Signals with the instrument gone: gonio-acquire does not wait on devices that do not answer
# (it once ignored SIGTERM for many seconds, held by the camera's reconnects). A second signal
# stops the point in hand; one while a device fault is waited out does too. Either way it exits 3
# within seconds with the run paused (interrupted, or after 2 s without the thread a device holds),
# and a resume on the instrument back finishes it.
# Sends SIGTERM and checks that the victim stopped within 8 s (2 s for the point in hand, 1.5 s for
# the stages' STOP, and a loaded CI's slack), exit 3, its run in DB paused; sets ms (from the
# signal to the exit). WHAT names the case in a failure, which shows LOG.
# Usage: term_stops LOG DB WHAT
term_stops() {
  local log=$1 db=$2 what=$3 t0 rc=0
  t0=$(date +%s%N)
  kill -TERM $victim 2>/dev/null || true
  wait $victim || rc=$?
  ms=$((($(date +%s%N) - t0) / 1000000))
  [[ $rc == 3 ]] || { echo "$what: exit $rc, expected 3"; cat "$log"; exit 1; }
  ((ms < 8000)) || { echo "$what: $ms ms to stop"; cat "$log"; exit 1; }
  [[ $(q "$db" "select status from runs") == paused ]] ||
    { echo "$what: the run is $(q "$db" "select status from runs"), not paused"; exit 1; }
}
gone=$work/gone.sqlite
start "$work/gone.log" --db "$gone" --retry-s 0.5 run "$work/plan.toml"
wait_points "$gone" 2
stop_gonio_sim
sleep 0.5
kill -TERM $victim  # the first: pause after the point in hand, which waits on the camera
sleep 1
term_stops "$work/gone.log" "$gone" "a second signal with the instrument gone"
twice_ms=$ms
restart_gonio_sim "$sim" 40 "$work"
start "$work/gone.log" --db "$gone" --retry-s 0.5 resume
wait_points "$gone" 4
stop_gonio_sim
for _ in $(seq 1200); do grep -q "^device fault" "$work/gone.log" && break; sleep 0.05; done
grep -q "^device fault" "$work/gone.log" ||
  { echo "the instrument's loss was not reported within 60 s"; cat "$work/gone.log"; exit 1; }
sleep 0.5
term_stops "$work/gone.log" "$gone" "a signal while a device fault is waited out"
restart_gonio_sim "$sim" 40 "$work"
acq --db "$gone" resume >> "$work/gone.log" ||
  { echo "the resume after the signals failed"; tail -5 "$work/gone.log"; exit 1; }
[[ $(q "$gone" "select count(*), count(distinct idx) from measurements") == "$total|$total" ]] ||
  { echo "after the signals and a resume: $(q "$gone" "select count(*) from measurements") of $total"; exit 1; }

echo "$kills kills, $resumes resumes: $total points, none lost or repeated, all within 5 sigma;" \
  "a power cycle mid-run waited out; an adaptive run killed $akills times chose $chosen points," \
  "each logged once, and stopped: $why; with the instrument gone, two signals stopped it in" \
  "$twice_ms ms and one during a device fault in $ms ms; with it there, two in $twice_live_ms ms"

