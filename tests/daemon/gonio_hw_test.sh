#!/usr/bin/env bash
# gonio-hw, the operator's hardware check, against gonio-sim through the real drivers: the stages
# over Modbus TCP, the camera over GigE Vision, the source monitor over its socket transport, with
# the example instrument config pointed at gonio-sim's ports.
# Usage: gonio_hw_test.sh GONIO_SIM GONIO_HW SOURCE_DIR WORKDIR
set -euo pipefail
sim=$1 hw=$2 src=$3 work=$4
mkdir -p "$work"
rm -f "$work/port" "$work/mport" "$work/frame.png"
"$sim" --port 0 --port-file "$work/port" --monitor-port 0 --monitor-port-file "$work/mport" \
  --speed 20 > "$work/sim.log" 2>&1 &
pid=$!
trap 'kill $pid 2>/dev/null || true; wait $pid 2>/dev/null || true' EXIT  # the port is free after
for _ in $(seq 200); do [[ -s "$work/port" ]] && break; sleep 0.05; done
port=$(cat "$work/port") mport=$(cat "$work/mport")
sed -e "s/^port = 5020/port = $port/" -e "s/^port = 5021/port = $mport/" \
  "$src/config/instrument.toml" > "$work/instrument.toml"
hw() { timeout 60 "$hw" -c "$work/instrument.toml" "$@"; }

hw stage status | tee "$work/status0.txt"
grep -q "^sample       0.0000 deg  READY" "$work/status0.txt"
hw stage move sample=10 arm=200 | tee "$work/move.txt"
grep -q "^sample      10.0000 deg" "$work/move.txt"
grep -q "^arm        200.0000 deg" "$work/move.txt"
# Outside the travel limits: refused with exit code 2, and nothing moved.
set +e
hw stage move sample=95 > "$work/refused.txt" 2>&1
rc=$?
set -e
[[ $rc == 2 ]] || { echo "exit $rc for a target outside the limits"; cat "$work/refused.txt"; exit 1; }
grep -q "outside the travel limits" "$work/refused.txt"
hw stage status sample | grep -q "^sample      10.0000 deg"

hw monitor idn | grep -q "^gonio-sim,PM100USB"
[[ $(hw monitor read --count 3 | grep -c " W$") == 3 ]]

hw camera info | tee "$work/info.txt"
grep -q "^sensor temperature: " "$work/info.txt"
hw camera snap --exposure 0.2 --roi 240,240,32,32 --out "$work/frame.png" | tee "$work/snap.txt"
grep -q "^roi 240,240 32x32: mean " "$work/snap.txt"
file "$work/frame.png" | grep -q "16-bit grayscale"

kill -TERM $pid
wait $pid
echo "gonio-hw checked the stages, the monitor and the camera through gonio-sim"
