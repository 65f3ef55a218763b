"""No fault weighed after an alarm (issue 48), against the faults alone,
side by side on the same runs: each run diagnosed twice, with
``DiagnosisOptions(no_fault=True)`` (the default) and ``no_fault=False``
(``--faults-only``: the thesis's verdict, an alarm always ends in a fault
named or "unexplained").

Fault-free runs of the three shipped plants (seeds 0 on) with the
detector's false-alarm probability raised (``--false-alarm``, 0.3 per
horizon, so that about a third of the runs alarm on chance alone): printed,
the runs that alarmed and their verdicts each way (an alarm on one reading
found a glitch, the diagnosis made again without it: "no fault (a
glitch)", docs/diagnosis.md section 6.2). Then faulty runs (the
documented scenarios of each plant, ``--faulty`` seeds from 0, at the default false-alarm
probability): the verdicts each way and how often the verdict named the
true fault (isolated on it, or it among an ambiguous verdict's candidates).

    .venv/bin/python bench/no_fault.py --runs 20 --faulty 5
    .venv/bin/python bench/no_fault.py --runs 100 --faulty 0
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402

MODELS = ("circuit", "two_tank", "ro")
#: Faulty scenarios per plant (the docs' own), at sizes a diagnosis isolates and a smaller one.
FAULTS = {
    "circuit": ("R2:abrupt:0.6@5", "R2:abrupt:0.2@10"),
    "two_tank": ("R12:abrupt:0.6@75", "R12:abrupt:0.15@75", "F12:bias:0.05@75"),
    "ro": ("R_pipe:abrupt:31@165", "P_memb:bias:30@165"),
}


def _named(d, truth: str) -> bool:
    return d.verdict in ("isolated", "ambiguous") and any(c.startswith(truth) for c in d.candidates)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=20, help="fault-free runs per plant")
    p.add_argument("--faulty", type=int, default=5, help="runs per faulty scenario (0: none)")
    p.add_argument("--false-alarm", type=float, default=0.3)
    args = p.parse_args(argv)
    print(f"bench/no_fault.py --runs {args.runs} --faulty {args.faulty} --false-alarm {args.false_alarm:g}")
    start = time.perf_counter()
    print(f"\nfault-free runs, false-alarm probability {args.false_alarm:g} per horizon: verdicts of the runs "
          f"that alarmed (no fault weighed | faults alone)")
    for name in MODELS:
        s = bgc.open(ROOT / "models" / f"{name}.yaml")
        each = {True: Counter(), False: Counter()}
        for seed in range(args.runs):
            run = bgc.simulate(s, "none", seed=seed).run
            for weigh in (True, False):  # (the detection is the same both ways: a run that does not alarm, once)
                d = bgc.diagnose(s, run, options=bgc.DiagnosisOptions(false_alarm=args.false_alarm,
                                                                      no_fault=weigh)).diagnosis
                glitch = any(type(e).__name__ == "Glitch" for e in d.events)  # alarmed, found a glitch
                if d.detection is None and not glitch:
                    break
                each[weigh][d.verdict + (" (a glitch)" if glitch else "")] += 1
        alarmed = sum(each[True].values())
        print(f"  {name:9s} {alarmed:3d} of {args.runs} alarmed | no fault weighed: "
              f"{dict(sorted(each[True].items()))} | faults alone: {dict(sorted(each[False].items()))}")
    runs = args.faulty
    print(f"\nfaulty runs (seeds 0 to {runs - 1}), the default false-alarm probability: verdicts, and the true "
          f"fault named (no fault weighed | faults alone)")
    for name in MODELS if runs else ():
        s = bgc.open(ROOT / "models" / f"{name}.yaml")
        for scenario in FAULTS[name]:
            each = {True: Counter(), False: Counter()}
            named = {True: 0, False: 0}
            for seed in range(runs):
                run = bgc.simulate(s, scenario, seed=seed).run
                for weigh in (True, False):
                    d = bgc.diagnose(s, run, options=bgc.DiagnosisOptions(no_fault=weigh)).diagnosis
                    each[weigh][d.verdict] += 1
                    named[weigh] += _named(d, scenario.split(":")[0])
            print(f"  {name:9s} {scenario:22s} named {named[True]}/{runs} {dict(sorted(each[True].items()))} | "
                  f"named {named[False]}/{runs} {dict(sorted(each[False].items()))}")
    print(f"\n({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
