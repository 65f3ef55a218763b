"""What step 6b costs and what it changes: every diagnosis of the regression
corpus with ``recheck`` off and on, side by side in one run.

    .venv/bin/python bench/recheck_cost.py [--repeat 1] [--cases SUBSTR] [--shipped SEEDS]

Step 6b (``DiagnosisOptions.recheck``, docs/diagnosis.md section 6) weighs the
fault models the symbols ruled out by their static posteriors before a
verdict. The cases: tests/regression/cases.json (seven plants, the four
filters, faults and fault-free runs), diagnosed as tests/test_regression.py
does, in this process; each case's two diagnoses alternate in order (off then
on, then on then off) so that drift of the machine's load falls on both
alike, after one untimed diagnosis per plant (imports, compilation). A
diagnosis is timed by the process's CPU seconds (``time.process_time``; the
corpus's two-worker case counts its own process only) and wall-clock seconds;
with ``--repeat K`` a case's time is the median of its K.

The corpus's models are the shipped ones before they declared sensor faults
(tests/regression/models) and test plants: few fault models for the symbols
to rule out. ``--shipped K`` adds the shipped models as they are (the RO
plant's 20 fault models, the circuit's 16, the two tanks' 16): each of
``SHIPPED`` scenarios simulated with seeds 0 .. K-1 and diagnosed (gpf, 1000
particles, one process) with recheck off and on, alternating in the same way.

Prints per plant the seconds off and on and the ratio on / off, then each case
whose verdict or candidates differ, with the injected fault (the case's
simulation) to judge which is right.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(1, str(ROOT / "tests"))


def diagnose(case: dict, recheck: bool):
    """(CPU seconds, wall seconds, diagnosis) of one case with ``recheck``."""
    from bgc import api
    from test_regression import options_for

    sim = case["simulation"]
    options = dataclasses.replace(options_for(case), recheck=recheck)
    return timed(lambda: api.diagnose(ROOT / case["model"], data=ROOT / case["run"], options=options,
                                      process_noise=sim["process_noise"], measurement_noise=sim["measurement_noise"]))


def timed(run):
    """(CPU seconds, wall seconds, diagnosis) of ``run()``, a report."""
    cpu, wall = time.process_time(), time.perf_counter()
    d = run().diagnosis
    return time.process_time() - cpu, time.perf_counter() - wall, d


#: The shipped models' scenarios of ``--shipped``: a parameter's step and drift and a sensor's bias each.
SHIPPED = {
    "models/ro.yaml": ("R_pipe:abrupt:31@165", "R_pipe:incipient:0.5@165", "P_memb:bias:72.7@150"),
    "models/circuit.yaml": ("R2:abrupt:0.6@5", "R2:incipient:0.06@5", "f2:bias:0.5@7.5"),
    "models/two_tank.yaml": ("R12:abrupt:0.8@75", "R12:incipient:0.005@75", "F12:bias:0.0889@75"),
}


def shipped(model: str, scenario: str, seed: int, recheck: bool):
    """(CPU seconds, wall seconds, diagnosis) of a shipped model's scenario with ``recheck``."""
    from bgc import api
    from bgc.diagnosis.options import DiagnosisOptions

    options = DiagnosisOptions(method="gpf", particles=1000, seed=seed, workers=1, recheck=recheck)
    return timed(lambda: api.diagnose(ROOT / model, scenario=scenario, seed=seed, options=options))


def run(case: dict, recheck: bool):
    return shipped(*case["shipped"], recheck) if "shipped" in case else diagnose(case, recheck)


def plant(case: dict) -> str:
    return ("shipped " if "shipped" in case else "") + Path(case["model"]).stem


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=1, help="diagnoses per case and side (the median is kept)")
    parser.add_argument("--cases", default="", help="only the cases whose name contains this")
    parser.add_argument("--shipped", type=int, default=0, metavar="SEEDS",
                        help="also the shipped models' scenarios, with this many seeds each")
    args = parser.parse_args(argv)
    cases = [c for c in json.loads((ROOT / "tests/regression/cases.json").read_text())["cases"]
             if args.cases in c["name"]]
    cases += [{"name": f"shipped {Path(m).stem} {sc} seed {k}", "shipped": (m, sc, k), "model": m,
               "simulation": {"fault": sc}} for m, scs in SHIPPED.items() for sc in scs for k in range(args.shipped)]
    warm = {}
    for c in cases:
        warm.setdefault(plant(c), c)
    for c in warm.values():  # imports and compilation, untimed
        run(c, False)
    times = {c["name"]: {False: [], True: []} for c in cases}
    verdicts = {}
    for r in range(args.repeat):
        for i, c in enumerate(cases):
            for recheck in ((False, True) if (i + r) % 2 == 0 else (True, False)):
                cpu, wall, d = run(c, recheck)
                times[c["name"]][recheck].append((cpu, wall))
                verdicts[(c["name"], recheck)] = (d.verdict, d.candidates)
            print(f"  {c['name']}", file=sys.stderr, flush=True)
    rows: dict[str, dict] = {}
    for c in cases:
        row = rows.setdefault(plant(c), {"cases": 0, False: [0.0, 0.0], True: [0.0, 0.0]})
        row["cases"] += 1
        for side in (False, True):
            cpu = statistics.median(t[0] for t in times[c["name"]][side])
            wall = statistics.median(t[1] for t in times[c["name"]][side])
            row[side][0] += cpu
            row[side][1] += wall
    print("| plant | cases | CPU s, recheck off | CPU s, on | ratio on/off | wall s, off | wall s, on |")
    print("|---|---|---|---|---|---|---|")
    total = {False: [0.0, 0.0], True: [0.0, 0.0]}
    for name, row in rows.items():
        print(f"| {name} | {row['cases']} | {row[False][0]:.2f} | {row[True][0]:.2f} | "
              f"{row[True][0] / row[False][0]:.2f} | {row[False][1]:.2f} | {row[True][1]:.2f} |")
        for side in (False, True):
            total[side][0] += row[side][0]
            total[side][1] += row[side][1]
    print(f"| all | {len(cases)} | {total[False][0]:.2f} | {total[True][0]:.2f} | "
          f"{total[True][0] / total[False][0]:.2f} | {total[False][1]:.2f} | {total[True][1]:.2f} |")
    print()
    changed = [c for c in cases if verdicts[(c["name"], False)] != verdicts[(c["name"], True)]]
    print(f"verdicts that differ: {len(changed)} of {len(cases)}")
    for c in changed:
        off, on = verdicts[(c["name"], False)], verdicts[(c["name"], True)]
        print(f"  {c['name']} (injected: {c['simulation']['fault'] or 'none'}): "
              f"off {off[0]} {', '.join(off[1])}; on {on[0]} {', '.join(on[1])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
