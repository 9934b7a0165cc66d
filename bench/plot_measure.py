#!/usr/bin/python3
"""Fit time against alpha's bias for the measurement equation's ways (point model, rectangle,
rectangle and apertures, ...), from bench/measurement_tradeoff's Markdown tables.

Usage: /usr/bin/python3 bench/plot_measure.py OUT.png TABLE.md [TABLE.md ...]

One chart: x the median time of a fit (s, log), y the mean bias of alpha over the noise draws in
the fits' own sigmas; a colour per case (sample, family, plate, rectangle), a marker per way, a
case's ways joined, hollow where fewer than 90 % of the draws' 2-sigma intervals covered the truth. The band is the issue's bound
(|mean bias| < 1 sigma). A way that is cheap and inside the band is one that models as much of the
scene as the case needs; one outside it models less.
"""
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

COLUMNS = ["sample", "family", "mm", "rect px", "fit", "median s", "bias", "bias/sigma",
           "noise-free bias/sigma", "coverage", "chi2/dof"]


def read(path):
    """The rows of one table, as dicts; an error names the file and line."""
    rows = []
    try:
        lines = open(path, encoding="utf-8").read().splitlines()
    except OSError as e:
        sys.exit(f"plot_measure: {e}")
    header = None
    for n, line in enumerate(lines, 1):
        if not line.startswith("|") or line.startswith("|---"):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if header is None:
            header = cells
            if header != COLUMNS:
                sys.exit(f"plot_measure: {path}:{n}: not measurement_tradeoff's table "
                         f"(columns {header})")
            continue
        if len(cells) != len(header):
            sys.exit(f"plot_measure: {path}:{n}: {len(cells)} cells, {len(header)} expected")
        r = dict(zip(header, cells))
        try:
            covered, draws = (int(x) for x in r["coverage"].split("/"))
            rows.append({
                "case": f"{r['sample']} {r['family']} {r['mm']} mm {r['rect px']} px",
                "way": r["fit"].split(" (")[0],
                "seconds": float(r["median s"]),
                "pull": float(r["bias/sigma"].split(" ± ")[0]),  # "+0.43 ± 0.21" or "+0.43"
                "covered": covered / draws if draws else 0.0,
            })
        except ValueError as e:
            sys.exit(f"plot_measure: {path}:{n}: {e}")
    if header is None:
        sys.exit(f"plot_measure: {path}: no table")
    return rows


def main():
    if len(sys.argv) < 3:
        sys.exit("usage: plot_measure.py OUT.png TABLE.md [TABLE.md ...]")
    rows = [r for path in sys.argv[2:] for r in read(path)]
    if not rows:
        sys.exit("plot_measure: the tables hold no rows")
    ways = list(dict.fromkeys(r["way"] for r in rows))
    cases = list(dict.fromkeys(r["case"] for r in rows))
    markers = "osD^vP*X"
    colours = plt.get_cmap("tab20")
    fig, ax = plt.subplots(figsize=(10, 6.4))
    ax.axhspan(-1, 1, color="0.9", zorder=0)
    ax.axhline(0, color="0.6", lw=0.8, zorder=0)
    for k, case in enumerate(cases):
        c = colours(k % 20)
        mine = [r for r in rows if r["case"] == case]
        # A case's ways joined in the tables' order: what each step of modelling costs and gives.
        ax.plot([max(r["seconds"], 1e-5) for r in mine], [r["pull"] for r in mine], color=c,
                lw=0.8, alpha=0.6)
        for r in mine:
            ax.scatter(max(r["seconds"], 1e-5), r["pull"], s=50, color=c,
                       marker=markers[ways.index(r["way"]) % len(markers)],
                       facecolors=c if r["covered"] >= 0.9 else "none", zorder=3)
        ax.plot([], [], color=c, lw=2, label=case)
    for w in ways:
        ax.scatter([], [], marker=markers[ways.index(w) % len(markers)], color="0.3", label=w)
    top = max(1.5, max(abs(r["pull"]) for r in rows) * 1.2)
    ax.set_xscale("log")
    ax.set_yscale("symlog", linthresh=2)
    ax.set_ylim(-top, top)
    ax.set_xlabel("median time of one fit (s, one core)")
    ax.set_ylabel("mean bias of alpha over the draws / the fits' sigma")
    ax.set_title("The measurement equation: fit time against alpha's bias\n(grey band: the "
                 "issue's 1 sigma; hollow: 2-sigma intervals covered the truth in under 90 %)",
                 fontsize=10)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False)
    fig.tight_layout()
    fig.savefig(sys.argv[1], dpi=110)


if __name__ == "__main__":
    main()
