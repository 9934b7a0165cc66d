#!/usr/bin/env python3
"""Per-sweep lobe shifts left in a fit's residuals (docs/measurement.md, antiglare's coverage).

For each incidence of each fit_curves_joint.csv (or, without the protocol, fit_curves.csv) that
gonio-fit wrote, fits one shift of the sweep along the view to value - prediction, with the fitted
model's slope along the view (central differences of the predictions) and weights from the stored
sigma. The shift's sigma counts the stored sigma and the arm's per-point read-back error
(angle_sigma times the slope). z = shift / sigma; with honest sigmas and nothing common to a
sweep, z has rms 1 (less where the fit's sample-stage offsets took part of each sweep's shift).
The joint fit's curves, not fit_curves.csv: under the protocol that holds the normal-incidence
fit's predictions, which at the other incidences carry neither their sample-stage offsets nor the
geometry the joint fit found (read so, antiglare's runs once seemed to shift 2.4 sigma a sweep).

  bench/coverage/sweep_shifts.py [--angle-sigma DEG] FIT_DIR...   (gonio-fit --out's directories)
"""
import argparse
import csv
import math
import os
import sys


def sweep_shift(rows, angle_sigma):
    tv = [float(r["theta_v_deg"]) for r in rows]
    pred_key = next(k for k in rows[0] if k.startswith("pred_"))
    p = [float(r[pred_key]) for r in rows]
    v = [float(r["value"]) for r in rows]
    s = [float(r["sigma"]) for r in rows]
    num = den = var = 0.0
    for i in range(1, len(rows) - 1):
        g = (p[i + 1] - p[i - 1]) / (tv[i + 1] - tv[i - 1])
        w = g / s[i] ** 2
        num += w * (v[i] - p[i])
        den += w * g
        var += w * w * (s[i] ** 2 + (angle_sigma * g) ** 2)
    if den <= 0:
        return None
    return num / den, math.sqrt(var) / den


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--angle-sigma", type=float, default=3e-4,
                    help="the arm's read-back sigma, degrees (instrument.toml's angle_sigma_deg)")
    ap.add_argument("fits", nargs="+")
    a = ap.parse_args()
    z_by_incidence = {}
    for d in a.fits:
        path = f"{d}/fit_curves_joint.csv"
        if not os.path.exists(path):
            path = f"{d}/fit_curves.csv"
        try:
            rows = list(csv.DictReader(open(path)))
        except OSError as e:
            sys.exit(f"sweep_shifts: {path}: {e.strerror}")
        incidences = sorted({r["theta_l_deg"] for r in rows}, key=float)
        out = []
        for inc in incidences:
            sweep = [r for r in rows if r["theta_l_deg"] == inc]
            if len(sweep) < 3:
                continue
            got = sweep_shift(sweep, a.angle_sigma)
            if got is None:
                continue
            shift, sigma = got
            z_by_incidence.setdefault(inc, []).append(shift / sigma)
            out.append(f"{inc} deg: {shift:+.2e} +- {sigma:.1e} deg (z {shift / sigma:+.1f})")
        print(f"{d}: " + "; ".join(out))
    for inc, z in z_by_incidence.items():
        print(f"incidence {inc} deg: z rms {math.sqrt(sum(x * x for x in z) / len(z)):.2f} over {len(z)}")


if __name__ == "__main__":
    main()
