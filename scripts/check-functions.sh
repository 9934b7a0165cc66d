#!/usr/bin/env bash
# Names every function outside tests/, bench/ and fuzz/ longer than the limit (120 lines, from its
# signature to its closing brace), with file:line, so that none creeps back past it: a function
# that long holds more than one idea (docs/design.md). Reads the layers' folders from
# cmake/layers.txt; knows the committed .clang-format's shape (definitions start in column 0,
# their closing brace too).
# Usage: scripts/check-functions.sh [ROOT [LIMIT]]   (ROOT: the repository, by default this
# script's; LIMIT: 120)
set -euo pipefail
root=${1:-"$(cd "$(dirname "$0")/.." && pwd)"}
limit=${2:-120}
exec /usr/bin/python3 - "$root" "$limit" <<'PY'
import pathlib, re, sys

root, limit = pathlib.Path(sys.argv[1]), int(sys.argv[2])
folders = [m.group(1) for line in (root / "cmake/layers.txt").read_text().splitlines()
           if (m := re.match(r"^([a-z]+):", line))]
# A definition's first line: in column 0, not a comment, directive, namespace, type or
# declaration statement, with a parameter list opening on it.
skip = re.compile(r"^(//|#|\}|namespace\b|using\b|struct\b|class\b|enum\b|template\b|"
                  r"typedef\b|extern\b|static_assert\b|constexpr\s+(double|int|long|char|bool|"
                  r"std::)\b)")
long_ones = []
checked = 0
for folder in folders:
    for path in sorted((root / folder).rglob("*.cc")):
        lines = path.read_text(errors="replace").splitlines()
        i = 0
        while i < len(lines):
            line = lines[i]
            if not line or line[0].isspace() or skip.match(line) or "(" not in line:
                i += 1
                continue
            # The signature runs to the line ending in "{" (a definition) or ";" (not one).
            j = i
            while j < len(lines) and not lines[j].rstrip().endswith(("{", ";")):
                j += 1
            if j == len(lines) or lines[j].rstrip().endswith(";"):
                i = j + 1
                continue
            k = j + 1
            while k < len(lines) and lines[k] != "}":
                k += 1
            checked += 1
            n = k - i + 1
            if n > limit:
                name = re.sub(r"\s*\(.*", "", line).split()[-1]
                long_ones.append((str(path.relative_to(root)), i + 1, name, n))
            i = k + 1
for path, line, name, n in long_ones:
    print(f"{path}:{line}: {name} is {n} lines (the limit is {limit}): split it by what it does")
if long_ones:
    sys.exit(f"check-functions: {len(long_ones)} function(s) over {limit} lines")
print(f"check-functions: {checked} functions in {', '.join(folders)}, none over {limit} lines")
PY
