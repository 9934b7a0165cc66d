#!/usr/bin/python3
"""Fit time against accuracy for the fitter's variants, from bench/fit_tradeoff's JSON.

Usage: /usr/bin/python3 bench/plot_fit_tradeoff.py tradeoff.json out.png

y is what the variant itself changes: the largest relative deviation of alpha from the default
variant's optimum on the same data. The dashed line is the statistical error of alpha (RMS over
noise draws): a variant below it costs nothing in accuracy. Variants that failed or converged to
a wrong minimum are drawn as crosses at the top.
"""
import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

FLOOR = 1e-12  # deviations of exactly 0 (same optimum to the last bit) are drawn here


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: plot_fit_tradeoff.py TRADEOFF.json OUT.png")
    with open(sys.argv[1], encoding="utf-8") as f:
        data = json.load(f)
    fig, axes = plt.subplots(1, len(data), figsize=(6.2 * len(data), 4.8), squeeze=False)
    for ax, (case, rows) in zip(axes[0], sorted(data.items(), reverse=True)):
        noise = min(r["rms_rel_error_alpha"] for r in rows if r["wrong"] == 0)
        top = 1.0
        at_floor = 0
        for r in rows:
            x = r["ms_per_fit"]
            if r["wrong"]:
                ax.scatter(x, top, marker="x", s=60, color="red")
                ax.annotate(f"{r['variant']}: {r['wrong']}/{r['draws']} wrong", (x, top),
                            textcoords="offset points", xytext=(5, -12), fontsize=7, color="red")
                continue
            y = max(r["max_rel_deviation_from_reference"], FLOOR)
            ax.scatter(x, y, s=40)
            # Several variants reach the default's optimum exactly: stack their labels.
            dy = 3 + 10 * at_floor if y == FLOOR else 3
            at_floor += y == FLOOR
            ax.annotate(r["variant"] + (" (same optimum)" if y == FLOOR else ""), (x, y),
                        textcoords="offset points", xytext=(5, dy), fontsize=7,
                        arrowprops={"arrowstyle": "-", "lw": 0.3} if dy > 3 else None)
        ax.axhline(noise, ls="--", color="gray", lw=0.8)
        ax.annotate("statistical error of alpha (noise)", (0.02, noise), xycoords=("axes fraction",
                    "data"), textcoords="offset points", xytext=(0, 4), fontsize=7, color="gray")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylim(FLOOR / 3, 3)
        ax.set_xlabel("time per fit (ms)")
        ax.set_ylabel("max relative change of alpha vs default optimum")
        ax.set_title(f"Fitter variants, {case} data (ground glass, Beckmann)")
        ax.grid(True, which="both", alpha=0.3)
        print(f"{case}: noise level {noise:.2e}")
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)
    print(f"wrote {sys.argv[2]}")


if __name__ == "__main__":
    main()
