#!/usr/bin/env bash
# The fault plan from gonio-sim's config reaches a third-party client as real hardware's faults
# would: mbpoll's first request to the arm gets no reply (a timeout), the next one is answered;
# the sample axis's first move stalls with alarm 0x10; gonio-sim reports each fault as it fires.
# Usage: fault_config_test.sh GONIO_SIM CONFIG WORKDIR
set -euo pipefail
sim=$1 config=$2 work=$3
mkdir -p "$work"
rm -f "$work/port"
"$sim" --config "$config" --no-camera --port-file "$work/port" --speed 20 > "$work/sim.log" 2>&1 &
pid=$!
trap 'kill $pid 2>/dev/null || true; wait $pid 2>/dev/null || true' EXIT  # the port is free after
for _ in $(seq 100); do [[ -s "$work/port" ]] && break; sleep 0.05; done
port=$(cat "$work/port")
mb() { timeout 10 mbpoll -m tcp -0 -t 4:int -B -1 -o 0.5 -p "$port" "$@"; }

if mb -a 2 -r 126 127.0.0.1 > "$work/first.txt" 2>&1; then
  echo "the arm's first request was answered"; cat "$work/first.txt"; exit 1
fi
grep -qi "timed out" "$work/first.txt" || { echo "not a timeout:"; cat "$work/first.txt"; exit 1; }
mb -a 2 -r 126 127.0.0.1 > /dev/null   # answered now

mb -a 1 -r 88 127.0.0.1 0 1 20000 4000 40000 40000 1000 1 > /dev/null
sleep 0.5   # 10 s simulated: the 5.1 s profile stalled half way
alarm=$(mb -a 1 -r 128 127.0.0.1 | sed -n 's/^\[128\]:[[:space:]]*//p')   # 0x0080
[[ "$alarm" == 16 ]] || { echo "alarm $alarm, expected 16 (0x10)"; exit 1; }
pos=$(mb -a 1 -r 198 127.0.0.1 | sed -n 's/^\[198\]:[[:space:]]*//p')
(( pos > 9000 && pos < 11000 )) || { echo "stalled at $pos, expected about 10000"; exit 1; }

kill -TERM $pid
wait $pid
grep -q "fault modbus_timeout on arm" "$work/sim.log" || { cat "$work/sim.log"; exit 1; }
grep -q "fault axis_stall on sample" "$work/sim.log" || { cat "$work/sim.log"; exit 1; }
echo "timeout on the arm, stall of the sample at $pos steps with alarm 0x10"
