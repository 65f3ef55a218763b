"""A fault outside the model beside the faults it has, on a thermal plant
bgc did not simulate: the verdicts over seeds.

    .venv/bin/python bench/stretch_misfit.py [--seeds 6] [--first 1]

The plant and its simulator are tests/heat_reference.py's
(tests/data/heat_two_body.yaml: a heater's block conducting to a cooled
load, T1, T2 and the cooler's heat flow read; integrated by scipy's
solve_ivp from its equations written out by hand, the model's noise). From
t = 300 of 600 one of: the block losing 0.5 W/K more to the room (no fault
model has it: the right verdict is "unexplained"), T1 reading 0.9 low, T2
frozen at 58.46 (about its own reading there), or nothing. Each record is
diagnosed with the default options (one process each). Prints per
scenario the count of each verdict (and of those naming the truth), then
each run's verdict. A change's effect is two runs of this script, before
and after it (a worktree of the commit before, run with ``PYTHONPATH`` at
it; the script and the test's plant from this checkout: ``--root``).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: (name, leak W/K, T1 bias, T2 stuck value, the fault model that is the truth (None: none is))
SCENARIOS = (("loss of the block", 0.5, 0.0, None, None), ("T1 bias -0.9", 0.0, -0.9, None, "T1_offset_bias"),
             ("T2 frozen", 0.0, 0.0, 58.46, "T2_stuck_stuck"), ("none", 0.0, 0.0, None, None))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--first", type=int, default=1)
    ap.add_argument("--root", default=str(ROOT), help="the checkout whose tests/ holds the plant (default: this one)")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(Path(a.root) / "tests"))
    import bgc
    from bgc.diagnosis.options import DiagnosisOptions
    from heat_reference import MODEL, heated

    session = bgc.open(str(MODEL))
    print(f"heat_two_body by solve_ivp, a fault from t = 300, record to t = 600, seeds {a.first} to "
          f"{a.first + a.seeds - 1}, the model's noise (bgc {bgc.__file__})")
    rows, lines = [], []
    for name, leak, bias, stuck, truth in SCENARIOS:
        counts = Counter()
        for seed in range(a.first, a.first + a.seeds):
            d = bgc.diagnose(session, data=heated(leak, bias, 300.0, 600, seed=seed, stuck=stuck),
                             options=DiagnosisOptions(seed=seed, workers=1)).diagnosis
            right = truth is not None and truth in d.candidates
            key = d.verdict + (" (truth)" if right and d.verdict in ("isolated", "ambiguous") else "")
            counts[key] += 1
            lines.append(f"{name}, seed {seed}: {d.verdict}: {', '.join(d.candidates) or '-'}")
            print(lines[-1], flush=True)
        rows.append((name, ", ".join(f"{n} {k}" for k, n in counts.most_common())))
    print("| fault | verdicts |")
    print("|---|---|")
    for name, text in rows:
        print(f"| {name} | {text} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
