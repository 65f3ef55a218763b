"""The residuals' correlation across sensors, and what the pooled test
whitens it with (bgc.diagnosis.detect, "pooled"): on fault-free runs of each
shipped plant, the nominal observer's normalised residuals z_k and the
correlation matrix C_k it predicts for them before each step (the cubature
rule from its mean and covariance, bgc.filters.cubature._Filter.predicted_measurement)
are recorded from the diagnoser's detector. Per plant: the covariance of the
raw z (its off-diagonal entries: the correlation the pooled test must know)
and of the whitened L_k^-1 z_k (C_k = L_k L_k'), which is the identity when
C_k is right. The first 20 steps of each run are left out (the observer's
start from its prior).

    .venv/bin/python bench/residual_correlation.py [--runs 10] [--filter gpf]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import bgc  # noqa: E402
from bgc.diagnosis import detect  # noqa: E402


def recorded(model: str, runs: int, method: str) -> tuple[np.ndarray, np.ndarray, int, tuple[str, ...]]:
    """Raw and whitened residuals of ``runs`` fault-free runs (seeds 100, ...), the alarms seen, the sensors."""
    seen: list = []
    original = detect.Detector.update

    def spy(self, z, mc=None, y=None, spread=None, corr=None):
        seen.append((np.array(z, dtype=float), None if corr is None else np.array(corr, dtype=float)))
        return original(self, z, mc, y, spread, corr)

    detect.Detector.update = spy
    try:
        session = bgc.open(ROOT / model)
        raw, white, alarms = [], [], 0
        for i in range(runs):
            sim = bgc.simulate(session, "none", seed=100 + i)
            seen.clear()
            d = session.diagnoser(bgc.DiagnosisOptions(detectors=("mean", "pooled"), filter=method, seed=i,
                                                       workers=1))
            for k, t in enumerate(sim.time):
                u = {n: v[k] for n, v in sim.inputs.items()}
                if sim.modes is not None and "mode" in session.package.MODELS["nominal"].INPUTS:
                    u["mode"] = float(sim.modes[k])  # a controlled mode: the data say it
                belief = d.step(float(t), u, {n: v[k] for n, v in sim.measurements.items()})
                if belief.alarm is not None:
                    alarms += 1
                    break
            for z, c in seen[20:]:
                if c is None or not np.isfinite(z).all():
                    continue
                raw.append(z)
                white.append(np.linalg.solve(np.linalg.cholesky(c), z))
        return np.array(raw), np.array(white), alarms, tuple(session.package.MODELS["nominal"].OUTPUTS)
    finally:
        detect.Detector.update = original


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--filter", default="gpf", help="the nominal observer: gpf, apf, opf or ckf")
    args = p.parse_args(argv)
    print(f"bench/residual_correlation.py --runs {args.runs} --filter {args.filter}: fault-free runs, the "
          "residuals' covariance raw and whitened by the predicted correlation\n")
    print("| model | sensors | samples | alarms | raw: largest |off-diagonal| | whitened: diagonal | "
          "whitened: largest |off-diagonal| |")
    print("|---|---|---|---|---|---|---|")
    for model in ("models/circuit.yaml", "models/two_tank.yaml", "models/ro.yaml"):
        raw, white, alarms, outputs = recorded(model, args.runs, args.filter)
        r, w = np.corrcoef(raw.T), np.cov(white.T)
        off = ~np.eye(len(outputs), dtype=bool)
        print(f"| {Path(model).stem} | {', '.join(outputs)} | {len(raw)} | {alarms}/{args.runs} | "
              f"{np.abs(r[off]).max():.3f} | {np.diagonal(w).min():.3f} to {np.diagonal(w).max():.3f} | "
              f"{np.abs(w[off]).max():.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
