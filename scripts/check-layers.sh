#!/usr/bin/env bash
# Checks every include of our own headers against the layers of cmake/layers.txt, before anything
# is built, and names each offending include with file:line and the rule it breaks. The build
# refuses the same includes (cmake/Layers.cmake); this says so for every file at once.
# Usage: scripts/check-layers.sh [ROOT]     (ROOT: the repository, by default this script's)
set -euo pipefail
root=${1:-"$(cd "$(dirname "$0")/.." && pwd)"}
exec /usr/bin/python3 - "$root" <<'PY'
import pathlib, re, sys

root = pathlib.Path(sys.argv[1])
layers = {}  # folder -> the folders it may include besides itself, in the file's order
for n, line in enumerate((root / "cmake/layers.txt").read_text().splitlines(), 1):
    m = re.match(r"^([a-z]+):(.*)$", line)
    if not m:
        continue
    folder, deps = m.group(1), m.group(2).split()
    for d in deps:
        if d not in layers:  # only folders listed above: dependencies point one way, no cycle
            sys.exit(f"cmake/layers.txt:{n}: {folder} may include {d}, which is not a layer "
                     f"listed above it")
    layers[folder] = set(deps)
ours = set(layers) | {"tests", "bench", "fuzz"}

include = re.compile(r'^\s*#\s*include\s+"([a-z_]+)/([^"]+)"')
bad = 0
for folder, allowed in layers.items():
    for path in sorted((root / folder).rglob("*")):
        if path.suffix not in (".h", ".cc") or not path.is_file():
            continue
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            m = include.match(line)
            if not m or m.group(1) not in ours:
                continue
            target = m.group(1)
            if target != folder and target not in allowed:
                rel = path.relative_to(root)
                see = ", ".join(sorted(allowed | {folder}))
                print(f"{rel}:{n}: {folder}/ may not include {target}/{m.group(2)} "
                      f"(its layer sees {see}; cmake/layers.txt)")
                bad += 1
if bad:
    sys.exit(f"check-layers: {bad} include(s) across a forbidden boundary")
print(f"check-layers: every include of {', '.join(layers)} keeps to cmake/layers.txt")
PY
