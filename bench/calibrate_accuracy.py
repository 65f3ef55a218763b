"""How close `bgc calibrate`'s estimates come to the truth, how often their
95 % intervals cover it, and (plants linear in their states) whether they
are the maximum of the exact Kalman likelihood (docs/calibrate.md,
"Measured").

    .venv/bin/python bench/calibrate_accuracy.py PLANT[:PARAMETER] [PLANT[:PARAMETER] ...]
        [--steps 1000] [--seeds 20] [--offset 1.1] [--workers 2] [--exact] [--jsonl FILE]
    .venv/bin/python bench/calibrate_accuracy.py PLANT[:PARAMETER] ... --summary FILE

The issue's campaign (five plants, 20 seeds, 1000 samples, about 40 minutes
on two cores):

    .venv/bin/python bench/calibrate_accuracy.py models/two_tank.yaml:R12 models/circuit.yaml:R2 \\
        models/ro.yaml:R_pipe tests/data/models/mass_spring_damper.yaml:c \\
        tests/data/models/orifice_tanks.yaml:cd --seeds 20 --exact --workers 2

For each plant, fault-free runs simulated by the truth simulator (RK4, 8
times finer than the filters) at the model file's values and noise levels,
seeds 100, 101, ...; each is calibrated with ``--estimate noise,PARAMETER``
(``noise`` alone when no parameter is named) from a model whose PARAMETER is
``--offset`` times the plant's (the user's guess, 10 % off by default), so
the truth is the plant's and the start is not.

**Exact reference** (``--exact``, plants linear in their states: checked at
random states, or the plant is skipped). A Kalman filter written here (not
bgc's cubature filter): the transition ``x' = F x + b(u) + w`` and the
reading ``y = H x + c(u) + v`` read off the generated ``predict`` and
``observe`` at 0 and the unit vectors, ``w ~ N(0, diag(PROCESS_STD^2))``,
``v ~ N(0, diag(MEASUREMENT_STD^2))``, the prior ``N(X0, diag(X0_STD^2))``,
the noise at each point of the search set as bgc sets it
(``_Likelihood.module``: the level's shape over the states). Its likelihood
is maximised from the model's own values by SciPy's BFGS, then Newton steps
with its own finite-difference Hessian until a step is under 1e-10; the
largest relative difference between that maximum and bgc's estimates is
printed (the issue's target: 1e-6), and the two log-likelihoods at bgc's
estimates (they are the same function: the cubature rule is exact for a
linear map).

Prints each run, then per plant and estimate: the mean and rms relative
error (a sensor's std, the process level, the parameter), the largest, the
rms relative half-width of the 95 % intervals (what the data allow: an
estimator that is efficient has an rms error about half-width / 1.96), how
many intervals cover the truth; and the seconds per calibration.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import yaml

import bgc
from bgc.analysis import calibrate as cal
from bgc.data import runs
from bgc.analysis import simulate


def offset_model(path: str, parameter: str | None, factor: float, folder: str) -> str:
    """A copy of the model file ``path`` in ``folder`` with ``parameter``'s
    value times ``factor`` (the model itself when none is named)."""
    if not parameter or factor == 1.0:
        return path
    data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    entry = data["parameters"][parameter]
    if isinstance(entry, dict):
        entry["value"] = float(entry["value"]) * factor
    else:
        data["parameters"][parameter] = float(entry) * factor
    out = Path(folder) / f"{Path(path).stem}_{parameter}_x{factor:g}.yaml"
    out.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return str(out)


def job(args: tuple) -> dict:
    """Calibrate one seed of one plant; the exact reference when asked."""
    plant, parameter, fit_path, steps, seed, exact = args
    truth = bgc.open(plant)
    fit = bgc.open(fit_path)
    settings = truth.compiled.model.settings
    result = simulate.simulate(truth.compiled.numerics, simulate.SimulationOptions(steps=steps, seed=seed))
    run = runs.parse_run(simulate.to_csv(result), f"seed {seed}")
    estimate = "noise" + (f",{parameter}" if parameter else "")
    start = time.perf_counter()
    c = fit.calibrate(run, estimate).calibration
    seconds = time.perf_counter() - start
    nominal = truth.package.MODELS["nominal"]
    stds = dict(zip(nominal.OUTPUTS, np.asarray(nominal.MEASUREMENT_STD, dtype=float)))
    values = {p.name: p.value for p in truth.compiled.model.parameters}
    rows = []
    for e in c.estimates:
        true = {"parameter": lambda: values[e.subject], "process_noise": lambda: settings.process_noise,
                "measurement_noise": lambda: stds[e.subject]}[e.kind]()
        rows.append({"name": e.name, "value": e.value, "true": true, "low": e.low, "high": e.high,
                     "identifiable": e.identifiable})
    out = {"plant": plant, "seed": seed, "rows": rows, "seconds": seconds, "loglik": c.loglik}
    if exact:
        out["exact"] = exact_check(fit, run, c, parameter)
    return out


# ------------------------------------------------------------------------------ the exact Kalman reference
def _affine(f, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Matrix and offset of the affine map ``f`` (columns in, columns out) from its values at 0 and the unit vectors."""
    v = np.asarray(f(np.hstack([np.zeros((n, 1)), np.eye(n)])), dtype=float)
    return v[:, 1:] - v[:, :1], v[:, 0]


def is_linear(module) -> bool:
    """Whether ``predict`` and ``observe`` are affine in the states (at random states)."""
    n = len(module.STATES)
    rng = np.random.default_rng(0)
    x0 = np.asarray(module.X0, dtype=float)
    xs = x0[:, None] + (np.abs(x0)[:, None] + 1.0) * 0.3 * rng.standard_normal((n, 8))
    u = np.asarray(module.inputs(0.0), dtype=float)
    for f in (lambda x: module.predict(x, u, module.THETA, module.DT), lambda x: module.observe(x, u, module.THETA)):
        a, b = _affine(f, n)
        if not np.allclose(f(xs), a @ xs + b[:, None], rtol=1e-8, atol=1e-10):
            return False
    return True


def exact_loglik(module, records) -> float:
    """The Kalman filter's log-likelihood of ``records`` (bgc's Record: ys (T, n_y), NaN not read; us (T, n_u))."""
    n = len(module.STATES)
    q = np.asarray(module.PROCESS_STD, dtype=float) ** 2
    r = np.asarray(module.MEASUREMENT_STD, dtype=float) ** 2
    total = 0.0
    maps: dict[bytes, tuple] = {}
    for rec in records:
        m = np.asarray(module.X0, dtype=float).copy()
        P = np.diag(np.asarray(module.X0_STD, dtype=float) ** 2)
        for y, u in zip(rec.ys, rec.us):
            key = u.tobytes()
            if key not in maps:
                F, b = _affine(lambda x: module.predict(x, u, module.THETA, module.DT), n)
                H, c = _affine(lambda x: module.observe(x, u, module.THETA), n)
                maps[key] = (F, b, H, c)
            F, b, H, c = maps[key]
            m = F @ m + b
            P = F @ P @ F.T + np.diag(q)
            seen = np.isfinite(y)
            if not seen.any():
                continue
            Hs = H[seen]
            S = Hs @ P @ Hs.T + np.diag(r[seen])
            v = y[seen] - (Hs @ m + c[seen])
            L = np.linalg.cholesky(S)
            a = np.linalg.solve(L, v)
            total += -0.5 * (a @ a) - np.log(np.diag(L)).sum() - 0.5 * len(v) * math.log(2 * math.pi)
            K = np.linalg.solve(S, Hs @ P).T
            m = m + K @ v
            P = P - K @ Hs @ P
            P = 0.5 * (P + P.T)
    return float(total)


def exact_check(fit, run, c, parameter: str | None) -> dict:
    """The exact Kalman likelihood's maximum, found here from the model's
    values, against bgc's estimates ``c``: the largest relative difference
    of the estimates, and the two log-likelihoods at bgc's."""
    from scipy.optimize import minimize

    compiled = fit.compiled
    module = fit.package.MODELS["nominal"]
    if not is_linear(module):
        return {"skipped": "not linear in its states"}
    record = cal.record_of(runs.check_run(run), module)
    held = {e.name for e in c.estimates if not e.identifiable}
    sensors = [s for s in module.OUTPUTS if f"noise {s}" not in held]
    zero = c.estimate("process noise").value == 0  # the data show none: held at 0, as bgc holds it
    process = "process noise" not in held and not zero
    params = [parameter] if parameter and parameter not in held else []
    lik = cal._Likelihood(module, compiled.numerics, [record], sensors, process, params, 0.0 if zero else None)
    neg = lambda z: -exact_loglik(lik.module(z), [record])  # noqa: E731
    z = minimize(neg, lik.start(), method="BFGS", options={"gtol": 1e-8, "maxiter": 500}).x
    h = 1e-4 * np.maximum(1.0, np.abs(z))
    for _ in range(20):  # Newton steps on the reference's own finite-difference derivatives
        f0 = neg(z)
        g, H = cal._hessian(neg, z, h, f0)
        step = -np.linalg.solve(H, g)
        z = z + step
        if np.max(np.abs(step)) < 1e-10:
            break
    sigma, level, theta = lik.values(z)
    ref = {f"noise {s}": sigma[list(module.OUTPUTS).index(s)] for s in sensors}
    if process:
        ref["process noise"] = level
    for p in params:
        ref[p] = theta[list(module.PARAMETERS).index(p)]
    differences = {name: abs(c.estimate(name).value / v - 1) for name, v in ref.items()}
    bgc_z = np.array([math.log(c.estimate(f"noise {s}").value) for s in sensors]
                     + ([math.log(c.estimate("process noise").value)] if process else [])
                     + [math.log(abs(c.estimate(p).value)) for p in params])
    return {"largest": max(differences.values()), "worst": max(differences, key=differences.get),
            "exact_at_bgc": -neg(bgc_z), "bgc_loglik": c.loglik}


# ------------------------------------------------------------------------------------------------- report
def report(plant: str, results: list[dict], steps: int, offset: float, parameter: str | None) -> None:
    print(f"\n{plant}, {steps} samples, --estimate noise{',' + parameter if parameter else ''}"
          + (f" from {parameter} x {offset:g}" if parameter else "") + f", {len(results)} seeds")
    print("| estimate | mean error | rms error | largest | rms half-width of the 95 % interval | covers |")
    print("|---|---|---|---|---|---|")
    names = [row["name"] for row in results[0]["rows"]]
    for name in names:
        rows = [row for r in results for row in r["rows"] if row["name"] == name]
        told = [row for row in rows if row["identifiable"]]
        if not told:
            print(f"| {name} | not identifiable in {len(rows)} of {len(rows)} runs | | | | |")
            continue
        err = np.array([row["value"] / row["true"] - 1 for row in told])
        half = np.array([(row["high"] - row["low"]) / 2 / row["true"] for row in told])
        cover = sum(1 for row in told if row["low"] < row["true"] < row["high"])
        held = len(rows) - len(told)
        print(f"| {name} | {100 * err.mean():+.2f} % | {100 * np.sqrt((err ** 2).mean()):.2f} % | "
              f"{100 * np.abs(err).max():.1f} % | {100 * np.sqrt((half ** 2).mean()):.2f} % | {cover}/{len(told)}"
              + (f" ({held} not identifiable)" if held else "") + " |")
    exact = [r["exact"] for r in results if "exact" in r]
    if exact and "skipped" in exact[0]:
        print(f"exact Kalman reference: skipped ({exact[0]['skipped']})")
    elif exact:
        largest = max(e["largest"] for e in exact)
        worst = max(exact, key=lambda e: e["largest"])["worst"]
        gap = max(abs(e["exact_at_bgc"] - e["bgc_loglik"]) for e in exact)
        print(f"exact Kalman reference: largest relative difference from its maximum {largest:.1e} ({worst}); "
              f"log-likelihoods at bgc's estimates differ by at most {gap:.1e}")
    seconds = [r["seconds"] for r in results]
    print(f"seconds per calibration: mean {np.mean(seconds):.1f}, {np.min(seconds):.1f} to {np.max(seconds):.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("plants", nargs="+", metavar="PLANT[:PARAMETER]")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--offset", type=float, default=1.1, help="the fitted model's parameter over the plant's")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--exact", action="store_true", help="the exact Kalman reference (linear plants)")
    parser.add_argument("--jsonl", default=None, metavar="FILE",
                        help="also append each run's result to FILE as a JSON line (--summary FILE reads them back)")
    parser.add_argument("--summary", default=None, metavar="FILE",
                        help="print the tables of the runs in FILE (written by --jsonl) and stop")
    args = parser.parse_args()
    if args.summary:
        results: dict[str, list[dict]] = {}
        for line in Path(args.summary).read_text(encoding="utf-8").splitlines():
            r = json.loads(line)
            results.setdefault(r["plant"], []).append(r)
        for item in args.plants:
            plant, _, parameter = item.partition(":")
            if plant in results:
                report(plant, sorted(results[plant], key=lambda r: r["seed"]), args.steps, args.offset,
                       parameter or None)
        return
    print("command: .venv/bin/python " + " ".join(sys.argv), flush=True)
    with tempfile.TemporaryDirectory(prefix="bgc-calibrate-bench-") as folder:
        plans = []
        for item in args.plants:
            plant, _, parameter = item.partition(":")
            plans.append((plant, parameter or None, offset_model(plant, parameter or None, args.offset, folder)))
        jobs = [(plant, parameter, fit, args.steps, seed, args.exact)  # seed by seed: a cut run stays balanced
                for seed in range(100, 100 + args.seeds) for plant, parameter, fit in plans]
        results: dict[str, list[dict]] = {}
        start = time.perf_counter()
        with ProcessPoolExecutor(args.workers) as pool:
            for done, r in enumerate(pool.map(job, jobs), 1):
                results.setdefault(r["plant"], []).append(r)
                if args.jsonl:
                    with open(args.jsonl, "a", encoding="utf-8") as f:
                        f.write(json.dumps(r, default=float) + "\n")
                ex = r.get("exact", {})
                print(f"[{done}/{len(jobs)}] {r['plant']} seed {r['seed']}: "
                      + ", ".join(f"{row['name']} {row['value']:.4g}" + ("" if row["identifiable"] else " (held)")
                                  for row in r["rows"])
                      + (f"; exact {ex['largest']:.1e}" if "largest" in ex else "")
                      + f" ({r['seconds']:.1f} s)", flush=True)
        for plant, parameter, _ in plans:
            report(plant, results[plant], args.steps, args.offset, parameter)
        print(f"\n{len(jobs)} calibrations in {time.perf_counter() - start:.0f} s on {args.workers} processes")


if __name__ == "__main__":
    main()
