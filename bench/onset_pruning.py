"""Pruning a hypothesis's onsets by their evidence: what a tighter bound saves
and whether it changes the estimate.

    .venv/bin/python bench/onset_pruning.py [--runs 10] [--bounds 20 10 7]

The RO plant's R_pipe drift (the thesis's, slope 0.5 from t = 165, model
noise), seeds 100, 101, ...; one diagnosis per seed and per bound on the log
evidence an onset may fall behind the best one (``bgc.diagnosis.hypothesis.PRUNE``),
hypothesis filters in this process (``workers=1``, so that the times add up
the same work). Prints, per bound, the mean slope error, the largest change of
an estimate against the first bound's, and the mean time, with its ratio to the
first bound's.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402
from bgc.diagnosis import hypothesis as runtime  # noqa: E402
from bgc.diagnosis.options import DiagnosisOptions

SCENARIO, TRUTH = "R_pipe:incipient:0.5@165", "R_pipe_incipient"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--bounds", type=float, nargs="+", default=[20.0, 10.0, 7.0])
    args = ap.parse_args()
    kept = runtime.PRUNE
    rows = {}
    try:
        for bound in args.bounds:
            runtime.PRUNE = bound
            values, seconds = [], []
            for i in range(args.runs):
                started = time.perf_counter()
                d = bgc.diagnose(ROOT / "models" / "ro.yaml", scenario=SCENARIO, seed=100 + i,
                                 generated=ROOT / "generated",
                                 options=DiagnosisOptions(seed=100 + i, workers=1)).diagnosis
                seconds.append(time.perf_counter() - started)
                h = next(h for h in d.hypotheses if h.name == TRUTH)
                values.append(h.estimate.value)
            rows[bound] = (np.array(values), np.array(seconds))
    finally:
        runtime.PRUNE = kept
    first = args.bounds[0]
    print(f"RO {SCENARIO}, seeds 100..{99 + args.runs}, hypothesis filters in one process\n")
    print(f"| pruning bound (nats) | mean slope error % | largest change of an estimate vs {first:g} | "
          "mean s per diagnosis | time vs the first |")
    print("|---|---|---|---|---|")
    for bound, (values, seconds) in rows.items():
        error = 100 * np.mean(np.abs(values - 0.5) / 0.5)
        change = np.max(np.abs(values - rows[first][0]))
        print(f"| {bound:g} | {error:.2f} | {change:.4f} | {seconds.mean():.2f} | "
              f"{seconds.mean() / rows[first][1].mean():.2f} |")


if __name__ == "__main__":
    main()
