#!/usr/bin/env bash
# scripts/check-functions.sh names a function past the limit with file:line and its length, and
# passes a tree without one: a repository of one layer with a long function, then without it.
# Usage: functions_test.sh SOURCE_DIR WORKDIR
set -euo pipefail
src=$1 work=$2
rm -rf "$work" && mkdir -p "$work/cmake" "$work/common"
printf 'common:\n' > "$work/cmake/layers.txt"
{
  echo '#include "common/x.h"'
  echo ''
  echo 'namespace gonio {'
  echo ''
  echo 'int Short(int a) {'
  echo '  return a + 1;'
  echo '}'
  echo ''
  echo 'static int LongOne(int a,'
  echo '                   int b) {'
  for i in $(seq 1 125); do echo "  a += b * $i;"; done
  echo '  return a;'
  echo '}'
  echo ''
  echo '}  // namespace gonio'
} > "$work/common/x.cc"
set +e
out=$(bash "$src/scripts/check-functions.sh" "$work" 2>&1)
rc=$?
set -e
[[ $rc == 1 ]] || { echo "a 129-line function passed the check (exit $rc): $out"; exit 1; }
grep -q '^common/x.cc:9: LongOne is 129 lines (the limit is 120)' <<< "$out" ||
  { echo "the long function was not named with file:line and length: $out"; exit 1; }
grep -q 'Short' <<< "$out" && { echo "the short function was named: $out"; exit 1; }
# Within the limit once split: the check passes and counts both functions.
sed -i '/a += b \* 1[0-2][0-9];/d' "$work/common/x.cc"
out=$(bash "$src/scripts/check-functions.sh" "$work")
grep -q '^check-functions: 2 functions in common, none over 120 lines' <<< "$out" ||
  { echo "after the split: $out"; exit 1; }
echo "the check named common/x.cc:9 (129 lines) and passed the split file"
