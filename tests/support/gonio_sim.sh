# Sourced by the shell tests that need the simulated instrument as a separate process.
# start_gonio_sim SIM SPEED WORK SRC [gonio-sim options...]: starts gonio-sim on 127.0.0.1 (free ports, written to
# WORK/port and WORK/mport), waits until it listens, writes WORK/instrument.toml (the example
# config pointed at those ports) and sets sim_pid. The program itself is the background job, so
# signals sent to $sim_pid reach it (not a subshell); the caller's EXIT trap should kill it.
start_gonio_sim() {
  local sim=$1 speed=$2 work=$3 src=$4
  shift 4
  "$sim" "$@" --speed "$speed" --port 0 --port-file "$work/port" --monitor-port 0 \
    --monitor-port-file "$work/mport" > "$work/sim.log" 2>&1 &
  sim_pid=$!
  for _ in $(seq 200); do [[ -s "$work/port" && -s "$work/mport" ]] && break; sleep 0.05; done
  [[ -s "$work/port" ]] || { echo "gonio-sim did not start:" >&2; cat "$work/sim.log" >&2; return 1; }
  sed -e "s/^port = 5020/port = $(cat "$work/port")/" \
    -e "s/^port = 5021/port = $(cat "$work/mport")/" \
    "$src/config/instrument.toml" > "$work/instrument.toml"
}

# stop_gonio_sim: SIGTERM, then waits for it to exit (it lets go of the GigE Vision port for the
# next test); SIGKILL after 10 s.
stop_gonio_sim() {
  [[ -n "${sim_pid:-}" ]] || return 0
  kill "$sim_pid" 2>/dev/null || true
  for _ in $(seq 200); do kill -0 "$sim_pid" 2>/dev/null || break; sleep 0.05; done
  kill -KILL "$sim_pid" 2>/dev/null || true
  wait "$sim_pid" 2>/dev/null || true
  sim_pid=""
}

# restart_gonio_sim SIM SPEED WORK: gonio-sim started again on the ports it had (a power cycle:
# the instrument config written by start_gonio_sim still points at it); sets sim_pid.
restart_gonio_sim() {
  local sim=$1 speed=$2 work=$3
  "$sim" --speed "$speed" --port "$(cat "$work/port")" --monitor-port "$(cat "$work/mport")" \
    >> "$work/sim.log" 2>&1 &
  sim_pid=$!
  for _ in $(seq 200); do
    (exec 3<>"/dev/tcp/127.0.0.1/$(cat "$work/port")") 2>/dev/null && break
    sleep 0.05
  done
}

# start_goniod GONIOD WORK SRC DB [goniod options...]: starts goniod on WORK/instrument.toml
# (written by start_gonio_sim) with the example specimens, the database DB and a free API port,
# its output appended to WORK/goniod.log. Waits until it listens; sets daemon (its pid) and url.
# Returns 1 when it does not start within 15 s.
start_goniod() {
  local goniod=$1 work=$2 src=$3 db=$4
  shift 4
  rm -f "$work/apiport"
  "$goniod" -c "$work/instrument.toml" --samples "$src/config/samples.toml" --db "$db" "$@" \
    --port 0 --port-file "$work/apiport" >> "$work/goniod.log" 2>&1 &
  daemon=$!
  for _ in $(seq 300); do [[ -s "$work/apiport" ]] && break; sleep 0.05; done
  [[ -s "$work/apiport" ]] || return 1
  url="http://127.0.0.1:$(cat "$work/apiport")"
}
