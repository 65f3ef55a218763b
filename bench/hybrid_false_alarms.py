"""False alarms at mode switches, and what a diagnosis across modes costs:
fault-free runs of the valve RO (models/ro_hybrid_valve.yaml, the valve in
the data) cycling through its three settings, diagnosed with the mode from
the run's mode column, beside the same number of samples of the RO of one
mode (models/ro.yaml), in one run.

    .venv/bin/python bench/hybrid_false_alarms.py [--runs 100] [--steps 300] [--noise 1,2]

Each run k has its own seed and its own schedule: the plant stays in
primary, secondary and purge for a time drawn uniformly from [40, 80],
[20, 50] and [10, 30] s (seeded by k), cycle after cycle, from t = 0 to the
run's end (at least 3 switches in a run of 300 s). At each noise factor F the
runs are simulated and diagnosed at F times the model's levels (process 0.03
F, measurement 0.02 F: ``process_noise`` and ``measurement_noise``), so the
diagnoser knows the noise. A false alarm is a run whose diagnosis is not "no
fault" (the detector's budget: a false-alarm probability of 0.01 per horizon,
the run). The cost is the CPU seconds of each diagnosis (``time.process_time``,
the same process; the two models alternate in order), the single-mode RO on
a fault-free run of the same seed, noise and length; the table gives the
medians and their ratio.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

HYBRID = ROOT / "models" / "ro_hybrid_valve.yaml"
SINGLE = ROOT / "models" / "ro.yaml"
#: Each setting's dwell time, uniform on these bounds (s), in cycle order.
DWELL = (("primary", 40.0, 80.0), ("secondary", 20.0, 50.0), ("purge", 10.0, 30.0))


def schedule(seed: int, end: float) -> str:
    """The controlled changes of run ``seed``: cycles of the three settings with drawn dwell times."""
    rng = np.random.default_rng(1000 + seed)
    t, changes, k = 0.0, [], 0
    while True:
        name, low, high = DWELL[k % 3]
        t += float(rng.uniform(low, high))
        if t >= end - 1.0:
            return ",".join(changes)
        k += 1
        changes.append(f"{DWELL[k % 3][0]}@{round(t)}")


def timed(call):
    cpu = time.process_time()
    out = call()
    return time.process_time() - cpu, out


def main(argv=None) -> int:
    import bgc

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--noise", default="1,2", help="noise factors, comma-separated")
    args = parser.parse_args(argv)
    hybrid, single = bgc.open(HYBRID, backend="numpy"), bgc.open(SINGLE, backend="numpy")
    rows = []
    for factor in (float(f) for f in args.noise.split(",")):
        noise = dict(process_noise=0.03 * factor, measurement_noise=0.02 * factor)
        h_session = bgc.open(HYBRID, backend="numpy", **noise) if factor != 1 else hybrid
        s_session = bgc.open(SINGLE, backend="numpy", **noise) if factor != 1 else single
        alarms, switches, h_cpu, s_cpu, wrong = 0, [], [], [], []
        for k in range(args.runs):
            sim = bgc.simulate(HYBRID, seed=k, steps=args.steps, modes=schedule(k, float(args.steps)), **noise)
            plain = bgc.simulate(SINGLE, seed=k, steps=args.steps, **noise)
            switches.append(len(sim.switches))
            order = ((h_session, sim), (s_session, plain)) if k % 2 == 0 else ((s_session, plain), (h_session, sim))
            for session, data in order:
                cpu, report = timed(lambda: bgc.diagnose(session, data=data))
                (h_cpu if session is h_session else s_cpu).append(cpu)
                if session is h_session and report.diagnosis.verdict != "no fault":
                    alarms += 1
                    wrong.append((k, report.diagnosis.verdict, report.diagnosis.candidates,
                                  report.diagnosis.detection.step if report.diagnosis.detection else None))
            print(f"  noise x{factor:g}: run {k + 1}/{args.runs}, {alarms} false alarm(s)", file=sys.stderr,
                  flush=True)
        rows.append((factor, args.runs, min(switches), statistics.median(switches), alarms,
                     statistics.median(h_cpu), statistics.median(s_cpu), wrong))
    print(f"valve RO ({HYBRID.name}) cycling, {args.steps} samples per run, mode from the data; "
          f"beside it the RO of one mode ({SINGLE.name}), fault-free runs of the same length")
    print()
    print("| noise | runs | switches per run (min, median) | false alarms | rate | CPU s per diagnosis, modes | "
          "one mode | ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for factor, runs, low, mid, alarms, h, s, _ in rows:
        print(f"| x{factor:g} | {runs} | {low}, {mid:g} | {alarms} | {alarms / runs:.3f} | {h:.2f} | {s:.2f} | "
              f"{h / s:.2f} |")
    for factor, *_, wrong in rows:
        for k, verdict, candidates, step in wrong:
            print(f"  noise x{factor:g}, run {k}: {verdict} {', '.join(candidates)} (alarm at step {step})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
