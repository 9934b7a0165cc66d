#!/usr/bin/python3
"""Peer comparison: scipy.optimize.least_squares against gonio's Ceres fitter on the same data.

For each case it writes a synthetic sweep with gonio-synth and fits it twice from the same start:
with scipy (the model written here in numpy, independently of the C++ code: Walter 2007 eq. 21
with Beckmann or GGX D and exact Smith G1, exact Fresnel), and with gonio (bench/fit_peer, one
Ceres solve, automatic differentiation). Both minimise the same weighted sum of squares over
(log alpha, log k). It prints the relative difference of the optima and the time ratio. The goal
(issue #3) is the same optimum to 1e-6 relative and gonio at least 20x faster.

Usage: /usr/bin/python3 bench/scipy_peer.py BUILD_DIR OUT_JSON
"""
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
from scipy.optimize import least_squares
from scipy.special import erf

ETA = 1.51


def directions(csv_path):
    d = np.genfromtxt(csv_path, delimiter=",", names=True)
    tl, pl = np.radians(d["theta_l_deg"]), np.radians(d["phi_l_deg"])
    tv, pv = np.radians(d["theta_v_deg"]), np.radians(d["phi_v_deg"])
    light = np.stack([np.sin(tl) * np.cos(pl), np.sin(tl) * np.sin(pl), np.cos(tl)], axis=1)
    view = np.stack([np.sin(tv) * np.cos(pv), np.sin(tv) * np.sin(pv), -np.cos(tv)], axis=1)
    return light, view, d["value"], d["sigma"]


def fresnel(c, eta):
    g2 = eta * eta - 1 + c * c
    g = np.sqrt(np.maximum(g2, 0))
    a = (g - c) / (g + c)
    b = (c * (g + c) - 1) / (c * (g - c) + 1)
    return np.where(g2 > 0, 0.5 * a * a * (1 + b * b), 1.0)


def btdf(model, light, view, alpha, eta=ETA):
    """Walter 2007 eq. 21, light in air (index 1) and view in glass (eta)."""
    h = -(light + eta * view)
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    h *= np.sign(h[:, 2:3])
    ldh, vdh = np.sum(light * h, axis=1), np.sum(view * h, axis=1)
    cos_h = h[:, 2]
    tan2_h = (1 - cos_h**2) / cos_h**2
    if model == "beckmann":
        d = np.exp(-tan2_h / alpha**2) / (np.pi * alpha**2 * cos_h**4)

        def g1(w):
            cos = np.abs(w[:, 2])
            with np.errstate(divide="ignore"):  # a = inf along the normal, where G1 = 1
                a = cos / (alpha * np.sqrt(1 - cos**2))
                return 2 / (1 + erf(a) + np.exp(-a * a) / (a * np.sqrt(np.pi)))
    else:
        d = alpha**2 / (np.pi * cos_h**4 * (alpha**2 + tan2_h) ** 2)

        def g1(w):
            cos2 = w[:, 2] ** 2
            return 2 / (1 + np.sqrt(1 + alpha**2 * (1 - cos2) / cos2))
    sided = (ldh * light[:, 2] > 0) & (vdh * view[:, 2] > 0)
    g = np.where(sided, g1(light) * g1(view), 0.0)
    f = fresnel(np.abs(ldh), eta)
    denom = ldh + eta * vdh
    return (np.abs(ldh) * np.abs(vdh) * eta**2 * (1 - f) * g * d
            / (np.abs(light[:, 2]) * np.abs(view[:, 2]) * denom**2))


def scipy_fit(model, light, view, value, sigma, start):
    cos_l = np.abs(light[:, 2])

    def residuals(x):
        return (np.exp(x[1]) * btdf(model, light, view, np.exp(x[0])) * cos_l - value) / sigma

    # k at its closed-form optimum for the starting width, as gonio does.
    m = btdf(model, light, view, start) * cos_l
    k0 = np.sum(value * m / sigma**2) / np.sum(m * m / sigma**2)
    return least_squares(residuals, [np.log(start), np.log(k0)], method="lm",
                         xtol=1e-15, ftol=1e-15, gtol=1e-15)


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: scipy_peer.py BUILD_DIR OUT_JSON")
    build, out_json = sys.argv[1], sys.argv[2]
    synth = os.path.join(build, "fitting", "gonio-synth")
    peer = os.path.join(build, "bench", "fit_peer")
    cases = [("beckmann", 0.344, 0.542, "0"), ("ggx", 0.394, 0.755, "0"),
             ("beckmann", 0.344, 0.542, "0,30,60,80"), ("ggx", 0.394, 0.755, "0,30,60,80")]
    start = 0.25
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for model, width, scale, incidences in cases:
            csv = os.path.join(tmp, f"{model}_{incidences.replace(',', '_')}.csv")
            subprocess.run([synth, csv, "--model", model, "--width", str(width), "--scale",
                            str(scale), "--incidences", incidences, "--seed", "7"],
                           check=True, capture_output=True)
            light, view, value, sigma = directions(csv)
            reps = 5
            t0 = time.perf_counter()
            for _ in range(reps):
                r = scipy_fit(model, light, view, value, sigma, start)
            t_scipy = (time.perf_counter() - t0) / reps
            out = subprocess.run([peer, csv, model, str(start), "200"], check=True,
                                 capture_output=True, text=True).stdout
            g = json.loads(out)
            a_s, k_s = np.exp(r.x)
            row = {
                "model": model, "incidences": incidences, "samples": int(len(value)),
                "alpha_scipy": a_s, "alpha_gonio": g["width"],
                "k_scipy": k_s, "k_gonio": g["scale"],
                "rel_diff_alpha": abs(a_s - g["width"]) / a_s,
                "rel_diff_k": abs(k_s - g["scale"]) / k_s,
                "chi2_scipy": float(2 * r.cost), "chi2_gonio": g["chi2"],
                "seconds_scipy": t_scipy, "seconds_gonio": g["seconds_per_fit"],
                "speedup": t_scipy / g["seconds_per_fit"], "scipy_nfev": int(r.nfev),
            }
            rows.append(row)
    print(f"{'case':26s} {'alpha scipy':>12s} {'alpha gonio':>12s} {'rel diff':>9s} "
          f"{'k rel diff':>10s} {'scipy ms':>9s} {'gonio ms':>9s} {'speedup':>8s}")
    for r in rows:
        name = f"{r['model']} @ {r['incidences']}"
        print(f"{name:26s} {r['alpha_scipy']:12.8f} {r['alpha_gonio']:12.8f} "
              f"{r['rel_diff_alpha']:9.1e} {r['rel_diff_k']:10.1e} {1e3 * r['seconds_scipy']:9.2f} "
              f"{1e3 * r['seconds_gonio']:9.3f} {r['speedup']:8.1f}")
    worst = max(max(r["rel_diff_alpha"], r["rel_diff_k"]) for r in rows)
    slowest = min(r["speedup"] for r in rows)
    print(f"worst relative difference of the optima {worst:.1e} (goal 1e-6); "
          f"smallest speedup {slowest:.1f}x (goal 20x)")
    with open(out_json, "w", encoding="utf-8") as f:
        json.dump(rows, f, indent=2)


if __name__ == "__main__":
    main()
