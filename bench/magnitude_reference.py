"""How well can the magnitude of an RO fault (the slope of R_pipe's drift, the
bias of its step, P_memb's sensor bias or drift) be known from the data? bgc's estimate against
an exact-in-the-limit reference on the same data.

    .venv/bin/python bench/magnitude_reference.py [--kind incipient|abrupt|sensor-bias|sensor-drift] [--seeds 5]
                                                  [--first-seed 100]
                                                  [--particles 1000] [--method gpf|apf] [--ref-particles 2000]

The RO plant is not linear in its states, so the reference is a grid posterior
computed with marginal likelihoods from particle filters (the pseudo-marginal
idea of PMMH, Andrieu, Doucet and Holenstein 2010, evaluated on a grid instead
of by MCMC): for every onset tau and magnitude c (slope or bias) of a grid, a bootstrap
particle filter with ``--ref-particles`` particles and both fixed gives an
unbiased estimate of p(y_1:T | tau, c); the nominal filter up to tau is shared
by every c. With a flat prior on the grid, p(c | y) is proportional to sum over
tau of p(y | tau, c). Its mean and std are what the data allow; bgc's estimate
(its own onset search and a magnitude state with Liu-West moves) is compared with it
run by run, and so is bgc's optional refinement (``--refine``:
:mod:`bgc.diagnosis.identify`, the same idea on a small grid around the
filter's interval).

The sensor faults (``--kind sensor-bias|sensor-drift``, P_memb's) enter the
same way: the fault model's augmented state is the sensor's offset (and its
slope), held at the grid's value, so the bootstrap filters weigh the readings
against h(x) plus that offset.

The reference filter is written here (a plain bootstrap filter with
systematic resampling on the generated model's ``transition`` and
``loglik``), not bgc's filter loop. Scenarios (``--kind``), those of the RO
rows of ``bench/diagnosis_accuracy.py``: the thesis's R_pipe incipient fault,
slope 0.5 from t = 165, or its abrupt fault, 69 -> 100 (bias 31) at t = 165;
model noise levels, seeds 100, 101, ... With ``--first-seed 0 --seeds 10
--particles 200`` the data and bgc's diagnoses are those of the thesis
tables' campaign (``experiments/thesis_tables.yaml``: seeds 0 to 9, 200
particles, the model's noise levels), so its slope row of Table IV.4 (per
filter, ``--method``) can be set against what its own ten data sets allow.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402
from bgc.model import package as packages  # noqa: E402
from bgc.analysis import track
from bgc.diagnosis.options import DiagnosisOptions

ONSET = 165.0
#: kind -> (what fails, its fault kind, fault model, true magnitude, reference grid of onsets (steps; dt = 1,
#: run time t = step + 1), of magnitudes): a drift's onset and slope trade off (a wide onset grid); a step's
#: onset is sharp. The sensor faults are P_memb's: a bias of 3 measurement stds (21.82, the campaign
#: experiments/sensor_faults.yaml's detection-delay case, whose onset is less sharp than a large step's),
#: and a drift of 0.3 per unit time (40.5 by the end of the run, 5.6 stds).
KINDS = {
    "incipient": ("R_pipe", "incipient", "R_pipe_incipient", 0.5, list(range(145, 186, 3)),
                  np.round(np.arange(0.30, 0.701, 0.02), 4)),
    "abrupt": ("R_pipe", "abrupt", "R_pipe_abrupt", 31.0, list(range(162, 169)),
               np.round(np.arange(25.0, 37.01, 0.25), 4)),
    "sensor-bias": ("P_memb", "bias", "P_memb_offset_bias", 21.82, list(range(158, 172, 1)),
                    np.round(np.arange(17.0, 26.61, 0.3), 4)),
    "sensor-drift": ("P_memb", "drift", "P_memb_offset_drift", 0.3, list(range(145, 186, 3)),
                     np.round(np.arange(0.15, 0.451, 0.01), 4)),
}


def logsumexp(a: np.ndarray) -> float:
    m = float(np.max(a))
    return m + math.log(float(np.sum(np.exp(a - m))))


def resample(x: np.ndarray, logw: np.ndarray, rng) -> np.ndarray:
    w = np.exp(logw - logw.max())
    w /= w.sum()
    n = len(w)
    positions = (rng.random() + np.arange(n)) / n
    idx = np.minimum(np.searchsorted(np.cumsum(w), positions), n - 1)
    return x[:, idx]


def bootstrap(model, x, ys, us, rng, fix=None) -> tuple[float, np.ndarray]:
    """log p(ys | start cloud x) by a bootstrap filter; ``fix`` (row, value)
    holds a state at a value (the fixed slope). Returns it and the final cloud."""
    theta = model.THETA
    total = 0.0
    for k in range(len(ys)):
        model.transition(x, us[k], theta, model.DT, rng, out=x)
        if fix is not None:
            x[fix[0]] = fix[1]
        ll = model.loglik(ys[k], x, us[k], theta)
        total += logsumexp(ll) - math.log(x.shape[1])
        x = resample(x, ll, rng)
    return total, x


def reference(package, fault_model: str, run, taus, slopes, n: int, seed: int) -> np.ndarray:
    """log p(y | tau, c) on the grid (rows: taus, columns: magnitudes)."""
    ys, us = track.run_arrays(run, package, "nominal")
    nominal = package.MODELS["nominal"]
    fault = package.MODELS[fault_model]
    rng = np.random.default_rng([seed, 77])
    out = np.empty((len(taus), len(slopes)))
    x = nominal.initial_particles(rng, n)
    done, ll0 = 0, 0.0
    row = len(fault.STATES) - 1
    for i, tau in enumerate(taus):  # the nominal filter advanced to each onset in turn
        part, x = bootstrap(nominal, x, ys[done:tau], us[done:tau], rng)
        ll0 += part
        done = tau
        for j, c in enumerate(slopes):
            xf = fault.augment(x.copy(), rng)
            # the fault changes R_pipe at the onset sample's instant: the transition into it is nominal (0),
            # then the state is held at c: the drift (R_pipe advances by c per step from the onset), or the bias
            xf[row] = 0.0
            part, _ = bootstrap(fault, xf, ys[tau:], us[tau:], rng, fix=(row, c))
            out[i, j] = ll0 + part
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kind", choices=sorted(KINDS), default="incipient")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--particles", type=int, default=1000, help="bgc diagnose's particles")
    ap.add_argument("--method", choices=["gpf", "apf"], default="gpf", help="bgc diagnose's filter")
    ap.add_argument("--ref-particles", type=int, default=2000)
    args = ap.parse_args()
    package = packages.load_package(ROOT / "generated", "ro", "models/ro.yaml")
    subject, kind, name, truth, taus, values = KINDS[args.kind]
    what, whats = ("slope", "slopes") if kind in ("incipient", "drift") else ("bias", "biases")
    scenario = f"{subject}:{kind}:{truth:g}@{ONSET:g}"
    print(f"{scenario} ({subject} {kind}, {what} {truth:g} from t = {ONSET:g}); reference grid: onsets "
          f"{taus[0]}..{taus[-1]} step {taus[1] - taus[0]}, {whats} {values[0]:g}..{values[-1]:g} step "
          f"{values[1] - values[0]:g}, {args.ref_particles} particles per filter\n")
    print("| seed | bgc estimate | bgc 95 % interval | bgc error % | bgc --refine | its interval | its error % | "
          "reference mean | reference sd | reference error % | reference s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    errors, refined, ref_errors, ref_sds, t_plain, t_refine = [], [], [], [], [], []
    for i in range(args.seeds):
        seed = args.first_seed + i
        r = bgc.diagnose(ROOT / "models" / "ro.yaml", scenario=scenario, seed=seed, generated=ROOT / "generated",
                         options=DiagnosisOptions(method=args.method, particles=args.particles, seed=seed))
        e = r.diagnosis.estimate
        t_plain.append(r.diagnosis.seconds)
        g = bgc.diagnose(ROOT / "models" / "ro.yaml", data=r.run, generated=ROOT / "generated",
                         options=DiagnosisOptions(method=args.method, particles=args.particles, seed=seed,
                                                  refine=True)).diagnosis
        t_refine.append(g.seconds)
        g_right = g.candidates[:1] == (name,)
        refined.append(abs(g.estimate.value - truth) / truth if g_right else float("nan"))
        started = time.perf_counter()
        ll = reference(package, name, r.run, taus, values, args.ref_particles, seed)
        seconds = time.perf_counter() - started
        post = np.exp(ll - ll.max()).sum(axis=0)
        post /= post.sum()
        if max(post[0], post[-1]) > 0.01:
            print(f"(seed {seed}: the reference posterior reaches the end of its grid: {post[0]:.3f}, {post[-1]:.3f})")
        mean = float(post @ values)
        sd = math.sqrt(float(post @ (values - mean) ** 2))
        right = r.diagnosis.candidates[:1] == (name,)
        err = abs(e.value - truth) / truth if right else float("nan")
        errors.append(err)
        ref_errors.append(abs(mean - truth) / truth)
        ref_sds.append(sd)
        ge = g.estimate
        print(f"| {seed} | {e.value:.3f}{'' if right else ' (wrong fault)'} | [{e.low:.3f}, {e.high:.3f}] | "
              f"{100 * err:.1f} | {ge.value:.3f}{'' if g_right else ' (wrong fault)'} | [{ge.low:.3f}, {ge.high:.3f}] | "
              f"{100 * refined[-1]:.1f} | {mean:.3f} | {sd:.3f} | {100 * ref_errors[-1]:.1f} | {seconds:.0f} |")
    print(f"\nmean error: bgc {100 * np.nanmean(errors):.1f} %, bgc --refine {100 * np.nanmean(refined):.1f} %, "
          f"reference {100 * np.mean(ref_errors):.1f} %; reference posterior sd {np.mean(ref_sds):.3f} "
          f"({100 * np.mean(ref_sds) / truth:.1f} % of the {what})")
    # An estimator whose error is N(0, sd^2), sd the exact posterior's, is off by sd sqrt(2 / pi) on average:
    # the mean error the data allow, which the reference's own error (a few seeds) estimates noisily.
    print(f"mean error the data allow (posterior sd x sqrt(2 / pi)): "
          f"{100 * math.sqrt(2 / math.pi) * np.mean(ref_sds) / truth:.1f} %")
    print(f"diagnosis seconds (2 processes, simulation excluded): bgc {np.mean(t_plain):.2f}, "
          f"bgc --refine {np.mean(t_refine):.2f}")


if __name__ == "__main__":
    main()
