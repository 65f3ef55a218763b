"""How close the nominal observer's normalised residuals are to N(0, 1):
the detector's false-alarm bound assumes they are.

    .venv/bin/python bench/residual_calibration.py [--runs 60] [--particles 1000]

Fault-free runs of each plant at its own noise (seeds 5000, 5001, ...: the
same as the false-alarm rows of bench/diagnosis_accuracy.py). Per plant: the
variance of z (1 when the observer's predicted std is right), the variance of
the detector's window statistics S_8 and S_32 (1 when, in addition, the
residuals are white), the lag-1 autocorrelation, and the tail probability at
the detector's threshold c that these variances imply, against the N(0, 1)
one the threshold is set from: their ratio is roughly how far above its
target the false-alarm rate can go.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from statistics import NormalDist

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402
from bgc.runtime.diagnose import DiagnosisOptions  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=60)
    ap.add_argument("--particles", type=int, default=1000)
    args = ap.parse_args()
    print(f"{args.runs} fault-free runs per plant, GPF with {args.particles} particles\n")
    print("| plant | var z | var S_8 | var S_32 | lag-1 corr | threshold c | P(|S_32| > c) / P(|Z| > c) | alarms |")
    print("|---|---|---|---|---|---|---|---|")
    for model in ("ro", "circuit", "two_tank"):
        zs, alarms, c = [], 0, None
        for i in range(args.runs):
            d = bgc.diagnose(ROOT / "models" / f"{model}.yaml", scenario="none", seed=5000 + i,
                             generated=ROOT / "generated",
                             options=DiagnosisOptions(seed=5000 + i, particles=args.particles, workers=1)).diagnosis
            zs.append(np.nan_to_num(d.nominal_z))
            alarms += d.detection is not None
            c = d.threshold
        z = np.array(zs)  # runs x steps x sensors
        cs = np.cumsum(z, axis=1)
        s8 = (cs[:, 8:] - cs[:, :-8]) / np.sqrt(8)
        s32 = (cs[:, 32:] - cs[:, :-32]) / np.sqrt(32)
        lag1 = float((z[:, 1:] * z[:, :-1]).mean() / (z * z).mean())
        tail = (lambda v: 2 * (1 - NormalDist().cdf(c / np.sqrt(v))))
        print(f"| {model} | {z.var():.3f} | {s8.var():.3f} | {s32.var():.3f} | {lag1:.3f} | {c:.2f} | "
              f"{tail(s32.var()) / tail(1.0):.2f} | {alarms}/{args.runs} |", flush=True)


if __name__ == "__main__":
    main()
