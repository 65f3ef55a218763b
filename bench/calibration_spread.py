"""What a calibration's own uncertainty leaves on fresh data's residuals,
against calibrations made again (issue 48: after calibration, fresh healthy
data say "no fault").

``bgc calibrate`` writes, per sensor, the standard deviation its noise
estimates' uncertainty leaves on the variance of the calibrated model's
normalised residuals on other data (``residual_variance_sd``: the delta
method through the inverse Hessian, bgc.analysis.calibrate._spread), and
the diagnosis's test of the model's fit adds it to the variance's standard
error in quadrature. This checks them against what they predict: one plant (the circuit
off its model file, tests/test_mismatch.py's ``plant_csv(.., seed, --off,
--noise)``), calibrated ``--calibrations`` times, each time on another
healthy recording of it (``noise`` and the six parameters, what the
mismatch verdict tells the user to run); each calibrated model filters the
same ``--fresh`` other recordings, and the mean over them of each sensor's
residual variance is what that calibration leaves (the fresh recordings
are the same for every calibration: their own sampling error is common to
all, not a spread between them). Its standard deviation across the
calibrations is the truth the allowance's average is compared with; the
mean of it, less 1, is how much wider fresh residuals are than the
calibrated model predicts (the calibration fitted its recording's noise:
about the number of estimates over the samples, shared by the sensors).

    .venv/bin/python bench/calibration_spread.py --calibrations 12

Prints a table per sensor: the allowance (mean over the calibrations), the
standard deviation measured across them, their ratio, and the fresh
recordings' variance averaged over every calibration.
"""

from __future__ import annotations

import argparse
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
            allowed.append([nominal.RESIDUAL_VARIANCE_SD.get(y, np.nan) for y in nominal.OUTPUTS])
            print(f"calibration {k + 1} of {a.calibrations}", file=sys.stderr, flush=True)
            outputs = nominal.OUTPUTS
    left, allowed = np.array(left)[:, :, 1], np.array(allowed)  # calibrations x sensors
    print(f"bench/calibration_spread.py --calibrations {a.calibrations} --fresh {a.fresh} --seed {a.seed}: "
          f"the circuit off its model by up to {100 * a.off:g} %, noise x{a.noise:g}, calibrated on "
          f"{a.calibrations} recordings of 300 samples, each filtering the same {a.fresh} fresh ones")
    print()
    print("| sensor | allowance (mean) | measured std across calibrations | ratio | fresh variance (mean) |")
    print("|---|---|---|---|---|")
    for j, y in enumerate(outputs):
        measured, allowance = float(np.std(left[:, j], ddof=1)), float(np.nanmean(allowed[:, j]))
        print(f"| {y} | {allowance:.3f} | {measured:.3f} | {measured / allowance:.2f} | {np.mean(left[:, j]):.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
