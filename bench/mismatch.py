"""The verdicts on data a model does not fit (issue 48): the circuit as a
plant gives it, simulated by another simulator (the exact solution of its
equations derived by hand, tests/test_mismatch.py's ``plant_csv``), its
parameters each off the model file's by up to ``--off`` (relative) and its
noise ``--noise`` times the model's, no fault; beside it, the same
simulator with the model's own numbers. Prints the count of each verdict
per plant, side by side.

    .venv/bin/python bench/mismatch.py --runs 12

With ``--null RUNS``: the test of the model's fit alone (bgc.diagnosis.fit,
over the whole record, as a diagnosis without an alarm runs it) on bgc's own
fault-free runs of the shipped and test plants (``bgc simulate``'s, seeds 0
to RUNS - 1): how often it finds a misfit in data the model made.

    .venv/bin/python bench/mismatch.py --null 60

With ``--timing RUNS``: the inputs' timing (docs/format.md section 9): the
circuit driven by a square wave (tests/test_input_timing.py's
``square_csv``: the exact solution, seeds 0 to RUNS - 1), logged with the
value set at each row's time (``start``) or held over the step that ends
there (``end``), the model's numbers or off by 3 % with 1.5x noise; each
diagnosed as bgc reads by default and with the timing it was logged with.
Prints the verdicts and how many mismatches named the other timing.

    .venv/bin/python bench/mismatch.py --timing 20

With ``--calibrated RUNS``: issue 48's target after calibration. Per seed,
the plant off its model (``--off``, ``--noise``) is recorded twice (the
same parameters, two noise draws): the model is calibrated on the first
(``Session.calibrate(..., "noise,R1,C1,R2,C2,L,R3")``, what the mismatch
verdict tells the user to run), and the second is diagnosed with the model
as written and with the calibrated one, each with the mean test alone and
with the detector's bank (``--detect all``). Prints the verdicts per
column.

    .venv/bin/python bench/mismatch.py --calibrated 40

With ``--as-written RUNS``: its rows of the model as written only; with
``--calibrated RUNS --only-calibrated``, its rows of the calibrated model only.
``--first SEED``: the plants' seeds start there (default 0), so that two
processes can each take a share of the seeds (their tables add up).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import bgc  # noqa: E402
from test_mismatch import plant_csv  # noqa: E402

VERDICTS = ("no fault", "mismatch", "isolated", "ambiguous", "unexplained")
PLANTS = ("models/circuit.yaml", "models/two_tank.yaml", "models/ro.yaml", "tests/data/models/dc_motor.yaml",
          "tests/data/models/orifice_tanks.yaml", "tests/data/models/mass_spring_damper.yaml")


def null(runs: int) -> None:
    """The fit test's findings on ``runs`` fault-free runs of each of :data:`PLANTS`, as a table."""
    import numpy as np

    from bgc.diagnosis.fit import LEVEL, fit

    print(f"| plant | runs | misfit found (level {LEVEL:g}) | findings |")
    print("|---|---|---|---|")
    for plant in PLANTS:
        session = bgc.open(ROOT / plant)
        nominal = session.package.MODELS["nominal"]
        found, said = 0, []
        for seed in range(runs):
            run = bgc.simulate(session, "none", seed=seed).run
            ys = np.column_stack([run.measurements[y] for y in nominal.OUTPUTS])
            us = np.column_stack([run.inputs[u] for u in nominal.INPUTS])
            f = fit(nominal, ys, us, tuple(nominal.OUTPUTS), len(ys))
            if f.findings:
                found += 1
                said += [f"seed {seed}: {x.split(':')[0]}" for x in f.findings]
        print(f"| {plant} | {runs} | {found} | {'; '.join(said)} |", flush=True)


def timing(runs: int) -> None:
    """The verdicts on the square-wave circuit logged either way, read either way, as a table."""
    from bgc import events
    from test_input_timing import square_csv

    session = bgc.open(ROOT / "models" / "circuit.yaml")
    print("| logged | plant | read as | runs | " + " | ".join(VERDICTS) + " | mismatch naming the other timing |")
    print("|---|---|---|---|" + "---|" * (len(VERDICTS) + 1))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "run.csv"
        for logged in ("start", "end"):
            for plant, (off, noise) in (("the model's numbers", (0.0, 1.0)), ("off 3 %, noise x1.5", (0.03, 1.5))):
                for read in dict.fromkeys(("end", logged)):
                    counts, named = Counter(), 0
                    for seed in range(runs):
                        square_csv(path, logged, seed, off=off, noise=noise)
                        d = bgc.diagnose(session, path, options=bgc.DiagnosisOptions(input_timing=read)).diagnosis
                        counts[d.verdict] += 1
                        named += any(isinstance(e, events.Mismatched) and e.timing for e in d.events)
                    print(f"| {logged} | {plant} | {read} | {runs} | " + " | ".join(str(counts[v]) for v in VERDICTS)
                          + f" | {named} |", flush=True)


def calibrated(runs: int, off: float, noise: float, calibrate: bool = True, written: bool = True,
               first: int = 0) -> None:
    """Verdicts on a fresh healthy run of a plant off its model, with the model as written and calibrated
    (``calibrate``: else as written only, without the calibrations' minutes; ``written``: else calibrated
    only; ``first``: the first seed)."""
    from bgc.diagnosis.detect import TESTS

    session = bgc.open(ROOT / "models" / "circuit.yaml")
    estimate = "noise," + ",".join(p.name for p in session.view.model.parameters)  # the model file's
    models = (("as written",) if written else ()) + (("calibrated",) if calibrate else ())
    columns = [(model, tests) for model in models for tests in (("mean",), TESTS)]
    counts = {c: Counter() for c in columns}
    with tempfile.TemporaryDirectory() as folder:
        healthy, fresh, model = (Path(folder) / name for name in ("healthy.csv", "fresh.csv", "calibrated.yaml"))
        for seed in range(first, first + runs):
            plant_csv(healthy, seed, off, noise)
            plant_csv(fresh, seed, off, noise, noise_seed=1)
            if calibrate:
                model.write_text(session.calibrate(healthy, estimate).text, encoding="utf-8")
                calibrated_session = bgc.open(model)
            said = []
            for column in columns:
                which = session if column[0] == "as written" else calibrated_session
                d = bgc.diagnose(which, fresh, options=bgc.DiagnosisOptions(detectors=column[1])).diagnosis
                counts[column][d.verdict] += 1
                said.append(d.verdict)
            print(f"seed {seed}: " + ", ".join(said), file=sys.stderr, flush=True)
    seeds = f"seeds {first} to {first + runs - 1}, " if first else ""
    print(f"| model ({runs} plants, {seeds}off {100 * off:g} %, noise x{noise:g}) | detector | " + " | ".join(VERDICTS) + " |")
    print("|---|---|" + "---|" * len(VERDICTS))
    for (name, tests), c in counts.items():
        print(f"| {name} | {'mean' if len(tests) == 1 else 'all'} | " + " | ".join(str(c[v]) for v in VERDICTS) + " |")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=12)
    p.add_argument("--off", type=float, default=0.03)
    p.add_argument("--noise", type=float, default=1.5)
    p.add_argument("--null", type=int, default=0, metavar="RUNS")
    p.add_argument("--timing", type=int, default=0, metavar="RUNS")
    p.add_argument("--calibrated", type=int, default=0, metavar="RUNS")
    p.add_argument("--as-written", type=int, default=0, metavar="RUNS",
                   help="--calibrated's rows of the model as written only (no calibration)")
    p.add_argument("--only-calibrated", action="store_true", help="--calibrated's rows of the calibrated model only")
    p.add_argument("--first", type=int, default=0, metavar="SEED", help="--calibrated's and --as-written's first seed")
    a = p.parse_args(argv)
    if a.calibrated or a.as_written:
        calibrated(a.calibrated or a.as_written, a.off, a.noise, calibrate=bool(a.calibrated),
                   written=not (a.calibrated and a.only_calibrated), first=a.first)
        return 0
    if a.timing:
        timing(a.timing)
        return 0
    if a.null:
        null(a.null)
        return 0
    session = bgc.open(ROOT / "models" / "circuit.yaml")
    plants = {f"off {100 * a.off:g} %, noise x{a.noise:g}": (a.off, a.noise), "the model's numbers": (0.0, 1.0)}
    counts = {name: Counter() for name in plants}
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "run.csv"
        for seed in range(a.runs):
            for name, (off, noise) in plants.items():
                plant_csv(path, seed, off, noise)
                d = bgc.diagnose(session, path).diagnosis
                counts[name][d.verdict] += 1
                print(f"seed {seed}, {name}: {d.verdict}" + (f" ({', '.join(d.candidates)})" if d.candidates else ""),
                      file=sys.stderr, flush=True)
    print(f"| plant ({a.runs} runs each) | " + " | ".join(VERDICTS) + " |")
    print("|---|" + "---|" * len(VERDICTS))
    for name, c in counts.items():
        print(f"| {name} | " + " | ".join(str(c[v]) for v in VERDICTS) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
