#!/usr/bin/python3
"""Bench time against alpha error for the acquisition strategies, from bench/acquire_strategies.

Usage: /usr/bin/python3 bench/plot_acquire.py strategies.json out.png

One panel per specimen: x is the median bench time of a run (hours), y its relative alpha error
(median: solid, 90th percentile: dashed), per strategy. Uniform and lobe points are grids of
decreasing step; adaptive points are budgets. The grey line marks the finest uniform grid's
median error, the issue's reference.
"""
import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

COLOURS = {"uniform": "tab:blue", "lobe": "tab:orange", "adaptive": "tab:green"}


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: plot_acquire.py STRATEGIES.json OUT.png")
    with open(sys.argv[1], encoding="utf-8") as f:
        rows = json.load(f)
    specimens = list(dict.fromkeys(r["specimen"] for r in rows))
    fig, axes = plt.subplots(1, len(specimens), figsize=(5.2 * len(specimens), 4.4), squeeze=False)
    for ax, specimen in zip(axes[0], specimens):
        mine = [r for r in rows if r["specimen"] == specimen and r.get("time_s", 0) > 0]
        for strategy, colour in COLOURS.items():
            pts = sorted((r for r in mine if r["strategy"] == strategy), key=lambda r: r["time_s"])
            if not pts:
                continue
            hours = [r["time_s"] / 3600 for r in pts]
            ax.plot(hours, [100 * r["error_median"] for r in pts], "o-", color=colour,
                    label=f"{strategy} (median)")
            ax.plot(hours, [100 * r["error_p90"] for r in pts], "--", color=colour, alpha=0.6,
                    label=f"{strategy} (90th pct)")
        uniform = [r for r in mine if r["strategy"] == "uniform"]
        if uniform:
            reference = max(uniform, key=lambda r: r["time_s"])  # the finest grid
            ax.axhline(100 * reference["error_median"], color="grey", lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("bench time per run (h, median)")
        ax.set_ylabel("|alpha error| (%)")
        ax.set_title(specimen)
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)


if __name__ == "__main__":
    main()
