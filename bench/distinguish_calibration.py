"""How well ``bgc distinguish`` predicted a campaign's isolation, from its runs.

    .venv/bin/python bench/distinguish_calibration.py [--runs out/sweep/runs.csv]

Every faulty run of a campaign carries the prediction made for its scenario
before any data (``separation``: the smallest probability that the data,
with the model's priors, name the truth over a rival; ``separable``: it is at
least 0.95). Among the runs bgc detected, this prints per plant how often
bgc's most probable hypothesis is right in each band of that probability. A
calibrated prediction is right about as often as it says in each band; the
runs predicted separable are the ones the campaign's summary counts in
"right where the data separate it (predicted)". Then every run predicted
separable that bgc got wrong, to look at.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


from bgc.experiment import runs_csv

BANDS = ((0.0, 0.5), (0.5, 0.8), (0.8, 0.95), (0.95, 0.99), (0.99, 1.0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", default=str(ROOT / "out" / "sweep" / "runs.csv"))
    args = ap.parse_args()
    rows = runs_csv.read_rows(Path(args.runs))
    seen = [r for r in rows if r["status"] == "ok" and r["fault"] and r["delay"] is not None
            and r["separation"] is not None]
    print(f"{len(seen)} detected faulty runs with a prediction, from {args.runs}\n")
    print("| plant | predicted P (band) | runs | bgc right | share right |")
    print("|---|---|---|---|---|")
    for model in sorted({r["model"] for r in seen}):
        mine = [r for r in seen if r["model"] == model]
        for lo, hi in BANDS:
            band = [r for r in mine if lo <= r["separation"] < hi or (hi == 1.0 and r["separation"] == 1.0)]
            if band:
                right = sum(bool(r["right"]) for r in band)
                print(f"| {Path(model).stem} | [{lo:g}, {hi:g}{']' if hi == 1.0 else ')'} | {len(band)} | {right} | "
                      f"{100 * right / len(band):.0f} % |")
    separable = [r for r in seen if r["separable"]]
    right = sum(bool(r["right"]) for r in separable)
    print(f"\npredicted separable: {len(separable)} runs, bgc right in {right} "
          f"({100 * right / max(len(separable), 1):.1f} %); not separable: {len(seen) - len(separable)} runs, "
          f"right in {sum(bool(r['right']) for r in seen if not r['separable'])}")
    wrong = [r for r in separable if not r["right"]]
    if wrong:
        print("\npredicted separable, named wrong:")
        for r in wrong:
            print(f"- {Path(r['model']).stem} {r['scenario']} {r['filter']} noise {r['noise']} seed {r['seed']}: "
                  f"{r['verdict']} {r['diagnosed']} (candidates {r['candidates']}), predicted P "
                  f"{r['separation']:.4f}")


if __name__ == "__main__":
    main()
