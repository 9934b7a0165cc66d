#!/usr/bin/env python3
"""alpha's coverage table over one or more series of fitted runs.

bench/instrument_coverage.sh fits each run into DIR/fitN/fit_summary.json (its work directory, or
COVERAGE_KEEP). A case is often run as several series (one per SIM_SEED, two at a time on their
own loopbacks): this puts them into one table. Per fit (normal incidence, joint): the runs
converged, how many 2-sigma intervals cover the truth, the mean bias over the mean sigma, the
pulls' rms, the mean sigma and its geometry part, and the range of chi^2/dof. --pulls also lists
each run's pull. --by-floor splits each fit's row by gonio-fit's floor choice (Floor::kAuto): kept
because BIC shows it, kept only because leaving it out moves the width by more than half its sigma
(a choice made on the data, so the fits it keeps are those whose floor-fitted width lies far from
the floor-free one), or left out with that move in sigma.

  bench/coverage/coverage_table.py TRUTH DIR [DIR...] [--pulls] [--by-floor]
"""
import argparse
import json
import math
import pathlib
import re
import statistics
import sys


def runs_in(directory):
    """fitN/fit_summary.json under directory, in N's order."""
    d = pathlib.Path(directory)
    if not d.is_dir():
        sys.exit(f"coverage_table: {directory}: not a directory")
    found = []
    for p in d.glob("fit*/fit_summary.json"):
        m = re.fullmatch(r"fit(\d+)", p.parent.name)
        if m:
            found.append((int(m.group(1)), p))
    if not found:
        sys.exit(f"coverage_table: {directory}: no fitN/fit_summary.json")
    return [p for _, p in sorted(found)]


def first_fit(path, key):
    try:
        s = json.load(open(path))
        f = s[key][0]
        w = f["width"]
        return (float(w["value"]), float(w["sigma"]), float(w.get("sigma_geometry", 0.0)),
                float(f["reduced_chi2"]), str(f["status"]),
                floor_kind(str(f.get("floor_choice", ""))))
    except (OSError, ValueError) as e:
        sys.exit(f"coverage_table: {path}: {e}")
    except (KeyError, IndexError, TypeError) as e:
        sys.exit(f"coverage_table: {path}: not a gonio-fit summary (no {key}[0]: {e})")


def floor_kind(choice):
    """gonio-fit's floor_choice (fitting/fitter.cc, FitWithFloor) as the rule that made it."""
    if choice.startswith("floor kept: BIC lower by only"):
        return "floor kept for the width's move"
    if choice.startswith("floor kept"):
        return "floor kept by BIC"
    if choice.endswith("which is in sigma"):
        return "no floor, its move in σ"
    return "no floor" if choice.startswith("no floor") else "floor not chosen"


def table(truth, paths, show_pulls, by_floor=False):
    lines = ["| fit | runs converged | 2σ covers truth | mean bias / mean σ | pull rms | mean σ(α) "
             "| of which geometry | χ²/dof range |", "|---|---|---|---|---|---|---|---|"]
    pull_lines = []
    fits = []
    for name, key in (("normal incidence", "normal_incidence_fits"), ("joint", "fits")):
        rows = [first_fit(p, key) for p in paths]
        kinds = sorted({r[5] for r in rows}) if by_floor else [None]
        fits += [(name if k is None else f"{name}, {k}", [r for r in rows if k in (None, r[5])])
                 for k in kinds]
    for name, rows in fits:
        ok = [r for r in rows if r[4] == "converged"]
        pulls = [(a - truth) / s for a, s, *_ in ok if s > 0]
        if not ok:
            lines.append(f"| {name} | 0/{len(rows)} | – | – | – | – | – | – |")
            continue
        covered = sum(abs(p) < 2 for p in pulls)
        mean_sigma = statistics.fmean(r[1] for r in ok)
        bias = statistics.fmean(r[0] for r in ok) - truth
        rms = math.sqrt(statistics.fmean(p * p for p in pulls)) if pulls else float("nan")
        geo = statistics.fmean(r[2] for r in ok)
        chi = [r[3] for r in ok]
        lines.append(f"| {name} | {len(ok)}/{len(rows)} | {covered}/{len(pulls)} "
                     f"| {bias / mean_sigma:+.2f} | {rms:.2f} | {mean_sigma:.2g} | {geo:.2g} "
                     f"| {min(chi):.2f}–{max(chi):.2f} |")
        pull_lines.append(f"{name} pulls: " + " ".join(f"{p:+.2f}" for p in pulls))
    return "\n".join(lines + (["", *pull_lines] if show_pulls else []))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("truth", help="the simulated sample's alpha")
    ap.add_argument("dirs", nargs="+", help="directories holding fitN/fit_summary.json")
    ap.add_argument("--pulls", action="store_true", help="also list each run's pull")
    ap.add_argument("--by-floor", action="store_true",
                    help="a row for each floor choice (kept by BIC, kept for the width's move, "
                    "left out)")
    a = ap.parse_args()
    try:
        truth = float(a.truth)
    except ValueError:
        sys.exit(f"coverage_table: TRUTH must be a number, not '{a.truth}'")
    if not math.isfinite(truth) or truth <= 0:
        sys.exit(f"coverage_table: TRUTH must be a positive width, not {a.truth}")
    print(table(truth, [p for d in a.dirs for p in runs_in(d)], a.pulls, a.by_floor))


if __name__ == "__main__":
    main()
