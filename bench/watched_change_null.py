"""The test of the record kept while watching on healthy plants: how often it
raises an alarm (bgc.diagnosis.diagnoser.Diagnoser._changed_while_watching;
bench/watched_change.py measures the faults it finds).

    .venv/bin/python bench/watched_change_null.py own [--models circuit,two_tank,ro] [--runs 100]
    .venv/bin/python bench/watched_change_null.py off [--runs 30] [--noise 1] [--plants circuit,supply]
    .venv/bin/python bench/watched_change_null.py cost [--models circuit,two_tank,ro]

``own``: each shipped model's own healthy runs (``bgc.simulate``, its declared
noise, seeds 1000 on), 2049 samples each, diagnosed keeping 1024 steps: the
record is tested once, at its 2048th sample. Printed per model: the runs, those
whose record failed the fit test at the watching level, those where the CUSUM
test found a shift, the alarms the test raised, the runs where it said the
model does not fit (a misfit without a change, said as the data come: a
``Mismatched`` event of a step), and the runs with any alarm
(the detector's own included: its budget is 1 % per horizon of the model's
declared length, and the runs are several horizons long).

``off``: plants off their model, from simulators written here: every
parameter off by up to 3 % (uniform), the noise ``--noise`` times the model's
(1 by default: a plant 1.5 times noisier than its model raises the detector's
alarm within tens of samples, and a record with an alarm is not tested). The
circuit by the matrix exponential of its equations (tests/test_mismatch.py's
``circuit``), 2100 samples kept 1024 steps; the supply of
docs/examples/switched_rc.yaml by solve_ivp (tests/test_watched_change.py's
``supply``), 1800 samples kept 15 s (two tests). Printed: the runs, those the
detector's own tests alarmed on (a record with an alarm is not tested), the alarms
the watching test raised, the runs where it said the model does not fit (the
diagnosis's events hold that misfit, dated), the verdicts. Each run on NumPy, cubature Kalman
filters for the circuit (the test reads the nominal Kalman track either way).

``cost``: one test's seconds, the screen a particle observer's residuals get
and the nominal Kalman track it is read on after (:func:`cost`).
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

KEEP = 1024


def own(models: list[str], runs: int) -> None:
    import bgc
    from bgc.diagnosis import diagnoser as D
    from bgc.diagnosis.options import DiagnosisOptions

    seen = {}
    fit, shifted = D.fit, D.shifted

    def fit_seen(*a, **k):  # the record's own test (the one at the watching level)
        f = fit(*a, **k)
        if "level" in k:
            seen["fit"] = not f.fits
        return f

    def shifted_seen(z, level):
        out = shifted(z, level)
        seen["shift"] = bool(out)
        return out

    D.fit, D.shifted = fit_seen, shifted_seen
    print(f"{'model':10s} {'runs':>5} {'fit failed':>10} {'shift':>6} {'alarms':>7} {'misfit said':>11} "
          f"{'any alarm':>10}")
    for name in models:
        s = bgc.open(ROOT / "models" / f"{name}.yaml", backend="numpy")
        dt = float(s.package.MODELS["nominal"].DT)
        counts = collections.Counter()
        for seed in range(runs):
            sim = bgc.simulate(s, "none", steps=2 * KEEP + 1, seed=1000 + seed)
            run = sim.run if hasattr(sim, "run") else sim
            d = s.diagnoser(DiagnosisOptions(keep=KEEP * dt, filter="ckf", workers=1))
            seen.clear()
            events = []
            for k in range(len(run.time)):
                u = {n: run.inputs[n][k] for n in run.inputs}
                if run.modes is not None:
                    u["mode"] = run.modes[k]
                events += d.step(run.time[k], u, {n: run.measurements[n][k] for n in run.measurements}).events
            counts["fit"] += bool(seen.get("fit"))
            counts["shift"] += bool(seen.get("shift"))
            counts["alarm"] += any(type(e).__name__ == "ChangeMissed" for e in events)
            counts["said"] += any(type(e).__name__ == "Mismatched" for e in events)
            counts["any"] += any(type(e).__name__ == "Alarmed" for e in events)
        print(f"{name:10s} {runs:5d} {counts['fit']:10d} {counts['shift']:6d} {counts['alarm']:7d} {counts['said']:11d} "
              f"{counts['any']:10d}", flush=True)


def off(runs: int, factor: float, plants: list[str]) -> None:
    import bgc
    from bgc.diagnosis.options import DiagnosisOptions
    import test_mismatch as M
    import test_watched_change as W

    print(f"{'plant':8s} {'runs':>5} {'detector':>9} {'alarms':>7} {'misfit said':>11}  verdicts")
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "run.csv"
        for plant in plants:
            verdicts, alarms, detected, said = collections.Counter(), 0, 0, 0
            if plant == "supply":
                s = bgc.open(W.MODEL, backend="numpy")
                base, noise = (W.R_S, W.C, W.R_LOAD), dict(W.NOISE)
            else:
                s = bgc.open(ROOT / "models" / "circuit.yaml", backend="numpy")
            for seed in range(runs):
                rng = np.random.default_rng(500 + seed)
                if plant == "supply":
                    W.R_S, W.C, W.R_LOAD = (v * (1 + rng.uniform(-0.03, 0.03)) for v in base)
                    W.NOISE = {k: factor * v for k, v in noise.items()}
                    path.write_text(W.supply(1800, None, 0.0, seed), encoding="utf-8")
                    options = DiagnosisOptions(keep=15.0, workers=1)
                else:
                    p = {k: v * (1 + rng.uniform(-0.03, 0.03)) for k, v in M.NOMINAL.items()}
                    e, process, sensor = M.circuit(p, factor)
                    x, lines = np.array(M.START), ["time,u:V,y:f2,y:f6,y:e11"]
                    for k in range(1, 2101):
                        x = e[:3, :3] @ x + e[:3, 3] * M.V + process * rng.standard_normal(3)
                        y = M.readings(p, x, M.V) + sensor * rng.standard_normal(3)
                        lines.append(",".join(f"{v:.6g}" for v in (k * M.DT, M.V, *y)))
                    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
                    options = DiagnosisOptions(keep=KEEP * M.DT, filter="ckf", workers=1)
                d = bgc.diagnose(s, path, options=options).diagnosis
                alarms += any(type(e).__name__ == "ChangeMissed" and e.watching for e in d.events)
                said += any(type(e).__name__ == "Mismatched" and e.said is not None for e in d.events)
                verdicts[d.verdict] += 1
                detected += d.detection is not None and d.detection.test != "change"
            if plant == "supply":
                W.R_S, W.C, W.R_LOAD = base
                W.NOISE = noise
            print(f"{plant:8s} {runs:5d} {detected:9d} {alarms:7d} {said:11d}  "
                  f"{', '.join(f'{k} {n}' for k, n in sorted(verdicts.items()))}", flush=True)


def cost(models: list[str]) -> None:
    """Per model, the seconds of one test of a record of 2 KEEP steps (its
    own healthy run): the screen on a particle observer's residuals (the
    fit test's failures and the CUSUM test, at ten times a level), and the
    nominal cubature Kalman track with the same tests on its residuals; the
    best of three, and each per row over the KEEP rows between tests."""
    import time

    import bgc
    from bgc.diagnosis.fit import fails, fit, shifted
    from bgc.filters.cubature import nominal_track

    print(f"{'model':10s} {'screen ms':>10} {'per row ms':>11} {'track ms':>9} {'per row ms':>11}")
    for name in models:
        s = bgc.open(ROOT / "models" / f"{name}.yaml", backend="numpy")
        nom = s.package.MODELS["nominal"]
        sim = bgc.simulate(s, "none", steps=2 * KEEP, seed=3)
        run = sim.run if hasattr(sim, "run") else sim
        outputs = tuple(nom.OUTPUTS)
        ys = np.column_stack([run.measurements[n] for n in outputs])
        us = np.column_stack([run.inputs[n] for n in nom.INPUTS])
        z = np.random.default_rng(1).standard_normal(ys.shape)  # a particle observer's residuals stand-in: the same sizes
        times = {"screen": [], "track": []}
        for _ in range(3):
            t = time.perf_counter()
            fails(nom, z, outputs, 0.005)
            shifted(z, 0.005)
            times["screen"].append(time.perf_counter() - t)
            t = time.perf_counter()
            track = nominal_track(nom, ys, us, 2 * KEEP)
            fit(nom, ys, us, outputs, 2 * KEEP, track=track)
            shifted(np.array(track.z, dtype=float).reshape(2 * KEEP, len(outputs)), 0.0005)
            times["track"].append(time.perf_counter() - t)
        a, b = min(times["screen"]), min(times["track"])
        print(f"{name:10s} {1000 * a:10.1f} {1000 * a / KEEP:11.4f} {1000 * b:9.0f} {1000 * b / KEEP:11.3f}", flush=True)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("what", choices=("own", "off", "cost"))
    p.add_argument("--models", default="circuit,two_tank,ro")
    p.add_argument("--runs", type=int, default=None)
    p.add_argument("--noise", type=float, default=1.0, help="off: the plants' noise, times the model's")
    p.add_argument("--plants", default="circuit,supply", help="off: the plants")
    a = p.parse_args()
    runs = a.runs or (100 if a.what == "own" else 30)
    if a.what == "cost":
        print(f"bench/watched_change_null.py cost --models {a.models}")
        cost(a.models.split(","))
        return 0
    print(f"bench/watched_change_null.py {a.what} --runs {runs}" + (f" --models {a.models}" if a.what == "own" else "")
          + (f" --noise {a.noise:g} --plants {a.plants}" if a.what == "off" else ""))
    if a.what == "own":
        own(a.models.split(","), runs)
    else:
        off(runs, a.noise, a.plants.split(","))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
