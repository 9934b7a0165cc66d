#!/usr/bin/env bash
# A third-party GenICam client (arv-camera-test-0.8, Debian package aravis-tools) sees a real
# camera: it opens gonio-sim's simulated CCD by numeric IP (no discovery) and acquires frames.
# Usage: arv_camera_test.sh GONIO_SIM WORKDIR. Holds the CTest lock "gvcp" (port 3956).
set -euo pipefail
sim=$1 work=$2
mkdir -p "$work"
rm -f "$work/port"
"$sim" --port 0 --monitor-port 0 --port-file "$work/port" --speed 20 > "$work/sim.log" 2>&1 &
pid=$!
trap 'kill $pid 2>/dev/null || true; wait $pid 2>/dev/null || true' EXIT  # the port is free after
for _ in $(seq 100); do [[ -s "$work/port" ]] && break; sleep 0.05; done
[[ -s "$work/port" ]] || { cat "$work/sim.log"; exit 1; }

# arv-camera-test acquires until stopped and prints a rate line per second.
# Under ASan the first 512 x 512 frame takes over 2 s to render: a window of 8 s, not 4.
timeout 8 stdbuf -oL arv-camera-test-0.8 -n 127.0.0.1 -e 20000 > "$work/arv.log" 2>&1 || true
cat "$work/arv.log"
grep -q "vendor name *= gonio" "$work/arv.log"
grep -q "payload *= 524288 bytes" "$work/arv.log"   # 512 x 512 Mono16
# At least two seconds with frames arriving.
n=$(grep -cE "^ *[1-9][0-9]* frames/s" "$work/arv.log" || true)
(( n >= 2 )) || { echo "only $n seconds with frames"; exit 1; }

kill -TERM $pid
wait $pid
grep -q "stopped" "$work/sim.log"
