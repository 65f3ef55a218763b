"""Observers of a plant whose sensor is sharp against the process noise: the
drivetrain test plant (tests/data/models/drivetrain.yaml), fault-free.

    .venv/bin/python bench/sharp_sensor.py [--seeds 8] [--filter-seeds 3]

The shaft torque is measured to 0.17 N m, while one step of the speeds'
process noise moves the next step's torque by several N m. Per data seed
(1, 2, ...; the model's own noise) and particle count: the generated generic
filter's (GPF) and locally optimal proposal's (OPF) mean effective sample
size, and how many of ``--filter-seeds`` OPF runs lost the state (some
normalised residual beyond 10); then the nominal cubature Kalman filter
(``bgc diagnose --filter ckf``'s observer; the Kalman filter of this linear
plant): the variance of its normalised residuals per sensor (1 when its
predicted std is right) and their largest lag-1 autocorrelation (0 when they
are white).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


from bgc.api import folders as api_folders
from bgc.filters import cubature as kalman
from bgc.data import runs
from bgc.analysis import simulate
from bgc.model import package as packages  # noqa: E402
from bgc.analysis import track

LOST = 10.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--filter-seeds", type=int, default=3)
    args = ap.parse_args()
    c, private = api_folders._compiled(ROOT / "tests" / "data" / "models" / "drivetrain.yaml")
    package = packages.load_package(private, "drivetrain")
    nominal = package.nominal
    print("| data seed | N | GPF mean ESS | OPF mean ESS | OPF runs that lost the state | CKF var(z) per sensor "
          "| CKF largest lag-1 autocorrelation |")
    print("|---|---|---|---|---|---|---|")
    lost_total = {1000: 0, 2000: 0}
    for seed in range(1, args.seeds + 1):
        result = simulate.simulate(c.numerics, simulate.SimulationOptions(seed=seed))
        ys, us = track.run_arrays(runs.parse_run(simulate.to_csv(result), "none"), package, "nominal")
        z = kalman.nominal_track(nominal, ys, us, len(ys)).z[10:]
        var = " ".join(f"{v:.2f}" for v in z.var(axis=0))
        lag = max(abs(np.corrcoef(z[:-1, j], z[1:, j])[0, 1]) for j in range(z.shape[1]))
        for n in (1000, 2000):
            gpf = package.filters.GenericParticleFilter(nominal, n, np.random.default_rng([0, seed])).run(ys, us)
            ess, lost = [], 0
            for f in range(1, args.filter_seeds + 1):
                with np.errstate(all="ignore"):
                    opf = package.filters.OptimalProposalParticleFilter(nominal, n,
                                                                        np.random.default_rng([f, seed])).run(ys, us)
                    zo = (ys - opf.y_mean) / opf.y_std
                ess.append(opf.ess.mean())
                lost += int(not np.all(np.abs(zo) < LOST))
            lost_total[n] += lost
            print(f"| {seed} | {n} | {gpf.ess.mean():.0f} | {np.mean(ess):.0f} | {lost} of {args.filter_seeds} "
                  f"| {var} | {lag:.3f} |")
    for n, lost in lost_total.items():
        print(f"\nN = {n}: the OPF lost the state in {lost} of {args.seeds * args.filter_seeds} runs")


if __name__ == "__main__":
    main()
