"""How often can any diagnoser name the right fault? bgc's isolation over the
sweep against the exact Bayes classifier on the same data.

    .venv/bin/python bench/isolation_reference.py [--runs out/sweep/runs.csv] [--groups circuit,two_tank]
                                                  [--limit N] [--magnitudes 24] [--workers 2]

Reads the rows of a finished sweep (``bgc experiment experiments/sweep.yaml -o
out/sweep``), re-simulates the data of every faulty scenario and noise level
that bgc detected (the same seeds: the same data), and computes the posterior
of every fault hypothesis exactly, under the distribution the sweep draws its
faults from (``draws`` in its config): each (parameter, kind) of the model's
pool equally likely, a direction its candidate allows, a change uniform in
the ``change`` range (a drift's slope: that change per run length), an onset
uniform over the samples of the ``onset`` range. The plants it takes are
linear in their states once the fault's parameter is fixed (checked), so a
Kalman filter gives p(y | hypothesis, onset, magnitude) exactly; a grid of
``--magnitudes`` magnitudes times every onset sample gives p(y | hypothesis)
by quadrature. The most probable (parameter, kind) is the Bayes classifier:
no diagnoser, knowing how the faults were drawn, names the right fault more
often on these runs. Printed per model, fault kind and noise level:

- runs: faulty runs bgc's GPF or APF detected;
- Bayes right: the share whose most probable hypothesis is the truth (the
  best accuracy the data allow); mean P(truth): the truth's posterior
  probability; decisive: the share whose truth has posterior >= 0.99;
- bgc right (GPF, APF): the share of its detected runs whose best hypothesis
  is the truth, as the sweep counts it (``right``); both right / only Bayes /
  only bgc: agreement run by run (GPF).

The Kalman filters are written here (batched over the grid in numpy), not
bgc's filters; the matrices are read off the committed generated model's (generated/) ``predict``
and ``observe`` at the unit vectors, with the fault state set to the grid
point's value at that step (a step change from its onset sample, a ramp from
its onset evaluated continuously inside the step, as the simulator does).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from functools import lru_cache
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bgc import pipeline  # noqa: E402
from bgc.kinds import DIRECTIONS, fault_kind  # noqa: E402
from bgc.data import runs
from bgc.analysis import simulate
from bgc.model import package as packages  # noqa: E402
from bgc.analysis import track


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", default=str(ROOT / "out" / "sweep" / "runs.csv"), help="the sweep's runs.csv")
    parser.add_argument("--config", default=str(ROOT / "experiments" / "sweep.yaml"))
    parser.add_argument("--groups", default="circuit,two_tank")
    parser.add_argument("--limit", type=int, default=0, help="at most this many scenarios per group (0: all)")
    parser.add_argument("--magnitudes", type=int, default=24, help="magnitudes on each hypothesis's grid")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    path = Path(args.runs)
    if not path.is_file():
        sys.exit(f"{path}: no such file; run: bgc experiment experiments/sweep.yaml -o out/sweep")
    config = yaml.safe_load(Path(args.config).read_text(encoding="utf-8"))
    draws = {g["name"]: g["draws"] for g in config["groups"] if "draws" in g}
    with path.open(encoding="utf-8") as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    groups = args.groups.split(",")
    by_data: dict[tuple, dict[str, dict]] = defaultdict(dict)  # (group, scenario, noise) -> filter -> row
    for r in rows:
        if r["group"] in groups and r["fault"] and r["status"] == "ok":
            by_data[(r["group"], r["scenario"], r["noise"])][r["filter"]] = r
    jobs = []
    for key, filters in by_data.items():
        if not any(r["detected"] == "true" for r in filters.values()):
            continue
        r = next(iter(filters.values()))
        jobs.append((key, str(ROOT / r["model"]), r, draws[r["group"]], args.magnitudes))
    if args.limit:  # the first --limit of each group
        seen: dict[str, int] = defaultdict(int)
        kept = []
        for j in jobs:
            seen[j[0][0]] += 1
            if seen[j[0][0]] <= args.limit:
                kept.append(j)
        jobs = kept
    print(f"exact Bayes classifier on {len(jobs)} detected scenarios x noise levels of {path} "
          f"({args.magnitudes} magnitudes x every onset sample per hypothesis)", flush=True)
    started = time.perf_counter()
    results = {}
    from tqdm import tqdm

    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for key, res in tqdm(zip([j[0] for j in jobs], pool.map(reference, jobs)), total=len(jobs),
                             desc="reference", unit="run", file=sys.stderr):
            results[key] = res
    print(f"{time.perf_counter() - started:.0f} s", flush=True)
    report(results, by_data)


def reference(job) -> dict:
    """The exact posterior of every (parameter, kind) on one run's data."""
    key, model, row, draws, n_mag = job
    c = _compiled(model)
    pn = float(row["process_noise"]) if row["process_noise"] else None
    mn = float(row["measurement_noise"]) if row["measurement_noise"] else None
    levels = c.numerics.noise_at(pn, mn)
    package = packages.load_package(ROOT / "generated", c.model.name, model,
                                 levels if (pn, mn) != (None, None) else None)
    inj = simulate.parse_fault(row["scenario"], c.numerics)
    result = simulate.simulate(c.numerics, simulate.SimulationOptions(
        steps=int(row["steps"]), process_noise=pn, measurement_noise=mn, seed=int(row["seed"]), fault=inj))
    run = runs.parse_run(simulate.to_csv(result), row["scenario"])
    ys, us = track.run_arrays(run, package, "nominal")
    steps = len(ys)
    dt = c.model.settings.dt
    duration = steps * dt
    lo, hi = draws["change"]
    o_lo, o_hi = draws["onset"]
    onsets = np.arange(min(max(round(o_lo * steps), 1), steps - 1), min(max(round(o_hi * steps), 1), steps - 1) + 1)
    changes = lo + (hi - lo) * (np.arange(n_mag) + 0.5) / n_mag  # midpoints: quadrature of the uniform prior
    nominal = package.MODELS["nominal"]
    candidates = {f.parameter: f for f in c.model.faults}
    pool = [(p, k) for p in candidates for k in candidates[p].kinds]
    logpost = {}
    for p, k in pool:
        module = package.MODELS[f"{p}_{k}"]
        _checked_affine(module, nominal, us[0], dt, len(nominal.STATES))
        p0 = float(dict(zip(module.PARAMETERS, module.THETA))[p])
        signs = DIRECTIONS[candidates[p].direction]
        terms = []
        for sign in signs:
            size = sign * changes * abs(p0)
            mags = size / duration if fault_kind(k).drifts else size
            ll = kalman_grid(module, nominal, ys, us, dt, onsets, mags, fault_kind(k).drifts, p0)
            terms.append(np.logaddexp.reduce(ll) - math.log(len(ll) * len(signs)))  # the grid's mean
        logpost[f"{p}_{k}"] = float(np.logaddexp.reduce(terms)) - math.log(len(pool))
    names = list(logpost)
    lp = np.array([logpost[n] for n in names])
    post = np.exp(lp - lp.max())
    post /= post.sum()
    return {"posterior": dict(zip(names, post.tolist())), "truth": f"{row['fault']}_{row['kind']}"}


@lru_cache(maxsize=None)
def _compiled(model: str) -> pipeline.Compiled:
    """The model compiled once per process (its equations, for the simulator;
    its filters are the committed ones in generated/)."""
    return pipeline.compile_model(model)


def kalman_grid(module, nominal, ys, us, dt, onsets, mags, drifts: bool, p0: float) -> np.ndarray:
    """log p(y | onset, magnitude) for every onset sample x magnitude (flattened),
    by Kalman filters batched over the grid. The physical states are the
    first ``n`` of ``module``'s; its fault states (a bias; or the parameter
    and its slope) are held at each grid point's values."""
    n = len(nominal.STATES)
    n_f = len(module.STATES) - n
    n_y = ys.shape[1]
    onset_of = np.repeat(onsets, len(mags))  # grid point -> onset sample
    mag_of = np.tile(mags, len(onsets))
    G = len(onset_of)
    q = np.asarray(module.PROCESS_STD[:n], dtype=float) ** 2
    r = np.diag(np.asarray(module.MEASUREMENT_STD, dtype=float) ** 2)
    theta = module.THETA
    basis = np.hstack([np.zeros((n, 1)), np.eye(n)])  # n x (n+1)
    # the shared nominal prefix: one filter up to the first onset
    m = np.asarray(nominal.X0, dtype=float).copy()
    P = np.diag(np.asarray(nominal.X0_STD, dtype=float) ** 2)
    ll0 = 0.0
    first = int(onsets.min())
    for k in range(first):
        a, b = _affine(nominal.predict(basis.copy(), us[k], nominal.THETA, dt))
        h, c = _affine(nominal.observe(basis.copy(), us[k], nominal.THETA))
        m, P, inc = _kf_step(a[None], b[None], h[None], c[None], m[None], P[None], q, r, ys[k])
        m, P = m[0], P[0]
        ll0 += float(inc[0])
    m = np.repeat(m[None], G, axis=0)
    P = np.repeat(P[None], G, axis=0)
    ll = np.full(G, ll0)
    cols = np.zeros((n + n_f, G, n + 1))
    cols[:n] = basis[:, None, :]
    for k in range(first, len(ys)):
        on = k >= onset_of  # the integration interval [k dt, (k+1) dt] starts at or after the onset
        if drifts:  # the parameter at the interval's start and its slope
            cols[n] = np.where(on, p0 + mag_of * (k - onset_of) * dt, p0)[:, None]
            cols[n + 1] = np.where(on, mag_of, 0.0)[:, None]
        else:
            cols[n] = np.where(on, mag_of, 0.0)[:, None]
        flat = cols.reshape(n + n_f, G * (n + 1))
        after = module.predict(flat, us[k], theta, dt).reshape(n + n_f, G, n + 1)
        a, b = _affine(after[:n].transpose(1, 0, 2))  # (G, n, n), (G, n)
        seen = after.copy()
        seen[:n] = basis[:, None, :]
        y = module.observe(seen.reshape(n + n_f, G * (n + 1)), us[k], theta).reshape(n_y, G, n + 1)
        h, c = _affine(y.transpose(1, 0, 2))
        m, P, inc = _kf_step(a, b, h, c, m, P, q, r, ys[k])
        ll += inc
    return ll


def _affine(v: np.ndarray):
    """Matrix and offset of an affine map from its values at 0 and the unit vectors (last axis)."""
    off = v[..., 0]
    return v[..., 1:] - off[..., None], off


def _checked_affine(module, nominal, u, dt, n) -> None:
    """The reference rests on linearity in the states for a fixed fault: check
    it at random states, with the fault state away from nominal."""
    rng = np.random.default_rng(0)
    p0 = abs(float(dict(zip(module.PARAMETERS, module.THETA))[module.FAULT["parameter"]]))
    fault = [0.1 * p0] if len(module.STATES) == n + 1 else [1.1 * p0, 0.01 * p0]
    xs = np.asarray(nominal.X0, dtype=float)[:, None] * (1 + 0.3 * rng.standard_normal((n, 8)))
    basis = np.hstack([np.zeros((n, 1)), np.eye(n)])
    with_fault = (lambda x: np.vstack([x, np.tile(np.array(fault)[:, None], x.shape[1])]))
    for f in (lambda x: module.predict(with_fault(x), u, module.THETA, dt)[:n],
              lambda x: module.observe(with_fault(x), u, module.THETA)):
        a, b = _affine(f(basis))
        if not np.allclose(f(xs), a @ xs + b[:, None], rtol=1e-9, atol=1e-12):
            raise SystemExit(f"{module.NAME}: not linear in its states for a fixed fault; the Kalman reference "
                             "needs that")


def _kf_step(a, b, h, c, m, P, q, r, y):
    """One predict-update of G Kalman filters: returns m, P and log p(y_k | y_<k)."""
    m = np.einsum("gij,gj->gi", a, m) + b
    P = a @ P @ a.transpose(0, 2, 1)
    P[:, np.arange(len(q)), np.arange(len(q))] += q
    ht = h.transpose(0, 2, 1)
    S = h @ P @ ht + r
    v = y[None, :] - (np.einsum("gij,gj->gi", h, m) + c)
    Sinv = np.linalg.inv(S)
    _, logdet = np.linalg.slogdet(S)
    inc = -0.5 * (np.einsum("gi,gij,gj->g", v, Sinv, v) + logdet + len(y) * math.log(2 * math.pi))
    K = P @ ht @ Sinv
    m = m + np.einsum("gij,gj->gi", K, v)
    P = P - K @ h @ P
    P = 0.5 * (P + P.transpose(0, 2, 1))
    return m, P, inc


def report(results: dict, by_data: dict) -> None:
    cells: dict[tuple, dict] = defaultdict(lambda: defaultdict(float))
    for key, res in results.items():
        group, _, noise = key
        filters = by_data[key]
        truth = res["truth"]
        post = res["posterior"]
        kind = truth.rsplit("_", 1)[1]
        best = max(post, key=post.get)
        for cell in ((group, kind, noise), (group, kind, "all"), (group, "all", "all")):
            s = cells[cell]
            s["runs"] += 1
            s["bayes"] += best == truth
            s["p_truth"] += post.get(truth, 0.0)
            s["decisive"] += post.get(truth, 0.0) >= 0.99
            for f in ("gpf", "apf"):
                row = filters.get(f)
                if row is not None and row["detected"] == "true":
                    s[f"{f}_n"] += 1
                    s[f"{f}_right"] += row["right"] == "true"
                    s[f"{f}_bayes"] += best == truth
            g = filters.get("gpf")
            if g is not None and g["detected"] == "true":
                s["both"] += (best == truth) and g["right"] == "true"
                s["only_bayes"] += (best == truth) and g["right"] != "true"
                s["only_bgc"] += (best != truth) and g["right"] == "true"
    print()
    print("| model | kind | noise | runs | Bayes right | mean P(truth) | decisive | bgc GPF right (Bayes on its runs) "
          "| bgc APF right (Bayes on its runs) | both right / only Bayes / only bgc (GPF) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    pct = (lambda a, b: f"{100 * a / b:.0f} %" if b else "-")
    for (group, kind, noise), s in sorted(cells.items(), key=lambda kv: (kv[0][0], kv[0][1] == "all", kv[0][1],
                                                                         kv[0][2] == "all", kv[0][2])):
        n = s["runs"]
        print(f"| {group} | {kind} | {noise} | {n:.0f} | {pct(s['bayes'], n)} | {s['p_truth'] / n:.2f} | "
              f"{pct(s['decisive'], n)} | {pct(s['gpf_right'], s['gpf_n'])} ({pct(s['gpf_bayes'], s['gpf_n'])}) | "
              f"{pct(s['apf_right'], s['apf_n'])} ({pct(s['apf_bayes'], s['apf_n'])}) | "
              f"{s['both']:.0f} / {s['only_bayes']:.0f} / {s['only_bgc']:.0f} |")


if __name__ == "__main__":
    main()
