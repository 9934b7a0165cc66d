#!/usr/bin/env python3
"""The stage angles each exported point was really taken at, against its read-backs.

gonio-sim --truth-log (bench/instrument_coverage.sh keeps it as COVERAGE_KEEP/truth.csv) writes
one line per frame with the stages' true angles. Each exported point (gonio-acquire export) is
matched, in order, to the first run of frames at its read-back angles (within half a step), and
the read-back errors (true - read) are summarised per incidence sweep, in steps of 1/1000 deg:
the sample stage's (one per sweep, as the fitter models it) and the arm's (one per point), with
their mean and spread. --true writes a copy of the export with the true angles in the read-back
columns (and angle_sigma_deg 0 in its response line) to refit without the read-back error: of
the last export given, so name the runs before it too (run1.csv ... runN.csv for run N): the
frames are matched in order, and every run of one plan visits the same read-back angles.

  bench/coverage/truth_angles.py TRUTH_CSV EXPORT_CSV... [--true OUT_CSV]
"""
import argparse
import csv
import json
import math
import statistics
import sys

STEP_DEG = 1e-3  # config/sim.toml's 1000 steps per degree


def frames(path):
    out = []
    try:
        for r in csv.DictReader(open(path)):
            key = (float(r["sample_deg"]), float(r["arm_deg"]))
            if not out or out[-1] != key:
                out.append(key)
    except (OSError, KeyError, ValueError) as e:
        sys.exit(f"truth_angles: {path}: {e}")
    return out


def read_export(path):
    lines = open(path).read().splitlines()
    header = [l for l in lines if l.startswith("#")]
    rows = list(csv.DictReader(l for l in lines if not l.startswith("#")))
    return header, rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("truth")
    ap.add_argument("exports", nargs="+")
    ap.add_argument("--true", help="write the last export with the true angles here")
    a = ap.parse_args()
    groups = frames(a.truth)
    g = 0
    for path in a.exports:
        header, rows = read_export(path)
        for r in rows:
            sr, ar = float(r["sample_read_deg"]), float(r["arm_read_deg"])
            while g < len(groups) and not (abs(groups[g][0] - sr) < STEP_DEG / 2 + 1e-9 and
                                           abs(groups[g][1] - ar) < STEP_DEG / 2 + 1e-9):
                g += 1
            if g == len(groups):
                sys.exit(f"truth_angles: {path}: no frame at sample {sr}, arm {ar}: "
                         "is the truth log the run's?")
            r["_true"] = groups[g]
            g += 1
        print(f"{path}:")
        for inc in sorted({r["theta_l_deg"] for r in rows}, key=float):
            sweep = [r for r in rows if r["theta_l_deg"] == inc]
            sample = [(r["_true"][0] - float(r["sample_read_deg"])) / STEP_DEG for r in sweep]
            arm = [(r["_true"][1] - float(r["arm_read_deg"])) / STEP_DEG for r in sweep]
            print(f"  incidence {inc}: {len(sweep)} points; sample stage {min(sample):+.3f}.."
                  f"{max(sample):+.3f} steps; arm mean {statistics.fmean(arm):+.3f} "
                  f"(sd of a mean {statistics.pstdev(arm) / math.sqrt(len(arm)):.3f}), "
                  f"sd {statistics.pstdev(arm):.3f} steps (uniform +-0.5: 0.289)")
        if a.true and path == a.exports[-1]:
            for r in rows:
                r["sample_read_deg"] = f"{r['_true'][0]:.9f}"
                r["arm_read_deg"] = f"{r['_true'][1]:.9f}"
                del r["_true"]
            with open(a.true, "w") as f:
                for h in header:
                    if h.startswith("# response: "):
                        response = json.loads(h[len("# response: "):])
                        response["bench"]["angle_sigma_deg"] = 0
                        h = "# response: " + json.dumps(response, separators=(",", ":"))
                    f.write(h + "\n")
                w = csv.DictWriter(f, fieldnames=list(rows[0].keys()), lineterminator="\n")
                w.writeheader()
                w.writerows(rows)


if __name__ == "__main__":
    main()
