"""The test of the record kept while watching on healthy plants: how often it
raises an alarm (bgc.diagnosis.diagnoser.Diagnoser._changed_while_watching;
bench/watched_change.py measures the faults it finds).

    .venv/bin/python bench/watched_change_null.py own [--models circuit,two_tank,ro] [--runs 100]
    .venv/bin/python bench/watched_change_null.py off [--runs 30]

``own``: each shipped model's own healthy runs (``bgc.simulate``, its declared
noise, seeds 1000 on), 2049 samples each, diagnosed keeping 1024 steps: the
record is tested once, at its 2048th sample. Printed per model: the runs, those
whose record failed the fit test at the watching level, those where the CUSUM
test found a shift, the alarms the test raised, and the runs with any alarm
(the detector's own included: its budget is 1 % per horizon of the model's
declared length, and the runs are several horizons long).

``off``: plants off their model, from simulators written here: every
parameter off by up to 3 % (uniform) and the noise 1.5 times the model's. The
circuit by the matrix exponential of its equations (tests/test_mismatch.py's
``circuit``), 2100 samples kept 1024 steps; the supply of
docs/examples/switched_rc.yaml by solve_ivp (tests/test_watched_change.py's
``supply``), 1800 samples kept 15 s (two tests). Printed: the runs, the alarms
the watching test raised, the verdicts. Each run on NumPy, cubature Kalman
filters for the circuit (the test reads the nominal Kalman track either way).
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
    print(f"{'model':10s} {'runs':>5} {'fit failed':>10} {'shift':>6} {'alarms':>7} {'any alarm':>10}")
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
            counts["any"] += any(type(e).__name__ == "Alarmed" for e in events)
        print(f"{name:10s} {runs:5d} {counts['fit']:10d} {counts['shift']:6d} {counts['alarm']:7d} {counts['any']:10d}",
              flush=True)


def off(runs: int) -> None:
    import bgc
    from bgc.diagnosis.options import DiagnosisOptions
    import test_mismatch as M
    import test_watched_change as W

    print(f"{'plant':8s} {'runs':>5} {'alarms':>7}  verdicts")
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "run.csv"
        for plant in ("circuit", "supply"):
            verdicts, alarms = collections.Counter(), 0
            if plant == "supply":
                s = bgc.open(W.MODEL, backend="numpy")
                base, noise = (W.R_S, W.C, W.R_LOAD), dict(W.NOISE)
            else:
                s = bgc.open(ROOT / "models" / "circuit.yaml", backend="numpy")
            for seed in range(runs):
                rng = np.random.default_rng(500 + seed)
                if plant == "supply":
                    W.R_S, W.C, W.R_LOAD = (v * (1 + rng.uniform(-0.03, 0.03)) for v in base)
                    W.NOISE = {k: 1.5 * v for k, v in noise.items()}
                    path.write_text(W.supply(1800, None, 0.0, seed), encoding="utf-8")
                    options = DiagnosisOptions(keep=15.0, workers=1)
                else:
                    p = {k: v * (1 + rng.uniform(-0.03, 0.03)) for k, v in M.NOMINAL.items()}
                    e, process, sensor = M.circuit(p, 1.5)
                    x, lines = np.array(M.START), ["time,u:V,y:f2,y:f6,y:e11"]
                    for k in range(1, 2101):
                        x = e[:3, :3] @ x + e[:3, 3] * M.V + process * rng.standard_normal(3)
                        y = M.readings(p, x, M.V) + sensor * rng.standard_normal(3)
                        lines.append(",".join(f"{v:.6g}" for v in (k * M.DT, M.V, *y)))
                    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
                    options = DiagnosisOptions(keep=KEEP * M.DT, filter="ckf", workers=1)
                d = bgc.diagnose(s, path, options=options).diagnosis
                alarms += any(type(e).__name__ == "ChangeMissed" and e.watching for e in d.events)
                verdicts[d.verdict] += 1
            if plant == "supply":
                W.R_S, W.C, W.R_LOAD = base
                W.NOISE = noise
            print(f"{plant:8s} {runs:5d} {alarms:7d}  {', '.join(f'{k} {n}' for k, n in sorted(verdicts.items()))}",
                  flush=True)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("what", choices=("own", "off"))
    p.add_argument("--models", default="circuit,two_tank,ro")
    p.add_argument("--runs", type=int, default=None)
    a = p.parse_args()
    runs = a.runs or (100 if a.what == "own" else 30)
    print(f"bench/watched_change_null.py {a.what} --runs {runs}" + (f" --models {a.models}" if a.what == "own" else ""))
    if a.what == "own":
        own(a.models.split(","), runs)
    else:
        off(runs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
