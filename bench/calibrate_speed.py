"""What evaluating a finite difference's points together saves a calibration
(`bgc calibrate` on the NumPy backend), measured side by side in one run.

    .venv/bin/python bench/calibrate_speed.py [--steps 300] [--seed 3]

For each case, fault-free data of the plant (`bgc simulate`, the model's
noise) calibrated twice in this process: the likelihood's points one at a
time (each difference point's nominal filter run alone, as before), and
together (:meth:`bgc.analysis.calibrate._Likelihood.many`: L-BFGS-B's value
with its forward differences, and the Hessian's and gradient's central
differences, one set of filters run side by side). Prints the seconds of
each, their ratio, the likelihood evaluations, and whether the two
calibrations' estimates and interval ends are the same to the bit (they
must be: the same numbers, in another order of work). The level plant
(docs/examples/level.yaml, a pump switched by its tank's pressure) is
calibrated without its mode column, the modes read from the measurements.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

import bgc  # noqa: E402
from bgc.analysis import calibrate as cal  # noqa: E402

CASES = [("models/two_tank.yaml", "noise,R12"), ("models/circuit.yaml", "noise,R2"),
         ("models/ro.yaml", "R_pipe"), ("docs/examples/level.yaml", "R_out")]


def _data(model: str, folder: Path, steps: int, seed: int) -> str:
    if model.endswith("level.yaml"):  # solve_ivp on the level plant's own equations, no mode column
        from hybrid_reference import level_csv, level_run

        times, modes, y_p, y_q, _ = level_run(4, fault=(0.0, "R_out", 1.65), steps=240)
        return str(level_csv(folder / "level.csv", times, modes, y_p, y_q, False))
    out = folder / (Path(model).stem + ".csv")
    subprocess.run([sys.executable, "-m", "bgc", "simulate", str(ROOT / model), "--steps", str(steps), "--seed",
                    str(seed), "-o", str(out)], check=True, capture_output=True)
    return str(out)


def _calibrate(session, data: str, estimate: str):
    start = time.perf_counter()
    c = session.calibrate(data, estimate).calibration
    numbers = [(e.name, e.value, e.low, e.high) for e in c.estimates]
    return time.perf_counter() - start, c.evaluations, numbers


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    print(f"bench/calibrate_speed.py --steps {args.steps} --seed {args.seed}")
    print(f"{'model':<28} {'estimate':<10} {'alone s':>8} {'together s':>10} {'ratio':>6} {'evaluations':>12}  same")
    with tempfile.TemporaryDirectory() as folder:
        for model, estimate in CASES:
            data = _data(model, Path(folder), args.steps, args.seed)
            session = bgc.open(ROOT / model, backend="numpy")
            with mock.patch.object(cal._Likelihood, "many", None):  # one point at a time
                alone, n_alone, numbers_alone = _calibrate(session, data, estimate)
            together, n_together, numbers_together = _calibrate(session, data, estimate)
            same = numbers_alone == numbers_together and n_alone == n_together
            print(f"{model:<28} {estimate:<10} {alone:8.1f} {together:10.1f} {alone / together:6.2f} "
                  f"{n_together:12d}  {'yes' if same else 'NO'}", flush=True)
            if not same:
                print(f"  alone {numbers_alone}\n  together {numbers_together}")
                return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
