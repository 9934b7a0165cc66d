#!/usr/bin/env python3
"""The stored lamp term against what the simulated lamp did over each point's frames.

gonio-sim --truth-log (bench/instrument_coverage.sh keeps it as COVERAGE_KEEP/truth.csv) logs each
frame's lamp output relative to nominal, averaged over its exposure. Each exported point is
matched to its frames (the last `frames` open-shutter frames at its read-back angles, as
truth_angles.py matches them), and per exposure this prints the rms over points of the stored
lamp term relative to the value, sigma_lamp / value, against the rms of what the lamp's
frame-to-frame scatter put into the point's mean, sd(frames' lamp) / sqrt(frames), and the stored
statistical term for scale. A lamp term far above what the lamp did inflates sigma; one below it
leaves scatter out.

  bench/coverage/lamp_check.py TRUTH_CSV EXPORT_CSV...
"""
import collections
import csv
import math
import statistics
import sys

STEP_DEG = 1e-3  # config/sim.toml's 1000 steps per degree


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__.strip().splitlines()[-1].strip())
    groups = []  # consecutive frames at one pair of stage angles
    try:
        for r in csv.DictReader(open(sys.argv[1])):
            key = (float(r["sample_deg"]), float(r["arm_deg"]))
            if not groups or groups[-1][0] != key:
                groups.append((key, []))
            if r["shutter_closed"] == "0":
                groups[-1][1].append((float(r["exposure_s"]), float(r["lamp_relative"])))
    except (OSError, KeyError, ValueError) as e:
        sys.exit(f"lamp_check: {sys.argv[1]}: {e}")
    by_exposure = collections.defaultdict(lambda: [0.0, 0.0, 0.0, 0])
    g = 0
    for path in sys.argv[2:]:
        try:
            rows = list(csv.DictReader(l for l in open(path) if not l.startswith("#")))
        except OSError as e:
            sys.exit(f"lamp_check: {e}")
        for r in rows:
            sr, ar = float(r["sample_read_deg"]), float(r["arm_read_deg"])
            while g < len(groups) and not (abs(groups[g][0][0] - sr) < STEP_DEG / 2 + 1e-9 and
                                           abs(groups[g][0][1] - ar) < STEP_DEG / 2 + 1e-9):
                g += 1
            if g == len(groups):
                sys.exit(f"lamp_check: {path}: no frame at sample {sr}, arm {ar}: "
                         "is the truth log the run's?")
            n = int(r["frames"])
            frames = groups[g][1][-n:]
            g += 1
            value = abs(float(r["value"]))
            if n < 2 or len(frames) < n or value == 0:
                continue
            lamp = [x[1] for x in frames]
            acc = by_exposure[round(frames[-1][0], 6)]
            acc[0] += (float(r["sigma_lamp"] or 0) / value) ** 2
            acc[1] += statistics.variance(lamp) / n
            acc[2] += (float(r["sigma_stat"]) / value) ** 2
            acc[3] += 1
    print("| exposure (s) | points | stored lamp / value | the lamp's scatter of the mean | stat / value |")
    print("|---|---|---|---|---|")
    for t, (lamp, true, stat, n) in sorted(by_exposure.items()):
        print(f"| {t:.4g} | {n} | {math.sqrt(lamp / n):.2e} | {math.sqrt(true / n):.2e} "
              f"| {math.sqrt(stat / n):.2e} |")


if __name__ == "__main__":
    main()
