"""The detector's bank of tests against its mean test alone (issue 48,
point 2): on the same simulated runs, the diagnoser with ``detectors=
("mean",)`` (today's default) and with the banks ``--banks`` names (default:
every family, ``mean``, ``drift``, ``variance``, ``frozen``, ``pooled``:
bgc.diagnosis.detect, "A bank of tests") is fed sample by sample until its
first alarm.

Per row, side by side: the runs alarmed at or after the fault's onset, the
false alarms (an alarm before the onset, or any alarm of a fault-free run),
the median delay from the onset to the alarm in samples, and, for the bank,
which test fired. Fault-free rows give the false-alarm rate per horizon the
bank must hold (at most the options' false_alarm, 1 %, per model run
length).

The scenarios: the sweep's slow drifts that the mean test misses (docs/
results.md section 11: the two tanks' inflow drift and RO's tau_rp drift,
on experiments/models/*_all_kinds.yaml), a sensor drift, a burst of noise
(five times the sensor's std) and a sensor that freezes at its last
reading (the run's readings held from the onset: what a stuck logger
writes; bgc simulate's own ``stuck`` kind reads a value with noise), and
the sources of the circuit and the two tanks off (a bias of 5 % and 25 %:
every sensor moves, the pooled test's case; the two tanks' flows move
together as their residuals are correlated, where whitening gains nothing).

``--cost`` instead times the watching (a fault-free run of each shipped
model, every sample through the diagnoser, the first run of each bank a
warm-up) per sample, each bank against the mean test alone.

    .venv/bin/python bench/detector_bank.py --runs 40
    .venv/bin/python bench/detector_bank.py --runs 40 --banks mean,drift,variance,frozen all
    .venv/bin/python bench/detector_bank.py --cost
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
import warnings
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import bgc  # noqa: E402
from bgc.analysis import simulate  # noqa: E402
from bgc.diagnosis.detect import TESTS, tests_named  # noqa: E402
from bgc.model.protocol import onset_sample  # noqa: E402

TANKS, RO = "experiments/models/two_tank_all_kinds.yaml", "experiments/models/ro_all_kinds.yaml"
#: (model, scenario or "none", a sensor frozen at its reading from the scenario's time, or None)
ROWS = (
    ("models/circuit.yaml", "none", None),
    ("models/two_tank.yaml", "none", None),
    ("models/ro.yaml", "none", None),
    (TANKS, "f_in:drift:0.002667@75", None),
    (RO, "tau_rp:drift:0.2133@150", None),
    (TANKS, "F20:drift:0.001185@75", None),
    (TANKS, "F20:noise:4@75", None),
    (RO, "F_back:noise:4@150", None),
    ("models/circuit.yaml", "none@7.5", "f6"),
    (TANKS, "none@75", "F20"),
    (RO, "none@150", "F_back"),
    ("models/circuit.yaml", "V:bias:-0.5@7.5", None),
    ("models/two_tank.yaml", "f_in:bias:-0.25@75", None),
)


def run(session, row, runs: int, first_seed: int, tests: tuple[str, ...]) -> dict:
    """The first alarms of ``runs`` seeded runs of ``row`` with the bank ``tests``."""
    _, scenario, frozen = row
    num = session.view.numerics
    process, measurement = session.noise
    settings = session.view.model.settings
    text, _, when = scenario.partition("@")
    injection = None if text == "none" else simulate.parse_fault(scenario, num)
    opts = session.options(bgc.DiagnosisOptions(workers=1, detectors=tests))
    out = dict(detected=0, false=0, delays=[], tests=Counter())
    for i in range(runs):
        r = simulate.simulate(num, simulate.SimulationOptions(steps=settings.steps, process_noise=process,
                                                              measurement_noise=measurement, seed=first_seed + i,
                                                              fault=injection))
        onset = None if not when else onset_sample(r.time, float(when))
        ys = np.array(r.measurements, dtype=float)
        if frozen is not None:
            j = list(session.package.MODELS["nominal"].OUTPUTS).index(frozen)
            ys[onset:, j] = ys[onset - 1, j]  # the logger repeats the last reading it had
        d = session.diagnoser(dataclasses.replace(opts, seed=first_seed + i))
        for k, t in enumerate(r.time):
            alarm = d.step(float(t), r.inputs[k], ys[k]).alarm
            if alarm is not None:
                if onset is not None and alarm.step >= onset:
                    out["detected"] += 1
                    out["delays"].append(alarm.step - onset)
                    out["tests"][alarm.test] += 1
                else:
                    out["false"] += 1
                break
    return out


def cost(banks) -> None:
    """Microseconds per sample of watching a fault-free run, each bank beside the mean test alone."""
    print("bench/detector_bank.py --cost: watching a fault-free run (the model's steps, seed 1), microseconds "
          "per sample, the best of 3 runs after a warm-up\n")
    print("| model | " + " | ".join(",".join(b) for b in banks) + " |")
    print("|---|" + "---|" * len(banks))
    for model in ("models/circuit.yaml", "models/two_tank.yaml", "models/ro.yaml"):
        session = bgc.open(ROOT / model)
        sim = bgc.simulate(session, "none", seed=1)
        rows = [(float(t), {n: v[k] for n, v in sim.inputs.items()}, {n: v[k] for n, v in sim.measurements.items()})
                for k, t in enumerate(sim.time)]
        times = []
        for tests in banks:
            best = float("inf")
            for attempt in range(4):
                d = session.diagnoser(bgc.DiagnosisOptions(workers=1, detectors=tests))
                start = time.perf_counter()
                for row in rows:
                    d.step(*row)
                if attempt:  # the first: a warm-up
                    best = min(best, time.perf_counter() - start)
            times.append(best / len(rows) * 1e6)
        print(f"| {Path(model).stem} | " + " | ".join(f"{t:.0f} ({t / times[0]:.2f}x)" for t in times) + " |",
              flush=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=40)
    p.add_argument("--seed", type=int, default=1000, help="the first run's seed")
    p.add_argument("--banks", nargs="+", default=["all"], metavar="TESTS",
                   help="the banks beside the mean test alone, each as --detect takes it (default: all)")
    p.add_argument("--cost", action="store_true", help="time the watching instead")
    args = p.parse_args(argv)
    banks = [("mean",)] + [tests_named(b) for b in args.banks]
    if any(b is None for b in banks):
        p.error(f"--banks: each some of {', '.join(TESTS)}, comma-separated, or all")
    if args.cost:
        cost(banks)
        return 0
    warnings.simplefilter("ignore")  # the scenarios outside a prior are meant
    names = [",".join(b) for b in banks]
    print(f"bench/detector_bank.py --runs {args.runs} --seed {args.seed} --banks {' '.join(args.banks)}: first "
          f"alarms, the mean test alone against {', '.join(names[1:])}, on the same runs\n")
    head = " | ".join(f"{n}: detected | {n}: false | {n}: median delay" for n in names)
    print(f"| model | scenario | {head} | {names[-1]}: test that fired | seconds |")
    print("|---|---|" + "---|---|---|" * len(banks) + "---|---|")
    for row in ROWS:
        session = bgc.open(ROOT / row[0])
        cells, seconds = [], []
        for tests in banks:
            start = time.perf_counter()
            r = run(session, row, args.runs, args.seed, tests)
            seconds.append(time.perf_counter() - start)
            delay = f"{statistics.median(r['delays']):g}" if r["delays"] else "–"
            cells += [f"{r['detected']}/{args.runs}", f"{r['false']}/{args.runs}", delay]
        fired = ", ".join(f"{k} {v}" for k, v in r["tests"].most_common()) or "–"
        scenario = row[1] if row[2] is None else f"{row[2]} frozen @{row[1].partition('@')[2]}"
        print(f"| {Path(row[0]).stem} | {scenario} | " + " | ".join(cells) + f" | {fired} | "
              + " / ".join(f"{t:.0f}" for t in seconds) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
