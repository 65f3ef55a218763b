"""Drifts found long after they began, on two tanks bgc did not simulate:
the verdicts over many seeds.

    .venv/bin/python bench/late_drifts.py [--seeds 30] [--end 330] [--process 1] [--measurement 1]
                                          [--workers 2]

The data are tests/test_late_drift.py's: the two tanks integrated by scipy's
solve_ivp from the equations written out by hand, one resistance drifting
from t = 150 (R12 up by 0.0055 per s, R10 down by 0.005, R20 up by 0.006;
and no drift at all), the model's process noise and the sensors' own noise
times ``--process`` and ``--measurement`` (0 and 1.3: a plant quieter than
its model, its sensors noisier), seeds 1 to ``--seeds``, the record to
``--end``. Each record is diagnosed
with the default options (``bgc.diagnose``). Prints per scenario the runs,
how many are isolated on the truth, isolated on another fault (a
confident wrong answer), ambiguous with the truth among the candidates,
any other verdict, the seeds of the wrong isolations, and the mean seconds
of a diagnosis; for the fault-free runs, how many say "no fault". A
change's effect is two runs of this script, before and after it (a
worktree of the commit before, run with ``PYTHONPATH`` at it).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

#: (parameter, slope per s): the drifts tried; a slope of 0 is the fault-free plant.
SCENARIOS = (("R12", 0.0055), ("R10", -0.005), ("R20", 0.006), ("R12", 0.0))


_SESSION = []  # per worker process, the two tanks opened once


def _diagnose(job):
    import bgc
    from bgc.diagnosis.options import DiagnosisOptions
    from test_late_drift import drifting_tanks

    if not _SESSION:
        _SESSION.append(bgc.open(str(ROOT / "models" / "two_tank.yaml")))
    parameter, slope, end, seed, process, measurement = job
    run = drifting_tanks(parameter, slope, 150.0, end, seed, process, measurement)
    started = time.perf_counter()
    d = bgc.diagnose(_SESSION[0], data=run, options=DiagnosisOptions(seed=seed)).diagnosis
    return job, d.verdict, d.candidates, time.perf_counter() - started


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--end", type=float, default=330.0)
    ap.add_argument("--process", type=float, default=1.0)
    ap.add_argument("--measurement", type=float, default=1.0)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    jobs = [(p, s, a.end, seed, a.process, a.measurement) for p, s in SCENARIOS for seed in range(1, a.seeds + 1)]
    tally: dict[tuple, Counter] = {(p, s): Counter() for p, s in SCENARIOS}
    wrong: dict[tuple, list[int]] = {(p, s): [] for p, s in SCENARIOS}
    seconds: dict[tuple, float] = {(p, s): 0.0 for p, s in SCENARIOS}
    with ProcessPoolExecutor(a.workers) as pool:
        for (p, s, _, seed, _, _), verdict, candidates, took in pool.map(_diagnose, jobs):
            truth = f"{p}_incipient"
            t = tally[(p, s)]
            seconds[(p, s)] += took
            if s == 0.0:
                t[verdict] += 1
            elif verdict == "isolated":
                t["right" if candidates == (truth,) else "wrong"] += 1
                if candidates != (truth,):
                    wrong[(p, s)].append(seed)
            elif verdict == "ambiguous" and truth in candidates:
                t["ambiguous, truth among"] += 1
            elif verdict == "mismatch":
                t["mismatch, truth among" if truth in candidates else "mismatch"] += 1
            else:
                t[verdict] += 1
    print(f"two tanks by solve_ivp, drift from t = 150, record to t = {a.end:g}, seeds 1 to {a.seeds}, noise: process "
          f"{a.process:g} and measurement {a.measurement:g} times the model's")
    print(f"{'scenario':<16} {'runs':>4} {'isolated right':>14} {'isolated wrong':>14} {'ambiguous (truth)':>17} "
          f"{'other':<28} {'s/run':>6}  wrong seeds")
    for p, s in SCENARIOS:
        t = tally[(p, s)]
        n = sum(t.values())
        name = "no drift" if s == 0.0 else f"{p} {s:+g}/s"
        if s == 0.0:
            other = ", ".join(f"{v} {k}" for k, v in sorted(t.items()))
            print(f"{name:<16} {n:>4} {'':>14} {'':>14} {'':>17} {other:<28} {seconds[(p, s)] / n:6.1f}")
            continue
        rest = ", ".join(f"{v} {k}" for k, v in sorted(t.items()) if k not in ("right", "wrong", "ambiguous, truth among"))
        print(f"{name:<16} {n:>4} {t['right']:>14} {t['wrong']:>14} {t['ambiguous, truth among']:>17} {rest or '-':<28} "
              f"{seconds[(p, s)] / n:6.1f}  {' '.join(map(str, wrong[(p, s)])) or '-'}")


if __name__ == "__main__":
    main()
