"""gonio-sim's truth log (--truth-log; bench/instrument_coverage.sh keeps it as
COVERAGE_KEEP/truth.csv), matched to exported points: shared by lamp_check.py and value_check.py.

Each exported point is matched, in order, to the next run of consecutive frames at its read-back
angles (within half a step of the true ones), and takes that run's last `frames` open-shutter
frames (the averaged ones: the last ranging try is the first of them).
"""
import csv
import re
import sys

STEP_DEG = 1e-3  # config/sim.toml's 1000 steps per degree


def groups(path, tool):
    """Runs of consecutive frames at one pair of true stage angles: [((sample, arm), [(exposure_s,
    lamp_relative) of each open-shutter frame])]."""
    out = []
    try:
        for r in csv.DictReader(open(path)):
            key = (float(r["sample_deg"]), float(r["arm_deg"]))
            if not out or out[-1][0] != key:
                out.append((key, []))
            if r["shutter_closed"] == "0":
                out[-1][1].append((float(r["exposure_s"]), float(r["lamp_relative"])))
    except (OSError, KeyError, ValueError) as e:
        sys.exit(f"{tool}: {path}: {e}")
    return out


def in_measured_order(paths):
    """The exports in the order their runs were measured, as instrument_coverage.sh numbers them
    (run1.csv, run2.csv, ..., run10.csv): a shell glob puts run10.csv before run2.csv, and the
    matcher, walking the log in order, then takes another run's frames at the same angles (every
    pull but the first run's came out 4-8 times too wide that way)."""
    return sorted(paths, key=lambda p: [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p)])


class Matcher:
    """Walks the truth log's runs of frames along the exports, in the order they were measured."""

    def __init__(self, runs, tool):
        self.runs, self.tool, self.at = runs, tool, 0

    def frames(self, row, path):
        """The true angles and the averaged frames of an exported row."""
        sr, ar = float(row["sample_read_deg"]), float(row["arm_read_deg"])
        g = self.runs
        while self.at < len(g) and not (abs(g[self.at][0][0] - sr) < STEP_DEG / 2 + 1e-9 and
                                        abs(g[self.at][0][1] - ar) < STEP_DEG / 2 + 1e-9):
            self.at += 1
        if self.at == len(g):
            sys.exit(f"{self.tool}: {path}: no frame at sample {sr}, arm {ar}: is the truth log "
                     "the run's?")
        key, frames = g[self.at]
        self.at += 1
        return key, frames[-int(row["frames"]):]
