"""Faults on two tanks bgc did not simulate, the plant as its model and a
little off it: the verdicts over many seeds.

    .venv/bin/python bench/off_model_faults.py [--seeds 10] [--first 100] [--off 0.02] [--workers 2]

The data are tests/test_off_model_fault.py's: the two tanks integrated by
scipy's solve_ivp from the equations written out by hand, the model's
noise, from t = 75 one fault (a step of R10, R12, R20 or C1, a sensor F12
or F10 reading off, the inflow delivered 5 % high while logged as 1; or
none), the record to t = 150. Each scenario runs on two plants: the
model's own parameters, and R10 and C1 ``--off`` above and R20 ``--off``
below them (the plant's own steady state). Seeds ``--first`` on. Each
record is diagnosed with the default options (``bgc.diagnose``, one
process each), on the NumPy backend (importing the test module runs
tests/conftest.py, which sets ``BGC_BACKEND=numpy``). Prints per plant and scenario the count of each outcome:
isolated on the truth, isolated on another fault (a confident wrong
answer), ambiguous with the truth among the candidates or without it,
and the other verdicts; then the seeds of the wrong ones. A change's effect
is two runs of this script, before and after it (a worktree of the commit
before, run with ``PYTHONPATH`` at it).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

#: (fault, size): the faults tried from t = 75 (None: no fault).
SCENARIOS = (("R10", 0.5), ("R12", 0.3), ("R20", 0.4), ("C1", -0.3), ("F12", 0.03), ("F10", -0.035),
             ("f_in", 0.05), (None, 0.0))

_SESSION = []  # per worker process, the two tanks opened once


def _diagnose(job):
    import bgc
    from bgc.diagnosis.options import DiagnosisOptions
    from test_off_model_fault import tanks

    if not _SESSION:
        _SESSION.append(bgc.open(str(ROOT / "models" / "two_tank.yaml")))
    plant, fault, size, seed = job
    d = bgc.diagnose(_SESSION[0], data=tanks(plant, fault, size, 75.0, 150.0, seed),
                     options=DiagnosisOptions(seed=seed, workers=1)).diagnosis
    return job, d.verdict, d.candidates


def outcome(fault: str | None, verdict: str, candidates: tuple[str, ...]) -> str:
    """The outcome's column: a fault model of ``fault`` is named ``<fault>_...``."""
    truth = [c.startswith(f"{fault}_") for c in candidates] if fault else []
    if verdict == "isolated":
        return "isolated right" if truth and truth[0] else "ISOLATED WRONG"
    if verdict == "ambiguous":
        return "ambiguous (truth)" if any(truth) else "ambiguous (not)"
    return verdict


def main() -> None:
    from test_off_model_fault import MODEL

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first", type=int, default=100)
    ap.add_argument("--off", type=float, default=0.02)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    off = dict(MODEL, R10=MODEL["R10"] * (1 + a.off), R20=MODEL["R20"] * (1 - a.off), C1=MODEL["C1"] * (1 + a.off))
    plants = (("as its model", MODEL), (f"off by {a.off:g}", off))
    jobs = [(plant, f, s, seed) for _, plant in plants for f, s in SCENARIOS
            for seed in range(a.first, a.first + a.seeds)]
    counts, wrong = Counter(), []
    with ProcessPoolExecutor(a.workers) as pool:
        for (plant, f, s, seed), verdict, candidates in pool.map(_diagnose, jobs):
            name = next(n for n, p in plants if p is plant or p == plant)
            o = outcome(f, verdict, candidates)
            counts[(name, f, o)] += 1
            if o in ("ISOLATED WRONG", "ambiguous (not)"):
                wrong.append(f"{name}, {f}: seed {seed}: {verdict}: {', '.join(candidates)}")
    print(f"two tanks by solve_ivp, a fault from t = 75, record to t = 150, seeds {a.first} to "
          f"{a.first + a.seeds - 1}, the model's noise")
    print("| plant | fault | outcomes |\n|---|---|---|")
    for name, _ in plants:
        for f, s in SCENARIOS:
            said = ", ".join(f"{n} {o}" for (p, g, o), n in sorted(counts.items(), key=lambda kv: -kv[1])
                             if p == name and g == f)
            print(f"| {name} | {f or 'none'} {s:+g} |" .replace(" +0 |", " |") + f" {said} |")
    for line in wrong:
        print(line)


if __name__ == "__main__":
    main()
