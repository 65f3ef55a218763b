"""A burst of sensor noise sized by bgc against the exact posterior of the same run.

    .venv/bin/python bench/noise_factor_reference.py [--model M] [--scenario S] [--seeds N] [--first K]

The runs: ``bgc.simulate`` of ``--scenario`` (a noise fault, default the
two tanks' ``F20:noise:4@75``: the sensor's noise std five times its own
from t = 75) on ``--model`` (default the two tanks that declare every
sensor kind, experiments/models/two_tank_all_kinds.yaml), seeds K..K+N-1,
each diagnosed by ``bgc.diagnose`` with GPF and 500 particles, as
experiments/sensor_grid.yaml does.

The reference knows what bgc cannot: the simulator's noise draws. The same
seed simulated without the fault gives the same plant and the same draws
(a noise fault moves no state, and the simulator draws the measurement
noise after the plant), so the faulty sensor's reading less the fault-free
one is (f - 1) sigma w after the onset, f = 1 + b the factor, w the
unit draws; the burst's noise in units of sigma is z = f w. From these n
values, the onset and sigma known, the posterior of b under bgc's uniform
prior is p(b | z) ~ |1 + b|^-n exp(-sum z^2 / (2 (1 + b)^2)): its central
95 % interval. It knows more than the data tell (the clean readings, the
onset), so it covers the truth at its nominal rate over many seeds; bgc's
interval should cover about as often and lie close to it (a little wider:
bgc filters the plant's state and marginalises the onset).

Prints each run (bgc's interval, the reference's, whether each covers),
then the counts, the mean and spread of the differences of the ends, and
the ratio of the widths. Diagnoses run on two processes.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402
from bgc.diagnosis.options import DiagnosisOptions  # noqa: E402

MODEL = "experiments/models/two_tank_all_kinds.yaml"
SCENARIO = "F20:noise:4@75"


def exact_interval(z: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """The central interval of p(b | z) for the n unit-variance draws ``z``
    scaled by 1 + b, b uniform on a grid fine against the posterior."""
    n, s = len(z), float(np.sum(z ** 2))
    b = np.linspace(-0.999, 20.0, 40001)
    log_p = -n * np.log1p(b) - s / (2.0 * (1.0 + b) ** 2)
    p = np.exp(log_p - log_p.max())
    cdf = np.cumsum(p) / p.sum()
    low, high = np.interp([(1.0 - level) / 2.0, (1.0 + level) / 2.0], cdf, b)
    return float(low), float(high)


def one(job) -> tuple:
    """(seed, truth, bgc's verdict, low, high, the reference's low, high) of one run."""
    model, scenario, seed = job
    sensor, kind, magnitude = scenario.split("@")[0].split(":")
    onset = float(scenario.split("@")[1])
    session = bgc.open(model)
    faulty = bgc.simulate(session, scenario=scenario, seed=seed)
    free = bgc.simulate(session, scenario="none", seed=seed)
    after = faulty.time > onset
    factor = 1.0 + float(magnitude)
    sigma = session.levels.measurement[list(faulty.measurements).index(sensor)]
    z = (faulty.measurements[sensor] - free.measurements[sensor])[after] * factor / ((factor - 1.0) * sigma)
    low, high = exact_interval(z)
    d = bgc.diagnose(session, data=faulty, options=DiagnosisOptions(filter="gpf", particles=500, seed=seed,
                                                                     workers=1)).diagnosis
    e = d.estimate
    named = d.verdict == "isolated" and d.candidates[0].startswith(f"{sensor}_noise") and e is not None
    return (seed, float(magnitude), d.verdict + (" " + d.candidates[0] if d.candidates else ""),
            e.low if named else float("nan"), e.high if named else float("nan"), low, high)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=MODEL)
    ap.add_argument("--scenario", default=SCENARIO)
    ap.add_argument("--seeds", type=int, default=200)
    ap.add_argument("--first", type=int, default=0)
    a = ap.parse_args(argv)
    os.chdir(ROOT)
    jobs = [(a.model, a.scenario, s) for s in range(a.first, a.first + a.seeds)]
    with ProcessPoolExecutor(2) as pool:
        rows = list(pool.map(one, jobs))
    print(f"{a.scenario} on {a.model}, seeds {a.first}..{a.first + a.seeds - 1}, GPF 500 particles")
    print("| seed | bgc's verdict | bgc's 95 % interval | covers | exact 95 % interval | covers |")
    print("|---|---|---|---|---|---|")
    for seed, truth, verdict, lo, hi, xlo, xhi in rows:
        print(f"| {seed} | {verdict} | [{lo:.3f}, {hi:.3f}] | {lo <= truth <= hi} | [{xlo:.3f}, {xhi:.3f}] | "
              f"{xlo <= truth <= xhi} |")
    named = [r for r in rows if np.isfinite(r[3])]
    print(f"\nnamed the noise fault: {len(named)} of {len(rows)}")
    print(f"bgc's interval covers the truth: {sum(r[3] <= r[1] <= r[4] for r in named)} of {len(named)}")
    print(f"the exact interval covers it:    {sum(r[5] <= r[1] <= r[6] for r in rows)} of {len(rows)}")
    if len(named) > 1:
        dl = [r[3] - r[5] for r in named]
        dh = [r[4] - r[6] for r in named]
        ratio = [(r[4] - r[3]) / (r[6] - r[5]) for r in named]
        print(f"bgc's low end less the exact one:  mean {statistics.mean(dl):+.4f}, sd {statistics.stdev(dl):.4f}")
        print(f"bgc's high end less the exact one: mean {statistics.mean(dh):+.4f}, sd {statistics.stdev(dh):.4f}")
        print(f"bgc's width over the exact one:    mean {statistics.mean(ratio):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
