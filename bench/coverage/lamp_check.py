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

import truth_log


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__.strip().splitlines()[-1].strip())
    match = truth_log.Matcher(truth_log.groups(sys.argv[1], "lamp_check"), "lamp_check")
    by_exposure = collections.defaultdict(lambda: [0.0, 0.0, 0.0, 0])
    for path in truth_log.in_measured_order(sys.argv[2:]):
        try:
            rows = list(csv.DictReader(l for l in open(path) if not l.startswith("#")))
        except OSError as e:
            sys.exit(f"lamp_check: {e}")
        for r in rows:
            _, frames = match.frames(r, path)
            n = int(r["frames"])
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
