"""How close the nominal observer's normalised residuals are to N(0, 1):
the detector's false-alarm bound assumes they are.

    .venv/bin/python bench/residual_calibration.py [--runs 60] [--particles 1000] [--kalman-runs 500]

Fault-free runs of each plant at its own noise (seeds 5000, 5001, ...: the
same as the false-alarm rows of bench/diagnosis_accuracy.py). Per plant: the
variance of z (1 when the observer's predicted std is right), the variance of
the detector's window statistics S_8 and S_32 (1 when, in addition, the
residuals are white), the lag-1 autocorrelation, and the tail probability at
the detector's threshold c that these variances imply, against the N(0, 1)
one the threshold is set from: their ratio is roughly how far above its
target the false-alarm rate can go.

Then, on the circuit (linear, so a Kalman filter is its exact observer), where
the false alarms come from: ``--kalman-runs`` fault-free runs (seeds 5000,
...) seen by the detector through white N(0, 1) residuals, the exact Kalman
filter's, and the generated GPF's and APF's at N = 1000 without and with the
detector's Monte Carlo allowance (bgc.diagnosis.detect, module docstring).
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
from bgc import pipeline  # noqa: E402
from bgc.analysis import simulate
from bgc.model import package as track  # noqa: E402
from bgc.diagnosis.detect import Detector, DetectorOptions, monte_carlo_share  # noqa: E402
from bgc.diagnosis.options import DiagnosisOptions


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=60)
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--kalman-runs", type=int, default=500)
    args = ap.parse_args()
    if args.kalman_runs:
        sources(args.kalman_runs, args.particles)
    if not args.runs:
        return
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


def kalman(model, ys: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The exact one-step predictions (mean, std) of ys for a model whose
    predict and observe are affine (A, b, H, c read off at 0 and the unit
    vectors): x_k = A x_k-1 + b + w, y_k = H x_k + c + v."""
    n = len(model.STATES)
    basis = np.hstack([np.zeros((n, 1)), np.eye(n)])
    step = model.predict(basis, u, model.THETA, model.DT)
    b, a = step[:, 0], step[:, 1:] - step[:, :1]
    obs = model.observe(basis, u, model.THETA)
    c, h = obs[:, 0], obs[:, 1:] - obs[:, :1]
    q, r = np.diag(model.PROCESS_STD ** 2), np.diag(model.MEASUREMENT_STD ** 2)
    m, p = model.X0.copy(), np.diag(model.X0_STD ** 2)
    means, stds = np.empty_like(ys), np.empty_like(ys)
    for k, y in enumerate(ys):
        m, p = a @ m + b, a @ p @ a.T + q
        s = h @ p @ h.T + r
        gain = np.linalg.solve(s, h @ p).T
        means[k], stds[k] = h @ m + c, np.sqrt(np.diag(s))
        m = m + gain @ (y - h @ m - c)
        p = (np.eye(n) - gain @ h) @ p
    return means, stds


def alarms(z: np.ndarray, mc: np.ndarray | None = None) -> bool:
    det = Detector(tuple(map(str, range(z.shape[1]))), DetectorOptions(steps=len(z)))
    return any(det.update(z[k], None if mc is None else mc[k]) is not None for k in range(len(z)))


def sources(runs: int, particles: int) -> None:
    compiled = pipeline.compile_model(ROOT / "models" / "circuit.yaml")
    package = track.load_package(ROOT / "generated", "circuit")
    model = package.MODELS["nominal"]
    u = model.inputs(0.0)
    rng = np.random.default_rng(1)
    count = {"white N(0, 1)": 0, "Kalman filter (exact)": 0}
    for name in ("GPF", "APF"):
        count[f"{name}, no allowance"] = count[f"{name}, with the allowance"] = 0
    shares = {"GPF": [], "APF": []}
    for i in range(runs):
        run = simulate.simulate(compiled.numerics, simulate.SimulationOptions(seed=5000 + i))
        ys = run.measurements
        count["white N(0, 1)"] += alarms(rng.standard_normal(ys.shape))
        mean, std = kalman(model, ys, u)
        count["Kalman filter (exact)"] += alarms((ys - mean) / std)
        for name, cls in (("GPF", package.filters.GenericParticleFilter),
                          ("APF", package.filters.AuxiliaryParticleFilter)):
            out = cls(model, particles, np.random.default_rng(5000 + i)).run(ys, np.tile(u, (len(ys), 1)))
            z = (ys - out.y_mean) / out.y_std
            ess = np.concatenate([[particles], out.ess[:-1]])  # of the weights that made each prediction
            mc = monte_carlo_share(out.y_std, model.MEASUREMENT_STD, ess[:, None], particles)
            shares[name].append(mc.mean())
            count[f"{name}, no allowance"] += alarms(z)
            count[f"{name}, with the allowance"] += alarms(z, mc)
    print(f"Circuit, {runs} fault-free runs (seeds 5000, ...), detector at 1 % per run, N = {particles}\n")
    print("| residuals | runs with an alarm | rate |")
    print("|---|---|---|")
    for name, n in count.items():
        print(f"| {name} | {n}/{runs} | {100 * n / runs:.1f} % |")
    print(f"\nmean Monte Carlo share a_k: GPF {np.mean(shares['GPF']):.3f}, APF {np.mean(shares['APF']):.3f}\n")


if __name__ == "__main__":
    main()
