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
alpha (1 + 1e-3)) beside a free scale, in units of the fit's own sigma(alpha) from the stored sigmas,
at the true angles. A part whose per-run width errors spread wider than 1 leaves out an error that
the points of a run share.

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

STEP_DEG = 1e-3  # config/sim.toml's 1000 steps per degree


def fail(message):
    sys.exit(f"value_check: {message}")


def truth_groups(path):
    groups = []  # consecutive frames at one pair of true stage angles
    try:
        for r in csv.DictReader(open(path)):
            key = (float(r["sample_deg"]), float(r["arm_deg"]))
            if not groups or groups[-1][0] != key:
                groups.append((key, []))
            if r["shutter_closed"] == "0":
                groups[-1][1].append((float(r["exposure_s"]), float(r["lamp_relative"])))
    except (OSError, KeyError, ValueError) as e:
        fail(f"{path}: {e}")
    return groups


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


def project(res, sig, grad):
    """Weighted least squares of res on [1, grad]: the coefficient of grad and its sigma."""
    w = [1 / s ** 2 for s in sig]
    s0 = sum(w)
    s1 = sum(wi * g for wi, g in zip(w, grad))
    s2 = sum(wi * g * g for wi, g in zip(w, grad))
    r0 = sum(wi * r for wi, r in zip(w, res))
    r1 = sum(wi * r * g for wi, r, g in zip(w, res, grad))
    det = s0 * s2 - s1 * s1
    if det <= 0:
        return float("nan"), float("nan")
    return (s0 * r1 - s1 * r0) / det, math.sqrt(s0 / det)


def main():
    if len(sys.argv) < 5:
        sys.exit(__doc__.strip().splitlines()[-3].strip())
    tool, config, truth = sys.argv[1:4]
    groups = truth_groups(truth)
    bumped = with_alpha(config, 1.001)
    g = 0
    print("| run | points | camera pull rms | norm pull rms | value pull rms "
          "| width error / σ(α): camera | norm | value |")
    print("|---|---|---|---|---|---|---|---|")
    totals = {"camera": [], "norm": [], "value": []}
    for path in sys.argv[4:]:
        rect, rows = read_export(path)
        points = []
        for r in rows:
            sr, ar = float(r["sample_read_deg"]), float(r["arm_read_deg"])
            while g < len(groups) and not (abs(groups[g][0][0] - sr) < STEP_DEG / 2 + 1e-9 and
                                           abs(groups[g][0][1] - ar) < STEP_DEG / 2 + 1e-9):
                g += 1
            if g == len(groups):
                fail(f"{path}: no frame at sample {sr}, arm {ar}: is the truth log the run's?")
            n = int(r["frames"])
            frames = groups[g][1][-n:]
            key = groups[g][0]
            g += 1
            if len(frames) < n or not r["monitor_w"]:
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
            use = [(e, sg, gr) for e, sg, gr in zip(res, sig, grad) if sg > 0]
            # The width error: the value's sigma is the fit's weights for every part.
            vsig = [s for _, s in parts["value"]]
            use = [(e, vs, gr) for e, vs, gr, sg in zip(res, vsig, grad, sig) if vs > 0]
            dln, sdln = project([u[0] for u in use], [u[1] for u in use], [u[2] for u in use])
            widths.append(dln / sdln)
            totals[name].append(dln / sdln)
        print(f"| {os.path.basename(path)} | {len(keep)} | " + " | ".join(cells) + " | " +
              " | ".join(f"{w:+.2f}" for w in widths) + " |")
    os.unlink(bumped)
    print()
    for name, w in totals.items():
        rms = math.sqrt(sum(x * x for x in w) / len(w))
        print(f"{name}: width errors' rms over {len(w)} runs {rms:.2f}, mean {sum(w) / len(w):+.2f}")


if __name__ == "__main__":
    main()
