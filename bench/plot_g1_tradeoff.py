#!/usr/bin/python3
"""Speed against accuracy of the Smith G1 variants, and BTDF evaluation rates, from a Google
Benchmark JSON file written by bench/optics_bench (scripts/bench.sh runs both).

Usage: /usr/bin/python3 bench/plot_g1_tradeoff.py optics.json out.png
Prints the table it plots; the cost ratios are what to quote (absolute rates depend on the machine).
"""
import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

# Relative error shown for a G1 that is exact (0 error) so it appears on a log axis.
EXACT_FLOOR = 1e-16


def load(path):
    with open(path, encoding="utf-8") as f:
        data = json.load(f)
    rows = {}
    for b in data["benchmarks"]:
        # With repetitions, keep the median aggregate; without, the plain run.
        if b.get("run_type") == "aggregate" and b.get("aggregate_name") != "median":
            continue
        name = b.get("run_name", b["name"])
        rows[name] = b
    return rows


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: plot_g1_tradeoff.py BENCH.json OUT.png")
    rows = load(sys.argv[1])
    g1 = {k.split("/")[-1]: v for k, v in rows.items() if k.startswith("BM_G1/")}
    btdf = {k.split("/")[-1]: v for k, v in rows.items() if k.startswith("BM_Btdf")}
    if not g1:
        sys.exit(f"{sys.argv[1]}: no BM_G1 results (was the benchmark filter too narrow?)")

    ns = {k: 1e9 / v["items_per_second"] for k, v in g1.items()}
    base = ns.get("beckmann_exact")
    print(f"{'G1 variant':20s} {'ns/eval':>9s} {'cost vs exact':>14s} {'max rel err':>12s}")
    for k in sorted(ns, key=ns.get):
        err = g1[k].get("max_rel_err", float("nan"))
        ratio = ns[k] / base if base else float("nan")
        print(f"{k:20s} {ns[k]:9.2f} {ratio:14.2f} {err:12.2e}")

    fig, axes = plt.subplots(1, 2 if btdf else 1, figsize=(11 if btdf else 6, 4.2), squeeze=False)
    ax1 = axes[0][0]
    for k, v in g1.items():
        err = max(v.get("max_rel_err", 0.0), EXACT_FLOOR)
        ax1.scatter(ns[k], err, s=40)
        ax1.annotate(k, (ns[k], err), textcoords="offset points", xytext=(5, 4), fontsize=8)
    ax1.set_xscale("log")
    ax1.set_yscale("log")
    ax1.set_xlabel("time per G1 evaluation (ns, median of repetitions)")
    ax1.set_ylabel("max relative error vs own exact Smith G1")
    ax1.set_title("Smith G1: speed against accuracy")
    ax1.grid(True, which="both", alpha=0.3)
    ax1.axhline(EXACT_FLOOR, color="gray", lw=0.5, ls=":")
    ax1.annotate("exact G1 (plotted at 1e-16)", (0.35, 0.1), xycoords="axes fraction",
                 fontsize=7, color="gray")

    if btdf:
        ax2 = axes[0][1]
        names = sorted(btdf, key=lambda k: btdf[k]["items_per_second"])
        ax2.barh(names, [btdf[k]["items_per_second"] / 1e6 for k in names])
        ax2.set_xlabel("BTDF evaluations per second (millions)")
        ax2.set_title("Full BTDF (eq. 21 / Sun eq. 25)")
        for k in names:
            print(f"BTDF {k:20s} {btdf[k]['items_per_second'] / 1e6:8.1f} M/s")
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)
    print(f"wrote {sys.argv[2]}")


if __name__ == "__main__":
    main()
