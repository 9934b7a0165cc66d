#!/usr/bin/env python3
"""Each stored value against what the simulated scene put into its rectangle, and where the error
of each run's width comes from.

Per point, with its frames in gonio-sim's truth log (matched as lamp_check.py matches them: the
last `frames` open-shutter frames at its read-back angles) and the scene rendered at the angles the
stages were truly at (gonio-sim-render, noise-free, at the lamp's nominal output):

  camera   value x monitor_w / (scene x lamp)  - 1   what the camera and the reduction measured
           against what the lamp lit the scene with over the point's frames (its error should be
           the statistical sigma)
  norm     monitor_w / lamp - 1                      the monitor's reading against what the lamp
           did over the frames (its error should be the lamp and monitor terms)
  value    value / scene - 1                         the stored value's whole error (sigma)

Each is taken relative to its run's weighted mean (the scale is fitted anyway). The table gives
their pulls' rms over every point, per run: then the width error each part implies, the weighted
least-squares projection of its residuals on the scene's change with alpha (rendered at alpha and
alpha (1 + 1e-3)) beside a free scale and a constant floor (as gonio-fit fits them), in units of the fit's own sigma(alpha) from the stored sigmas,
at the true angles, beside what that part's own sigmas predict for them (the statistical for the
camera, the lamp, monitor and background terms for the normalisation). A part whose width errors
spread wider than its sigmas say leaves out an error that the points of a run share.

  bench/coverage/value_check.py RENDER SIM_TOML TRUTH_CSV EXPORT_CSV...

RENDER is build/sim/gonio-sim-render; SIM_TOML the config the runs were simulated with (its alpha).
"""
import csv
import json
import math
import os
import re
import subprocess
import sys
import tempfile

import truth_log


def fail(message):
    sys.exit(f"value_check: {message}")


def read_export(path):
    try:
        text = open(path).read().splitlines()
    except OSError as e:
        fail(str(e))
    rect = None
    for line in text:
        m = re.match(r"# response: (.*)", line)
        if m:
            r = json.loads(m.group(1))["rectangle"]
            rect = (r["x"], r["y"], r["width"], r["height"])
    if rect is None:
        fail(f"{path}: no '# response:' line with the rectangle")
    rows = list(csv.DictReader(l for l in text if not l.startswith("#")))
    return rect, rows


def render(tool, config, rect, angles):
    with tempfile.NamedTemporaryFile("w", suffix=".csv", delete=False) as f:
        for s, a in angles:
            f.write(f"{s!r},{a!r}\n")
        name = f.name
    try:
        out = subprocess.run([tool, "--config", config, "--rect", ",".join(map(str, rect))],
                             stdin=open(name), capture_output=True, text=True, check=True).stdout
    except subprocess.CalledProcessError as e:
        fail(f"{tool}: {e.stderr.strip()}")
    finally:
        os.unlink(name)
    return [float(r["rate_e_per_s"]) for r in csv.DictReader(out.splitlines())]


def with_alpha(config, factor):
    text = open(config).read()
    m = re.search(r"^alpha = ([0-9.eE+-]+)", text, re.M)
    if not m:
        fail(f"{config}: no 'alpha = ' line")
    f = tempfile.NamedTemporaryFile("w", suffix=".toml", delete=False)
    f.write(text[:m.start(1)] + repr(float(m.group(1)) * factor) + text[m.end(1):])
    f.close()
    return f.name


def solve(m, b):
    """m x = b by Gauss-Jordan with partial pivoting (m small and well conditioned); and m^-1."""
    n = len(m)
    a = [row[:] + [1.0 if i == j else 0.0 for j in range(n)] for i, row in enumerate(m)]
    for c in range(n):
        p = max(range(c, n), key=lambda r: abs(a[r][c]))
        a[c], a[p] = a[p], a[c]
        pivot = a[c][c]
        a[c] = [x / pivot for x in a[c]]
        for r in range(n):
            if r != c:
                f = a[r][c]
                a[r] = [x - f * y for x, y in zip(a[r], a[c])]
    inv = [row[n:] for row in a]
    return [sum(inv[i][j] * b[j] for j in range(n)) for i in range(n)], inv


def project(res, sig, columns, err):
    """Weighted least squares (weights 1 / sig^2) of res on the columns: the second column's
    coefficient, its sigma, and its sigma were the residuals' errors `err` instead (independent)."""
    k = len(columns)
    w = [1 / s ** 2 for s in sig]
    ata = [[sum(wi * ca * cb for wi, ca, cb in zip(w, columns[a], columns[b])) for b in range(k)]
           for a in range(k)]
    atb = [sum(wi * ca * r for wi, ca, r in zip(w, columns[a], res)) for a in range(k)]
    x, inv = solve(ata, atb)
    # The sandwich: row 1 of inv A'W, applied to errors of variance err^2.
    row = [sum(inv[1][a] * columns[a][i] for a in range(k)) * w[i] for i in range(len(res))]
    return x[1], math.sqrt(inv[1][1]), math.sqrt(sum((r * e) ** 2 for r, e in zip(row, err)))


def main():
    if len(sys.argv) < 5:
        sys.exit(__doc__.strip().splitlines()[-3].strip())
    tool, config, truth = sys.argv[1:4]
    match = truth_log.Matcher(truth_log.groups(truth, "value_check"), "value_check")
    bumped = with_alpha(config, 1.001)
    print("| run | points | camera pull rms | norm pull rms | value pull rms "
          "| width error / σ(α): camera | norm | value |")
    print("|---|---|---|---|---|---|---|---|")
    totals = {"camera": [], "norm": [], "value": []}
    expected = {"camera": [], "norm": [], "value": []}  # what each part's own sigmas predict
    for path in truth_log.in_measured_order(sys.argv[4:]):
        rect, rows = read_export(path)
        points = []
        for r in rows:
            key, frames = match.frames(r, path)
            if len(frames) < int(r["frames"]) or not r["monitor_w"]:
                continue
            lamp = sum(x[1] for x in frames) / len(frames)
            points.append((key, float(r["value"]), float(r["monitor_w"]), lamp,
                           float(r["sigma_stat"]), float(r["sigma"])))
        scene = render(tool, config, rect, [p[0] for p in points])
        scene2 = render(tool, bumped, rect, [p[0] for p in points])
        keep = [(p, s, s2) for p, s, s2 in zip(points, scene, scene2) if s > 0 and p[1] > 0]
        grad = [math.log(s2 / s) / math.log(1.001) for _, s, s2 in keep]
        parts = {
            # (the part's relative error, its relative sigma)
            "camera": [(v * mw / (s * lamp), st / v) for (_, v, mw, lamp, st, _), s, _ in keep],
            "norm": [(mw / lamp, math.sqrt(max(sg * sg - st * st, 0)) / v)
                     for (_, v, mw, lamp, st, sg), _, _ in keep],
            "value": [(v / s, sg / v) for (_, v, _, _, _, sg), s, _ in keep],
        }
        cells = []
        widths = []
        for name in ("camera", "norm", "value"):
            x = parts[name]
            ok = [(r, sg) for r, sg in x if sg > 0]
            mean = sum(r / sg ** 2 for r, sg in ok) / sum(1 / sg ** 2 for _, sg in ok)
            res = [r / mean - 1 for r, _ in x]
            sig = [sg for _, sg in x]
            pulls = [e / sg for e, sg in zip(res, sig) if sg > 0]
            cells.append(f"{math.sqrt(sum(p * p for p in pulls) / len(pulls)):.2f}")
            # The width error: the value's sigma is the fit's weights for every part. Beside the
            # scale and alpha, the fit's constant floor (in value units, so relative to each point
            # peak / scene), which takes an offset the tails share.
            vsig = [s for _, s in parts["value"]]
            peak = max(s for _, s, _ in keep)
            use = [(e, vs, gr, peak / s, sg)
                   for e, vs, gr, (_, s, _), sg in zip(res, vsig, grad, keep, sig) if vs > 0]
            dln, sdln, expect = project([u[0] for u in use], [u[1] for u in use],
                                        [[1.0] * len(use), [u[2] for u in use],
                                         [u[3] for u in use]], [u[4] for u in use])
            widths.append(dln / sdln)
            totals[name].append(dln / sdln)
            expected[name].append((expect / sdln) ** 2)
        print(f"| {os.path.basename(path)} | {len(keep)} | " + " | ".join(cells) + " | " +
              " | ".join(f"{w:+.2f}" for w in widths) + " |")
    os.unlink(bumped)
    print()
    for name, w in totals.items():
        rms = math.sqrt(sum(x * x for x in w) / len(w))
        said = math.sqrt(sum(expected[name]) / len(w))
        print(f"{name}: width errors' rms over {len(w)} runs {rms:.2f} (its sigmas say {said:.2f}), "
              f"mean {sum(w) / len(w):+.2f}")


if __name__ == "__main__":
    main()
