"""What a calibration's own uncertainty leaves on fresh data's residuals,
against calibrations made again (issue 48: after calibration, fresh healthy
data say "no fault").

``bgc calibrate`` writes, per sensor, the standard deviations its estimates'
uncertainty leaves on the mean and the variance of the calibrated model's
normalised residuals (``residual_mean_sd``, ``residual_variance_sd``: the
delta method through the inverse Hessian, bgc.analysis.calibrate._spread),
and the diagnosis's test of the model's fit adds them to its standard
errors. This checks them against what they predict: one plant (the circuit
off its model file, tests/test_mismatch.py's ``plant_csv(.., seed, --off,
--noise)``), calibrated ``--calibrations`` times, each time on another
healthy recording of it (``noise`` and the six parameters, what the
mismatch verdict tells the user to run); each calibrated model filters the
same ``--fresh`` other recordings, and the mean over them of each sensor's
residual mean and variance is what that calibration leaves. Their standard
deviation across the calibrations (less the fresh recordings' own share,
which the mean over them divides by ``--fresh``) is the truth the
allowance's average is compared with.

    .venv/bin/python bench/calibration_spread.py --calibrations 12

Prints a table per sensor: the allowance (mean over the calibrations), the
standard deviation measured across them, and their ratio.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import bgc  # noqa: E402
from bgc.data.runs import read_run  # noqa: E402
from bgc.filters.cubature import nominal_track  # noqa: E402
from test_mismatch import plant_csv  # noqa: E402


def moments(nominal, path: Path) -> np.ndarray:
    """Per sensor of ``nominal``, (mean, variance) of its normalised residuals on the recording ``path``."""
    run = read_run(path)
    ys = np.column_stack([run.measurements[y] for y in nominal.OUTPUTS])
    us = np.column_stack([run.inputs[u] for u in nominal.INPUTS])
    z = np.asarray(nominal_track(nominal, ys, us, len(ys)).z, dtype=float).reshape(len(ys), -1)
    return np.array([[np.nanmean(z[:, j]), np.nanvar(z[:, j])] for j in range(z.shape[1])])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--calibrations", type=int, default=12)
    p.add_argument("--fresh", type=int, default=10)
    p.add_argument("--seed", type=int, default=33, help="the plant (tests/test_mismatch.py's plant_csv seed)")
    p.add_argument("--off", type=float, default=0.03)
    p.add_argument("--noise", type=float, default=1.5)
    a = p.parse_args(argv)
    session = bgc.open(ROOT / "models" / "circuit.yaml")
    estimate = "noise," + ",".join(q.name for q in session.view.model.parameters)
    left, allowed = [], []
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        fresh = []
        for k in range(a.fresh):
            fresh.append(folder / f"fresh{k}.csv")
            plant_csv(fresh[-1], a.seed, a.off, a.noise, noise_seed=100 + k)
        for k in range(a.calibrations):
            healthy, model = folder / "healthy.csv", folder / f"calibrated{k}.yaml"
            plant_csv(healthy, a.seed, a.off, a.noise, noise_seed=1000 + k)
            model.write_text(session.calibrate(healthy, estimate).text, encoding="utf-8")
            nominal = bgc.open(model).package.MODELS["nominal"]
            left.append(np.mean([moments(nominal, f) for f in fresh], axis=0))
            allowed.append([nominal.RESIDUAL_SD[y] for y in nominal.OUTPUTS])
            print(f"calibration {k + 1} of {a.calibrations}", file=sys.stderr, flush=True)
            outputs = nominal.OUTPUTS
    left, allowed = np.array(left), np.array(allowed)  # calibrations x sensors x (mean, variance)
    n = 300  # plant_csv's samples
    own = np.array([1 / n, 2 / n]) / a.fresh  # the fresh recordings' share in the mean over them
    print(f"bench/calibration_spread.py --calibrations {a.calibrations} --fresh {a.fresh} --seed {a.seed}: "
          f"the circuit off its model by up to {100 * a.off:g} %, noise x{a.noise:g}, calibrated on "
          f"{a.calibrations} recordings of {n} samples")
    print()
    print("| sensor | statistic | allowance (mean) | measured std across calibrations | ratio |")
    print("|---|---|---|---|---|")
    for j, y in enumerate(outputs):
        for s, name in enumerate(("mean", "variance")):
            measured = math.sqrt(max(float(np.var(left[:, j, s], ddof=1)) - own[s], 0.0))
            allowance = float(np.mean(allowed[:, j, s]))
            print(f"| {y} | {name} | {allowance:.3f} | {measured:.3f} | {measured / allowance:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
