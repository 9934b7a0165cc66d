#!/usr/bin/env bash
# A third-party Modbus client (mbpoll, Debian package) sees a real device: it reads the status of
# gonio-sim's stage controller and moves an axis by writing the documented registers
# (docs/stage_register_map.md), over Modbus TCP and over Modbus RTU on gonio-sim's pty.
# Usage: mbpoll_test.sh GONIO_SIM WORKDIR
set -euo pipefail
sim=$1 work=$2
mkdir -p "$work"
rm -f "$work/port"
"$sim" --no-camera --port 0 --port-file "$work/port" --monitor-port 0 --rtu-link "$work/rtu" \
  --speed 20 > "$work/sim.log" 2>&1 &
pid=$!
trap 'kill $pid 2>/dev/null || true; wait $pid 2>/dev/null || true' EXIT  # the port is free after
for _ in $(seq 100); do [[ -s "$work/port" ]] && break; sleep 0.05; done
port=$(cat "$work/port")
mb() { timeout 10 mbpoll -m tcp -0 -t 4:int -B -1 -o 2 -p "$port" "$@"; }

# Status of unit 2 (0x007E = 126): READY (bit 5) set, MOVE (bit 13) clear.
status=$(mb -a 2 -r 126 127.0.0.1 | sed -n 's/^\[126\]:[[:space:]]*//p')
(( (status & 32) && !(status & 8192) )) || { echo "unexpected status $status"; exit 1; }

# Direct data at 0x0058 = 88: absolute, 9000 steps, 4000 steps/s, 40000 steps/s^2, trigger.
mb -a 2 -r 88 127.0.0.1 0 1 9000 4000 40000 40000 1000 1 > /dev/null
sleep 0.4   # 2.35 s of simulated motion at x20
pos=$(mb -a 2 -r 198 127.0.0.1 | sed -n 's/^\[198\]:[[:space:]]*//p')   # 0x00C6
[[ "$pos" == 9000 ]] || { echo "command position $pos, expected 9000"; exit 1; }
other=$(mb -a 1 -r 198 127.0.0.1 | sed -n 's/^\[198\]:[[:space:]]*//p')
[[ "$other" == 0 ]] || { echo "unit 1 moved to $other"; exit 1; }

# The same controller on the RS-485 line (a pty): unit 2 reads back where TCP moved it; unit 1
# moves by an RTU write. Line settings are the driver's; a pty ignores them.
mbr() { timeout 10 mbpoll -m rtu -b 115200 -P even -0 -t 4:int -B -1 -o 2 "$@"; }
[[ -L "$work/rtu" ]] || { echo "no RTU link"; cat "$work/sim.log"; exit 1; }
pos_rtu=$(mbr -a 2 -r 198 "$work/rtu" | sed -n 's/^\[198\]:[[:space:]]*//p')
[[ "$pos_rtu" == 9000 ]] || { echo "RTU read $pos_rtu, expected 9000"; exit 1; }
mbr -a 1 -r 88 "$work/rtu" -- 0 1 -3000 4000 40000 40000 1000 1 > /dev/null
sleep 0.3
pos1=$(mb -a 1 -r 198 127.0.0.1 | sed -n 's/^\[198\]:[[:space:]]*//p')
[[ "$pos1" == -3000 ]] || { echo "unit 1 at $pos1 after the RTU move, expected -3000"; exit 1; }

kill -TERM $pid
wait $pid
grep -q "stopped" "$work/sim.log"
[[ ! -e "$work/rtu" ]] || { echo "RTU link left behind"; exit 1; }
echo "mbpoll moved unit 2 to $pos over TCP (127.0.0.1:$port) and unit 1 to $pos1 over RTU"
