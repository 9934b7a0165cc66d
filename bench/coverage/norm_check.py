#!/usr/bin/env python3
"""The normalisation's error, exposure by exposure, against its stored sigma.

Each exported point is matched to its frames in gonio-sim's truth log (as lamp_check.py matches
them). Its normalisation error is monitor_w over the lamp's mean output during its frames, taken
relative to the run's weighted mean (the lamp's nominal power and the meter's scale are the fit's
scale anyway). Per exposure this prints the rms of that error over every point of every run
beside the rms of what the stored lamp and monitor terms predict for it, and their ratio: a
ratio above 1 is scatter the budget leaves out at that exposure.

  bench/coverage/norm_check.py TRUTH_CSV EXPORT_CSV...
"""
import collections
import csv
import math
import sys

import truth_log


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__.strip().splitlines()[-1].strip())
    match = truth_log.Matcher(truth_log.groups(sys.argv[1], "norm_check"), "norm_check")
    by_exposure = collections.defaultdict(lambda: [0, 0.0, 0.0, 0.0, 0.0])
    for path in truth_log.in_measured_order(sys.argv[2:]):
        try:
            rows = list(csv.DictReader(l for l in open(path) if not l.startswith("#")))
        except OSError as e:
            sys.exit(f"norm_check: {e}")
        points = []
        for r in rows:
            _, frames = match.frames(r, path)
            n = int(r["frames"])
            value = float(r["value"])
            if len(frames) < n or not r["monitor_w"] or value <= 0:
                continue
            lamp = sum(x[1] for x in frames) / len(frames)
            rel_lamp = float(r["sigma_lamp"] or 0) / value
            rel_monitor = float(r["sigma_monitor"] or 0) / value
            if rel_lamp == 0 and rel_monitor == 0:
                continue
            points.append((round(frames[-1][0], 6), float(r["monitor_w"]) / lamp, rel_lamp,
                           rel_monitor))
        if not points:
            sys.exit(f"norm_check: {path}: no point with a monitor reading and a matched frame")
        weights = [1 / (l * l + m * m) for _, _, l, m in points]
        mean = sum(w * p[1] for w, p in zip(weights, points)) / sum(weights)
        for t, ratio, rel_lamp, rel_monitor in points:
            acc = by_exposure[t]
            acc[0] += 1
            acc[1] += (ratio / mean - 1) ** 2
            acc[2] += rel_lamp ** 2 + rel_monitor ** 2
            acc[3] += rel_lamp ** 2
            acc[4] += rel_monitor ** 2
    print("| exposure (s) | points | error rms | its sigma (lamp, monitor) | ratio |")
    print("|---|---|---|---|---|")
    for t, (n, err, said, lamp, monitor) in sorted(by_exposure.items()):
        print(f"| {t:.4g} | {n} | {math.sqrt(err / n):.2e} | {math.sqrt(said / n):.2e} "
              f"({math.sqrt(lamp / n):.1e}, {math.sqrt(monitor / n):.1e}) "
              f"| {math.sqrt(err / said):.2f} |")


if __name__ == "__main__":
    main()
