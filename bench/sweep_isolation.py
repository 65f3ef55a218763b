"""The sweep's isolation per plant, fault kind and filter, from its runs.

    .venv/bin/python bench/sweep_isolation.py [--runs out/sweep/runs.csv]

Reads a finished sweep (``bgc experiment experiments/sweep.yaml -o
out/sweep``) and prints, per group, fault kind and filter, among the faulty
runs bgc detected: how many it names right (its most probable hypothesis is
the truth), how many have the truth among the survivors, how many it
isolates (one survivor) and how many of those are right. These are the
columns ``bench/isolation_reference.py`` sets beside the exact Bayes
classifier (whose rows do not depend on bgc's isolation: the detected runs
are the nominal observer's).
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


from bgc.experiment import runs_csv


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", default=str(ROOT / "out" / "sweep" / "runs.csv"))
    a = ap.parse_args()
    if not Path(a.runs).is_file():
        sys.exit(f"{a.runs}: no finished sweep; run: bgc experiment experiments/sweep.yaml -o out/sweep")
    tally = defaultdict(lambda: [0, 0, 0, 0, 0])
    for r in runs_csv.read_rows(Path(a.runs)):
        if r["kind"] is None or r["detected"] is not True:
            continue
        t = tally[(r["group"], r["kind"], r["filter"])]
        t[0] += 1
        t[1] += bool(r["right"])
        t[2] += bool(r["in_candidates"])
        t[3] += r["verdict"] == "isolated"
        t[4] += r["verdict"] == "isolated" and bool(r["right"])
    print("| group | kind | filter | detected | right | truth among survivors | isolated | right when isolated |")
    print("|---|---|---|---|---|---|---|---|")
    for (g, k, f), (n, right, among, iso, iso_right) in sorted(tally.items()):
        print(f"| {g} | {k} | {f} | {n} | {right} ({100 * right / n:.0f} %) | {among} ({100 * among / n:.0f} %) "
              f"| {iso} | {iso_right} |")


if __name__ == "__main__":
    main()
