#!/usr/bin/env bash
# The layers of cmake/layers.txt hold by construction: an include across a forbidden boundary
#   1. stops the compiler with an #error naming the rule (the acquisition layer's include roots,
#      as cmake/Layers.cmake made them for this build), and
#   2. is listed by scripts/check-layers.sh with file:line and the rule, in a scratch tree;
# while the same include from a layer allowed to make it compiles.
# Usage: layers_test.sh CXX SOURCE_DIR BUILD_DIR WORK_DIR
set -euo pipefail
cxx=$1 src=$2 build=$3 work=$4
rm -rf "$work" && mkdir -p "$work"
fail() { echo "layers_test: $*" >&2; exit 1; }

# 1. The compiler, with the acquisition layer's roots: a backend header is refused by name.
printf '#include "backends/aravis_camera.h"\nint main() { return 0; }\n' > "$work/forbidden.cc"
layer=$build/layers/acquisition
if "$cxx" -std=c++20 -fsyntax-only -I"$layer/allowed" -I"$layer/refused" "$work/forbidden.cc" \
    > "$work/compile.log" 2>&1; then
  fail "acquisition/ compiled an include of backends/"
fi
grep -q "layering: acquisition/ may not include backends/aravis_camera.h - see cmake/layers.txt" \
  "$work/compile.log" || fail "the compiler's message does not name the rule: $(head -5 "$work/compile.log")"
# ... and the daemon's layer may include it (its roots find the real header).
printf '#include "devices/stage.h"\nint main() { return 0; }\n' > "$work/allowed.cc"
"$cxx" -std=c++20 -fsyntax-only -I"$build/layers/daemon/allowed" -I"$build/layers/daemon/refused" \
  "$work/allowed.cc" > "$work/allowed.log" 2>&1 || fail "daemon/ could not include devices/: $(head -5 "$work/allowed.log")"

# 2. The check script on a scratch tree with the project's layers: file:line and the rule.
mkdir -p "$work/tree/cmake" "$work/tree/sim" "$work/tree/backends"
cp "$src/cmake/layers.txt" "$work/tree/cmake/"
printf '#pragma once\n' > "$work/tree/backends/modbus_stage.h"
printf '// a simulated device\n#include "backends/modbus_stage.h"\n' > "$work/tree/sim/bad.h"
if bash "$src/scripts/check-layers.sh" "$work/tree" > "$work/check.log" 2>&1; then
  fail "check-layers.sh passed a sim/ file that includes backends/"
fi
grep -q "sim/bad.h:2: sim/ may not include backends/modbus_stage.h" "$work/check.log" ||
  fail "check-layers.sh did not name the file, line and rule: $(cat "$work/check.log")"
# The real tree keeps to its layers.
bash "$src/scripts/check-layers.sh" "$src" > "$work/real.log" 2>&1 || fail "$(cat "$work/real.log")"
echo "layers_test: a forbidden include is refused by the compiler and by check-layers.sh, naming the rule"
