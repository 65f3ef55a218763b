"""Step faults of the shipped plants diagnosed over seeds: how often the true
fault is isolated, and how often another fault is isolated in its place
(docs/results.md section 76).

    .venv/bin/python bench/retried_steps.py [--seeds 8] [--reference 40]

bgc's own simulations (``bgc.diagnose(..., scenario=...)``) of the two
tanks' and the circuit's parameter steps and one sensor bias, and, with
``--reference N``, N runs each of the two tanks' R12 and R20 steps (+0.6
from t = 150) by tests/two_tank_reference.py (solve_ivp on the equations by
hand). Each run's verdict is counted as: the truth isolated, another fault
isolated (a confident wrong answer), ambiguous with or without the truth,
or the verdict itself (no fault, unexplained, mismatch). A verdict that is
not the truth isolated is printed. To compare two versions of bgc, run it
from each checkout (``PYTHONPATH=<checkout>``) side by side.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

import bgc  # noqa: E402
import two_tank_reference as reference  # noqa: E402

#: Per plant: the scenarios (bgc's simulator) and the run's samples.
PLANTS = {
    "two_tank": (["R10:abrupt:0.6@150", "R12:abrupt:0.6@150", "R20:abrupt:0.6@150", "R12:incipient:0.004@150",
                  "F12:bias:0.05@150"], 600),
    "circuit": (["R2:abrupt:0.6@5", "R1:abrupt:-0.5@5", "R3:abrupt:0.5@5"], 300),
}


def outcome(d, truth: str) -> str:
    named = truth in d.candidates
    if d.verdict == "isolated":
        return "truth isolated" if named else "ANOTHER FAULT ISOLATED"
    if d.verdict == "ambiguous":
        return "ambiguous, the truth among" if named else "AMBIGUOUS WITHOUT THE TRUTH"
    return d.verdict


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8, help="seeds of bgc's simulator per scenario (from 0)")
    ap.add_argument("--reference", type=int, default=0, help="runs of the hand-derived two tanks per fault")
    args = ap.parse_args()
    counts: dict[str, Counter] = {"bgc's simulator": Counter(), "solve_ivp (tests/two_tank_reference.py)": Counter()}
    started = time.process_time()
    for plant, (scenarios, steps) in PLANTS.items():
        session = bgc.open(str(ROOT / "models" / f"{plant}.yaml"))
        for scenario in scenarios:
            parameter, kind = scenario.split(":")[:2]
            truth = f"{parameter}_{kind}" if kind in ("abrupt", "incipient") else f"{parameter}_offset_{kind}"
            for seed in range(args.seeds):
                d = bgc.diagnose(session, scenario=scenario, steps=steps, seed=seed).diagnosis
                said = outcome(d, truth)
                counts["bgc's simulator"][said] += 1
                if said != "truth isolated":
                    print(f"  {plant} {scenario} seed {seed}: {d.verdict} {', '.join(d.candidates)}", flush=True)
    if args.reference:
        session = bgc.open(str(ROOT / "models" / "two_tank.yaml"))
        with tempfile.TemporaryDirectory() as tmp:
            for parameter in ("R12", "R20"):
                for seed in range(args.reference):
                    run = reference.write(Path(tmp) / "run.csv", reference.run(seed, (parameter, 0.6, 150.0)))
                    d = bgc.diagnose(session, data=run).diagnosis
                    said = outcome(d, f"{parameter}_abrupt")
                    counts["solve_ivp (tests/two_tank_reference.py)"][said] += 1
                    if said != "truth isolated":
                        print(f"  reference {parameter} +0.6 seed {seed}: {d.verdict} {', '.join(d.candidates)}",
                              flush=True)
    kinds = sorted({k for c in counts.values() for k in c})
    print("| simulator | runs | " + " | ".join(kinds) + " |")
    print("|---|---|" + "---|" * len(kinds))
    for name, c in counts.items():
        if sum(c.values()):
            print(f"| {name} | {sum(c.values())} | " + " | ".join(str(c[k]) for k in kinds) + " |")
    print(f"CPU {time.process_time() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
