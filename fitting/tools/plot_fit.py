#!/usr/bin/python3
"""Plots gonio-fit's output directory like Figures 10 and 11 of Walter 2007.

Top: measured BTDF*cos (points with 1-sigma bars) and each model's curve, per incidence, on a
log scale against the view angle. With the paper's protocol the curves are the normal-incidence
fits, so off-normal curves are predictions. Bottom: the empirical D (eq. 21 solved with G = 1)
and each model's fitted D against the half-vector angle.

Usage: /usr/bin/python3 fitting/tools/plot_fit.py FIT_DIR [OUT.png]   (default FIT_DIR/fit.png)
"""
import csv
import math
import os
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def read(path):
    try:
        with open(path, encoding="utf-8", newline="") as f:
            return list(csv.DictReader(f))
    except OSError as e:
        sys.exit(f"plot_fit: {path}: {e.strerror} (is this a gonio-fit --out directory?)")


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit("usage: plot_fit.py FIT_DIR [OUT.png]")
    d = sys.argv[1]
    out = sys.argv[2] if len(sys.argv) == 3 else os.path.join(d, "fit.png")
    curves, emp, fitted = (read(os.path.join(d, n))
                           for n in ("fit_curves.csv", "empirical_d.csv", "fitted_d.csv"))
    if not curves:
        sys.exit(f"plot_fit: {d}/fit_curves.csv has no samples")
    models = [k[len("pred_"):] for k in curves[0] if k.startswith("pred_")]
    # A failed fit leaves non-finite predictions: its curves are left out (and said so), the rest
    # is drawn.
    finite = [m for m in models
              if all(math.isfinite(float(r["pred_" + m])) for r in curves)
              and all(math.isfinite(float(r["d_" + m])) for r in fitted)]
    for m in models:
        if m not in finite:
            print(f"plot_fit: {m}: the fit did not converge (non-finite curve); not drawn")
    models = finite

    by_incidence = defaultdict(list)
    for r in curves:
        by_incidence[round(float(r["theta_l_deg"]), 3)].append(r)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 9))
    peak = max(float(r["value"]) for r in curves)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (tl, rows) in enumerate(sorted(by_incidence.items())):
        rows.sort(key=lambda r: float(r["theta_v_deg"]))
        c = colors[i % len(colors)]
        tv = [float(r["theta_v_deg"]) for r in rows]
        # A log axis: non-positive (noise around zero) values are not drawn, and error bars stop
        # just above zero.
        pos = [r for r in rows if float(r["value"]) > 0]
        vals = [float(r["value"]) for r in pos]
        sig = [float(r["sigma"]) for r in pos]
        top.errorbar([float(r["theta_v_deg"]) for r in pos], vals,
                     [[min(e, 0.999 * v) for e, v in zip(sig, vals)], sig],
                     fmt=".", ms=3, color=c, alpha=0.6, label=f"measured, theta_l {tl:g}")
        for m, ls in zip(models, ("-", "--", ":", "-.")):
            top.plot(tv, [float(r["pred_" + m]) for r in rows], ls, color=c, lw=1,
                     label=m if i == 0 else None)
    top.set_yscale("log")
    top.set_ylim(peak * 1e-4, peak * 3)  # four decades, as Walter's Figures 10-11
    top.set_xlabel("view angle theta_v (deg; from -n through the glass, from +n in reflection)")
    top.set_ylabel("BTDF * cos theta_l")
    top.set_title("Measured and fitted (normal-incidence fit; other incidences predicted)")
    top.legend(fontsize=7, ncol=2)

    d_max = 0.0
    for m, ls in zip(models, ("-", "--", ":", "-.")):
        pts = [r for r in emp if r["model"] == m]
        dv = [float(r["d"]) for r in pts]
        ds = [float(r["d_sigma"]) for r in pts]
        d_max = max([d_max] + [v for v in dv if math.isfinite(v)])
        bottom.errorbar([float(r["theta_h_deg"]) for r in pts], dv,
                        [[min(e, 0.999 * v) for e, v in zip(ds, dv)], ds], fmt=".", ms=3,
                        alpha=0.5, label=f"empirical D (scale of {m})")
        bottom.plot([float(r["theta_h_deg"]) for r in fitted],
                    [float(r["d_" + m]) for r in fitted], ls, color="k", lw=1,
                    label=f"fitted D, {m}")
    bottom.set_yscale("log")
    if d_max > 0:
        bottom.set_ylim(d_max * 1e-4, d_max * 3)
    bottom.set_xlim(0, 80)
    bottom.set_xlabel("half-vector angle theta_h (deg)")
    bottom.set_ylabel("D")
    bottom.set_title("Empirical D (G = 1, |i.n|, |o.n| > 0.5) and fitted D")
    bottom.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"plot_fit: wrote {out}")


if __name__ == "__main__":
    main()
