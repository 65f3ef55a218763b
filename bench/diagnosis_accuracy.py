"""Accuracy of ``bgc diagnose`` over seeded runs: isolation, onset, the fault
magnitude's error and whether its interval covers the truth.

    .venv/bin/python bench/diagnosis_accuracy.py [--runs 20] [--particles 1000] [--false-alarm-runs 100]
                                                 [--only TEXT] [--identify kalman|filter] [--jitter-scale X]

Each scenario is simulated by the truth simulator (8x finer RK4 than the
filters) with seeds 100, 101, ...; the same seed drives the filters. Prints
one table row per scenario: the runs with an alarm, the share of runs whose
best hypothesis is the injected fault, verdicts, mean and worst relative error of the magnitude,
coverage of the 95 % interval, mean |onset error|, mean detection delay and
the z-scores' mean and spread (error / reported std: about 0 and 1 when the
estimate is unbiased and its std honest).
Then, per plant and noise level, the share of fault-free runs that raise an
alarm (the detector's target: 1 % per run).

``--jitter-scale X`` is an experiment: the fault states' random walk
(``FaultKind.jitter`` in ``bgc/kinds.py``) times X, the models compiled into a
private folder instead of read from ``generated/``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402
from bgc.diagnosis.options import DiagnosisOptions

#: (model, scenario, process noise, measurement noise): the thesis's RO faults
#: at its noise levels and at others, and the other plants' faults.
SCENARIOS = [
    ("ro", "R_pipe:abrupt:31@165", None, None),
    ("ro", "R_pipe:incipient:0.5@165", None, None),
    ("ro", "R_memb:abrupt:24@165", 0.01, 0.005),
    ("ro", "R_pipe:abrupt:20@120", 0.06, 0.04),
    ("ro", "R_pipe:abrupt:31@165", 0.01, 0.05),
    ("ro", "R_pipe:incipient:0.5@165", 0.01, 0.05),
    ("ro", "R_memb:abrupt:24@165", 0.01, 0.05),
    ("circuit", "R2:abrupt:0.6@5", 0.01, 0.01),
    ("two_tank", "R12:incipient:0.01@60", None, None),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--particles", type=int, default=1000)
    parser.add_argument("--filter", default="gpf", choices=["gpf", "apf"])
    parser.add_argument("--false-alarm-runs", type=int, default=100)
    parser.add_argument("--only", metavar="TEXT", help="only the scenarios whose model or scenario holds TEXT")
    parser.add_argument("--identify", default="kalman", choices=["kalman", "filter"])
    parser.add_argument("--jitter-scale", type=float, default=None, metavar="X",
                        help="multiply the fault states' random walk by X (models compiled privately)")
    args = parser.parse_args()
    args.generated = ROOT / "generated"
    if args.jitter_scale is not None:
        import dataclasses

        from bgc import kinds

        for name, kind in list(kinds.FAULT_KINDS.items()):
            kinds.FAULT_KINDS[name] = dataclasses.replace(kind, jitter=kind.jitter * args.jitter_scale)
        args.generated = None  # compiled with the changed kinds
    if args.runs:
        accuracy(args)
    if args.false_alarm_runs:
        false_alarms(args)


#: Noise levels (process, measurement) of the fault-free runs: the models' own,
#: lower and higher.
NOISE = [(None, None), (0.01, 0.005), (0.06, 0.04)]


def false_alarms(args) -> None:
    print(f"\nFault-free runs with an alarm, {args.false_alarm_runs} per row (seeds 5000, 5001, ...); "
          "target at most 1 %")
    head = f"{'model':<9} {'noise q/r':<11} {'alarms':>7} {'rate':>6} {'s/run':>6}"
    print(head)
    print("-" * len(head))
    for model in ("ro", "circuit", "two_tank"):
        for q, r in NOISE:
            started = time.perf_counter()
            alarms = sum(bgc.diagnose(ROOT / "models" / f"{model}.yaml", scenario="none", seed=5000 + i,
                                      process_noise=q, measurement_noise=r, generated=args.generated,
                                      options=DiagnosisOptions(method=args.filter, particles=args.particles,
                                                               seed=5000 + i, identify=args.identify)
                                      ).diagnosis.detection is not None
                         for i in range(args.false_alarm_runs))
            noise = f"{q if q is not None else '-'}/{r if r is not None else '-'}"
            print(f"{model:<9} {noise:<11} {alarms:>7} {100 * alarms / args.false_alarm_runs:>5.1f}% "
                  f"{(time.perf_counter() - started) / args.false_alarm_runs:>6.2f}", flush=True)


def accuracy(args) -> None:
    jitter = "" if args.jitter_scale is None else f", fault-state random walk x {args.jitter_scale:g}"
    print(f"{args.runs} seeded runs per scenario, {args.filter.upper()} with {args.particles} particles, "
          f"identify={args.identify}{jitter}\n")
    head = (f"{'model':<9} {'scenario':<26} {'noise q/r':<11} {'det.':>6} {'right':>6} {'isol.':>6} {'err %':>6} {'worst %':>8} "
            f"{'cover':>6} {'|onset err|':>11} {'delay':>6} {'z mean':>6} {'z sd':>5} {'s/run':>6}")
    print(head)
    print("-" * len(head))
    for model, scenario, q, r in SCENARIOS:
        if args.only and args.only not in f"{model} {scenario}":
            continue
        rows = []
        started = time.perf_counter()
        for i in range(args.runs):
            seed = 100 + i
            rep = bgc.diagnose(ROOT / "models" / f"{model}.yaml", scenario=scenario, seed=seed, process_noise=q,
                               measurement_noise=r, generated=args.generated,
                               options=DiagnosisOptions(method=args.filter, particles=args.particles, seed=seed,
                                                        identify=args.identify))
            d = rep.diagnosis
            truth = f"{rep.injected.parameter}_{rep.injected.kind}"
            h = next((h for h in d.hypotheses if h.name == truth), None)
            e = h.estimate if h is not None else None
            rows.append({
                "detected": d.detection is not None,
                "right": bool(d.candidates) and d.candidates[0] == truth,
                "isolated": d.verdict == "isolated" and d.candidates == (truth,),
                "err": e.relative_error if e is not None and e.truth is not None else np.nan,
                "cover": e.covers if e is not None and e.truth is not None else None,
                "z": (e.value - e.truth) / e.std if e is not None and e.truth is not None and e.std > 0 else np.nan,
                "onset": abs(d.time_of(h.onset) - rep.injected.time) if h is not None else np.nan,
                "delay": d.time_of(d.detection.step) - rep.injected.time if d.detection else np.nan,
            })
        seconds = (time.perf_counter() - started) / args.runs
        covered = [x["cover"] for x in rows if x["cover"] is not None]
        noise = f"{q if q is not None else '-'}/{r if r is not None else '-'}"
        print(f"{model:<9} {scenario:<26} {noise:<11} {sum(x['detected'] for x in rows):>3}/{len(rows):<2} "
              f"{sum(x['right'] for x in rows):>3}/{len(rows):<2} "
              f"{sum(x['isolated'] for x in rows):>3}/{len(rows):<2} {100 * np.nanmean([x['err'] for x in rows]):>6.1f} "
              f"{100 * np.nanmax([x['err'] for x in rows]):>8.1f} {sum(covered):>3}/{len(covered):<2} "
              f"{np.nanmean([x['onset'] for x in rows]):>11.1f} {np.nanmean([x['delay'] for x in rows]):>6.1f} "
              f"{np.nanmean([x['z'] for x in rows]):>6.2f} {np.nanstd([x['z'] for x in rows]):>5.2f} {seconds:>6.1f}",
              flush=True)


if __name__ == "__main__":
    main()
