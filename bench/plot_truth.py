#!/usr/bin/python3
"""Charts of bench/truth_bench's JSON (issue #8).

Usage: /usr/bin/python3 bench/plot_truth.py truth.json cost.png failure.png

cost.png: seconds against error (relative L1 of the transmitted lobe beyond the Monte Carlo noise,
vs a converged explicit-surface Monte Carlo) for the analytic model and both Monte Carlo methods, one panel per s.
failure.png: the error of Walter's and Sun's single-scattering models against explicit surfaces
over smoothness s and incidence, for light from air (n = 1.4) and from glass (n = 1/1.4). Cells
above MEASUREMENT_NOISE (the relative L1 a real sweep resolves) are hatched: there the scene must
use a Monte Carlo ground truth.
"""
import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

MEASUREMENT_NOISE = 0.03
FLOOR = 1e-3  # errors indistinguishable from the Monte Carlo noise are drawn here


def main():
    if len(sys.argv) != 4:
        sys.exit("usage: plot_truth.py TRUTH.json COST.png FAILURE.png")
    with open(sys.argv[1], encoding="utf-8") as f:
        data = json.load(f)

    cases = data["cost_accuracy"]
    fig, axes = plt.subplots(1, len(cases), figsize=(4.2 * len(cases), 4), squeeze=False)
    for ax, case in zip(axes[0], cases):
        for method, marker in (("statistical", "o-"), ("explicit", "s-")):
            rows = [r for r in case["rows"] if r["method"] == method]
            ax.plot([r["seconds"] for r in rows], [max(r["excess_l1"], FLOOR) for r in rows],
                    marker, label=method)
        an = [r for r in case["rows"] if r["method"] == "analytic"][0]
        ax.plot([an["seconds"]], [max(an["excess_l1"], FLOOR)], "r*", ms=12,
                label="analytic (Walter)")
        ax.axhline(MEASUREMENT_NOISE, color="k", ls="--", lw=0.6)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"s = {case['s']:g}")
        ax.set_xlabel("seconds per table")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("L1 beyond MC noise, vs converged explicit MC")
    axes[0][0].legend(fontsize=7)
    fig.suptitle("Ground truth: cost against accuracy (dashed: a measurement's noise; "
                 f"errors below {FLOOR} drawn at {FLOOR})", fontsize=9)
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=100)

    fm = data["failure_map"]
    ns = sorted({r["n"] for r in fm}, reverse=True)
    tis = sorted({r["theta_i"] for r in fm})
    ss = sorted({r["s"] for r in fm})
    fig, axes = plt.subplots(2, len(ns), figsize=(5.2 * len(ns), 6.4), squeeze=False)
    for col, n in enumerate(ns):
        for row, (key, name) in enumerate((("walter_l1", "Walter 2007"), ("sun_l1", "Sun 2008"))):
            ax = axes[row][col]
            grid = np.array([[next(r[key] for r in fm if r["n"] == n and r["theta_i"] == ti
                                   and r["s"] == s) for s in ss] for ti in tis])
            im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis", vmin=0, vmax=1)
            for i in range(len(tis)):
                for j in range(len(ss)):
                    bad = grid[i, j] > MEASUREMENT_NOISE
                    ax.text(j, i, f"{grid[i, j]:.2f}", ha="center", va="center", fontsize=7,
                            color="white" if grid[i, j] < 0.5 else "black",
                            fontweight="bold" if bad else "normal")
                    if bad:
                        ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False,
                                                   hatch="//", edgecolor="red", lw=0))
            ax.set_xticks(range(len(ss)), [f"{s:g}" for s in ss])
            ax.set_yticks(range(len(tis)), [f"{t:g}" for t in tis])
            ax.set_xlabel("smoothness s = tau / sigma")
            ax.set_ylabel("theta_i (deg)")
            ax.set_title(f"{name}, n = {n:.3g}: L1 beyond MC noise", fontsize=9)
            fig.colorbar(im, ax=ax, fraction=0.046)
    fig.suptitle(f"Where single scattering fails against explicit surfaces (hatched: error "
                 f"beyond the Monte Carlo noise > {MEASUREMENT_NOISE}, a measurement's noise)",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(sys.argv[3], dpi=100)
    print(f"wrote {sys.argv[2]} and {sys.argv[3]}")


if __name__ == "__main__":
    main()
