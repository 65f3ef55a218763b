"""Compare bgc's filters on the two tanks, each on its own estimate.

Simulates RUNS runs of each fault scenario from Python (bgc.simulate), diagnoses every run with
the particle filters GPF, APF and OPF sizing the fault by their own magnitude state
(identify="filter": without it every filter's estimate would be the same Kalman grid's) and with
the cubature Kalman filter (CKF, whose own estimate is that grid's), and prints a DataFrame of
the onset and size errors, then the mean over runs per filter, where every run whose error is not
defined (the fault not named, no estimate) is counted as NaN, not dropped.

    python docs/examples/compare_filters.py                 # 4 faults x 5 runs x 4 filters
    python docs/examples/compare_filters.py --runs 1 --scenarios R12:abrupt:0.5@75 --particles 200
"""

from __future__ import annotations

import argparse
import math

import pandas as pd

import bgc

MODEL = "models/two_tank.yaml"
SCENARIOS = ("R10:abrupt:0.8@75", "R12:abrupt:0.5@75", "R20:abrupt:0.6@75", "R12:incipient:0.01@60")
FILTERS = ("gpf", "apf", "opf", "ckf")


def one_run(session, sim, filter: str, particles: int, seed: int) -> dict:
    """One diagnosis of ``sim`` by ``filter``, with its own estimate, as a row of errors."""
    identify = "kalman" if filter == "ckf" else "filter"  # ckf has no particle filter of the magnitude
    r = bgc.diagnose(session, data=sim, filter=filter, identify=identify, particles=particles, seed=seed)
    d, truth = r.diagnosis, sim.truth
    name = truth["hypothesis"]  # the fault model's name as bgc gives it: R12_abrupt, F12_offset_bias
    named = bool(d.candidates) and d.candidates[0] == name
    e = d.estimate if named else None
    return {"scenario": sim.scenario, "filter": filter, "seed": seed, "verdict": d.verdict,
            "right": named and d.verdict == "isolated", "candidates": list(d.candidates),
            "onset_error": d.onset - truth["onset"] if named else math.nan,
            "size_error_pct": 100 * (e.value - truth["magnitude"]) / abs(truth["magnitude"]) if e else math.nan,
            "covers": e.low <= truth["magnitude"] <= e.high if e else None,
            "estimate_method": e.method if e else None}


def summary(runs: pd.DataFrame) -> pd.DataFrame:
    """Per filter: runs, right verdicts, the mean |onset error| and |size error| (its standard deviation
    over the runs beside it) with how many were NaN."""
    def stats(g: pd.DataFrame) -> pd.Series:
        onset, size = g["onset_error"].abs(), g["size_error_pct"].abs()
        return pd.Series({"runs": len(g), "isolated_right": int(g["right"].sum()),
                          "mean_abs_onset_error": onset.mean(), "onset_nan": int(onset.isna().sum()),
                          "mean_abs_size_error_pct": size.mean(), "sd_abs_size_error_pct": size.std(),
                          "size_nan": int(size.isna().sum()),
                          "estimate_method": ",".join(sorted(set(g["estimate_method"].dropna())))})
    return runs.groupby("filter", sort=False)[list(runs.columns)].apply(stats)


def main(argv=None) -> pd.DataFrame:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=5, help="simulated runs per scenario (seeds 1..RUNS)")
    p.add_argument("--particles", type=int, default=500)
    p.add_argument("--scenarios", default=",".join(SCENARIOS), help="comma-separated NAME:KIND:MAGNITUDE@TIME")
    p.add_argument("--filters", default=",".join(FILTERS))
    args = p.parse_args(argv)
    session = bgc.open(MODEL)
    rows = []
    for scenario in args.scenarios.split(","):
        for seed in range(1, args.runs + 1):
            sim = bgc.simulate(session, scenario, seed=seed)
            rows += [one_run(session, sim, f, args.particles, seed) for f in args.filters.split(",")]
    runs = pd.DataFrame(rows)
    with pd.option_context("display.width", 160, "display.max_columns", 20):
        print(runs.to_string(index=False))
        print()
        print(summary(runs).to_string())
    return runs


if __name__ == "__main__":
    main()
