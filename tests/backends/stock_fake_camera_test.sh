#!/usr/bin/env bash
# The camera driver and gonio-hw against a camera this project did not write: Aravis's own fake
# GigE Vision camera (arv-fake-gv-camera-0.8, aravis-tools), on 127.0.0.1 (opened by address, no
# discovery). It has no cooler, no temperature sensor, no shutter and no exposure-end status, and
# its gain is an Integer (GainRaw): info and snap work and say what it lacks, and cool says there
# is no cooler. Holds the GigE Vision port (gvcp lock).
# Usage: stock_fake_camera_test.sh GONIO_HW SOURCE_DIR WORKDIR
set -euo pipefail
hw=$1 src=$2 work=$3
mkdir -p "$work"
rm -f "$work"/*.txt "$work/frame.png"
arv-fake-gv-camera-0.8 -i 127.0.0.1 > "$work/fake.log" 2>&1 &
pid=$!
trap 'kill $pid 2>/dev/null || true; wait $pid 2>/dev/null || true' EXIT
cp "$src/config/instrument.toml" "$work/instrument.toml"  # as shipped: the camera at 127.0.0.1
hw() { timeout 60 "$hw" -c "$work/instrument.toml" "$@"; }
# The fake camera needs a moment to listen.
for _ in $(seq 50); do hw camera info > "$work/info.txt" 2>&1 && break; sleep 0.1; done
cat "$work/info.txt"
grep -q "^camera: Aravis" "$work/info.txt"
grep -q "^has: temperature no, cooler no, shutter no" "$work/info.txt"
grep -q "^note: no temperature sensor" "$work/info.txt"
# Its latch register reads back what was written last, never a time: paired by order, and said.
grep -q "timestamp latch no" "$work/info.txt"
grep -q "no timestamp latch: frames are paired with triggers by order" "$work/info.txt"
if grep -q "^sensor temperature" "$work/info.txt"; then echo "a temperature from no sensor"; exit 1; fi

hw camera snap --exposure 0.01 --roi 0,0,64,64 --out "$work/frame.png" | tee "$work/snap.txt"
grep -q "^roi 0,0 64x64: mean " "$work/snap.txt"
[[ -s "$work/frame.png" ]]

hw camera cool --setpoint -20 --hold 1 | tee "$work/cool.txt"
grep -q "has no cooler" "$work/cool.txt"
echo "gonio-hw: info, snap and cool against Aravis's stock fake camera"
