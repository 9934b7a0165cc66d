#!/usr/bin/env bash
# The fit's verdict through the whole instrument, run after run: gonio-sim, goniod on a new
# database, a schedule of RUNS runs of the demo's plan at normal incidence (17 points) with
# Beckmann and GGX fitted after each, as the demo fits them. Prints each run's status word per
# model and the tally (GGX on the Beckmann ground glass should get one word, run after run), and
# the first run's exposure beside what the new database's dry run priced it at (the instrument
# config's [throughput]). Holds the GigE Vision port: no other simulated camera may run meanwhile.
# Usage: bench/verdicts.sh BUILD_DIR [RUNS]      (default 20 runs; about 40 s each at x50)
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:?usage: bench/verdicts.sh BUILD_DIR [RUNS]}
runs=${2:-20}
work=out/bench/verdicts
rm -rf "$work"
mkdir -p "$work"
source tests/support/gonio_sim.sh
daemon=""
trap '[[ -n "$daemon" ]] && kill -TERM "$daemon" 2>/dev/null; stop_gonio_sim' EXIT
start_gonio_sim "$build/sim/gonio-sim" 50 "$work" . --config config/sim.toml
sed 's/^incidence_deg = .*/incidence_deg = [0]/' config/plan_demo.toml > "$work/plan_normal.toml"
printf '[[job]]\nplan = "plan_normal.toml"\nrepeat = %d\nfit = ["beckmann", "ggx"]\n' "$runs" \
  > "$work/schedule.toml"
"$build/daemon/goniod" -c "$work/instrument.toml" --samples config/samples.toml \
  --db "$work/runs.sqlite" --port 0 --port-file "$work/apiport" > "$work/goniod.log" 2>&1 &
daemon=$!
for _ in $(seq 300); do [[ -s "$work/apiport" ]] && break; sleep 0.05; done
ctl() {
  "$build/daemon/gonioctl" --url "http://127.0.0.1:$(cat "$work/apiport")" \
    --token-file "$work/runs.sqlite.token" "$@"
}
echo "# Fit verdicts through the instrument: $runs runs of the demo's plan at normal incidence"
echo
echo "The new database's dry run:"
ctl schedule "$work/schedule.toml" --dry-run | sed 's/^/    /'
ctl schedule "$work/schedule.toml" --wait > "$work/wait.log" 2>&1 ||
  { cat "$work/wait.log"; exit 1; }
echo
echo "Run 1 (priced on the new database):"
ctl show 1 | sed -n '2,/^theta_l/p' | sed '$d' | sed 's/^/    /'
echo
echo "| run | beckmann | alpha | ggx | ggx chi2/dof |"
echo "|---|---|---|---|---|"
for run in $(seq "$runs"); do
  ctl --json fits "$run" > "$work/fits$run.json"
  /usr/bin/python3 - "$work/fits$run.json" "$run" <<'EOF'
import json, sys
fits = {f["model"]: f["summary"] for f in json.load(open(sys.argv[1]))["fits"]}
b, g = fits.get("beckmann", {}), fits.get("ggx", {})
print(f"| {sys.argv[2]} | {b.get('status', '?')} | {b.get('width', {}).get('value', float('nan')):.5f} "
      f"| {g.get('status', '?')} | {g.get('reduced_chi2', float('nan')):.3g} |")
EOF
done | tee "$work/table.md"
echo
echo "GGX's verdicts: $(awk -F'|' '{print $5}' "$work/table.md" | sort | uniq -c | xargs)"
