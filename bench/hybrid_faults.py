"""Parametric faults through mode switches: isolation, the magnitude's error,
the detection delay and the cost of a diagnosis of the valve RO
(models/ro_hybrid_valve.yaml, the valve in the data) cycling through its
three settings, beside the same fault in the RO of one mode (models/ro.yaml),
in one run.

    .venv/bin/python bench/hybrid_faults.py [--runs 20] [--steps 300] [--only TEXT]

Each run k of a scenario has its own seed, schedule and fault: the plant stays
in primary, secondary and purge for a time drawn uniformly from [40, 80],
[20, 50] and [10, 30] s (the schedules of ``bench/hybrid_false_alarms.py``),
the fault's onset is drawn uniformly from [80, 180] s and its magnitude
uniformly from the scenario's bounds (seeded by k and the scenario). The runs
are simulated by the truth simulator (RK4 on a finer grid than the filters',
each switch at its scheduled time) at the model's noise and diagnosed with the
mode from the run's mode column. The same fault, onset, magnitude and seed are
then simulated and diagnosed in the RO of one mode (primary throughout), where
the fault exists there.

Per scenario the table gives: the runs whose alarm went off; the runs whose
verdict is "isolated" with the injected fault alone; the mean and worst
relative error of the magnitude (|estimate - truth| / truth, over the runs whose
best hypothesis is the injected fault) and of the faulty parameter's value at the
run's end (the size of the fault as a published hybrid RO diagnoser reports it:
|estimated - true| / true, a drift's value at the end); the share of 95 % intervals that cover
the truth; the median detection delay in samples (the alarm's time - the onset, over dt);
the switches between onset and detection (median); the CPU seconds per diagnosis
(``time.process_time``, medians) and the ratio of the two models' costs.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import zlib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from hybrid_false_alarms import HYBRID, SINGLE, schedule, timed  # noqa: E402

from bgc.kinds import fault_kind  # noqa: E402

#: (fault, kind, magnitude bounds, in the RO of one mode too): abrupt magnitudes are the
#: parameter's change (added to its nominal value), incipient ones its slope per second.
SCENARIOS = [
    ("R_pipe", "abrupt", (20.0, 40.0), True),
    ("R_pipe", "incipient", (0.3, 0.7), True),
    ("R_memb", "abrupt", (10.0, 24.0), True),
    ("R_rp", "abrupt", (0.01, 0.03), True),
    ("R_brine", "abrupt", (100.0, 200.0), True),  # its path is open in primary only
    ("R_back", "abrupt", (2.0, 6.0), False),  # in secondary only
]


def draw(name: str, kind: str, bounds: tuple[float, float], k: int) -> tuple[float, float]:
    """Run ``k``'s onset (s) and magnitude for the scenario, seeded by both."""
    rng = np.random.default_rng([zlib.crc32(f"{name}:{kind}".encode()), k])
    onset = float(round(rng.uniform(80.0, 180.0)))
    return onset, float(rng.uniform(*bounds))


def outcome(report, truth: str, dt: float) -> dict:
    d = report.diagnosis
    h = next((h for h in d.hypotheses if h.name == truth), None)
    e = h.estimate if h is not None else None
    right = bool(d.candidates) and d.candidates[0] == truth
    return {
        "detected": d.detection is not None,
        "isolated": d.verdict == "isolated" and tuple(d.candidates) == (truth,),
        "verdict": f"{d.verdict} {', '.join(d.candidates)}",
        "err": e.relative_error if right and e is not None and e.truth is not None else np.nan,
        "cover": e.covers if right and e is not None and e.truth is not None else None,
        "param": parameter_error(e, report, d) if right and e is not None and e.truth is not None else np.nan,
        "delay": round((d.time_of(d.detection.step) - report.injected.time) / dt) if d.detection else np.nan,
        "detection": d.detection.step if d.detection else None,
    }


def parameter_error(e, report, d) -> float:
    """|estimated - true| / true of the faulty parameter's value at the run's end (a drift's too)."""
    true = fault_kind(e.kind).value(e.nominal, e.truth, report.injected.time, float(d.time[-1]))
    return abs(e.parameter_value - true) / abs(true)


def summary(rows: list[dict]) -> str:
    covered = [r["cover"] for r in rows if r["cover"] is not None]
    errs = [r["err"] for r in rows if not np.isnan(r["err"])]
    params = [r["param"] for r in rows if not np.isnan(r["param"])]
    delays = [r["delay"] for r in rows if not np.isnan(r["delay"])]
    n = len(rows)
    return (f"{sum(r['detected'] for r in rows)}/{n} | {sum(r['isolated'] for r in rows)}/{n} | "
            + (f"{100 * np.mean(errs):.1f} | {100 * np.max(errs):.1f} | " if errs else "- | - | ")
            + (f"{100 * np.mean(params):.2f} | {100 * np.max(params):.2f} | " if params else "- | - | ")
            + f"{sum(covered)}/{len(covered)} | " + (f"{statistics.median(delays):g}" if delays else "-"))


def main(argv=None) -> int:
    import bgc

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--only", metavar="TEXT", help="only the scenarios whose fault or kind holds TEXT")
    args = parser.parse_args(argv)
    hybrid, single = bgc.open(HYBRID, backend="numpy"), bgc.open(SINGLE, backend="numpy")
    table, notes = [], []
    for name, kind, bounds, in_single in SCENARIOS:
        if args.only and args.only not in f"{name}:{kind}":
            continue
        truth = f"{name}_{kind}"
        h_rows, s_rows, h_cpu, s_cpu, between = [], [], [], [], []
        for k in range(args.runs):
            onset, magnitude = draw(name, kind, bounds, k)
            fault = f"{name}:{kind}:{magnitude:.6g}@{onset:g}"
            sim = bgc.simulate(HYBRID, fault, seed=k, steps=args.steps, modes=schedule(k, float(args.steps)))
            cpu, report = timed(lambda: bgc.diagnose(hybrid, data=sim))
            h_cpu.append(cpu)
            row = outcome(report, truth, float(sim.time[1] - sim.time[0]))
            h_rows.append(row)
            if row["detection"] is not None:
                between.append(sum(onset < w.time <= sim.time[row["detection"]] for w in sim.switches))
            if not row["isolated"]:
                notes.append(f"  {fault}, run {k}: {row['verdict']} (alarm at step {row['detection']})")
            if in_single:
                plain = bgc.simulate(SINGLE, fault, seed=k, steps=args.steps)
                cpu, report = timed(lambda: bgc.diagnose(single, data=plain))
                s_cpu.append(cpu)
                s_rows.append(outcome(report, truth, float(plain.time[1] - plain.time[0])))
            print(f"  {truth}: run {k + 1}/{args.runs}, {sum(r['isolated'] for r in h_rows)} isolated",
                  file=sys.stderr, flush=True)
        h_med = statistics.median(h_cpu)
        s_med = statistics.median(s_cpu) if s_cpu else None
        table.append((truth, bounds, h_rows, s_rows, between, h_med, s_med))
    print(f"valve RO ({HYBRID.name}) cycling, {args.steps} samples per run, mode from the data, "
          f"{args.runs} runs per fault; beside it the RO of one mode ({SINGLE.name}), the same faults")
    print()
    print("| fault | magnitudes | model | alarm | isolated | magnitude error % mean | worst | parameter error % mean | "
          "worst | 95 % covers | delay (samples, median) | switches before the alarm | CPU s | ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for truth, bounds, h_rows, s_rows, between, h_med, s_med in table:
        sw = f"{statistics.median(between):g}" if between else "-"
        ratio = f"{h_med / s_med:.2f}" if s_med else "-"
        print(f"| {truth} | {bounds[0]:g} to {bounds[1]:g} | modes | {summary(h_rows)} | {sw} | {h_med:.2f} | "
              f"{ratio} |")
        if s_rows:
            print(f"| {truth} | {bounds[0]:g} to {bounds[1]:g} | one mode | {summary(s_rows)} | - | {s_med:.2f} | |")
    for line in notes:
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
